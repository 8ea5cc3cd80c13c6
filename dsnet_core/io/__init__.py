"""Readers and writers for the field's file formats."""
