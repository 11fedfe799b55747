"""Report hooks of the flux observer + PLL family (placeholder until the family record lands).

firmware_io.py declares its firmware importers and exporters for the shared ``init --from`` and
``export`` commands; the family's ``HOOKS`` names them.
"""
