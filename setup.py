"""Package discovery: the four card folders install as subpackages of the ``sensorless`` namespace.

pyproject.toml holds the metadata; this file only lists the packages, so that a new family's folders
(``symbolic/<family>/``, ``design/<family>/``, ...) are installed without editing any list.
"""

from setuptools import find_packages, setup

ROOTS = ("symbolic", "design", "tuning", "reports")

setup(
    packages=[f"sensorless.{r}" for r in ROOTS]
    + [f"sensorless.{r}.{p}" for r in ROOTS for p in find_packages(r)],
    package_dir={f"sensorless.{r}": r for r in ROOTS},
)
