"""The data flows one way: a module imports only from its own stage or stages above it.

Parsed from the source (including imports inside functions), so a lazy import cannot hide a cycle.
"""

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "metafovea"

SHARED = {"units", "errors", "io", "parallel", "config", "materials", "__init__"}
#: stage rank; a module may import from ranks <= its own. layout and optics are sibling branches.
RANK = {
    "rcwa": 1, "library": 2, "lens": 3, "design_report": 3,
    "layout": 4, "optics": 4,
    "imaging": 5, "reconstruct": 6, "metrics": 7, "report": 7, "validate": 8, "cli": 9,
}
SIBLINGS = {("layout", "optics"), ("optics", "layout")}


def stage_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "metafovea":
        return None
    if len(parts) == 1:
        return "__init__"
    name = parts[1]
    if name.startswith("cli") or name == "__main__":
        return "cli"
    return name


def imported_modules(path: Path, modname: str) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    out = set()
    pkg_parts = modname.split(".")[:-1] if path.name != "__init__.py" else modname.split(".")
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg_parts[: len(pkg_parts) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)
    return {m for m in out if m.startswith("metafovea")}


def test_imports_follow_the_data_flow():
    problems = []
    for path in PKG.rglob("*.py"):
        rel = path.relative_to(PKG.parent).with_suffix("")
        modname = ".".join(rel.parts)
        if modname.endswith(".__init__"):
            modname = modname[: -len(".__init__")]
        me = stage_of(modname)
        if me in SHARED or me is None:
            # shared modules may import only other shared modules
            for m in imported_modules(path, modname):
                s = stage_of(m)
                if s not in SHARED and s != me:
                    problems.append(f"{modname} (shared) imports {m}")
            continue
        assert me in RANK, f"unknown stage for {modname}: add it to RANK"
        for m in imported_modules(path, modname):
            s = stage_of(m)
            if s is None or s in SHARED or s == me:
                continue
            if s not in RANK:
                continue  # a name imported from the package root, e.g. metafovea.__version__
            if RANK[s] > RANK[me] or (me, s) in SIBLINGS:
                problems.append(f"{modname} ({me}) imports {m} ({s})")
    assert not problems, "\n".join(problems)
