"""sagg_sim_bridge."""
