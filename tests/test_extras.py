"""What the tests need is what README's first command installs, and what CI runs is README's two commands.

* Every package a test skips without (``pytest.importorskip``, ``importlib.util.find_spec``) is a core dependency
  or in the ``test`` extra (directly, or through an extra it names: ``dask[distributed]``), so that
  ``pip install -e ".[test]"`` runs it; every package a test imports is installed by that command.
* The ``test`` extra carries every other extra (``dask``, ``recordings``).
* ``.ci/run`` installs the package with README's first command's extras, once, and runs README's test command.
* Every other way a test can skip (``pytest.skip``, ``skipif``, ``xfail``) is on :data:`SKIPS`, with the reason a
  reviewer reads in pytest's summary (README, "Tests", lists them).

Each rule is a function that returns its violations, shown to fail on planted cases.
"""

from __future__ import annotations

import ast
import importlib.metadata as md
import re
import sys
import tomllib
from collections.abc import Iterable
from functools import cache
from pathlib import Path

from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"

#: the only places where a test may skip other than on a missing package (file -> why, as a reviewer reads it).
#: A new skip fails :func:`test_every_skip_is_listed_with_its_reason` until it is added here and to README's Tests.
SKIPS = {
    "tests/conftest.py": "the browser tests (browser_check) render the HTML reports in Chromium, a system package, "
                         "not a pip one: apt-get install chromium (.ci/run installs it where apt-get can)",
    "tests/test_lint.py": "ruff, in the test extra: skips only outside README's install",
    "tests/cli/test_signals.py": "process groups and /proc: Linux only",
    "tests/studies/test_bench.py": "Ctrl-C of the bench sent to its process group: Linux only",
    "tests/recordings/test_flir.py": "ExifTool (the FLIR format's reference reader) runs on perl and ships with "
                                     "flirpy; the FLIR i7 image is in some flirpy releases only",
    "tests/reconstruct/test_deconvolve.py": "a known loss of the default PSF-aware method (issue 31), kept as a strict "
                                            "xfail: it fails the suite the day it is fixed, so its test is turned on",
    "tests/reconstruct/test_spectra.py": "a known false alarm of the noise floor (an anisotropic scene through a PSF "
                                         "that passes everything), kept as a strict xfail until fixed",
}


def _norm(name: str) -> str:
    """A distribution's name as PEP 503 compares them (``scikit_image`` = ``scikit-image``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


@cache
def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def _requirements(extra: str | None = None) -> list[Requirement]:
    """The core dependencies (``extra=None``) or one extra's, as pyproject declares them."""
    project = _pyproject()["project"]
    return [Requirement(r) for r in (project["dependencies"] if extra is None
                                     else project["optional-dependencies"][extra])]


def _extra_dists(req: Requirement) -> set[str]:
    """The distributions the extras of ``req`` add (``dask[distributed]`` -> distributed), from the installed
    metadata; without it, each extra's name (the usual spelling)."""
    if not req.extras:
        return set()
    try:
        requires = md.requires(req.name) or []
    except md.PackageNotFoundError:
        return {_norm(e) for e in req.extras}
    out = set()
    for line in requires:
        r = Requirement(line)
        if r.marker is not None and any(r.marker.evaluate({"extra": e}) for e in req.extras):
            out.add(_norm(r.name))
    return out


def declared(requirements: Iterable[Requirement]) -> set[str]:
    """The distributions ``requirements`` name, and those their extras add."""
    out = set()
    for r in requirements:
        out |= {_norm(r.name)} | _extra_dists(r)
    return out


def installed_closure(requirements: Iterable[Requirement]) -> set[str]:
    """Every distribution that installing ``requirements`` installs here (their installed dependencies, with the
    extras asked for, transitively)."""
    done: set[tuple[str, frozenset[str]]] = set()
    todo = [(_norm(r.name), frozenset(r.extras)) for r in requirements]
    while todo:
        item = todo.pop()
        if item in done:
            continue
        done.add(item)
        name, extras = item
        try:
            requires = md.requires(name) or []
        except md.PackageNotFoundError:
            continue
        env = [{"extra": e} for e in extras] or [{"extra": ""}]
        for line in requires:
            r = Requirement(line)
            if r.marker is None or any(r.marker.evaluate(x) for x in env):
                todo.append((_norm(r.name), frozenset(r.extras)))
    return {name for name, _ in done}


@cache
def _module_dists() -> dict[str, list[str]]:
    return md.packages_distributions()


def distribution_of(module: str) -> str:
    """The distribution that installs ``module`` (its top-level package) here, else the module's own name."""
    top = module.split(".")[0]
    dists = _module_dists().get(top)
    return _norm(dists[0]) if dists else _norm(top)


def _call_name(node: ast.Call) -> str:
    f = node.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""


def imports_of(path: Path) -> tuple[list[tuple[int, str]], list[tuple[int, str]]]:
    """``(optional, plain)``: the modules a test file skips without (``importorskip("X")``, ``find_spec("X")``) and
    those it imports, each with its line, leaving out the standard library, metafovea and the tests' own modules."""
    tree = ast.parse(path.read_text(), str(path))
    optional, plain = [], []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and _call_name(node) in ("importorskip", "find_spec") and node.args \
                and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
            optional.append((node.lineno, node.args[0].value))
        elif isinstance(node, ast.Import):
            plain += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            plain.append((node.lineno, node.module))
    local = {"metafovea", "tests", "conftest"}
    keep = [(n, m) for n, m in plain if m.split(".")[0] not in sys.stdlib_module_names | local]
    return [(n, m) for n, m in optional if m.split(".")[0] not in sys.stdlib_module_names], keep


def undeclared_imports(paths: Iterable[Path], extra: str = "test") -> list[str]:
    """Each module the test files ``paths`` skip without that neither the core dependencies nor ``extra`` declare,
    and each module they import that installing both does not install: ``file:line: module (distribution) ...``."""
    reqs = _requirements() + _requirements(extra)
    direct, everything = declared(reqs), installed_closure(reqs)
    out = []
    for p in sorted(paths):
        optional, plain = imports_of(p)
        name = p.relative_to(ROOT) if p.is_relative_to(ROOT) else p
        for line, module in optional:
            if distribution_of(module) not in direct:
                out.append(f"{name}:{line}: skips without {module} ({distribution_of(module)}), which neither "
                           f"the dependencies nor the {extra!r} extra of pyproject.toml declare")
        for line, module in plain:
            if distribution_of(module) not in everything:
                out.append(f"{name}:{line}: imports {module} ({distribution_of(module)}), which "
                           f"pip install -e '.[{extra}]' does not install")
    return out


def extras_missing_from(extra: str = "test") -> list[str]:
    """The requirements of the other extras that ``extra`` does not carry (name and extras)."""
    have = {_norm(r.name): set(r.extras) for r in _requirements(extra)}
    out = []
    for other in _pyproject()["project"]["optional-dependencies"]:
        for r in _requirements(other) if other != extra else []:
            if _norm(r.name) not in have or not set(r.extras) <= have[_norm(r.name)]:
                out.append(f"extra {other!r}: {r} is not in the {extra!r} extra")
    return out


def ci_differs_from_readme(readme: str, ci: str) -> list[str]:
    """How ``.ci/run`` (text ``ci``) differs from README's two commands (text ``readme``): the package installed
    with other extras, or more than once, or another test command."""
    block = re.search(r"```bash\n(.*?)```", readme, re.S)
    if block is None:
        return ["README has no first ```bash block"]
    install = re.findall(r"pip install (?:--quiet )?-e (\S+)", block.group(1))
    test_cmd = re.search(r"(python -m pytest[^\n&]*)", block.group(1))
    out = []
    if len(install) != 1 or test_cmd is None:
        return [f"README's first block: {len(install)} pip install -e commands and "
                f"{'a' if test_cmd else 'no'} pytest command (one each expected)"]
    ci_lines = [x for x in ci.splitlines() if not x.lstrip().startswith("#")]
    ci_install = [m for x in ci_lines for m in re.findall(r"pip install (?:--quiet )?-e (\S+)", x)]
    if ci_install != install:
        out.append(f".ci/run installs {ci_install}, README's first command {install}")
    if not any(x.strip() == test_cmd.group(1).strip() for x in ci_lines):
        out.append(f".ci/run does not run README's test command {test_cmd.group(1).strip()!r}")
    return out


def skips_outside(paths: Iterable[Path], allowed: dict[str, str]) -> list[str]:
    """The skips (``pytest.skip``, ``skipif``, ``mark.skip``, ``xfail``) in test files not on ``allowed``."""
    out = []
    for p in sorted(paths):
        name = str(p.relative_to(ROOT)) if p.is_relative_to(ROOT) else str(p)
        if name in allowed:
            continue
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            if isinstance(node, ast.Attribute) and node.attr in ("skip", "skipif", "xfail"):
                out.append(f"{name}:{node.lineno}: {node.attr}, not listed in tests/test_extras.py SKIPS")
    return out


def _test_files() -> list[Path]:
    return sorted(TESTS.rglob("*.py"))


# ---------------------------------------------------------------------------------------------
# the rules
# ---------------------------------------------------------------------------------------------
def test_every_package_the_tests_need_is_installed_by_readme_command_1():
    bad = undeclared_imports(_test_files())
    assert not bad, "\n".join(bad)


def test_the_test_extra_carries_every_other_extra():
    bad = extras_missing_from("test")
    assert not bad, "\n".join(bad)


def test_ci_runs_readme_s_two_commands():
    bad = ci_differs_from_readme((ROOT / "README.md").read_text(), (ROOT / ".ci" / "run").read_text())
    assert not bad, "\n".join(bad)


def test_every_skip_is_listed_with_its_reason():
    bad = skips_outside(_test_files(), SKIPS)
    assert not bad, "\n".join(bad)
    assert all(not Path(ROOT / f).is_file() or f in (ROOT / "README.md").read_text() for f in SKIPS), \
        "README's Tests section names each file that can skip"


# ---------------------------------------------------------------------------------------------
# the rules fail on planted cases
# ---------------------------------------------------------------------------------------------
def test_the_rules_fail_on_planted_cases(tmp_path):
    planted = tmp_path / "test_planted.py"
    planted.write_text("import importlib.util\nimport pytest\nimport no_such_package_xyz\n"
                       "pd = pytest.importorskip('pandas')\nh5py = pytest.importorskip('h5py')\n"
                       "dist = pytest.importorskip('distributed')\nos_ok = pytest.importorskip('json')\n"
                       "have = importlib.util.find_spec('some_linter_xyz')\n"
                       "@pytest.mark.skipif(True, reason='why not')\ndef test_x():\n    pytest.skip('no')\n")
    bad = undeclared_imports([planted])
    assert len(bad) == 3, bad  # pandas and some_linter_xyz undeclared, no_such_package_xyz not installed
    assert any(":4: skips without pandas" in b for b in bad) and any("some_linter_xyz" in b for b in bad)
    assert any(":3: imports no_such_package_xyz" in b for b in bad)
    assert len(skips_outside([planted], {})) == 2 and skips_outside([planted], {str(planted): "planted"}) == []
    readme = '```bash\npip install -e ".[test]" && metafovea validate\npython -m pytest -q -n auto\n```\n'
    ci_ok = 'python -m pip install --quiet -e ".[test]"\n# README\'s test command:\npython -m pytest -q -n auto\n'
    assert ci_differs_from_readme(readme, ci_ok) == []
    ci_more = ci_ok.replace('".[test]"\n', '".[test]"\npython -m pip install --quiet -e ".[test,dask]"\n')
    assert "installs" in ci_differs_from_readme(readme, ci_more)[0]
    assert "test command" in ci_differs_from_readme(readme, ci_ok.replace("-n auto", "-x"))[0]
