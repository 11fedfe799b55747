"""The architecture holds: layers without cycles, families apart, shared code blind to families, one
registering module per drive kind, and no name taken from a paper's storage number.

The import contracts are checked by import-linter (PyPI ``import-linter``) on the installed package:
the layers contract of pyproject.toml, plus contracts generated here from the registry, so that a new
family is covered without editing any list.
"""

import ast
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


# --------------------------------------------------------------------------------------------------
# Shared code names no family's vocabulary
# --------------------------------------------------------------------------------------------------
# Words a family declares that are also the shared contract's own (checked by hand, each with why):
SHARED_WORDS = {
    "gain",  # the shared LoopSetup.gain / RuntimeSetup.gain and the traces' provenance line "gain"
}


def _module_path(module: str) -> Path:
    parts = module.split(".")[1:]
    path = ROOT.joinpath(*parts)
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def _names_used(path: Path) -> set[str]:
    """The identifiers a module uses as data or members: string constants that are whole words (not
    docstrings), attribute names, keyword-argument names and class-level field names."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    # format specs ("{x:g}") are not names; nor are the members of imported modules (tomllib.loads)
    skip = docstrings | {
        id(c)
        for node in ast.walk(tree)
        if isinstance(node, ast.FormattedValue) and node.format_spec
        for c in ast.walk(node.format_spec)
    }
    modules = {
        (a.asname or a.name).split(".")[0]
        for node in ast.walk(tree)
        if isinstance(node, ast.Import)
        for a in node.names
    }
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules:
            continue
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            word = node.value.lstrip("-").replace("-", "_")  # an option flag is its dest
            if word.isidentifier():
                out.add(word)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, ast.keyword) and node.arg:
            out.add(node.arg)
        elif isinstance(node, ast.ClassDef):
            out |= {
                s.target.id
                for s in node.body
                if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)
            }
    return out


def _fields(obj: object) -> set[str]:
    """Field names of a dataclass instance and of its dataclass sections, one level down."""
    import dataclasses

    out: set[str] = set()
    for f in dataclasses.fields(obj):
        out.add(f.name)
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            out |= {g.name for g in dataclasses.fields(v)}
    return out


def _shared_vocabulary() -> set[str]:
    """What the shared contract and the shared PMSM loop name themselves: the Drive Protocol and the
    family record's attributes, the PMSM loop's numbers, [control] section, fields and panels."""
    import dataclasses
    import inspect

    from sensorless.design import (
        envelope,
        family,
        linearization,
        motor_data,
        plausibility,
        pmsm_drive,
        pmsm_schema,
        runtime,
        scenario,
        simulate,
    )
    from sensorless.symbolic import pmac
    from sensorless.symbolic import pmsm_drive as loop
    from sensorless.symbolic import runtime as contract

    out = set(SHARED_WORDS)
    out |= set(family.Drive.__annotations__) | {n for n in vars(family.Drive) if not n.startswith("_")}
    out |= {n for n in vars(family.ObserverFamily) if not n.startswith("_")}
    shared_records = (
        pmsm_schema.PmsmMotor,
        motor_data.MotorData,  # the shared motor record read from datasheet terms
        pmsm_schema.PmsmEstimate,
        pmsm_schema.PmsmControl,
        envelope.Envelope,
        envelope.TuningSettings,
        family.DriveScales,
        family.Panel,
        simulate.LoopSetup,
        runtime.RuntimeSetup,
        scenario.Scenario,
        linearization.Linearization,
    )
    for cls in shared_records:
        out |= {f.name for f in dataclasses.fields(cls)}
    out |= (
        {k for keys in scenario._SCHEMA.values() for k in keys}
        | set(scenario._SCHEMA)
        | set(scenario._PROFILES)
    )
    out |= {
        f
        for cls in (pmac.EmfSeries, pmac.PmacParams, pmac.CurrentControlled, contract.Field)
        for f in cls._fields
    }
    # the shared plausibility check of a PMSM drive's rating and inverter: its keys are its own
    out |= set(inspect.signature(plausibility.plausibility).parameters)
    out |= set(pmsm_drive.ESTIMATE_KEYS) | {pmsm_drive.CURRENT_PANEL.name}
    # the shared [tuning] section's keys (the envelope every law is tuned over)
    out |= set(envelope._KEYS)
    out |= {
        f.name
        for group in (loop.LOOP_STATE, loop.INPUTS, loop.PARAMS, loop.RECORD, loop.MEAS_FIELDS)
        for f in group
    }
    return out


def _family_drive(fam) -> object:
    from importlib import resources

    from sensorless.design.drive import load_drive

    names = sorted(p.name[:-5] for p in resources.files(fam.presets).iterdir() if p.name.endswith(".toml"))
    return load_drive(names[0])


def _vocabulary(fam) -> dict[str, str]:
    """What ``fam`` declares (name -> what it is), without the shared contract's own words."""
    out: dict[str, str] = {}
    for law, keys in fam.laws.items():
        out[law.replace("-", "_")] = "gain law"  # as _names_used reads a string: "-" as "_"
        out.update({k: f"gain of law {law}" for k in keys})
    out.update({old.replace("-", "_"): "former law name" for old in fam.law_aliases})
    for section, keys in fam.scenario_options.items():
        out.update({k: f"scenario option [{section}]" for k in keys})
    out.update({k: "[estimate_scale] key" for k in fam.estimate_keys})
    out.update({p.name: "trace panel" for p in fam.panels})
    if fam.presets is not None:
        out.update({k: "drive field" for k in _fields(_family_drive(fam)) if k not in out})
    shared = _shared_vocabulary()
    # single letters (g, L, R, w) are the symbols of many equations, not a family's vocabulary
    return {k: v for k, v in out.items() if k not in shared and len(k) > 1}


def _with_test_family():
    sys.path.insert(0, str(ROOT / "tests"))
    from families.pll.design import FAMILY
    from sensorless.design.registry import registered

    return registered(FAMILY)


def _offences() -> dict[str, dict[str, set[str]]]:
    """Shared module (path) -> name -> the families that declare it."""
    out: dict[str, dict[str, set[str]]] = {}
    with _with_test_family():
        vocab = {fam.name: _vocabulary(fam) for fam in families()}
        assert "pmsm_pll" in vocab  # the test family is among them
        # what every family declares (the drive file's [motor], [control], [observer], ...) is the
        # drive files' common vocabulary, no one family's
        common = set.intersection(*(set(v) for v in vocab.values()))
        vocab = {
            fam: {w: what for w, what in words.items() if w not in common} for fam, words in vocab.items()
        }
        for module in _shared_modules():
            path = _module_path(module)
            used = _names_used(path)
            for fam, words in vocab.items():
                for word in used & set(words):
                    out.setdefault(str(path.relative_to(ROOT)), {}).setdefault(word, set()).add(fam)
    return out


def test_shared_modules_name_no_family_vocabulary():
    """No shared module names a family's gain laws, gains, scenario options, [estimate_scale] keys,
    trace panels or drive fields (string constants, attribute and keyword names; whole words), for
    every registered family and the test family."""
    found = _offences()
    assert not found, {p: {w: sorted(f) for w, f in names.items()} for p, names in found.items()}


def test_the_vocabulary_check_can_fail(tmp_path):
    """The check sees a family's word in a shared module, and not a word that merely contains it."""
    src = tmp_path / "m.py"
    src.write_text(
        '"""Doc: injection."""\nx = opts["injection"]\ny = s.w_eps\nf(law16=1)\nz = "injections"\n'
    )
    assert {"injection", "w_eps", "law16"} <= _names_used(src)
    assert "injections" in _names_used(src) and "Doc" not in _names_used(src)
    with _with_test_family():
        vocab = {w for fam in families() for w in _vocabulary(fam)}
    assert {"injection", "w_eps", "law16", "load_torque_estimation", "alpha_fo", "w_pll"} <= vocab


def _import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, from every import statement of its file (those in
    functions and under TYPE_CHECKING included: each is an edge of the file graph). ``from p import m``
    of a module m is an edge to m, not to p."""
    files = {}
    for layer in LAYERS:
        for path in (root / layer).rglob("*.py"):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            files["sensorless." + ".".join(parts)] = path
    graph: dict[str, set[str]] = {}
    for module, path in files.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names]
            else:
                continue
            deps |= {n for n in names if n in files and n != module}
        graph[module] = deps
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The import cycles: strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[frozenset[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_between_files():
    """No module imports, directly or through others, a module that imports it."""
    assert not [sorted(c) for c in _cycles(_import_graph(ROOT))]


def test_the_cycle_check_can_fail(tmp_path):
    """A synthetic cycle (one import inside a function, one under TYPE_CHECKING) is found, and a chain
    without a cycle is not."""
    for layer in LAYERS:
        (tmp_path / layer).mkdir()
        (tmp_path / layer / "__init__.py").write_text("")
    (tmp_path / "design" / "a.py").write_text("def f():\n    from sensorless.design import b\n")
    (tmp_path / "design" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from sensorless.design.c import X\n"
    )
    (tmp_path / "design" / "c.py").write_text("from . import a\nX = 1\n")
    (tmp_path / "reports" / "d.py").write_text("from sensorless.design import a\n")
    graph = _import_graph(tmp_path)
    assert graph["sensorless.design.c"] == {"sensorless.design.a"}
    assert _cycles(graph) == [
        frozenset({"sensorless.design.a", "sensorless.design.b", "sensorless.design.c"})
    ]
    (tmp_path / "design" / "c.py").write_text("X = 1\n")
    assert _cycles(_import_graph(tmp_path)) == []
