"""Prefect flows and the ``dsnet`` command line."""
