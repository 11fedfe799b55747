"""Symbolic (CasADi SX) definitions of the motor models and observers: each paper equation once.

Everything downstream (linearization in ``sensorless.design``, tuning, simulation, C generation)
builds on these expressions; nothing re-types an equation.
"""
