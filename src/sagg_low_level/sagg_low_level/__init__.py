"""sagg_low_level."""
