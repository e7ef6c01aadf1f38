"""The architecture as a test: data flows one way, each idea has one home, commands stay thin.

Parsed from the source (including imports inside functions), so a lazy import cannot hide a cycle. Every
allow-list entry carries its reason.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "metafovea"

#: ground floor: conventions, checks, files, executors, shared data types and primitives; imports only itself
SHARED = {"units", "errors", "io", "parallel", "config", "materials", "radiometry", "measurement", "report", "plotting",
          "polarizer", "stopping", "__init__"}
#: stage rank; a module may import from ranks <= its own. layout and optics are sibling branches.
RANK = {
    "rcwa": 1, "library": 2, "lens": 3, "design_report": 3,
    "layout": 4, "optics": 4,
    "imaging": 5, "recordings": 5, "reconstruct": 6, "validate": 7, "studies": 7, "codesign": 7, "cli": 8,
}
SIBLINGS = {("layout", "optics"), ("optics", "layout")}
#: ideas that must have exactly one home (the issue that cut them found each written two or three times)
ONE_HOME = ("blas_threads", "as_rng", "spectral_weights", "planck_radiance", "psf_wavelengths", "jsonable",
            "cache_dir", "fig_to_png", "array_png", "score", "file_stem")
#: the longest functions allowed, with the reason each reads better whole (lines, including the docstring)
MAX_FUNCTION_LINES = 120
LONG_FUNCTIONS: dict[str, str] = {}
#: the longest a command module may be
MAX_CLI_LINES = 200


def modules() -> tuple[tuple[Path, str, ast.Module], ...]:
    """``(path, module name, tree)`` of every module of the package, parsed once per test process (the rules only
    read the trees)."""
    return _parsed(tuple((p, p.stat().st_mtime_ns) for p in sorted(PKG.rglob("*.py"))))


@functools.cache
def _parsed(files: tuple[tuple[Path, int], ...]) -> tuple[tuple[Path, str, ast.Module], ...]:
    out = []
    for path, _ in files:
        rel = path.relative_to(PKG.parent).with_suffix("")
        modname = ".".join(rel.parts)
        if modname.endswith(".__init__"):
            modname = modname[: -len(".__init__")]
        out.append((path, modname, ast.parse(path.read_text(), str(path))))
    return tuple(out)


@functools.cache
def walk(tree: ast.AST) -> tuple[ast.AST, ...]:
    """``ast.walk(tree)``, listed once per tree: every rule walks every module."""
    return tuple(ast.walk(tree))


def stage_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "metafovea":
        return None
    if len(parts) == 1:
        return "__init__"
    return "cli" if parts[1] == "__main__" else parts[1]


def imports(tree: ast.AST, path: Path, modname: str, skip: set[int] = frozenset()) -> list[tuple[str, str | None]]:
    """``(module, name)`` for every import (``name`` None for ``import module``), but those whose node's ``id`` is in
    ``skip``."""
    out = []
    pkg_parts = modname.split(".")[:-1] if path.name != "__init__.py" else modname.split(".")
    for node in walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg_parts[: len(pkg_parts) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out += [(mod, a.name) for a in node.names]
    return out


def metafovea_imports(tree, path, modname) -> set[str]:
    out = set()
    for mod, name in imports(tree, path, modname):
        out.add(mod)
        if name is not None:
            out.add(f"{mod}.{name}")
    return {m for m in out if m.startswith("metafovea")}


def test_imports_follow_the_data_flow():
    problems = []
    for path, modname, tree in modules():
        me = stage_of(modname)
        for m in metafovea_imports(tree, path, modname):
            s = stage_of(m)
            if me in SHARED:
                if s not in SHARED and s != me:
                    problems.append(f"{modname} (ground floor) imports {m} ({s})")
                continue
            assert me in RANK, f"unknown stage for {modname}: add it to RANK or SHARED"
            if s is None or s in SHARED or s == me or s not in RANK:
                continue
            if RANK[s] > RANK[me] or (me, s) in SIBLINGS:
                problems.append(f"{modname} ({me}) imports {m} ({s})")
    assert not problems, "\n".join(problems)


def test_private_names_stay_inside_their_stage():
    """A stage's private module or name (``_x``) is imported only from inside that stage."""
    problems = []
    for path, modname, tree in modules():
        me = stage_of(modname)
        for mod, name in imports(tree, path, modname):
            if not mod.startswith("metafovea") or stage_of(mod) == me:
                continue
            private = any(p.startswith("_") and p != "__init__" for p in mod.split(".")) or \
                (name is not None and name.startswith("_") and name != "__version__")
            if private:
                problems.append(f"{modname} imports {mod}{'.' + name if name else ''}")
    assert not problems, "\n".join(problems)


def test_commands_are_thin():
    """A command parses, calls one library function, prints and writes: no figures, no numerical stage internals,
    at most ~200 lines."""
    problems = []
    for path, modname, tree in modules():
        if stage_of(modname) != "cli":
            continue
        n = len(path.read_text().splitlines())
        if n > MAX_CLI_LINES:
            problems.append(f"{modname}: {n} lines (> {MAX_CLI_LINES})")
        for mod, _name in imports(tree, path, modname):
            if mod.split(".")[0] in ("matplotlib", "scipy", "jax", "skimage"):
                problems.append(f"{modname} imports {mod} (figures and numerics belong to the library)")
        for node in walk(tree):
            if isinstance(node, ast.Attribute) and node.attr in ("savefig", "subplots", "imshow", "figure"):
                problems.append(f"{modname}:{node.lineno} uses .{node.attr} (figures belong to the library)")
    assert not problems, "\n".join(problems)


def test_each_idea_has_one_home():
    defs: dict[str, list[str]] = {}
    for _, modname, tree in modules():
        for node in tree.body:  # module level: a method that delegates to the one home is not a second home
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                defs.setdefault(node.name.lstrip("_"), []).append(modname)
    problems = [f"{name} defined in {where}" for name in ONE_HOME if len(where := defs.get(name, [])) != 1]
    assert not problems, "\n".join(problems)


def test_only_report_saves_figures():
    users = [modname for path, modname, _ in modules()
             if "savefig" in path.read_text() and modname != "metafovea.report"]
    assert not users, f"savefig outside metafovea.report: {users}"


def test_functions_are_short():
    problems = []
    for _, modname, tree in modules():
        for node in walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                key = f"{modname}.{node.name}"
                if n > MAX_FUNCTION_LINES and key not in LONG_FUNCTIONS:
                    problems.append(f"{key}: {n} lines")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("bad", ["from metafovea.validate import run", "import matplotlib.pyplot as plt"])
def test_the_checks_can_fail(bad, tmp_path):
    """The rules above catch a violation (a ground-floor module importing a stage; a command importing matplotlib)."""
    tree = ast.parse(bad)
    found = metafovea_imports(tree, tmp_path / "units.py", "metafovea.units")
    if bad.startswith("from metafovea"):
        assert {stage_of(m) for m in found} - SHARED == {"validate"}
    else:
        assert [m for m, _ in imports(tree, tmp_path / "x.py", "metafovea.cli.x") if m.startswith("matplotlib")]


def test_tests_use_public_names_only():
    """Tests exercise the public API: no ``from metafovea.x import _y``, no ``module._y`` on an imported metafovea
    module, no import of a private metafovea module."""
    problems = []
    for path in sorted((PKG.parent / "tests").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        aliases = set()
        for node in walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("metafovea"):
                if any(p.startswith("_") for p in node.module.split(".")):
                    problems.append(f"{path.name}:{node.lineno} imports {node.module}")
                for a in node.names:
                    if a.name.startswith("_") and a.name != "__version__":
                        problems.append(f"{path.name}:{node.lineno} imports {node.module}.{a.name}")
                    aliases.add(a.asname or a.name)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("metafovea"):
                        aliases.add(a.asname or a.name.split(".")[0])
        for node in walk(tree):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__") \
                    and isinstance(node.value, ast.Name) and node.value.id in aliases:
                problems.append(f"{path.name}:{node.lineno} uses {node.value.id}.{node.attr}")
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------------------------------
# One home for the paper's platform and camera numbers
# ------------------------------------------------------------------------------------------------
#: the paper's platform and camera numbers and the pattern of the names they are values of (None: any name): outside
#: their home (config.py, refractive indices materials.py) a module takes them from there or requires them
PLATFORM_LITERALS: dict[float, str | None] = {
    3.42: None,                                # n_Si at 10 um: no other number of the package is 3.42
    4.0: r"period",                            # lattice period (um)
    10.0: r"height|wavelength|lambda|\bwl\b",  # post height, design wavelength (um)
    290: r"crop|shape",                        # the sensor's working crop (px)
    17.0: r"pitch",                            # pixel pitch (um)
    12.0: r"frame_rate|fps",                   # frame rate (Hz)
    8.0: r"band", 14.0: r"band",               # the LWIR band (um)
}
PLATFORM_HOMES = {"metafovea.config", "metafovea.materials"}
#: ``module:name`` that may keep a platform literal, with the reason
PLATFORM_LITERALS_ALLOWED: dict[str, str] = {
    **dict.fromkeys((f"metafovea.studies.{m}:crop" for m in ("focal_ratio", "frames", "gallery", "resolution",
                                                            "transients")),
                    "a study's full-size run, stated beside its fast one (FULL / FAST), not a default of the camera"),
    "metafovea.studies.transients:frame_rate_hz": "the study's report of the paper's camera, in step with its text "
                                                  "('12 frames/s'); the run takes the camera's own rate",
}


def _numbers(node: ast.AST):
    """The numeric constants a value is made of: a number, or a tuple / list of them."""
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        yield node
    elif isinstance(node, (ast.Tuple, ast.List)):
        for elt in node.elts:
            yield from _numbers(elt)


def _named_values(tree: ast.AST):
    """``(name, value)`` for every value given a name: parameter defaults, fields and assignments, keyword arguments,
    ``mapping.get('name', default)`` fallbacks and dict entries."""
    for node in walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            a = node.args
            pos = a.posonlyargs + a.args
            yield from ((arg.arg, d) for arg, d in zip(pos[len(pos) - len(a.defaults):], a.defaults))
            yield from ((arg.arg, d) for arg, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None)
        elif isinstance(node, ast.AnnAssign) and node.value is not None and isinstance(node.target, ast.Name):
            yield node.target.id, node.value
        elif isinstance(node, ast.Assign):
            for t in node.targets:
                if isinstance(t, (ast.Name, ast.Attribute)):
                    yield (t.id if isinstance(t, ast.Name) else t.attr), node.value
        elif isinstance(node, ast.Call):
            yield from ((k.arg, k.value) for k in node.keywords if k.arg is not None)
            key = node.args[0] if len(node.args) == 2 else None
            if isinstance(node.func, ast.Attribute) and node.func.attr in ("get", "pop", "setdefault") and \
                    isinstance(key, ast.Constant) and isinstance(key.value, str):
                yield key.value, node.args[1]
        elif isinstance(node, ast.Dict):
            yield from ((k.value, v) for k, v in zip(node.keys, node.values)
                        if isinstance(k, ast.Constant) and isinstance(k.value, str))


def platform_literals(tree: ast.AST) -> list[tuple[int, str, float]]:
    """``(line, name, value)`` of every platform literal (:data:`PLATFORM_LITERALS`) in ``tree``: a value given a name
    of its pattern, or a number that is one under any name (name '' when it has none)."""
    import re

    found: dict[tuple[int, int], tuple[int, str, float]] = {}
    for name, value in _named_values(tree):
        for c in _numbers(value):
            for number, pattern in PLATFORM_LITERALS.items():
                if c.value == number and (pattern is None or re.search(pattern, name.lower())):
                    found.setdefault((c.lineno, c.col_offset), (c.lineno, name, c.value))
    for c in walk(tree):
        if isinstance(c, ast.Constant) and type(c.value) in (int, float):
            for number, pattern in PLATFORM_LITERALS.items():
                if pattern is None and c.value == number:
                    found.setdefault((c.lineno, c.col_offset), (c.lineno, "", c.value))
    return sorted(found.values())


def test_platform_numbers_have_one_home():
    """The paper's platform and camera numbers (n_Si 3.42, period 4 um, post height and design wavelength 10 um, crop
    290 px, pitch 17 um, 12 frames/s, the 8-14 um band) are written in config.py / materials.py only: elsewhere a
    default, field, keyword or file fallback of that name takes them from there (or the value is required)."""
    problems, used = [], set()
    for _, modname, tree in modules():
        if modname in PLATFORM_HOMES:
            continue
        for line, name, value in platform_literals(tree):
            key = f"{modname}:{name}"
            if key in PLATFORM_LITERALS_ALLOWED:
                used.add(key)
            else:
                problems.append(f"{modname}:{line}: {name or 'a constant'} = {value!r} (take it from metafovea.config "
                                "or metafovea.materials)")
    problems += [f"{key}: allowed but no longer there (remove it from PLATFORM_LITERALS_ALLOWED)"
                 for key in sorted(set(PLATFORM_LITERALS_ALLOWED) - used)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("bad, name", [
    ("def width_grid(period_um: float = 4.0, step_um: float = 0.1): ...", "period_um"),
    ("@dataclass\nclass SensorModel:\n    shape: tuple[int, int] = (290, 290)\n", "shape"),
    ("r = post_response(w, w, harmonics=8, wavelength_um=10.0)", "wavelength_um"),
    ("h = float(lib.meta.get('height_um', 10.0))", "height_um"),
    ("kw = {'n_post': 1.0, 'n_substrate': complex(3.42)}", ""),
])
def test_the_platform_literal_check_can_fail(bad, name):
    """A planted platform literal is found (a default, a field, a keyword, a file fallback, a bare index)."""
    assert {n for _, n, _ in platform_literals(ast.parse(bad))} == {name}


def test_the_platform_literal_check_spares_ordinary_numbers():
    """The same numbers as a tolerance, a factor, a range or under another name are not platform literals."""
    good = ("def f(x, tol: float = 10.0, factor=4.0, n=290, delta_k=10.0):\n"
            "    check_range('n_post', x, 1.0, 10.0, hi=10.0)\n"
            "    return {'scale': 4.0, 'frames': 12.0} if x > 17.0 else (8.0, 14.0)\n")
    assert platform_literals(ast.parse(good)) == []


#: reconstruct modules that may read a metadata dict themselves, with the reason
META_READERS = {
    "metafovea.reconstruct.result": "reads the metadata of its own Reconstruction file, not a Measurement's",
}


def _meta_reads(tree: ast.AST) -> list[int]:
    """Lines that index a metadata dict (``meta[...]``, ``x.meta[...]``, ``meta.get(...)``, ``x.meta.get(...)``)."""
    def is_meta(node: ast.AST) -> bool:
        return (isinstance(node, ast.Name) and node.id == "meta") or (isinstance(node, ast.Attribute)
                                                                       and node.attr == "meta")
    lines = []
    for node in walk(tree):
        if isinstance(node, ast.Subscript) and is_meta(node.value):
            lines.append(node.lineno)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
              and is_meta(node.func.value)):
            lines.append(node.lineno)
    return lines


def test_the_reconstruction_reads_a_measurements_metadata_through_measurement_py():
    """``metafovea/measurement.py`` is the one reader of the Measurement format's metadata: the reconstruction
    asks the Measurement (``m.dark_dn``, ``m.radiometric_calibration``, ...) instead of indexing ``meta`` itself."""
    problems = [f"{modname}:{line}" for path, modname, tree in modules()
                if modname.startswith("metafovea.reconstruct.") and modname not in META_READERS
                for line in _meta_reads(tree)]
    assert not problems, "index a Measurement's metadata in metafovea/measurement.py: " + ", ".join(problems)
    planted = ast.parse("offset = float(m.meta.get('dark_dn', 0.0))\nsen = meta['sensor']")
    assert sorted(_meta_reads(planted)) == [1, 2]


def _polarizer_formulas(tree: ast.AST) -> list[str]:
    """The polariser's physics written out: Malus's ``cos(x) ** 2`` or a lag ``atan(... tau ...)``."""
    found = []
    for node in walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow) and isinstance(node.left, ast.Call) \
                and getattr(node.left.func, "attr", getattr(node.left.func, "id", None)) == "cos" \
                and isinstance(node.right, ast.Constant) and node.right.value == 2:
            found.append(f"line {node.lineno}: Malus cos(.) ** 2")
        name = getattr(node.func, "attr", getattr(node.func, "id", None)) if isinstance(node, ast.Call) else None
        if name in ("atan", "arctan") and any("tau" in (getattr(n, "id", None) or getattr(n, "attr", None) or "")
                        for a in node.args for n in ast.walk(a)):
            found.append(f"line {node.lineno}: bolometer lag atan(.. tau ..)")
    return found


def test_the_polarizer_model_has_one_home():
    """The angle law, Malus, bolometer lag and extinction leak are written once, in ``metafovea.polarizer``; the
    simulator and the reconstruction use it (issue 29 found them written twice in different algebra)."""
    problems = [f"{modname} {f}" for _, modname, tree in modules() if modname != "metafovea.polarizer"
                for f in _polarizer_formulas(tree)]
    assert not problems, "\n".join(problems)
    assert _polarizer_formulas(ast.parse("from math import atan\nlag = atan(w * self.tau_s)")), "the rule cannot fail"
    assert _polarizer_formulas(ast.parse("import numpy as np\nalpha = np.cos(theta) ** 2")), "the rule cannot fail"
    home = ast.parse((PKG / "polarizer.py").read_text())
    assert len(_polarizer_formulas(home)) == 2, "metafovea.polarizer no longer holds both formulas: update this rule"


#: what a measurement or a piece of history looks like in a docstring: a date, "(was ...)" / "before 2026", a
#: sentence that says "measured" and gives a number, a figure in dB. Module docstrings hold the model and the file
#: map; measured figures live in BENCHMARKS.md (they rot in code with the next tuning commit). Any docstring: no date.
_HISTORY = re.compile(r"\((?:was|before)\b|\bwas -?\d|\bbefore (?:19|20)\d\d|\b[Mm]easured\b[^.;]*?\d"
                      r"|-?\d+(?:\.\d+)? ?dB\b")
_DATE = re.compile(r"\b(?:19|20)\d\d-\d\d(?:-\d\d)?\b")


def docstring_history(tree: ast.AST) -> list[str]:
    """What in ``tree``'s docstrings reads as a measurement or history: any of :data:`_HISTORY` in the module
    docstring, a date in any docstring."""
    found = []
    module_doc = (ast.get_docstring(tree) or "") if isinstance(tree, ast.Module) else ""
    found += [f"module docstring: {m.group(0)!r}" for m in _HISTORY.finditer(module_doc)]
    for node in walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            doc = ast.get_docstring(node) or ""
            found += [f"{getattr(node, 'name', 'module')} docstring: date {m.group(0)}" for m in _DATE.finditer(doc)]
    return found


def test_docstrings_describe_the_code_not_its_history():
    """No module docstring carries a measurement or history, no docstring a date (issue 29: the reconstruct
    docstrings had become a changelog of dB tables and 'was -1.98, before 2026-12-03')."""
    problems = [f"{modname}: {f}" for _, modname, tree in modules() for f in docstring_history(tree)]
    assert not problems, "move measured figures to BENCHMARKS.md:\n" + "\n".join(problems)


@pytest.mark.parametrize("doc", ['"""Wiener prior.\n\nMeasured: +0.18 dB on the star."""',
                                 '"""The prior (the estimator before 2026-12-03)."""',
                                 '"""Padding (was -1.98)."""',
                                 '"""x"""\ndef f():\n    """Chosen on 2026-12-03."""'])
def test_the_docstring_history_check_can_fail(doc):
    assert docstring_history(ast.parse(doc))
    assert not docstring_history(ast.parse('"""The model: y = a x1 + (1 - a) x2 (BENCHMARKS.md, "Reconstruction")."""'))


#: modules allowed to name a CLI flag in a raise, with the reason (delete an entry once its module is clean)
FLAG_NAMES_ALLOWED: dict[str, str] = {}


def _is_flag(node: ast.AST | None) -> bool:
    """A string constant (or an f-string's first part) that starts with ``--``: a CLI flag's spelling."""
    if isinstance(node, ast.JoinedStr) and node.values:
        node = node.values[0]
    return isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("--")


def flag_named_raises(tree: ast.AST) -> list[tuple[int, str]]:
    """``(line, what)`` for every place a stage names a CLI flag as the parameter of an error: ``XError("--x", ...)``
    and validators ``check_*("--x", ...)`` / ``as_*("--x", ...)``; a ``name=`` / ``parameter=`` keyword ``"--x"``
    (the name an error will carry); a function parameter defaulting to ``"--x"``."""
    out = []
    for node in walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            fname = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            if (fname.endswith("Error") or fname.startswith(("check_", "as_"))) and node.args \
                    and _is_flag(node.args[0]):
                out.append((node.lineno, f"{fname}({ast.unparse(node.args[0])}, ...)"))
            out += [(node.lineno, f"{fname}(..., {k.arg}={ast.unparse(k.value)})") for k in node.keywords
                    if k.arg in ("name", "parameter") and _is_flag(k.value)]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            out += [(node.lineno, f"def {node.name}(... = {ast.unparse(d)})")
                    for d in node.args.defaults + node.args.kw_defaults if _is_flag(d)]
    return out


def test_stages_raise_with_parameter_names():
    """Flags live only in ``cli/``: a stage's error names the Python parameter (or the file's key), and the CLI's one
    map (``metafovea.cli.flags``) turns it into the flag a user typed. A Python caller is never told about a
    flag they did not type."""
    problems = []
    for _, modname, tree in modules():
        if stage_of(modname) == "cli" or modname in FLAG_NAMES_ALLOWED:
            continue
        problems += [f"{modname}:{line}: {what}" for line, what in flag_named_raises(tree)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("bad", ['raise InputError("--flat", True, "only with gds")',
                                 'x = check_int("--max-refs", n, 16)',
                                 'raise InputError(f"--{name}", v, "a number")',
                                 'p = prepare_output(path, force, name="--tiff")',
                                 'def load(path, name="--post-set"): pass'])
def test_the_flag_rule_can_fail(bad):
    """Each form of a flag-named raise outside ``cli/`` is caught; the parameter's name is not."""
    assert flag_named_raises(ast.parse(bad))
    assert not flag_named_raises(ast.parse(bad.replace('"--', '"').replace("f\"--", "f\"")))


def _type_checking_only(node: ast.AST) -> bool:
    """``if TYPE_CHECKING:`` (or ``typing.TYPE_CHECKING``): imports for annotations, never run."""
    t = node.test if isinstance(node, ast.If) else None
    return isinstance(t, ast.Name) and t.id == "TYPE_CHECKING" or isinstance(t, ast.Attribute) and \
        t.attr == "TYPE_CHECKING"


def import_graph(sources) -> dict[str, set[str]]:
    """Module -> the metafovea modules it imports when it runs, at module level or inside a function (an import
    under ``if TYPE_CHECKING:`` is left out: it never runs). ``from package import name`` is an edge to the
    submodule ``package.name`` when there is one, else to the package. ``sources``: ``(path, modname, tree)``."""
    sources = list(sources)
    names = {modname for _, modname, _ in sources}
    graph: dict[str, set[str]] = {}
    for path, modname, tree in sources:
        # the imports inside type-checking blocks (their bodies; the tests and the else branches run) are left out
        skip = {id(n) for node in walk(tree) if _type_checking_only(node) for b in node.body for n in ast.walk(b)}
        deps = set()
        for mod, name in imports(tree, path, modname, skip):
            if name is not None and f"{mod}.{name}" in names:
                deps.add(f"{mod}.{name}")
            elif mod in names:
                deps.add(mod)
        deps.discard(modname)
        graph[modname] = deps
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle ``[a, b, ..., a]`` through each group of modules that import each other (strongly connected
    components, Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in graph:
                    continue
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                group = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    group.append(w)
                    if w == v:
                        break
                if len(group) > 1:
                    groups.append(set(group))
    return [_cycle_in(graph, g) for g in groups]


def _cycle_in(graph: dict[str, set[str]], group: set[str]) -> list[str]:
    """A shortest cycle through the first module of ``group`` (breadth first inside the group)."""
    start = min(group)
    prev: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & group):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(prev[path[-1]])
                    return [*reversed(path), start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return sorted(group)  # pragma: no cover - a strongly connected group always has a cycle


def test_no_import_cycles():
    """No module imports, directly or through others, a module that imports it back, counting the imports inside
    functions: a lazy import hides a cycle from Python, not from the design (each idea has one home, below the
    ideas that use it)."""
    cycles = import_cycles(import_graph(modules()))
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles)


def test_the_cycle_rule_can_fail(tmp_path):
    """A planted cycle through a function-level import is found; the same edge under ``if TYPE_CHECKING:`` is not
    one (it never runs)."""
    src = {"metafovea.layout.a": "from metafovea.layout.b import B\n",
           "metafovea.layout.b": "def f():\n    from metafovea.layout import c\n",
           "metafovea.layout.c": "if TYPE_CHECKING:\n    from metafovea.layout.a import A\n"}

    def graph(sources):
        return import_graph((tmp_path / (m.split(".")[-1] + ".py"), m, ast.parse(s)) for m, s in sources.items())

    assert import_cycles(graph(src)) == []
    src["metafovea.layout.c"] += "def g():\n    import metafovea.layout.a\n"
    assert import_cycles(graph(src)) == [["metafovea.layout.a", "metafovea.layout.b", "metafovea.layout.c",
                                          "metafovea.layout.a"]]
