"""Tuning: observer gains optimized over an operating envelope (the shared global phase, max-min damping NLP and pointwise bound, and the families' tuning hooks)."""
