"""The family contract type-checks: mypy over the contract (design/family.py, design/capabilities.py,
design/registry.py), the registered families' records, the shared modules typed throughout (``CHECKED``)
and every module of every registered family (the registry's list: their drive dataclass in every
signature, so the hook records' and the capabilities' types hold them to the contract; a new family is
held to it too).

One mypy run (settings: pyproject.toml [tool.mypy]) also checks two scratch files written here:
- ``conformance.py``: every registered family assigned to every capability Protocol it has at run time
  (``isinstance``), typed with its own drive dataclass: a family whose method signatures do not match
  the Protocol's (a runtime check sees only the names) fails here;
- ``offence.py``: a family that breaks the contract on purpose, which mypy must report (so the check
  can fail).

A census (an AST walk, no import of the modules) counts ``Any`` in the shared modules' annotations and
holds it to at most half of the 297 the contract's review found (``SHARED_ANY_MAX``).
"""

import ast
import importlib.util
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest
from sensorless.design import capabilities
from sensorless.design.registry import families

ROOT = Path(__file__).resolve().parents[2]
CAPABILITIES = [getattr(capabilities, name) for name in capabilities.__all__ if name != "require"]
CHECKED = [
    "sensorless.design.family",
    "sensorless.design.capabilities",
    "sensorless.design.registry",
    "sensorless.design.simulate",
    "sensorless.design.low_speed",
    "sensorless.design.startup_check",
    "sensorless.design.drive",
    "sensorless.design.pmsm_drive",
    "sensorless.reports.montecarlo",
    "sensorless.reports.tune_proof",
    # shared modules typed throughout (no Any where a real type exists)
    "sensorless.design.rotor_frame",
    "sensorless.design.memo",
    "sensorless.design.drive_analysis",
    "sensorless.design.poles",
    "sensorless.design.forked",
    "sensorless.design.discrete",
    "sensorless.design.runtime",
    "sensorless.tuning.conditions",
    "sensorless.design.envelope",
    "sensorless.reports.fixed_review",
    "sensorless.reports.time_domain",
    "sensorless.reports.document",
    "sensorless.reports.cli.analyze",
    "sensorless.reports.cli.export",
    "sensorless.reports.cli.montecarlo",
    "sensorless.reports.cli.tune",
    "sensorless.reports.cli.common",
    "sensorless.reports.options",
    "sensorless.reports.review",
    "sensorless.reports.gain_csv",
    "sensorless.reports.traces",
    "sensorless.reports.csv_cells",
    "sensorless.reports.interrupts",
    "sensorless.reports.sim_figure",
    "sensorless.reports.low_speed",
    "sensorless.reports.drive_analysis",
    "sensorless.reports.envelope_review",
]
OFFENCE = """
from collections.abc import Mapping
from typing import Any

from sensorless.design.capabilities import Linearizable
from sensorless.design.family import GainSet, ObserverFamily
from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive


class Wrong(ObserverFamily[IpmsmDrive]):
    def load(self, data: Mapping[str, Any], file: str, digest: str) -> IpmsmDrive:
        raise NotImplementedError

    def linearize(self, drive: IpmsmDrive, gains: GainSet) -> int:  # not the Protocol's signature
        return 0


wrong: Linearizable[IpmsmDrive] = Wrong()
"""


# ``Any`` in the annotations of the shared modules (every module of symbolic/, design/, tuning/ and
# reports/ outside a family's folder): 297 when the contract was reviewed; at most half of that now, each
# one where no real type exists (a parsed TOML table, a family's own options)
SHARED_ANY_MAX = 146


def _annotation_anys(path: Path) -> int:
    """The ``Any`` (``Any`` or ``typing.Any``) in the annotations of a module: its functions' parameters
    and returns, and its annotated assignments (fields, variables)."""

    def count(node: ast.AST | None) -> int:
        if node is None:
            return 0
        return sum(
            (isinstance(n, ast.Name) and n.id == "Any") or (isinstance(n, ast.Attribute) and n.attr == "Any")
            for n in ast.walk(node)
        )

    total = 0
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            a = node.args
            params = [*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg]
            total += sum(count(p.annotation) for p in params if p is not None) + count(node.returns)
        elif isinstance(node, ast.AnnAssign):
            total += count(node.annotation)
    return total


def shared_any() -> dict[str, int]:
    """Per shared module (path from the repository root), its annotations' ``Any``."""
    own = {fam.name for fam in families()}
    out = {}
    for layer in ("symbolic", "design", "tuning", "reports"):
        for path in sorted((ROOT / layer).rglob("*.py")):
            rel = path.relative_to(ROOT)
            if not own & set(rel.parts) and (n := _annotation_anys(path)):
                out[str(rel)] = n
    return out


def test_shared_modules_are_typed_with_few_any():
    found = shared_any()
    worst = sorted(found.items(), key=lambda kv: -kv[1])[:10]
    assert sum(found.values()) <= SHARED_ANY_MAX, f"{sum(found.values())} Any in shared annotations: {worst}"


def _drive_type(fam: object) -> type:
    """The drive dataclass a family states: the type argument of its ObserverFamily base."""
    for base in getattr(type(fam), "__orig_bases__", ()):
        if getattr(base, "__args__", None):
            return base.__args__[0]
    raise AssertionError(f"{fam!r} does not state its drive type (ObserverFamily[ItsDrive])")


def _typed_modules() -> list[str]:
    """Every module of every registered family: its design package and its hook packages (the family
    record names them), with all their submodules."""
    out = []
    for fam in families():
        for root in (type(fam).__module__, fam.tuning, fam.report):
            if root is None:
                continue
            pkg = importlib.import_module(root)
            out.append(root)
            out += [m.name for m in pkgutil.walk_packages(pkg.__path__, root + ".")]
    assert out, "no registered family"
    return out


def _conformance() -> str:
    lines = ["from sensorless.design import capabilities"]
    for i, fam in enumerate(families()):
        drive = _drive_type(fam)
        lines += [
            f"from {type(fam).__module__} import FAMILY as F{i}",
            f"from {drive.__module__} import {drive.__name__}",
        ]
        for cap in CAPABILITIES:
            if isinstance(fam, cap):
                arg = f"[{drive.__name__}]" if getattr(cap, "__parameters__", ()) else ""
                lines.append(f"c{i}_{cap.__name__}: capabilities.{cap.__name__}{arg} = F{i}")
    return "\n".join(lines) + "\n"


def test_the_contract_and_every_family_type_check(tmp_path):
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (pip install -e '.[test]')")
    # the package root is the repository (a PEP 420 namespace installed by a finder hook mypy does not
    # run): mypy finds it through a link named sensorless
    (tmp_path / "path").mkdir()
    (tmp_path / "path" / "sensorless").symlink_to(ROOT)
    (tmp_path / "path" / "conformance.py").write_text(_conformance())
    (tmp_path / "path" / "offence.py").write_text(OFFENCE)
    own = [type(f).__module__ for f in families()]
    modules = list(dict.fromkeys([*CHECKED, *own, *_typed_modules(), "conformance", "offence"]))
    cmd = [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml")]
    # no incremental cache written (mypy's documented /dev/null): a fresh run reads none, and writing
    # it was a tenth of the run's CPU
    cmd += ["--cache-dir", os.devnull, "--namespace-packages", "--explicit-package-bases"]
    cmd += [a for m in modules for a in ("-m", m)]
    env = {"MYPYPATH": str(tmp_path / "path"), "PATH": "/usr/bin:/bin"}
    run = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, env=env, check=False)
    out = run.stdout + run.stderr
    errors = [line for line in out.splitlines() if ": error:" in line]
    caught = [line for line in errors if "offence.py" in line.split(":")[0]]
    assert caught and "Linearizable" in caught[0], out  # the deliberate offence is reported
    assert [line for line in errors if line not in caught] == [], out
