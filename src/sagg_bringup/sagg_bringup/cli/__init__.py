"""The ``sagg`` command line: parser and dispatch."""
