"""uav-console: the operator console server."""

__version__ = "0.1.0"
