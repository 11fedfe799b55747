"""Tuning: observer gains optimized over an operating envelope.

The shared global phase, max-min damping NLP and pointwise bound, and the families' tuning hooks.
"""
