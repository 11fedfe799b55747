"""A back-EMF PLL observer for non-salient PMSMs: a whole observer family defined in the test tree.

The acceptance test of the family architecture (design/family.py): this package is everything the
family has, one module per layer, mirroring the folders of the built-in families:

- symbolic.py: its equations (reduced-order back-EMF observer + PI-type PLL) and the runtime step
  (the one runtime contract, symbolic/runtime.py);
- design.py: drive-file schema, gains, runtime set-up, its observer in rotor coordinates for the shared
  linearizations, simulation on the shared PMSM drive loop, and the family record FAMILY;
- tuning.py: its gain law ``pll`` (one PLL bandwidth), a constant law of the shared tuning pipeline;
- report.py: the shared ``analyze`` output and stability report, and its law's ``tune`` option;
- presets/ and scenarios/: its drive TOML and its one built-in scenario.

Nothing outside this package names it: ``with registered(FAMILY):`` makes it known.
"""
