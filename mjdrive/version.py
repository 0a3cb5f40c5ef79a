"""The package's version (recorded in every episode log)."""

__version__ = "0.1.0"
