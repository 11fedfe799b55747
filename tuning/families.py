"""Registry of tunable gain families: which family can be tuned on which drive kind.

A family module registers a builder ``(drive, settings, seed) -> TuningModel`` for each drive kind it
supports (see tuning/family_paper000.py). A family may name a *seed family*: the tuner first tunes
the seed family and passes its tuned parameters as ``seed`` (e.g. the free schedule starts from the
tuned law (16), which it can represent exactly, so it can only improve on it); otherwise ``seed`` is
None. The families known to the gain-table format
(tuning/gain_table.py) are always listed, so asking for one that has no builder for the drive's kind
gives a clear error instead of an unknown-name error. Adding paper 002's ``deangelo`` family is one
module that calls :func:`register` and one line in ``FAMILY_MODULES``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import numpy as np
from sensorless.design.envelope import TuningSettings
from sensorless.tuning.model import TuningModel

Builder = Callable[[Any, TuningSettings, np.ndarray | None], TuningModel]

# family -> what it tunes (for help texts and errors)
DESCRIPTIONS: dict[str, str] = {
    "law16": "paper 000 eq. (16): lambda', omega_lambda (optionally alpha_fo)",
    "schedule": "free speed schedule: (lambda1, lambda2) at speed breakpoints, linear in between",
    "deangelo": "paper 002 reduced-order EMF/load-torque observer: g, Gamma",
}

# Modules that register builders when imported.
FAMILY_MODULES = ("sensorless.tuning.family_paper000", "sensorless.tuning.family_paper002")

_BUILDERS: dict[str, dict[str, Builder]] = {}
_SEEDS: dict[tuple[str, str], str] = {}  # (family, kind) -> seed family
# Families with a tuner of their own instead of a TuningModel for the generic NLP:
# (drive, settings or None, progress) -> a result with .table (GainTable) and .summary_lines().
Tuner = Callable[[Any, Any, Callable[[str], None] | None], Any]
_TUNERS: dict[tuple[str, str], Tuner] = {}


class FamilyError(ValueError):
    """A family was asked for on a drive kind that does not support it."""


def register(family: str, kind: str, builder: Builder, seed: str | None = None) -> None:
    """Register ``builder`` for ``family`` on drives of ``kind``; ``seed``: the family tuned first,
    whose parameters the builder receives."""
    if family not in DESCRIPTIONS:
        raise ValueError(f"family {family!r} has no description in DESCRIPTIONS")
    _BUILDERS.setdefault(family, {})[kind] = builder
    if seed is not None:
        _SEEDS[family, kind] = seed


def register_tuner(family: str, kind: str, tuner: Tuner) -> None:
    """Register a family's own tuner on drives of ``kind`` (for families the generic NLP of
    tuning/nlp.py does not fit; e.g. paper 002's, whose poles are Floquet exponents)."""
    if family not in DESCRIPTIONS:
        raise ValueError(f"family {family!r} has no description in DESCRIPTIONS")
    _TUNERS[family, kind] = tuner


def tuner_for(family: str, kind: str) -> Tuner | None:
    """The family's own tuner on ``kind``, if it has one."""
    _load()
    return _TUNERS.get((family, kind))


def seed_family(family: str, kind: str) -> str | None:
    """The family whose tuned parameters start ``family`` on ``kind`` (None: none)."""
    _load()
    return _SEEDS.get((family, kind))


def _load() -> None:
    for name in FAMILY_MODULES:
        importlib.import_module(name)


def families_for(kind: str) -> list[str]:
    """Families that can be tuned on drives of ``kind``."""
    _load()
    return [f for f in DESCRIPTIONS if kind in _BUILDERS.get(f, {}) or (f, kind) in _TUNERS]


def build_model(
    drive: Any, family: str, settings: TuningSettings, seed: np.ndarray | None = None
) -> TuningModel:
    """The TuningModel of ``family`` for ``drive`` (``seed``: the tuned parameters of its seed
    family, if it has one); FamilyError if the kind does not support it."""
    _load()
    if family not in DESCRIPTIONS:
        raise FamilyError(f"unknown family {family!r} (known: {', '.join(DESCRIPTIONS)})")
    builder = _BUILDERS.get(family, {}).get(drive.kind)
    if builder is None:
        kinds = sorted({*_BUILDERS.get(family, {}), *(k for f, k in _TUNERS if f == family)})
        here = ", ".join(families_for(drive.kind)) or "none"
        raise FamilyError(
            f"{drive.file}: family '{family}' ({DESCRIPTIONS[family]}) is not available for drive kind "
            f"'{drive.kind}'; it is available for: {', '.join(kinds) or 'no installed drive kind'}. "
            f"Families for '{drive.kind}': {here}"
        )
    return builder(drive, settings, seed)
