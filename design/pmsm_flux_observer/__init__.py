"""The flux observer + PLL family of motor firmware (placeholder until the family record lands).

The family record (``FAMILY``, its kind and hooks) is written on the family's own branch; this file
only makes the folder a package for its firmware formats (firmware/).
"""
