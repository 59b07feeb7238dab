"""The package version (read by setuptools, the CLI and the exporters)."""

__version__ = "0.1.0"
