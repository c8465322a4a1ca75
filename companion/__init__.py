"""Cooperative multi-UAV target search: core algorithm, batch engine and companion process."""

__version__ = "0.1.0"
