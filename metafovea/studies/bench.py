"""Speed against error of every stage, measured on the machine at hand: ``metafovea bench``.

:func:`run_bench` runs a short sweep per stage (:data:`STAGES`) and writes one self-contained page (``index.html``,
its figures embedded as PNG) and ``bench.json`` (every number) into a folder:

=========== ================================================ =============================================
stage       the sweep                                        error against
=========== ================================================ =============================================
rcwa        harmonics M of the RCWA solver (Li's and         the zero-order phase of the same posts at a
            Laurent's factorisation), random posts of the    high truncation (``rcwa_reference``); the
            paper's platform at 10 um; time per post         largest over the posts (rad)
psf         the sensor PSF's spectral bins (8-14 um, on      the same PSF with many bins (max abs / peak);
            and off axis) and the engine budget off axis     the engines' own estimate beside it (which
            (rays or MFT per wavelength, 9.7-10.3 um at      bounds the propagation, not the spectral
            1 deg)                                           sampling)
simulate    ``simulate(..., tolerance_k=T)``, the planner's  the full model (K rms referred to the scene,
            reduced model, for several T and scenes          :func:`metafovea.imaging.ablate.model_error_k`)
reconstruct the separation methods on a synthetic           the truth (PSNR, dB); the linear Wiener bound
            measurement (known alpha: video LSQ, the         beside the deconvolutions
            sliding solver; unknown: alternating,
            snapshot) and the PSF-aware deconvolutions
            (wiener, wavelet, tv) on a simulated recording;
            a field-dependent PSF with the on-axis kernel
            and with its patches
export      GDSII and OASIS export of patches of the foveal  the disk's own write speed: an ``O_DIRECT``
            lens, bytes against seconds                      write of as many bytes, fsynced
=========== ================================================ =============================================

``quick`` sizes (:meth:`BenchSizes.of`; the CI size) run every stage with fewer points and smaller references; the
page says which. Each stage records the load average before and after it, its seconds and the command that reruns it
alone. Nothing is written until every stage is done (then the two files, each atomically); the export's scratch
files live in a temporary folder inside the output folder (the disk measured is the one written to) and are removed
on any exit.

Shared with the scripts in ``benchmarks/``: :func:`smooth_scene` (``bench_plan.py``) and :func:`disk_write_seconds`
(``bench_export_disk.py``).
"""

from __future__ import annotations

import datetime
import math
import os
import platform
import subprocess
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import (
    PAPER_BAND_UM,
    PAPER_CROP_PX,
    PAPER_PERIOD_UM,
    PAPER_PIXEL_PITCH_UM,
    PAPER_POST_HEIGHT_UM,
    PAPER_WAVELENGTH_UM,
)
from metafovea.errors import InputError
from metafovea.io import atomic_write_json, prepare_output

#: the stages, in the order they run and the page shows them
STAGES = ("rcwa", "psf", "simulate", "reconstruct", "export")
#: the random posts' widths (um) and seed (benchmarks/bench_convergence.py's)
RCWA_WIDTHS_UM = (0.5, 3.5)
RCWA_SEED = 2026
#: O_DIRECT writes of this size at most (a pre-filled buffer, as an exporter's writer would hand the disk)
DISK_BLOCK_BYTES = 32 << 20


@dataclass(frozen=True)
class BenchSizes:
    """The sweep of every stage; :meth:`of` gives the quick (CI) or the full sizes."""

    rcwa_posts: int
    rcwa_harmonics: tuple[int, ...]
    rcwa_reference: int
    psf_bins: tuple[int, ...]
    psf_reference_bins: int
    psf_size_px: int
    psf_lenses: tuple[tuple[str, float], ...]
    psf_budgets: tuple[float, ...]
    sim_scenes: tuple[str, ...]
    sim_crop: int
    sim_frames: int
    sim_tolerances_k: tuple[float, ...]
    rec_size: int
    rec_frames: int
    rec_snapshot_iterations: int
    rec_crop: int
    rec_case_frames: int
    export_patches_mm: tuple[float, ...]

    @classmethod
    def of(cls, quick: bool) -> BenchSizes:
        if quick:
            return cls(rcwa_posts=3, rcwa_harmonics=(3, 4, 5, 6, 8), rcwa_reference=10, psf_bins=(5, 9, 17, 31),
                       psf_reference_bins=61, psf_size_px=21, psf_lenses=(("foveal", 0.0),),
                       psf_budgets=(1e6, 5e6, 2e7), sim_scenes=("siemens-star",), sim_crop=64, sim_frames=8,
                       sim_tolerances_k=(0.03, 0.1, 0.3), rec_size=64, rec_frames=24, rec_snapshot_iterations=30,
                       rec_crop=64, rec_case_frames=12, export_patches_mm=(0.5, 1.0, 2.0))
        return cls(rcwa_posts=8, rcwa_harmonics=(3, 4, 5, 6, 8, 10, 12, 14), rcwa_reference=20,
                   psf_bins=(5, 9, 17, 31, 61), psf_reference_bins=121, psf_size_px=41,
                   psf_lenses=(("foveal", 0.0), ("perifoveal", 0.0), ("perifoveal", 3.8)),
                   psf_budgets=(1e6, 5e6, 2e7, 1e8), sim_scenes=("smooth", "siemens-star"), sim_crop=PAPER_CROP_PX,
                   sim_frames=24, sim_tolerances_k=(0.01, 0.02, 0.05, 0.1, 0.2, 0.5), rec_size=PAPER_CROP_PX,
                   rec_frames=80, rec_snapshot_iterations=100, rec_crop=160, rec_case_frames=48,
                   export_patches_mm=(1.0, 2.0, 4.0, 8.0))


# ---------------------------------------------------------------------------------------------------------------
# shared with the scripts in benchmarks/


def smooth_scene(kind: str = "smooth") -> np.ndarray:
    """A smooth thermal scene (K), 256 x 256: ``smooth`` a 6 K blob on a 3 K gradient over 296 K (a 2-5 K step to the
    ambient 294 K at the field's edge); ``smooth-fade`` an 8 K blob over 294 K that fades into the ambient."""
    y, x = np.mgrid[0:256, 0:256] / 255.0
    if kind == "smooth-fade":
        return 294.0 + 8.0 * np.exp(-((x - 0.45) ** 2 + (y - 0.55) ** 2) / 0.03)
    return 296.0 + 6.0 * np.exp(-((x - 0.4) ** 2 + (y - 0.55) ** 2) / 0.08) + 3.0 * x


def disk_write_seconds(path: str | os.PathLike, nbytes: int, block: int = DISK_BLOCK_BYTES) -> tuple[float, str]:
    """Seconds to write ``nbytes`` of random data to a new file ``path`` and fsync it: the disk's own speed, the
    floor of any exporter. The file is removed afterwards.

    Parameters
    ----------
    path : str or PathLike
        A file that does not exist yet, on the disk to measure.
    nbytes : int
        Bytes to write (rounded up to whole 4 KiB pages).
    block : int
        Bytes per ``write`` call at most (one pre-filled, page-aligned buffer).

    Returns
    -------
    seconds : float
    mode : str
        ``'O_DIRECT'``, or ``'buffered'`` where the file system refuses ``O_DIRECT`` (tmpfs):
        :func:`disk_write_seconds_buffered`.
    """
    import mmap

    n = max(4096, -(-int(nbytes) // 4096) * 4096)
    size = min(int(block), n)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_DIRECT, 0o644)
    except (AttributeError, OSError):  # no O_DIRECT on this system or file system
        return disk_write_seconds_buffered(path, n)
    buf = mmap.mmap(-1, size)  # page-aligned, as O_DIRECT needs
    buf.write((os.urandom(1 << 16) * (size // (1 << 16) + 1))[:size])
    try:
        t0 = time.perf_counter()
        left = n
        while left > 0:
            left -= os.write(fd, buf if left >= size else memoryview(buf)[:left])
        os.fsync(fd)
        dt = time.perf_counter() - t0
    except OSError:  # a file system that opens O_DIRECT files but refuses their writes
        dt = None
    finally:
        os.close(fd)
        buf.close()
        os.unlink(path)
    return (dt, "O_DIRECT") if dt is not None else disk_write_seconds_buffered(path, n)


def disk_write_seconds_buffered(path: str | os.PathLike, nbytes: int) -> tuple[float, str]:
    """:func:`disk_write_seconds` through the page cache (fsynced): where ``O_DIRECT`` writes fail."""
    data = os.urandom(1 << 20)
    t0 = time.perf_counter()
    with open(path, "wb") as fh:
        left = int(nbytes)
        while left > 0:
            left -= fh.write(data[:left])
        fh.flush()
        os.fsync(fh.fileno())
    dt = time.perf_counter() - t0
    os.unlink(path)
    return dt, "buffered"


# ---------------------------------------------------------------------------------------------------------------
# the machine


def machine_info() -> dict[str, Any]:
    """The machine a bench's timings belong to: cores usable, CPU model, memory, Python and platform."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    cpu, mem = platform.processor() or platform.machine(), None
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), cpu)
        with open("/proc/meminfo") as fh:
            kb = next((int(ln.split()[1]) for ln in fh if ln.startswith("MemTotal:")), None)
            mem = None if kb is None else round(kb / 2 ** 20, 1)
    except OSError:
        pass
    return {"nproc": cores, "cpu_model": cpu, "memory_gib": mem, "python": platform.python_version(),
            "platform": platform.platform()}


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (None where the system has none)."""
    return [round(v, 2) for v in os.getloadavg()] if hasattr(os, "getloadavg") else None


def git_commit() -> str | None:
    """The checkout's commit (``+dirty`` with uncommitted changes to tracked files); None outside a git checkout."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "")


def _timed(fn: Callable[[], Any], quick_s: float = 0.0, repeats: int = 3) -> tuple[Any, float]:
    """``fn()`` and its wall seconds; a call under ``quick_s`` seconds is repeated (``repeats`` in all) and the
    least time kept (a short call's time is mostly the machine's noise)."""
    t0 = time.perf_counter()
    out = fn()
    best = time.perf_counter() - t0
    for _ in range(repeats - 1 if best < quick_s else 0):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


# ---------------------------------------------------------------------------------------------------------------
# the stages: each returns {"parameters", "rows", "notes"}; a row has "series", "setting" and "seconds"


def bench_rcwa(sizes: BenchSizes, say: Callable[[str], None]) -> dict[str, Any]:
    """Harmonics against the zero-order phase error and the time per post (module docstring), with one BLAS thread
    (as the library's sweeps run: on a loaded machine OpenBLAS' threads make the same solve 10-40x slower at random)."""
    from metafovea.parallel import blas_threads
    from metafovea.rcwa.posts import post_response

    g = np.random.default_rng(RCWA_SEED)
    wx = np.round(g.uniform(*RCWA_WIDTHS_UM, sizes.rcwa_posts), 3)
    wy = np.round(g.uniform(*RCWA_WIDTHS_UM, sizes.rcwa_posts), 3)
    n = sizes.rcwa_posts

    def solve(M: int, factorization: str) -> tuple[np.ndarray, float]:
        # post by post: a Ctrl-C waits for one post's solve at most, not for the whole batch's
        t, dt = np.empty(n, complex), 0.0
        with blas_threads(1):
            for i in range(n):
                r, dti = _timed(lambda i=i: post_response(wx[i], wy[i], PAPER_WAVELENGTH_UM, harmonics=M,
                                                          factorization=factorization, polarizations=("x",)),
                                quick_s=0.2)
                t[i], dt = complex(np.ravel(r.t_x)[0]), dt + dti
        return t, dt

    say(f"rcwa: the reference, Li's factorisation at M = {sizes.rcwa_reference}, {n} posts")
    ref, t_ref = solve(sizes.rcwa_reference, "li")
    rows = []
    for fact in ("li", "laurent"):
        for M in sizes.rcwa_harmonics:
            t, dt = solve(M, fact)
            err = np.abs(np.angle(t / ref))
            rows.append({"series": f"{fact} factorisation", "setting": f"M = {M}", "harmonics": M,
                         "plane_waves": (2 * M + 1) ** 2, "error": float(err.max()), "error_median": float(
                             np.median(err)), "seconds": dt / n})
        say(f"rcwa: {fact} factorisation, M = {', '.join(map(str, sizes.rcwa_harmonics))}")
    return {"parameters": {"posts": n, "widths_um": [[float(a), float(b)] for a, b in zip(wx, wy)],
                           "period_um": PAPER_PERIOD_UM, "height_um": PAPER_POST_HEIGHT_UM,
                           "wavelength_um": PAPER_WAVELENGTH_UM,
                           "polarisation": "x", "reference": f"li, M = {sizes.rcwa_reference}",
                           "reference_seconds_per_post": t_ref / n},
            "rows": rows, "x": ("error", "zero-order phase error, largest over the posts (rad)"),
            "y": ("seconds", "seconds per post (one polarisation, the mean over the posts)"),
            "notes": "error: |arg(t_M / t_ref)| of the x-polarised zero order, the largest over the posts; time: the "
                     "mean solve of one post (a solve under 0.2 s: the best of 3), with one BLAS thread."}


def _psf_band(lens: Any, n: int, band: tuple[float, float] = PAPER_BAND_UM) -> tuple[np.ndarray, np.ndarray]:
    from metafovea.radiometry import psf_wavelengths

    return psf_wavelengths(band, design_um=lens.wavelength_um, n=n, temperature_k=300.0)


def _psf_rows(sizes: BenchSizes, say: Callable[[str], None]) -> list[dict[str, Any]]:
    from metafovea.config import LensDesign
    from metafovea.optics import sensor_psf

    lenses = {"foveal": LensDesign.foveal(), "perifoveal": LensDesign.perifoveal()}
    px, size = PAPER_PIXEL_PITCH_UM, sizes.psf_size_px
    rows = []
    for name, field in sizes.psf_lenses:
        lens = lenses[name]
        say(f"psf: {name} lens at {field:g} deg, {', '.join(map(str, sizes.psf_bins))} bins against "
            f"{sizes.psf_reference_bins}")
        wl, w = _psf_band(lens, sizes.psf_reference_bins)
        ref = sensor_psf(lens, pixel_pitch_um=px, field_deg=field, wavelengths_um=wl, weights=w, size_px=size)
        for n in sizes.psf_bins:
            wl, w = _psf_band(lens, n)
            s, dt = _timed(lambda lens=lens, field=field, wl=wl, w=w: sensor_psf(
                lens, pixel_pitch_um=px, field_deg=field, wavelengths_um=wl, weights=w, size_px=size), quick_s=0.5)
            rows.append({"series": f"{name}, {field:g} deg, 8-14 um bins", "setting": f"{n} bins", "bins": n,
                         "engines": s.info.get("engines"), "error_estimate": float(s.error_estimate),
                         "error": float(np.abs(s.intensity - ref.intensity).max() / ref.intensity.max()),
                         "seconds": dt})
    lens = lenses["foveal"]
    wl, w = _psf_band(lens, 7, (9.7, 10.3))
    say(f"psf: foveal lens at 1 deg, budgets {', '.join(f'{b:g}' for b in sizes.psf_budgets)} against all-wave MFT")
    ref = sensor_psf(lens, pixel_pitch_um=px, field_deg=1.0, wavelengths_um=wl, weights=w, size_px=size,
                     engine="mft", error=1e-3)
    for budget in sizes.psf_budgets:
        s, dt = _timed(lambda b=budget: sensor_psf(lens, pixel_pitch_um=px, field_deg=1.0, wavelengths_um=wl,
                                                   weights=w, size_px=size, budget=b), quick_s=0.5)
        rows.append({"series": "foveal, 1 deg, 9.7-10.3 um, engine budget", "setting": f"budget {budget:g}",
                     "budget": budget, "engines": s.info.get("engines"), "error_estimate": float(s.error_estimate),
                     "error": float(np.abs(s.intensity - ref.intensity).max() / ref.intensity.max()),
                     "seconds": dt})
    return rows


def bench_psf(sizes: BenchSizes, say: Callable[[str], None]) -> dict[str, Any]:
    """Spectral bins and engine budgets of the sensor PSF against a reference (module docstring)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the cheap settings miss the default error on purpose: each row has its own
        rows = _psf_rows(sizes, say)
    return {"parameters": {"pixel_pitch_um": PAPER_PIXEL_PITCH_UM, "size_px": sizes.psf_size_px,
                           "bins": list(sizes.psf_bins),
                           "reference_bins": sizes.psf_reference_bins, "budgets": list(sizes.psf_budgets),
                           "posts": "ideal posts (PostSet.ideal), 8 phase levels on the lattice"},
            "rows": rows, "x": ("error", "error against the reference (max |I - I_ref| / peak)"),
            "y": ("seconds", "seconds per sensor PSF"),
            "notes": "The bins are geometric around the design wavelength, weighted by a 300 K Planck spectrum "
                     "(metafovea.radiometry.psf_wavelengths); the reference is the same PSF with "
                     f"{sizes.psf_reference_bins} bins (on axis) or every wavelength by MFT (off axis). The open "
                     "markers are the engines' own error estimates: they bound the propagation, not the spectral "
                     "sampling."}


def bench_simulate(sizes: BenchSizes, say: Callable[[str], None]) -> dict[str, Any]:
    """``simulate(..., tolerance_k=T)`` against the full model (module docstring; benchmarks/bench_plan.py)."""
    from metafovea.config import SystemDesign
    from metafovea.imaging import simulate
    from metafovea.imaging.ablate import model_error_k

    system = SystemDesign.paper()
    system = replace(system, sensor=replace(system.sensor, crop=(sizes.sim_crop, sizes.sim_crop)))
    kw = {"frames": sizes.sim_frames}
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the simulator's notes on a scene (a step at the field's edge and such)
        for name in sizes.sim_scenes:
            scene = smooth_scene(name) if name in ("smooth", "smooth-fade") else name
            say(f"simulate: {name}, the full model and T = {', '.join(f'{t:g}' for t in sizes.sim_tolerances_k)} K")
            simulate(system, scene, **{**kw, "frames": 2})  # warm-up: imports, the PSF and post caches
            simulate(system, scene, tolerance_k=sizes.sim_tolerances_k[0], **{**kw, "frames": 2})
            full, t_full = _timed(lambda s=scene: simulate(system, s, **kw))
            rows.append({"series": name, "setting": "full model", "tolerance_k": None, "error": 0.0,
                         "seconds": t_full, "reduced": []})
            for tol in sizes.sim_tolerances_k:
                red, dt = _timed(lambda s=scene, t=tol: simulate(system, s, tolerance_k=t, **kw))
                err = float(model_error_k(red, full))
                rows.append({"series": name, "setting": f"T = {tol:g} K", "tolerance_k": tol, "error": err,
                             "within_budget": err <= tol, "seconds": dt,
                             "reduced": list(red.meta["model"]["reduce"])})
    return {"parameters": {"system": "the paper's (SystemDesign.paper())", "band": "8-14 um (no filter)",
                           "crop_px": sizes.sim_crop, "frames": sizes.sim_frames,
                           "tolerances_k": list(sizes.sim_tolerances_k), "scenes": list(sizes.sim_scenes)},
            "rows": rows, "x": ("error", "realised error against the full model (K rms)"),
            "y": ("seconds", "seconds per simulate() call (plan included)"),
            "notes": "Each scene: a warm-up of both models (imports, PSF and post caches), then the full model once "
                     "and the planner's reduced model once per tolerance. The full model's error is 0 by definition "
                     "(drawn at the plot's left edge)."}


def _separation_rows(sizes: BenchSizes) -> list[dict[str, Any]]:
    """The separation methods on a synthetic measurement (benchmarks/bench_reconstruct.py's scene)."""
    from metafovea.reconstruct import SlidingLSQ, alternating, snapshot, video
    from metafovea.reconstruct.metrics import psnr
    from metafovea.reconstruct.synthetic import measure, polariser_alpha, scene

    x1, x2 = scene(sizes.rec_size)
    a = polariser_alpha(sizes.rec_frames)
    Y = measure(x1, x2, a, sigma=0.01, rng=0, dtype=np.float32)
    windows = sizes.rec_frames - 7

    def both(r1: np.ndarray, r2: np.ndarray) -> float:
        return 0.5 * (psnr(r1, x1, 1.0) + psnr(r2, x2, 1.0))

    def sliding() -> None:
        s = SlidingLSQ(8)
        for t in range(len(Y)):
            s.push(Y[t], a[t])
            if s.ready:
                s.solve()

    rows = []
    v, dt = _timed(lambda: video(Y, a, window=8))
    p = float(np.mean([both(v.x1[k], v.x2[k]) for k in range(0, windows, max(1, windows // 5))]))
    rows.append({"series": "separation (synthetic, sigma 0.01)", "setting": "video LSQ, known alpha",
                 "psnr_db": p, "seconds": dt / windows})
    _, dt = _timed(sliding)
    rows.append({"series": "separation (synthetic, sigma 0.01)", "setting": "SlidingLSQ, known alpha",
                 "psnr_db": p, "seconds": dt / windows})
    for prior in (None, "tv"):
        r, dt = _timed(lambda pr=prior: alternating(Y[:8], prior=pr))
        rows.append({"series": "separation (synthetic, sigma 0.01)",
                     "setting": f"alternating ({prior or 'no prior'}), unknown alpha", "psnr_db": both(r.x1, r.x2),
                     "seconds": dt})
    y0 = measure(x1, x2, [0.5], sigma=0.01, rng=0)[0]
    r, dt = _timed(lambda: snapshot(y0, iterations=sizes.rec_snapshot_iterations))
    rows.append({"series": "separation (synthetic, sigma 0.01)",
                 "setting": f"snapshot, 1 frame, {sizes.rec_snapshot_iterations} iterations",
                 "psnr_db": both(r.x1, r.x2), "seconds": dt})
    return rows


def _field_rows(system: Any, sizes: BenchSizes) -> list[dict[str, Any]]:
    """The siemens-star recording at 10 um with a field-dependent PSF (``field_patches=3``), reconstructed (wiener)
    with the on-axis kernel alone and with the file's patches (``field_psf``)."""
    from metafovea.imaging import simulate
    from metafovea.reconstruct.deconvolve import deconvolve_measurement
    from metafovea.reconstruct.fpn import estimate_fpn
    from metafovea.reconstruct.metrics import psnr

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = simulate(system, "siemens-star", field_patches=3, frames=sizes.rec_case_frames, rng=0,
                     calibration_frames=min(16, sizes.rec_case_frames), filter_enabled=True)
    fpn, info = estimate_fpn(calibration=m.extras["calibration"])
    rows = []
    for mode in ("on-axis", "auto"):
        d, dt = _timed(lambda md=mode: deconvolve_measurement(m, fpn=fpn, fpn_error_dn=info["error_rms_dn"],
                                                              method="wiener", field_psf=md, score_truth=False),
                       repeats=1)
        for i, ch in enumerate(("foveal", "perifoveal")):
            rows.append({"series": f"field-dependent PSF, {ch} channel", "setting": f"wiener, field_psf {mode}",
                         "psnr_db": psnr(d.scene[i], m.scene_truth[i]), "seconds": dt})
    return rows


def bench_reconstruct(sizes: BenchSizes, say: Callable[[str], None]) -> dict[str, Any]:
    """Reconstruction methods: PSNR against the truth and time (module docstring)."""
    from metafovea.config import SystemDesign
    from metafovea.reconstruct.deconvolve import DECONVOLUTION_METHODS
    from metafovea.studies.heldout import CASE_CALIBRATION_FRAMES, HeldOutCase, run_case

    say(f"reconstruct: separation methods on a synthetic {sizes.rec_size}^2 scene, {sizes.rec_frames} frames")
    rows = _separation_rows(sizes)
    system = SystemDesign.paper()
    system = replace(system, sensor=replace(system.sensor, crop=(sizes.rec_crop, sizes.rec_crop)))
    methods = sorted(DECONVOLUTION_METHODS)
    say(f"reconstruct: deconvolution ({', '.join(methods)}) of a simulated siemens-star recording, 10 um filter")
    case = HeldOutCase("siemens-star", True, frames=sizes.rec_case_frames,
                       calibration_frames=min(CASE_CALIBRATION_FRAMES, sizes.rec_case_frames))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run_case(system, case, methods)
    for r in res["rows"]:
        rows.append({"series": f"deconvolution, {r['channel']} channel", "setting": r["method"],
                     "psnr_db": float(r["psnr_db"]), "bound_db": float(r["bound_db"]), "seconds": r["seconds"]})
    say("reconstruct: a field-dependent PSF (3 x 3 patches), wiener with the on-axis kernel and with the patches")
    rows += _field_rows(system, sizes)
    return {"parameters": {"synthetic_size_px": sizes.rec_size, "synthetic_frames": sizes.rec_frames,
                           "window": 8, "sigma": 0.01, "deconvolution_scene": "siemens-star",
                           "deconvolution_crop_px": sizes.rec_crop, "deconvolution_frames": sizes.rec_case_frames,
                           "band": "10 um filter", "fpn": "estimated from the shutter frames",
                           "wiener_bound_seconds": res.get("bound_seconds")},
            "rows": rows, "x": ("psnr_db", "PSNR against the truth (dB)"),
            "y": ("seconds", "seconds (per window, or per recording)"),
            "notes": "Separation: the scikit-image camera / astronaut pair of benchmarks/bench_reconstruct.py, "
                     "mean PSNR of both images (data range 1). Deconvolution: one simulated recording, the fixed "
                     "pattern estimated from its shutter frames, each method against the scene; bound_db is the "
                     "linear Wiener bound of that recording (dashed lines): the filter the scene's own spectrum, "
                     "the true PSFs and noise give, the best stationary linear one on average over the noise, not a "
                     "strict limit on one recording of a scene that is not stationary (a method, the data-driven "
                     "wiener among them, can sit above it). Field-dependent PSF: the same scene "
                     "simulated in 3 x 3 field patches, wiener with the on-axis kernel alone and with the file's "
                     "patches (reconstruct --field-psf)."}


def bench_export(sizes: BenchSizes, say: Callable[[str], None], scratch: Path) -> dict[str, Any]:
    """Layout export against the disk's own write speed (module docstring; benchmarks/bench_export_disk.py)."""
    from metafovea.config import LensDesign
    from metafovea.layout.export import ExportOptions, export_layout
    from metafovea.layout.tiling import load_spec

    lens = LensDesign.foveal()
    rows = []
    for w in sizes.export_patches_mm:
        spec = load_spec(lens, patch_mm=(10.0, 5.0, w))
        say(f"export: a {w:g} mm patch of the foveal lens, GDSII and OASIS, and the disk")
        for fmt in ("gds", "oas"):
            path = scratch / f"patch.{fmt}"
            res, dt = _timed(lambda s=spec, p=path, f=fmt: export_layout(s, p, f, ExportOptions(force=True,
                                                                                               resume=False)))
            nbytes = int(res.bytes)
            path.unlink()
            disk, mode = disk_write_seconds(scratch / "disk.bin", nbytes)
            rows.append({"series": f"export {fmt}", "setting": f"{w:g} mm patch", "patch_mm": w, "bytes": nbytes,
                         "posts": int(res.posts), "seconds": dt, "mb_per_s": nbytes / dt / 1e6,
                         "disk_seconds": disk, "disk_mode": mode, "vs_disk": dt / disk})
    return {"parameters": {"design": "the paper's foveal lens (LensDesign.foveal())",
                           "patches_mm": list(sizes.export_patches_mm), "patch_centre_mm": [10.0, 5.0],
                           "posts": "the platform's RCWA post set", "workers": "one per core (the default)",
                           "disk": str(scratch.parent)},
            "rows": rows, "x": ("bytes", "file size (bytes)"), "y": ("seconds", "seconds (export, or the disk alone)"),
            "notes": "Each export is followed by a write of as many bytes straight to the disk (O_DIRECT where the "
                     "file system takes it, fsynced): vs_disk = export seconds / disk seconds, >= 1, near 1 where "
                     "the disk is the bottleneck. Small files are dominated by fixed costs (threads, the journal, "
                     "the fsyncs)."}



# ---------------------------------------------------------------------------------------------------------------
# the page

#: each stage's title on the page
TITLES = {"rcwa": "RCWA: harmonics against the zero-order phase error",
          "psf": "PSF: spectral sampling and engines against a reference",
          "simulate": "simulate: the error budget (--tolerance-k) against the full model",
          "reconstruct": "Reconstruction methods: PSNR against the truth",
          "export": "Layout export against the disk's own write speed"}
#: an exact result (error 0) is drawn on a logarithmic axis at this fraction of the smallest error above 0
PLOT_FLOOR = 0.1


def stage_figure(name: str, stage: dict[str, Any]) -> bytes:
    """The stage's speed-against-error plot as PNG: one line per series, seconds against the error (log-log; the
    reconstruction: against PSNR; the export: against the bytes, the disk's own time beside each export)."""
    from metafovea.report import fig_to_png
    from metafovea.studies.common import figure

    fig, axes = figure(1, 1, (9.5, 4.2))
    ax = axes[0, 0]
    xkey, xlabel = stage["x"]
    ykey, ylabel = stage["y"]
    series = list(dict.fromkeys(r["series"] for r in stage["rows"]))
    positive = [float(r[k]) for r in stage["rows"] for k in (xkey, "error_estimate") if float(r.get(k) or 0) > 0]
    floor = PLOT_FLOOR * min(positive, default=1.0)
    for k, s in enumerate(series):
        rows = [r for r in stage["rows"] if r["series"] == s]
        x = [max(float(r[xkey]), floor) if xkey != "psnr_db" else float(r[xkey]) for r in rows]
        y = [float(r[ykey]) for r in rows]
        swept = [i for i, r in enumerate(rows) if r["setting"] != "full model"]  # the reference: a star, apart
        line, = ax.plot([x[i] for i in swept], [y[i] for i in swept], "o-" if xkey != "psnr_db" else "o", label=s,
                        color=f"C{k}")
        ax.plot([x[i] for i in range(len(rows)) if i not in swept], [y[i] for i in range(len(rows)) if i not in swept],
                "*", ms=11, color=line.get_color())
        if "error_estimate" in rows[0]:
            ax.plot([max(float(r["error_estimate"]), floor) for r in rows], y, "o", mfc="none",
                    color=line.get_color(), label=f"{s}: the engine's estimate")
        if name == "export":
            ax.plot(x, [float(r["disk_seconds"]) for r in rows], "s--", mfc="none", color=line.get_color(),
                    label=f"the disk alone, as many bytes as {s}")
        if "bound_db" in rows[0]:
            ax.axvline(float(rows[0]["bound_db"]), ls="--", lw=0.8, color=line.get_color())
        if name in ("simulate", "reconstruct"):
            for xi, yi, r in zip(x, y, rows):
                ax.annotate(str(r["setting"]).split(",")[0], (xi, yi), fontsize=6, xytext=(3, 3),
                            textcoords="offset points")
    if xkey != "psnr_db":
        ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)  # beside the plot
    ax.set_title(TITLES[name], fontsize=10)
    return fig_to_png(fig)


def _table(stage: dict[str, Any]) -> tuple[list[str], list[list[Any]]]:
    skip = {"series"}
    keys = [k for k in dict.fromkeys(k for r in stage["rows"] for k in r) if k not in skip]
    return ["series", *keys], [[r["series"], *[r.get(k) for k in keys]] for r in stage["rows"]]


def write_page(result: dict[str, Any], path: Path) -> Path:
    """The bench's self-contained HTML page (figures embedded) from its JSON content ``result``."""
    from metafovea.report import HtmlReport, fmt

    page = HtmlReport("metafovea bench: speed against error, per stage" + (" (--quick)" if result["quick"] else ""))
    m = result["machine"]
    page.paragraph(f"Measured {result['date']} on {m['nproc']} cores ({m['cpu_model']}), {fmt(m['memory_gib'])} GiB "
                   f"of memory, {m['platform']}, Python {m['python']}; commit {result['git_commit'] or 'n/a'}, "
                   f"metafovea {result['version']}. Seconds depend on the machine and its load (the load average "
                   "before and after each stage is given): compare rows of one page, not pages of two machines.")
    page.key_values([("command", result["command"]), ("sizes", "quick (CI)" if result["quick"] else "full"),
                     ("stages", ", ".join(result["stages"])), ("seconds in all", result["seconds"])])
    for name, st in result["stages"].items():
        page.heading(TITLES[name])
        page.key_values([("command (this stage alone)", st["command"]),
                         ("load average before (1, 5, 15 min)", fmt(st["load_before"])),
                         ("load average after", fmt(st["load_after"])), ("seconds", st["seconds"]),
                         *[(k.replace("_", " "), fmt(v)) for k, v in st["parameters"].items()]])
        page.image(st.get("figure") or stage_figure(name, st), TITLES[name])
        page.paragraph(st["notes"], note=True)
        header, rows = _table(st)
        page.table(header, rows, text_columns=(0, 1))
    return page.write(path)


# ---------------------------------------------------------------------------------------------------------------
# the bench


def check_stages(stages: Sequence[str] | None) -> tuple[str, ...]:
    """``stages`` checked (names of :data:`STAGES`, any order, no repeats: run in :data:`STAGES`' order); None:
    every stage."""
    if stages is None:
        return STAGES
    given = [str(s) for s in stages]
    bad = [s for s in given if s not in STAGES]
    if bad or not given or len(set(given)) != len(given):
        raise InputError("stages", " ".join(given), f"one or more of {', '.join(STAGES)}, each once")
    return tuple(s for s in STAGES if s in given)


def stage_command(name: str, quick: bool) -> str:
    """The command line that reruns one stage alone."""
    return f"metafovea bench --stages {name}{' --quick' if quick else ''} --out DIR"


def run_bench(out_dir: str | os.PathLike, *, quick: bool = False, stages: Sequence[str] | None = None,
              force: bool = False, progress: Callable[[str], None] | None = None,
              command: str | None = None) -> dict[str, Any]:
    """Run each stage's sweep on this machine and write ``index.html`` and ``bench.json`` into ``out_dir``.

    Parameters
    ----------
    out_dir : str or PathLike
        A new or empty folder (or any, with ``force``: the two files are replaced).
    quick : bool
        The small sizes (CI), :meth:`BenchSizes.of`.
    stages : sequence of str, optional
        Some of :data:`STAGES` (default all), run in that order.
    force : bool
        Write into a folder that holds files.
    progress : callable(str), optional
        Called with one line per step (the CLI prints them).
    command : str, optional
        The command line recorded on the page (default: the Python call).

    Returns
    -------
    dict
        What ``bench.json`` holds: ``date``, ``git_commit``, ``version``, ``machine``, ``command``, ``quick``,
        ``seconds`` and per stage (``stages``) its ``command``, ``load_before``, ``load_after``, ``seconds``,
        ``parameters``, ``rows`` (each ``series``, ``setting``, ``seconds`` and the stage's measure: ``error`` (>= 0)
        or ``psnr_db``, or the export's ``bytes`` and ``vs_disk``), ``x``, ``y`` and ``notes``; and ``files``.

    Notes
    -----
    Nothing is written before every stage is done; an interrupted run leaves the folder as it found it (the
    export's scratch files are removed).
    """
    from metafovea import __version__

    names = check_stages(stages)
    out = prepare_output(out_dir, force, is_dir=True, name="out")
    say = progress or (lambda msg: None)
    sizes = BenchSizes.of(bool(quick))
    t_all = time.perf_counter()
    result: dict[str, Any] = {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"), "git_commit": git_commit(),
        "version": __version__, "machine": machine_info(), "quick": bool(quick),
        "command": command or f"run_bench({str(out)!r}, quick={bool(quick)}, stages={list(names)!r})",
        "stages": {}}
    runners: dict[str, Callable[..., dict[str, Any]]] = {
        "rcwa": bench_rcwa, "psf": bench_psf, "simulate": bench_simulate, "reconstruct": bench_reconstruct}
    with tempfile.TemporaryDirectory(prefix=".bench-", dir=out) as scratch:
        for name in names:
            load0 = load_average()
            t0 = time.perf_counter()
            st = (bench_export(sizes, say, Path(scratch)) if name == "export" else runners[name](sizes, say))
            st = {"command": stage_command(name, bool(quick)), "load_before": load0, "load_after": load_average(),
                  "seconds": time.perf_counter() - t0, **st}
            result["stages"][name] = st
            say(f"{name}: done in {st['seconds']:.1f} s")
    result["seconds"] = time.perf_counter() - t_all
    _check_numbers(result)
    figures = {name: stage_figure(name, st) for name, st in result["stages"].items()}
    files = {"json": atomic_write_json(out / "bench.json", result)}
    files["html"] = write_page({**result, "stages": {n: {**st, "figure": figures[n]}
                                                     for n, st in result["stages"].items()}}, out / "index.html")
    result["files"] = {k: str(v) for k, v in files.items()}
    return result


def _check_numbers(result: dict[str, Any]) -> None:
    """Every measured number finite and every error >= 0: a warning for each that is not (the files are still
    written: the numbers that were measured are kept)."""
    for name, st in result["stages"].items():
        for r in st["rows"]:
            for k, v in r.items():
                if isinstance(v, float) and not math.isfinite(v):
                    warnings.warn(f"bench {name}: {r['series']}, {r['setting']}: {k} = {v}", stacklevel=2)
                if k.startswith("error") and isinstance(v, float) and v < 0:
                    warnings.warn(f"bench {name}: {r['series']}, {r['setting']}: {k} = {v} < 0", stacklevel=2)
