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
          "__init__"}
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


#: modules allowed to name a CLI flag in a raise, with the reason (delete an entry once its module is clean)
FLAG_NAMES_ALLOWED = {
    "metafovea.reconstruct.deconvolve": "its two flags go with the deconvolve cut, another part of issue 29",
}


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
    for node in ast.walk(tree):
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
    map (``metafovea.cli.PARAMETER_FLAGS``) turns it into the flag a user typed. A Python caller is never told about a
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
        tree = ast.parse(ast.unparse(tree))  # a copy, pruned of the type-checking blocks below
        for node in ast.walk(tree):
            if _type_checking_only(node):
                node.body = [ast.Pass()]
        deps = set()
        for mod, name in imports(tree, path, modname):
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
