"""The architecture holds: layers without cycles, families apart, shared code blind to families, one
registering module per drive kind, and no name taken from a paper's storage number.

The import contracts are checked by import-linter (PyPI ``import-linter``) on the installed package:
the layers contract of pyproject.toml, plus contracts generated here from the registry, so that a new
family is covered without editing any list.
"""

import ast
import functools
import gc
import importlib.util
import pkgutil
import posixpath
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


CLI = "sensorless.reports.cli"


def _below_the_command_line() -> list[str]:
    """Every package and module of the four layers outside the command line (reports/cli/)."""
    out = [f"sensorless.{layer}" for layer in LAYERS if layer != "reports"]
    pkg = importlib.import_module("sensorless.reports")
    return out + sorted(
        info.name for info in pkgutil.iter_modules(pkg.__path__, "sensorless.reports.") if info.name != CLI
    )


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
        "[importlinter:contract:cli-on-top]",
        "name = the command line only parses: nothing else imports it (option types: reports/options.py)",
        "type = forbidden",
        "source_modules =",
        *(f"    {m}" for m in _below_the_command_line()),
        "forbidden_modules =",
        f"    {CLI}",
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
    assert "BROKEN" not in r.stdout and r.stdout.count("KEPT") >= 3 + len(families()) - 1


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


# the nodes :func:`_fold` can read a string from (a prefilter: the others, most nodes, skip the call)
FOLDABLE = (ast.Constant, ast.BinOp, ast.Call, ast.JoinedStr)


def _fold(node: ast.AST) -> str | None:
    """The string a expression always evaluates to, where the parser leaves it in pieces: a constant,
    a sum of such (``"pmsm_flux" + "_observer"``), an f-string of such, ``"".join`` of such, a
    %-format or ``str.format`` of such (numbers allowed as arguments); else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        a, b = _fold(node.left), _fold(node.right)
        return a + b if a is not None and b is not None else None
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mod) and (fmt := _fold(node.left)) is not None:
        args = _fold_args(node.right.elts if isinstance(node.right, ast.Tuple) else [node.right])
        return _formatted(lambda: fmt % tuple(args)) if args is not None else None
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "format"
        and not node.keywords
        and (fmt := _fold(node.func.value)) is not None
        and (args := _fold_args(node.args)) is not None
    ):
        return _formatted(lambda: fmt.format(*args))
    if isinstance(node, ast.JoinedStr):
        parts = [
            _fold(v.value) if isinstance(v, ast.FormattedValue) and v.format_spec is None else _fold(v)
            for v in node.values
        ]
        return "".join(parts) if all(x is not None for x in parts) else None  # type: ignore[arg-type]
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "join"
        and len(node.args) == 1
        and isinstance(node.args[0], ast.List | ast.Tuple)
        and (sep := _fold(node.func.value)) is not None
    ):
        parts = [_fold(e) for e in node.args[0].elts]
        return sep.join(parts) if all(x is not None for x in parts) else None  # type: ignore[arg-type]
    return None


def _fold_args(nodes: list[ast.expr]) -> list[object] | None:
    """The values of a format's arguments where each is a string as :func:`_fold` reads it or a number."""
    out: list[object] = []
    for a in nodes:
        if isinstance(a, ast.Constant) and isinstance(a.value, int | float) and not isinstance(a.value, bool):
            out.append(a.value)
        elif (s := _fold(a)) is not None:
            out.append(s)
        else:
            return None
    return out


def _formatted(make) -> str | None:
    try:
        return make()
    except (TypeError, ValueError, IndexError, KeyError):
        return None


def _docstrings(nodes: tuple[ast.AST, ...]) -> frozenset[int]:
    return frozenset(
        id(node.body[0].value)
        for node in nodes
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    )


@functools.cache
def _parsed(text: str) -> tuple[tuple[ast.AST, ...], frozenset[int]]:
    """A module's nodes (ast.walk's order) and its docstrings (node ids), once per source text: the
    checks below each read every shared module (the tree is kept alive by its nodes). The collector
    is off meanwhile: the trees are hundreds of thousands of objects, none of them garbage, and its
    passes over them while they were made were half of the parsing's time."""
    was = gc.isenabled()
    gc.disable()
    try:
        nodes = tuple(ast.walk(ast.parse(text)))
    finally:
        if was:
            gc.enable()
    return nodes, _docstrings(nodes)


@pytest.fixture(scope="module", autouse=True)
def _forget_the_trees():
    """The parsed modules are freed after this file's tests (each later collection on this worker
    would otherwise walk them again)."""
    yield
    _parsed.cache_clear()
    _file_strings.cache_clear()


def _source(path: Path, text: str | None = None) -> str:
    return path.read_text(encoding="utf-8") if text is None else text


def _strings(text: str) -> set[str]:
    """Every string value a module writes, however quoted or pieced together (docstrings left out)."""
    nodes, skip = _parsed(text)
    foldable = (node for node in nodes if isinstance(node, FOLDABLE) and id(node) not in skip)
    return {s for node in foldable if (s := _fold(node)) is not None}


@functools.cache
def _file_strings(path: Path) -> frozenset[str]:
    return frozenset(_strings(path.read_text(encoding="utf-8")))


def _kind_modules(kind: str, paths: list[Path]) -> list[Path]:
    """The modules among ``paths`` that write the drive kind string ``kind`` (any quoting, pieced
    together or not)."""
    return [p for p in paths if kind in _file_strings(p)]


def test_each_drive_kind_string_is_written_in_one_registering_module():
    """The registry is the only place that maps a kind to code: the kind string of each family
    appears in its registering module (design/<family>/__init__.py) and in no other module."""
    sources = _package_sources()
    for fam in families():
        assert _kind_modules(fam.kind, sources) == [ROOT / "design" / fam.name / "__init__.py"], fam.kind


def _tracked() -> list[str]:
    """The repository's files (git's list; the tree where this is not a git checkout)."""
    tracked = subprocess.run(
        ["git", "ls-files"], capture_output=True, text=True, cwd=ROOT, check=False
    ).stdout.split()
    if not tracked:  # not a git checkout: walk the tree
        tracked = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if p.is_file() and ".git" not in p.parts]
    assert tracked
    return tracked


def test_no_name_is_a_paper_storage_number():
    """No file, module, function or scenario is named by a paper's file number (000, 002)."""
    tracked = _tracked()
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


def test_no_issue_number_and_no_file_outside_the_repository_is_cited():
    """Code and docs stand on their own: no "issue 28" nor "the issue" (the tracker is not part of the
    repository) and no path into the workplace's shared folder (its facts are carried with their public
    sources)."""
    tracked = _tracked()
    issue = re.compile(r"\bissues? ?#?\d+|\b(the|this|that) issue\b", re.I)
    outside = re.compile(r"shared/(references|papers)/")
    here = str(Path(__file__).relative_to(ROOT))
    bad = []
    for f in tracked:
        if f != here and f.endswith((".py", ".md", ".toml", ".j2", ".c", ".h", ".txt", ".html")):
            text = (ROOT / f).read_text(encoding="utf-8", errors="replace")
            bad += [(f, m.group()) for m in (issue.search(text), outside.search(text)) if m]
            bad += [(f, name) for name in _missing_pages(f, text, tracked)]
    assert not bad, bad


# a Markdown page a text names (``docs/x.md``, ``../x.md``, ``x.md``): found by its ending, then read back
PAGE_END = re.compile(r"\.md\b")
PAGE_NAME = re.compile(r"[\w.-]+(?:/[\w.-]+)*$")


def _missing_pages(f: str, text: str, tracked: list[str]) -> list[str]:
    """The Markdown pages ``text`` (of the tracked file ``f``) names that the repository does not hold: a
    path from the root or from ``f``'s folder, or a page's name alone (a fact sheet outside the
    repository, cited by its name, is one). A web address and a quoted file name (a file a test writes:
    ``out / "x.md"``) are not citations."""
    pages = {t for t in tracked if t.endswith(".md")}
    tails = {p.split("/", k)[-1] for p in pages for k in range(p.count("/") + 1)}  # "families/x.md", ...
    out = []
    for m in PAGE_END.finditer(text):
        head = text[text.rfind("\n", 0, m.start()) + 1 : m.start()]
        if not (found := PAGE_NAME.search(head)):
            continue
        name, before = found.group() + ".md", head[: found.start()]
        if re.search(r"(https?://|github\.com/)\S*$", before) or before.endswith(("'", '"', "/")):
            continue
        near = posixpath.normpath(posixpath.join(posixpath.dirname(f), name))
        if not (name in tails or near in pages):
            out.append(name)
    return out


# --------------------------------------------------------------------------------------------------
# Shared code names no family's vocabulary
# --------------------------------------------------------------------------------------------------
# Words a family declares that are also the shared contract's own (checked by hand, each with why):
SHARED_WORDS = {
    "gain",  # the shared LoopSetup.gain / RuntimeSetup.gain and the traces' provenance line "gain"
    "min_damping",  # the shared damping floor (design/poles.py MIN_DAMPING; report/tune --min-damping)
    "f_s",  # the shared [inverter] sampling frequency that design/drive_file.py reads for every family
    "gain_set",  # the shared codegen/export --gain-set (one of a drive file's named gain sets)
    "base",  # the per-unit base of the shared commands (speed_base, a base record), a section of one family
}
# A local or parameter named as an equation's symbol (w_c, w_0, T_s: a letter, "_", one or two more)
# takes the equation's meaning, not a family's field of the same symbol
SYMBOL = re.compile(r"[A-Za-z]_[A-Za-z0-9]{1,2}")


def _module_path(module: str) -> Path:
    parts = module.split(".")[1:]
    path = ROOT.joinpath(*parts)
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def _names_used(path: Path, text: str | None = None) -> set[str]:
    """The identifiers a module uses as data, members or names of its own: string values that are whole
    words (not docstrings; pieced-together strings folded, any quoting), attribute names, keyword-argument
    names, class-level field names, and the names it binds (variables, parameters, functions, classes).
    ``text`` stands for the file's content (the self-tests inject offences into a copy)."""
    nodes, docstrings = _parsed(_source(path, text))
    # format specs ("{x:g}") are not names; nor are the members of imported modules (tomllib.loads)
    skip = docstrings | {
        id(c)
        for node in nodes
        if isinstance(node, ast.FormattedValue) and node.format_spec
        for c in ast.walk(node.format_spec)
    }
    modules = {
        (a.asname or a.name).split(".")[0]
        for node in nodes
        if isinstance(node, ast.Import)
        for a in node.names
    }
    out: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules:
            continue
        if isinstance(node, FOLDABLE) and id(node) not in skip and (value := _fold(node)) is not None:
            word = value.lstrip("-").replace("-", "_")  # an option flag is its dest
            if word.isidentifier():
                out.add(word)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, ast.keyword) and node.arg:
            out.add(node.arg)
        elif (isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store)) or isinstance(node, ast.arg):
            name = node.id if isinstance(node, ast.Name) else node.arg
            if not SYMBOL.fullmatch(name):
                out.add(name)
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            out.add(node.name)
        if isinstance(node, ast.ClassDef):
            out.add(node.name)
            out |= {
                s.target.id
                for s in node.body
                if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)
            }
    return out


def _family_references(path: Path, text: str | None = None) -> set[str]:
    """Where a module names a registered family itself (the test family included): an import of or a
    string naming one of its packages (``importlib.import_module("sensorless.design.<family>.x")``), its
    name or kind in a string however written or pieced together (``fam.name == 'pmsm_flux_observer'``),
    an attribute or variable of that name. Returns the offending names."""
    nodes, skip = _parsed(_source(path, text))
    idents = {f.name for f in families()} | {f.kind for f in families()}
    idents |= {i.replace("-", "_") for i in idents}
    out: set[str] = set()
    for node in nodes:
        words: list[str] = []
        if isinstance(node, ast.Import):
            words = [p for a in node.names for p in a.name.split(".")]
        elif isinstance(node, ast.ImportFrom):
            words = [*(node.module or "").split("."), *(a.name for a in node.names)]
        elif isinstance(node, ast.Attribute):
            words = [node.attr]
        elif isinstance(node, ast.Name):
            words = [node.id]
        elif isinstance(node, FOLDABLE) and id(node) not in skip and (value := _fold(node)) is not None:
            words = [w for part in re.split(r"[^\w-]+", value) for w in (part, part.replace("-", "_"))]
        out |= idents.intersection(words)
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
        gain_table,
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
        gain_table.GainTable,  # the shared gain-table format's fields ("points", ...)
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
    # the shared motor record's datasheet keys (KV, kE, ...) and the panels every family draws
    out |= set(motor_data.MOTOR_KEYS) | set(motor_data.FLUX_KEYS) | set(scenario.GENERIC_PANELS)
    out |= {
        f.name
        for group in (loop.LOOP_STATE, loop.INPUTS, loop.PARAMS, loop.RECORD, loop.MEAS_FIELDS)
        for f in group
    }
    # the shared tune options of the shared envelope and constraints (reports/envelope_options.py), which
    # families declare among theirs: defined once there, no one family's
    from sensorless.reports import envelope_options

    out |= {o.dest for o in (*envelope_options.ENVELOPE_OPTIONS, *envelope_options.NOISE_OPTIONS)}
    return out


def _preset_names(fam) -> list[str]:
    """The names of ``fam``'s presets (none where it has no presets package)."""
    from importlib import resources

    if fam.presets is None:
        return []
    return sorted(p.name[:-5] for p in resources.files(fam.presets).iterdir() if p.name.endswith(".toml"))


def _family_drive(fam) -> object:
    from sensorless.design.drive import load_drive

    return load_drive(_preset_names(fam)[0])


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
    out.update({name: "preset" for name in _preset_names(fam)})
    out.update({dest: what for dest, what in _cli_options(fam).items() if dest not in out})
    if fam.presets is not None:
        out.update({k: "drive field" for k in _fields(_family_drive(fam)) if k not in out})
    shared = _shared_vocabulary()
    # single letters (g, L, R, w) are the symbols of many equations, not a family's vocabulary
    return {k: v for k, v in out.items() if k not in shared and len(k) > 1}


def _cli_options(fam) -> dict[str, str]:
    """The command-line options ``fam`` declares (reports/family.py): their dest -> what they are."""
    from sensorless.reports.family import hooks

    h = hooks(fam)
    out = {
        o.dest: f"{command} option {o.flags[0]}"
        for command in ("analyze", "tune", "simulate")
        for o in getattr(h, f"{command}_options")
    }
    for name, imp in h.importers.items():
        out.update({o.dest: f"init --from {name} option {o.flags[0]}" for o in imp.options})
    return out


def _with_test_family():
    sys.path.insert(0, str(ROOT / "tests"))
    from families.pll.design import FAMILY
    from sensorless.design.registry import registered

    return registered(FAMILY)


@functools.cache
def _vocabularies() -> dict[str, dict[str, str]]:
    """Family name -> its own words (name -> what it is), the test family included, without the words
    every family declares (the drive file's [motor], [control], [observer], ...: the drive files'
    common vocabulary, no one family's)."""
    with _with_test_family():
        vocab = {fam.name: _vocabulary(fam) for fam in families()}
    assert "pmsm_pll" in vocab  # the test family is among them
    common = set.intersection(*(set(v) for v in vocab.values()))
    return {fam: {w: what for w, what in words.items() if w not in common} for fam, words in vocab.items()}


def _module_offences(path: Path, text: str | None = None) -> dict[str, set[str]]:
    """What one shared module names of a family: word -> the families that own it (their vocabulary,
    and the families named themselves). ``text`` stands for the file's content."""
    out: dict[str, set[str]] = {}
    used = _names_used(path, text)
    for fam, words in _vocabularies().items():
        for word in used & set(words):
            out.setdefault(word, set()).add(fam)
    with _with_test_family():
        for word in _family_references(path, text):
            out.setdefault(word, set()).add("the family itself")
    return out


def _offences() -> dict[str, dict[str, set[str]]]:
    """Shared module (path) -> name -> the families that declare it."""
    out: dict[str, dict[str, set[str]]] = {}
    with _with_test_family():
        modules = _shared_modules()
    for module in modules:
        path = _module_path(module)
        if found := _module_offences(path):
            out[str(path.relative_to(ROOT))] = found
    return out


def test_shared_modules_name_no_family_vocabulary():
    """No shared module names a family (its packages, name or kind), its gain laws, gains, scenario
    options, [estimate_scale] keys, trace panels, presets, command-line options or drive fields (string values
    however written, attribute, keyword, variable, parameter and definition names; whole words), for
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
    vocab = {w for words in _vocabularies().values() for w in words}
    assert {"injection", "w_eps", "law16", "load_torque_estimation", "alpha_fo", "w_pll"} <= vocab


# Offences a contributor could write in shared code, each as it would be written: the checks above must
# find every one (injected into a copy of a real shared module) and nothing in the unmodified copy.
OFFENCES = {
    "static import of a family module": "from sensorless.design.ipmsm_adaptive import carrier\n",
    "dynamic import of a family module": (
        "import importlib\ncarrier = importlib.import_module('sensorless.design.ipmsm_adaptive.carrier')\n"
    ),
    "family name compared": 'def f(fam):\n    return fam.name == "pmsm_flux_observer"\n',
    "kind string, double quotes": 'def f(drive):\n    return drive.kind == "pmsm-flux-observer"\n',
    "kind string, single quotes": "def f(drive):\n    return drive.kind == 'pmsm-flux-observer'\n",
    "family gain as a string key": "def f(gains):\n    return gains['w_eps']\n",
    "family field as an attribute": "def f(drive):\n    return drive.observer.injection\n",
    "local variable named after a family field": "def f(drive):\n    injection = 1.0\n    return injection\n",
    "parameter named after a family field": "def f(drive, injection=False):\n    return drive\n",
    "family command-line option read from args": "def f(args):\n    return args.tune_alpha_fo\n",
    "string built by concatenation": "def f(opts):\n    return opts['inj' + 'ection']\n",
    "string built as an f-string": "def f(opts):\n    return opts[f\"{'w'}_eps\"]\n",
    "family name built by concatenation": "def f(fam):\n    return fam.name == 'pmsm_flux' + '_observer'\n",
    "kind string built by a %-format": "def f(d):\n    return d.kind == 'pmsm-%s-observer' % 'flux'\n",
    "family gain built by str.format": "def f(gains):\n    return gains['{}_{}'.format('w', 'eps')]\n",
    "a family's preset named": "def f(load):\n    return load('hubmotor48')\n",
}
SCRATCH = ROOT / "design" / "simulate.py"  # a real shared module, copied with one offence appended


def test_the_unmodified_copy_is_clean():
    assert not _module_offences(SCRATCH, SCRATCH.read_text(encoding="utf-8"))


@pytest.mark.parametrize("offence", sorted(OFFENCES))
def test_each_offence_in_shared_code_is_caught(offence):
    text = SCRATCH.read_text(encoding="utf-8") + "\n\n" + OFFENCES[offence]
    assert _module_offences(SCRATCH, text), offence


def test_a_kind_string_outside_the_registering_module_is_caught(tmp_path):
    """However the kind string is quoted or pieced together, the module writing it is found."""
    kind = "pmsm-flux-observer"
    for i, line in enumerate(
        [f'k = "{kind}"', f"k = '{kind}'", "k = 'pmsm-flux' + '-observer'", "k = f\"{'pmsm'}-flux-observer\""]
    ):
        (tmp_path / f"m{i}.py").write_text(f'"""Doc."""\n{line}\n')
    (tmp_path / "clean.py").write_text(f'"""The {kind} family (a docstring may name it)."""\n')
    paths = sorted(tmp_path.glob("*.py"))
    assert _kind_modules(kind, paths) == [tmp_path / f"m{i}.py" for i in range(4)]


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
        for node in _parsed(path.read_text(encoding="utf-8"))[0]:  # parsed once for all the checks
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


def test_the_readme_and_the_architecture_name_every_family_and_preset():
    """README.md and docs/architecture.md name every registered family and each of its presets (a new
    family or preset is not left out of the two pages a reader starts from)."""
    for doc in (ROOT / "README.md", ROOT / "docs" / "architecture.md"):
        text = doc.read_text(encoding="utf-8")
        for fam in families():
            names = (fam.name, *_preset_names(fam))
            missing = [n for n in names if not re.search(rf"`{re.escape(n)}`", text)]
            assert not missing, (doc.name, missing)
