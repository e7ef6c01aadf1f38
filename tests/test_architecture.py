"""The architecture as a test: data flows one way, each idea has one home, commands stay thin.

Parsed from the source (including imports inside functions), so a lazy import cannot hide a cycle. Every
allow-list entry carries its reason.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "metafovea"

#: ground floor: conventions, checks, files, executors, shared data types and primitives; imports only itself
SHARED = {"units", "errors", "io", "parallel", "config", "materials", "radiometry", "measurement", "report", "plotting",
          "polarizer", "__init__"}
#: stage rank; a module may import from ranks <= its own. layout and optics are sibling branches.
RANK = {
    "rcwa": 1, "library": 2, "library_report": 2, "lens": 3, "design_report": 3,
    "layout": 4, "optics": 4,
    "imaging": 5, "recordings": 5, "reconstruct": 6, "validate": 7, "studies": 7, "cli": 8,
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


def modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG.parent).with_suffix("")
        modname = ".".join(rel.parts)
        if modname.endswith(".__init__"):
            modname = modname[: -len(".__init__")]
        yield path, modname, ast.parse(path.read_text(), str(path))


def stage_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "metafovea":
        return None
    if len(parts) == 1:
        return "__init__"
    return "cli" if parts[1] == "__main__" else parts[1]


def imports(tree: ast.AST, path: Path, modname: str) -> list[tuple[str, str | None]]:
    """``(module, name)`` for every import (``name`` None for ``import module``)."""
    out = []
    pkg_parts = modname.split(".")[:-1] if path.name != "__init__.py" else modname.split(".")
    for node in ast.walk(tree):
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
        for node in ast.walk(tree):
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
        for node in ast.walk(tree):
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
        for node in ast.walk(tree):
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
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__") \
                    and isinstance(node.value, ast.Name) and node.value.id in aliases:
                problems.append(f"{path.name}:{node.lineno} uses {node.value.id}.{node.attr}")
    assert not problems, "\n".join(problems)


def _polarizer_formulas(tree: ast.AST) -> list[str]:
    """The polariser's physics written out: Malus's ``cos(x) ** 2`` or a lag ``atan(... tau ...)``."""
    found = []
    for node in ast.walk(tree):
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
