"""sagg_bringup."""
