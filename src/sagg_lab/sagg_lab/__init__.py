"""Lab tools: benchmarks, soaks and figure scripts; never imported by the runtime nodes."""
