"""Preset drive TOMLs of the PLL test family."""
