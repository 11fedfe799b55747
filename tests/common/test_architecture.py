"""The architecture holds: layers without cycles, families apart, shared code blind to families, one
registering module per drive kind, and no name taken from a paper's storage number.

The import contracts are checked by import-linter (PyPI ``import-linter``) on the installed package:
the layers contract of pyproject.toml, plus contracts generated here from the registry, so that a new
family is covered without editing any list.
"""

import importlib.util
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest
from sensorless.design.registry import families

LAYERS = ("symbolic", "design", "tuning", "reports")
ROOT = Path(__file__).resolve().parents[2]


def _exists(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def _family_packages(name: str) -> list[str]:
    return [f"sensorless.{layer}.{name}" for layer in LAYERS if _exists(f"sensorless.{layer}.{name}")]


def _shared_modules() -> list[str]:
    """Every module of the four layers outside a family's folder."""
    names = {f.name for f in families()}
    out = []
    for layer in LAYERS:
        pkg = importlib.import_module(f"sensorless.{layer}")
        for info in pkgutil.walk_packages(pkg.__path__, f"sensorless.{layer}."):
            part = info.name.split(".")[2]
            if part not in names:
                out.append(info.name)
    return sorted(out)


def _config() -> str:
    fams = [f.name for f in families()]
    lines = [
        "[importlinter]",
        "root_packages =",
        *(f"    sensorless.{layer}" for layer in LAYERS),
        "",
        "[importlinter:contract:layers]",
        "name = layers: symbolic < design < tuning < reports",
        "type = layers",
        "layers =",
        *(f"    sensorless.{layer}" for layer in reversed(LAYERS)),
        "",
        "[importlinter:contract:shared]",
        "name = shared code reaches families only through the registry and the contracts",
        "type = forbidden",
        "source_modules =",
        *(f"    {m}" for m in _shared_modules()),
        "forbidden_modules =",
        *(f"    {m}" for name in fams for m in _family_packages(name)),
        "",
    ]
    for name in fams:
        others = [m for other in fams if other != name for m in _family_packages(other)]
        if not others:
            continue
        lines += [
            f"[importlinter:contract:family-{name}]",
            f"name = family {name} imports no other family",
            "type = forbidden",
            "source_modules =",
            *(f"    {m}" for m in _family_packages(name)),
            "forbidden_modules =",
            *(f"    {m}" for m in others),
            "",
        ]
    return "\n".join(lines)


def test_import_contracts_hold(tmp_path):
    """import-linter: the layers contract, shared code without family imports, families apart."""
    lint = Path(sys.executable).parent / "lint-imports"
    if not lint.is_file():
        pytest.skip("import-linter is not installed (pip install '.[test]')")
    cfg = tmp_path / "contracts.ini"
    cfg.write_text(_config())
    r = subprocess.run(
        [str(lint), "--config", str(cfg), "--no-cache"], capture_output=True, text=True, cwd=tmp_path
    )
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert "BROKEN" not in r.stdout and r.stdout.count("KEPT") >= 2 + len(families()) - 1


def test_the_contracts_can_fail(tmp_path):
    """The generated contracts are real: a forbidden import added to a copy of the config is caught."""
    lint = Path(sys.executable).parent / "lint-imports"
    if not lint.is_file():
        pytest.skip("import-linter is not installed (pip install '.[test]')")
    cfg = tmp_path / "contracts.ini"
    # reversing the layers makes every existing downward import a violation
    text = _config().replace(
        "    sensorless.reports\n    sensorless.tuning\n    sensorless.design\n    sensorless.symbolic",
        "    sensorless.symbolic\n    sensorless.design\n    sensorless.tuning\n    sensorless.reports",
    )
    cfg.write_text(text)
    r = subprocess.run(
        [str(lint), "--config", str(cfg), "--no-cache"], capture_output=True, text=True, cwd=tmp_path
    )
    assert r.returncode != 0 and "BROKEN" in r.stdout


def _package_sources() -> list[Path]:
    return sorted(p for layer in LAYERS for p in (ROOT / layer).rglob("*.py"))


def test_each_drive_kind_string_is_written_in_one_registering_module():
    """The registry is the only place that maps a kind to code: the kind string of each family
    appears in its registering module (design/<family>/__init__.py) and in no other module."""
    for fam in families():
        where = [p for p in _package_sources() if f'"{fam.kind}"' in p.read_text(encoding="utf-8")]
        assert where == [ROOT / "design" / fam.name / "__init__.py"], (fam.kind, where)


def test_no_name_is_a_paper_storage_number():
    """No file, module, function or scenario is named by a paper's file number (000, 002)."""
    tracked = subprocess.run(
        ["git", "ls-files"], capture_output=True, text=True, cwd=ROOT, check=False
    ).stdout.split()
    if not tracked:  # not a git checkout: walk the tree
        tracked = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if p.is_file() and ".git" not in p.parts]
    assert tracked
    bad = [f for f in tracked if re.search(r"(?<!\d)00[02](?!\d)", Path(f).name)]
    assert not bad, bad
    ident = re.compile(r"\b\w*(paper|drive|runtime|family|step)_?00[02]\w*\b", re.I)
    prose = re.compile(r"\bpaper[ -]?00[02]\b", re.I)
    for f in tracked:
        if f.endswith((".py", ".md", ".toml", ".j2", ".c", ".h")):
            text = (ROOT / f).read_text(encoding="utf-8", errors="replace")
            assert not ident.search(text) and not prose.search(text), (
                f,
                (ident.search(text) or prose.search(text)).group(),
            )
