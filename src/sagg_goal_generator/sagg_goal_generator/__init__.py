"""sagg_goal_generator."""
