"""Symbolic (CasADi SX) definitions of the motor models and observers: each paper equation once.

Everything downstream builds on these expressions: linearization, tuning, simulation and C generation
differentiate, compose or evaluate them as CasADi Functions, and where the design layer needs a
model's number (the rated point of a drive file in design/motor_data.py: MTPA current, steady stator
voltage) it evaluates them too. Only the tests type closed forms from the papers independently, to
check these expressions against.
"""
