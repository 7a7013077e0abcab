"""The ``sagg`` command line: parser and dispatch, and the ``sagg bench`` plug-ins other packages add."""
