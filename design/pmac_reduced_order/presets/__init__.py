"""Preset drive files of the reduced-order observer family (package data)."""
