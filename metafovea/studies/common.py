"""What every study shares: its options, its result, the camera it varies, the sweep through the executor and
the files it writes.

A study is a function ``run(options) -> StudyResult``. The result holds the numbers (``results``, ``trend``:
what the paper reports against what this model gives), what was modelled and why, the figure (PNG bytes) and
the machine's timings apart (``timing``: the only part of the JSON that changes between two runs with the same
``--seed``). :func:`write_study` writes ``<name>.json``, ``<name>.png`` and ``<name>.html``.

Every case of a sweep runs through :func:`metafovea.parallel.run_tasks` (local processes, or Dask with a
scheduler address), so the results come back in the order of the items whatever the order they finish in.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.config import SystemDesign
from metafovea.errors import InputError
from metafovea.io import atomic_write_bytes, atomic_write_json, prepare_output
from metafovea.measurement import Measurement
from metafovea.report import FIGURE_DPI

if TYPE_CHECKING:
    from metafovea.imaging.scene import Scene

#: the 10 um / 0.5 um filter is in place in every study unless it says otherwise: without it the foveal channel
#: (designed at 10 um, F/2) is mostly chromatic haze (validate's report: haze fraction ~0.8 over 8-14 um), and the
#: studies are about separation, sampling and motion, not the chromatic blur of a single-wavelength metalens
FILTER = True


@dataclass(frozen=True)
class StudyOptions:
    """How a study runs: ``fast`` (small sizes, for CI: each study says which), ``seed`` (every random stream;
    same seed, same JSON), ``workers``/``scheduler`` (the executor of :mod:`metafovea.parallel`; 1, the
    default here, runs the cases in this process: a notebook or a script without a main guard, and the fast
    sizes, whose cases cost less than starting worker processes that each import and compile the solvers again;
    None = one process per core, never more than the cases, the default of ``metafovea study --workers``),
    ``system`` (default: the paper's prototype), ``psf`` (the simulator's PSF provider)."""

    fast: bool = False
    seed: int = 0
    workers: int | None = 1
    scheduler: str | None = None
    progress: bool = False
    system: SystemDesign | None = None
    psf: str = "auto"


@dataclass
class StudyResult:
    """One study's outcome; :meth:`to_json` is what ``<name>.json`` holds."""

    name: str
    title: str
    modelled: str  #: what the run simulated and reconstructed
    why: str  #: why it was modelled that way (and where it differs from the paper)
    paper: str  #: what the paper reports
    parameters: dict[str, Any]
    results: dict[str, Any]
    trend: dict[str, Any]  #: {'expected', 'observed', 'holds', 'note'}
    figure: bytes | None = None
    caption: str = ""
    tables: list[dict[str, Any]] = field(default_factory=list)  #: {'caption', 'header', 'rows'} for the page
    timing: dict[str, Any] = field(default_factory=dict)  #: seconds, speed and the machine: not reproducible
    files: dict[str, Path] = field(default_factory=dict)  #: what :func:`write_study` wrote (not in the JSON)

    def to_json(self) -> dict[str, Any]:
        return {"study": self.name, "title": self.title, "modelled": self.modelled, "why": self.why,
                "paper": self.paper, "parameters": self.parameters, "results": self.results, "trend": self.trend,
                "timing": self.timing}


def machine() -> dict[str, Any]:
    """The machine a run's timings belong to: cores usable, load average, Python and platform."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = [round(v, 2) for v in os.getloadavg()] if hasattr(os, "getloadavg") else None
    return {"nproc": cores, "load_average": load, "python": platform.python_version(), "platform": platform.platform()}


def camera(options: StudyOptions, crop: Sequence[int] | None = None, expansion: float | None = None) -> SystemDesign:
    """The study's camera: the options' system (default the paper's prototype), the sensor's working crop set to
    ``crop`` (rows, columns) and, with ``expansion`` k, the perifoveal lens at ``f2 = f1 / k`` with ``D2 = f2``
    (F/1 kept: its spot, its pixels' blur and its radiometry stay those of the prototype; only its field grows) and
    its lens-to-sensor distance f2. The foveal lens (f1, D1) is unchanged."""
    s = options.system or SystemDesign.paper()
    if crop is not None:
        s = replace(s, sensor=replace(s.sensor, crop=(int(crop[0]), int(crop[1]))))
    if expansion is not None:
        if not 1.0 < float(expansion) <= 50.0:
            raise InputError("expansion", expansion, "1 < f1/f2 <= 50")
        f2 = s.lens_to_sensor_um[0] / float(expansion)
        s = replace(s, perifoveal=s.perifoveal.with_(f_um=f2, diameter_um=f2),
                    lens_to_sensor_um=(s.lens_to_sensor_um[0], f2))
    return s


def sweep(fn: Callable[[Any], Any], items: Sequence[Any], options: StudyOptions, desc: str) -> list[Any]:
    """``[fn(item) for item in items]`` through the project's executor (results in the items' order)."""
    from metafovea.parallel import run_tasks

    out: list[Any] = [None] * len(items)
    for i, r in run_tasks(fn, items, workers=options.workers, scheduler=options.scheduler,
                          progress=options.progress, desc=desc):
        out[i] = r
    return out


#: the shutter-frame FPN's rank in the studies: the rank-20 projection their recorded figures (docs/studies.md) were
#: measured with; ``estimate_fpn``'s default is now optimal shrinkage (error 0.14 against 0.23 DN on the simulated
#: sensor): set None to use it, and re-run the full-size studies
STUDY_FPN_RANK: int | None = 20


def shutter_fpn(meas: Measurement) -> np.ndarray:
    """The fixed pattern from the measurement's closed-shutter ``calibration`` frames (as ``validate`` does, at
    rank :data:`STUDY_FPN_RANK`)."""
    from metafovea.reconstruct import estimate_fpn

    f, _ = estimate_fpn(calibration=np.asarray(meas.extras["calibration"], dtype=np.float64), rank=STUDY_FPN_RANK,
                        bound=max(0.1 * float(np.ptp(meas.frames)), 1e-9))
    return f



def measure(system: SystemDesign, scene: str | Scene, frames: int, seed: int, psf: str,
            filter_enabled: bool = FILTER) -> tuple[Measurement, np.ndarray]:
    """``frames`` frames of ``scene`` on ``system`` (a free-running polariser, 16 shutter frames) and the fixed
    pattern from those frames: every study's measurement."""
    from metafovea.imaging.simulate import simulate

    meas = simulate(system, scene, frames=frames, rng=seed, filter_enabled=filter_enabled, polarizer_mode="free",
                    calibration_frames=16, psf=psf)
    return meas, shutter_fpn(meas)


def simulated(options: StudyOptions, p: dict[str, Any], sw: Stopwatch,
              filter_enabled: bool) -> tuple[Measurement, np.ndarray]:
    """:func:`measure` of ``p['scene']`` (``p['frames']`` frames on the ``p['crop']`` camera), timed under
    ``sw('simulate')``."""
    with sw("simulate"):
        return measure(camera(options, p["crop"]), p["scene"], p["frames"], options.seed, options.psf,
                       filter_enabled)


def rounded(obj: Any, digits: int = 6) -> Any:
    """Floats rounded to ``digits`` significant digits (nested dicts/lists; NaN kept): what the JSON holds, so
    that the last bits of a sum taken in another order cannot tell two runs apart."""
    if isinstance(obj, dict):
        return {k: rounded(v, digits) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [rounded(v, digits) for v in obj]
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if not np.isfinite(v) or v == 0.0 else float(f"{v:.{digits}g}")
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.ndarray):
        return rounded(obj.tolist(), digits)
    return obj


class Stopwatch:
    """Named wall-clock intervals: ``with sw('simulate'): ...``; :attr:`seconds` for the timing key."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._t0 = time.perf_counter()

    def __call__(self, name: str) -> Stopwatch:
        self._name = name
        return self

    def __enter__(self) -> Stopwatch:
        self._t = time.perf_counter()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.seconds[self._name] = self.seconds.get(self._name, 0.0) + time.perf_counter() - self._t

    def total(self) -> float:
        return time.perf_counter() - self._t0


def write_study(result: StudyResult, out_dir: str | Path, *, force: bool = False) -> dict[str, Path]:
    """Write ``<name>.json``, ``<name>.png`` (when there is a figure) and ``<name>.html`` into ``out_dir``."""
    from metafovea.report import HtmlReport, fmt

    out = prepare_output(out_dir, force, is_dir=True)
    files = {"json": atomic_write_json(out / f"{result.name}.json", result.to_json())}
    if result.figure is not None:
        files["figure"] = atomic_write_bytes(out / f"{result.name}.png", result.figure)
    page = HtmlReport(f"metafovea study {result.name}: {result.title}")
    tr = result.trend
    page.verdict([{"stage": result.name, "check": tr.get("expected", ""), "value": tr.get("observed", ""),
                   "reference": "the paper", "passed": bool(tr.get("holds"))}])
    if tr.get("note"):
        page.paragraph(tr["note"], note=True)
    page.heading("What was modelled")
    page.paragraph(result.modelled)
    page.heading("Why")
    page.paragraph(result.why)
    page.heading("The paper")
    page.paragraph(result.paper)
    page.heading("Parameters")
    page.key_values([(k.replace("_", " "), fmt(v)) for k, v in result.parameters.items()])
    page.heading("Results")
    for t in result.tables:
        page.paragraph(t["caption"])
        page.table(t["header"], t["rows"], text_columns=t.get("text_columns", (0,)))
    if result.figure is not None:
        page.image(result.figure, result.caption)
    page.heading("Timing and machine")
    page.paragraph("Seconds and speeds depend on the machine and its load; they are kept apart from the results "
                   "(the JSON's 'timing' key), which the same --seed reproduces exactly.", note=True)
    page.key_values([(k.replace("_", " "), fmt(v)) for k, v in result.timing.items()])
    files["html"] = page.write(out / f"{result.name}.html")
    return files


def figure(rows: int, cols: int, size: tuple[float, float]) -> tuple[Any, Any]:
    """A matplotlib Figure (no pyplot state) and its axes, for :func:`metafovea.report.fig_to_png`."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=FIGURE_DPI)
    return fig, fig.subplots(rows, cols, squeeze=False)
