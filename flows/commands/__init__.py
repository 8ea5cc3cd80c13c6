"""Bodies of the ``dsnet`` commands (registered in :mod:`flows.cli`)."""
