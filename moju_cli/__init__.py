"""The ``moju`` command line."""
