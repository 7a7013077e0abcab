"""sagg_lab: the measuring tools (benchmarks, soaks, diagnoses, figure scripts, the peer comparison).
Nothing of the product imports it; ``sagg bench`` finds its benchmarks as entry points."""
