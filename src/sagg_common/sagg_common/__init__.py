"""sagg_common."""
