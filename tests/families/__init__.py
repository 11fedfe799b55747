"""Observer families defined in the test tree: proof that a family is added in one place.

``pll/`` is a complete third family (a back-EMF PLL observer for non-salient PMSMs) that registers
from here (``sensorless.design.registry.registered``) and runs through every command; see
tests/common/test_third_family.py.
"""
