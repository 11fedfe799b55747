"""Tuning: observer gain optimization and gain tables, and the ``sensorless`` command line."""
