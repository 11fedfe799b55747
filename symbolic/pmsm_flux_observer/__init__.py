"""Equations of the nonlinear flux observer + PLL that VESC, ODrive and SimpleFOC run (Lee et al. 2010).

observer.py: the gradient observer of Lee, Hong, Nam, Ortega, Praly, Astolfi (IEEE TPEL 2010), its
firmware variants (correction, inductance rule, online flux adaptation), the PI PLL, and the runtime
step of the one runtime contract (symbolic/runtime.py). Theory: docs/families/pmsm_flux_observer.md.
"""
