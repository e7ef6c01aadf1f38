import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DESIGNS = REPO / "designs"

os.environ.setdefault("MPLBACKEND", "Agg")
if os.environ.get("PYTEST_XDIST_WORKER"):
    # the test workers (-n auto) already fill the cores: one BLAS thread each, also for the commands they start (two
    # workers with two OpenBLAS threads each on 2 cores: tests/rcwa and optics' RCWA tests took 72 s, 118 CPU s;
    # with one, 52 s, 73 CPU s). Set before numpy loads (xdist sets the variable before it reads this file).
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        os.environ.setdefault(_var, "1")


@pytest.fixture
def designs_dir() -> Path:
    return DESIGNS


#: the ways a file is damaged in the tests: empty, cut short, replaced by junk bytes, replaced by text
DAMAGES = ("empty", "truncated", "garbage", "text")


def damage_file(src: Path, dst: Path, damage: str, *, keep: float = 0.5) -> Path:
    """Write a damaged copy of ``src`` to ``dst`` (``damage`` one of :data:`DAMAGES`; ``truncated`` keeps the
    first ``keep`` fraction of the bytes, or ``int(keep)`` bytes when ``keep >= 1``)."""
    data = Path(src).read_bytes()
    if damage == "empty":
        out = b""
    elif damage == "truncated":
        out = data[: int(keep) if keep >= 1 else int(len(data) * keep)]
    elif damage == "garbage":
        out = b"\x00junk" * max(1, len(data) // 5 // 8)
    elif damage == "text":
        out = b"this is not the file you are looking for\n"
    else:
        raise ValueError(f"damage must be one of {DAMAGES}, not {damage!r}")
    dst = Path(dst)
    dst.write_bytes(out)
    return dst


@pytest.fixture
def damaged():
    """Factory fixture: ``damaged(src, dst, damage, keep=0.5)`` writes a damaged copy of ``src`` (see
    :func:`damage_file`); parametrise a test over :data:`DAMAGES` to try each."""
    return damage_file


def write_lens_toml(tmp_path: Path, name: str = "qa", f_mm: float = 0.8, d_mm: float = 0.4, levels: int = 8,
                    lattice: str = "integer", pol: str = "x") -> Path:
    """A small lens design file (0.8 mm focal length, 0.4 mm aperture by default: fast to export and verify)."""
    p = tmp_path / f"{name}.toml"
    p.write_text(f'name = "{name}"\nf_mm = {f_mm}\ndiameter_mm = {d_mm}\nwavelength_um = 10.0\n'
                 f'polarization = "{pol}"\nlevels = {levels}\nlattice = "{lattice}"\n')
    return p


def cli_error_line(capsys) -> str:
    """The command's stderr, stripped; never a traceback."""
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err


@pytest.fixture(scope="session")
def lens_toml():
    """Factory fixture: ``lens_toml(tmp_path, name="qa", f_mm=0.8, d_mm=0.4, levels=8, lattice="integer",
    pol="x")`` writes a small lens TOML and returns its path."""
    return write_lens_toml


@pytest.fixture(scope="session")
def cli_error():
    """Factory fixture: ``cli_error(capsys)`` returns the command's stderr and asserts it holds no traceback."""
    return cli_error_line


_BROWSER_JS = """<script>window.addEventListener('load', () => { const d = document.documentElement;
const imgs = [...document.images]; const broken = imgs.filter(i => !(i.complete && i.naturalWidth > 0)).length;
const unlabelled = imgs.filter(i => !i.alt).length;
document.title = 'CHECK ' + JSON.stringify({scroll_width: d.scrollWidth, inner_width: window.innerWidth,
  broken: broken, images: imgs.length, unlabelled: unlabelled, text: document.body.innerText}); });</script>"""
#: what a raw Python repr looks like in a page's text
_RAW_REPR = r"\bNone\b|\{'|\['|\bnan\b|\binf\b|np\.float|array\(|<function|object at 0x|\bTrue\b|\bFalse\b"


def _render_in_chromium(page: Path, width: int, tmp: Path) -> dict:
    import json
    import re
    import shutil
    import subprocess

    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("the browser test needs Chromium, a system package (not a pip one): apt-get install chromium "
                    "(Debian; chromium-browser on Ubuntu); .ci/run installs it where apt-get can")
    probe = tmp / f"probe_{width}_{page.name}"
    probe.write_text(page.read_text().replace("</body>", _BROWSER_JS + "</body>"))
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
           f"--user-data-dir={tmp / 'chromium-profile'}", f"--window-size={width},1000", "--virtual-time-budget=10000",
           "--dump-dom", probe.as_uri()]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120).stdout
    m = re.search(r"<title>CHECK (.*?)</title>", out, re.S)
    assert m, f"chromium did not render {page.name}: {out[:300]}"
    import html as _html

    res = json.loads(_html.unescape(m.group(1)))
    res["raw_reprs"] = sorted(set(re.findall(_RAW_REPR, res.pop("text"))))
    return res


@pytest.fixture
def browser_check(tmp_path):
    """``browser_check(page.html)``: renders the page in headless Chromium at 800 and 1400 px and asserts no
    horizontal overflow, no broken or unlabelled images and no raw Python reprs in its text."""
    def check(page: Path) -> list[dict]:
        results = []
        for width in (800, 1400):
            r = _render_in_chromium(Path(page), width, tmp_path)
            assert r["scroll_width"] <= r["inner_width"], f"{page.name} overflows at {width} px: {r}"
            assert r["broken"] == 0 and r["unlabelled"] == 0, f"{page.name} at {width} px: {r}"
            assert not r["raw_reprs"], f"{page.name} shows raw Python values {r['raw_reprs']}"
            results.append(r)
        return results
    return check


@pytest.fixture(scope="session")
def made_once(tmp_path_factory):
    """Factory fixture: ``made_once(key, make)`` returns a folder that ``make(folder)`` filled, once per test run
    even under ``-n auto``: the first worker to ask makes it, the others wait for it (a file lock) and read it. For
    an expensive module fixture (a CLI report) whose tests the workers share: each would make its own."""
    import shutil

    from metafovea.io import cache_lock

    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # the workers' common folder

    def made(key: str, make) -> Path:
        d = root / f"made-once-{key}"
        with cache_lock(d):
            if not (d / ".made").is_file():
                shutil.rmtree(d, ignore_errors=True)
                d.mkdir()
                make(d)
                (d / ".made").write_text("")
        return d

    return made


# ------------------------------------------------------------------------------------------------------------------
# scheduling on the test workers (-n auto): the long tests first, and an idle worker takes over another's queue
# ------------------------------------------------------------------------------------------------------------------
def pytest_collection_modifyitems(config, items):
    """The modules that hold a test marked ``slow`` first (each module's tests kept together and in order, so that
    its module-scoped fixtures are made once): a long study that started last kept one worker busy for a minute after
    the other had finished. The order is the same on every worker (xdist requires it)."""
    slow_modules = {item.module.__name__ for item in items if item.get_closest_marker("slow") is not None
                    and getattr(item, "module", None) is not None}
    items.sort(key=lambda item: getattr(getattr(item, "module", None), "__name__", "") not in slow_modules)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``-n N`` without ``--dist``: xdist's work stealing instead of its default ``load``, which hands each worker
    fixed chunks of the queue (a worker then waits on the other's last long tests); an idle worker takes half of the
    other's pending tests. Any other ``--dist`` keeps xdist's own scheduler."""
    if config.getoption("dist", "no") != "load":
        return None
    return _module_stealing()(config, log)


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def _module_cut(collection: list[str], queue: list[int], cut: int, lo: int) -> int:
    """The cut of ``queue`` (``queue[:cut]`` stays, ``queue[cut:]`` goes to another worker) moved to the nearest
    boundary between two modules in ``[lo, len(queue) - 1]``; ``cut`` itself where there is none (the queue from
    ``lo - 1`` on is one module)."""
    cuts = [c for c in range(max(lo, 1), len(queue))
            if _module(collection[queue[c - 1]]) != _module(collection[queue[c]])]
    return min(cuts, key=lambda c: (abs(c - cut), c)) if cuts else cut


def _module_stealing():
    """xdist's work stealing with every cut at a module boundary, so that a module's tests stay on one worker and
    its module-scoped fixtures are made once: a cut inside tests/codesign/test_run.py made both workers build its
    20 s co-design run. A module is split only where the queue left to split is that one module (the run's end)."""
    from xdist.scheduler import WorkStealingScheduling
    from xdist.scheduler.worksteal import MIN_PENDING

    class ModuleStealing(WorkStealingScheduling):
        def _send_tests(self, node, num: int) -> None:
            if 0 < num < len(self.pending):
                num = _module_cut(self.collection, self.pending, num, 1)
            super()._send_tests(node, num)

        def check_schedule(self) -> None:
            # xdist's own (3.8), with the steal's cut moved by _module_cut
            nodes_up = [(node, pending) for node, pending in self.node2pending.items() if not node.shutting_down]

            def idle() -> list:
                return [node for node, pending in nodes_up if len(pending) < MIN_PENDING]

            idle_nodes = idle()
            if not idle_nodes:
                return
            if self.pending:
                for i, node in enumerate(idle_nodes):
                    self._send_tests(node, len(self.pending) // (len(idle_nodes) - i))
                idle_nodes = idle()
                if not idle_nodes:
                    return
            if self.steal_requested_from_node is not None:
                return
            victim = max(nodes_up, key=lambda np_: len(np_[1]), default=None)
            num = 0 if victim is None else min(len(victim[1]) // 2, max(0, len(victim[1]) - MIN_PENDING))
            if num == 0:
                for node in idle_nodes:
                    node.shutdown()
                return
            queue = victim[1]
            cut = _module_cut(self.collection, queue, len(queue) - num, MIN_PENDING)
            victim[0].send_steal(queue[cut:])
            self.steal_requested_from_node = victim[0]

    return ModuleStealing
