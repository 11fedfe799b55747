"""Preset drive files of the adaptive-observer family (package data)."""
