"""End-to-end validation of a system: the README's main job (``metafovea validate``).

Stages run in the package's data-flow order and each reports what it computed, the reference it is
checked against and how long it took:

1. **design**: both lenses' numbers (exact post counts, NA, zone widths, efficiency estimates);
2. **library**: the RCWA scatterer library of the platform (computed once, then cached) and the two
   birefringent post sets (foveal lens focuses x, perifoveal focuses y);
3. **psf**: on-axis PSFs at the design wavelength with the RCWA post sets on the real lattice, checked
   against the paraxial Airy encircled energy and the lattice-efficiency estimate of the design stage;
4. **simulate**: a bundled thermal scene through the paper's camera (broadband 8-14 um as designed, and
   with the 10 um / 0.5 um filter), with closed-shutter calibration frames for the fixed-pattern noise, through
   the camera's optical train with the library's post sets (:mod:`metafovea.optics.train`: its per-channel
   throughput is printed, the same numbers ``simulate`` and ``psf`` print for the same posts);
5. **reconstruct**: every method (known-alpha least squares, with TV denoising, unknown-alpha
   alternating minimisation, the double deep image prior with a small network, single-frame snapshot)
   scored against the simulator's ground truth: the speed-against-error table.

The report is written as JSON and one self-contained HTML page (:class:`metafovea.report.HtmlReport`, figures via
:func:`metafovea.report.fig_to_png`); :func:`format_report` is the text ``metafovea validate`` prints. Every
reconstruction row goes through :func:`metafovea.reconstruct.reconstruct_measurement`, the pipeline the
``reconstruct`` command runs, and is scored by :func:`metafovea.reconstruct.metrics.score`
(:func:`reconstruction_table`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import sys
import textwrap
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.config import SystemDesign
from metafovea.design_report import format_summary, summary_dict
from metafovea.io import atomic_write_bytes, atomic_write_json
from metafovea.lens import summarize
from metafovea.measurement import Measurement
from metafovea.optics.train import throughput_lines
from metafovea.parallel import blas_threads

if TYPE_CHECKING:
    from metafovea.report import HtmlReport

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ValidateOptions:
    """What the validation runs. Defaults: the paper's 96-frame sequence (8 s at 12 frames/s)."""

    scene: str = "siemens-star"
    scene_unit: str = "kelvin"  #: of a scene file's temperatures: 'kelvin' | 'celsius' (simulate's scene_unit)
    frames: int = 96
    calibration_frames: int = 16
    window: int = 8
    filters: tuple[bool, ...] = (False, True)  #: spectral cases: broadband as designed, then the 10 um filter
    alternating_windows: int = 4  #: windows (spread over the sequence) for the unknown-alpha solver
    dip_steps: int = 20  #: warm-started from the classical solver: more steps change PSNR by < 0.05 dB (BENCHMARKS.md)
    dip_channels: int = 8
    dip_cases: str = "last"  #: run the (slow) deep image prior in 'last' case only, or 'all'/'none'
    snapshot_iterations: int = 200
    seed: int = 0
    #: the paper's polariser turns freely (phase and rate unknown to the reconstruction: the unknown-alpha rows
    #: estimate them); 'sync' locks it to the frames with a known phase, which makes alpha known
    polarizer_mode: str = "free"
    library_grid_step_um: float = 0.1
    library_harmonics: int = 10
    cache_dir: str | None = None
    psf: str = "auto"  #: PSF provider of the simulator ('auto' = metafovea.optics, cached; 'airy' for quick checks)
    #: scenes of the generator's held-out set (the first ones, test seeds: metafovea.imaging.generator) that the
    #: PSF-aware check also runs, in every spectral case, as a user records them (48 frames, the shutter frames)
    heldout_scenes: int = 4
    heldout_frames: int = 48
    progress: bool = False


def _progress(enabled: bool) -> Callable[[str], None]:
    """A ``say(msg)`` that prints one line per stage with the elapsed time (to stderr), or does nothing."""
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if enabled:
            sys.stderr.write(f"[{time.perf_counter() - t0:6.1f} s] {msg}\n")
            sys.stderr.flush()

    return say


def _airy_ee(r_um: float, wavelength_um: float, f_number: float) -> float:
    """Paraxial Airy encircled energy 1 - J0(v)^2 - J1(v)^2, v = pi r / (lambda F#)."""
    from scipy.special import j0, j1
    v = math.pi * r_um / (wavelength_um * f_number)
    return float(1.0 - j0(v) ** 2 - j1(v) ** 2)


def _psf_stage(system: SystemDesign, post_sets: dict[str, Any], lens_summaries: dict[str, Any],
               curves: dict[str, Any]) -> dict[str, Any]:
    """Both lenses' on-axis PSF numbers; ``curves`` receives each lens' PSFs and MTF curves (for the figure)."""
    from metafovea.optics import encircled_energy, pupil_mtf
    from metafovea.optics import psf as optics_psf

    out: dict[str, Any] = {}
    for lens in (system.foveal, system.perifoveal):
        t = time.perf_counter()
        ideal = optics_psf(lens, error=1e-4)
        real = optics_psf(lens, post_set=post_sets.get(lens.polarization), quantize=True, lattice=True, error=1e-4)
        fnum = lens.f_um / lens.diameter_um
        ee = encircled_energy(ideal, [17.0, 24.0])
        mtf = pupil_mtf(lens, [10.0, 29.4])
        cutoff = 2 * lens.na / lens.wavelength_um * 1000.0
        nu = np.linspace(0.0, cutoff, 41)
        curves[lens.name] = {"ideal": ideal, "real": real, "nu": nu, "mtf": pupil_mtf(lens, nu),
                             "airy_um": 1.22 * lens.wavelength_um * fnum,
                             "mtf_real": pupil_mtf(lens, nu, post_set=post_sets.get(lens.polarization),
                                                   quantize=True, lattice=True)}
        peak_ratio = float(real.intensity.max() / ideal.intensity.max())
        s = lens_summaries[lens.name]
        expected = s.post_set.get("expected_lens_efficiency") if s.post_set else s.lattice_efficiency
        out[lens.name] = {
            "seconds": time.perf_counter() - t, "engine": ideal.engine, "error_estimate": ideal.error_estimate,
            "ee17": float(ee[0]), "ee24": float(ee[1]),
            "ee17_paraxial_airy": _airy_ee(17.0, lens.wavelength_um, fnum),
            "ee24_paraxial_airy": _airy_ee(24.0, lens.wavelength_um, fnum),
            "mtf_10": float(mtf[0]), "mtf_29p4": float(mtf[1]),
            "peak_ratio_fabricated_vs_continuous": peak_ratio,
            "expected_peak_ratio_from_design": expected,
            "note": "EE and MTF: continuous-phase non-paraxial lens (paraxial Airy EE for comparison); peak ratio: "
                    "RCWA post set, 8 levels, 4 um lattice, against the design-stage estimate",
        }
    return out


#: the image metrics of a table row, in the row's order
ROW_METRICS = ("psnr_x1", "psnr_x2", "ssim_x1", "ssim_x2", "psnr_x1_level_free")


def reconstruction_table(meas: Measurement, opts: ValidateOptions, label: str, *, run_dip: bool = True,
                         say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run every method on one measurement (with closed-shutter ``calibration`` frames in its extras and the
    simulator's truth): ``{'rows', 'images', 'truth', 'fpn'}``, the rows of the speed-against-error table (case
    ``label``), the first output of each method and its truth, and the FPN estimate's report."""
    from metafovea.reconstruct import denoise, estimate_fpn, reconstruct_measurement
    from metafovea.reconstruct.metrics import score

    say = say or (lambda msg: None)
    T = meas.shape[0]
    w = min(opts.window, T)
    rows: list[dict[str, Any]] = []
    images: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def add(method: str, secs: float, unit: str, n: int, x1s: np.ndarray, x2s: np.ndarray, metrics: dict[str, float],
            alpha_mae: float | None = None, extra: dict[str, Any] | None = None) -> None:
        row = {"case": label, "method": method, "seconds": secs, "unit": unit, "n": n,
               "ms_per_unit": 1000.0 * secs / max(n, 1), **{k: metrics[k] for k in ROW_METRICS}}
        if alpha_mae is not None:
            row["alpha_mae"] = alpha_mae
        rows.append({**row, **(extra or {})})
        images[method] = (np.asarray(x1s[0]), np.asarray(x2s[0]))

    # fixed-pattern noise from the closed-shutter calibration frames stored with the measurement
    t = time.perf_counter()
    fpn, finfo = estimate_fpn(calibration=np.asarray(meas.extras["calibration"], dtype=np.float64),
                              bound=max(0.1 * float(np.ptp(meas.frames)), 1e-9))
    t_fpn = time.perf_counter() - t
    fpn_err = fpn_err_dn = None
    if meas.fpn is not None:
        tf = np.asarray(meas.fpn, dtype=np.float64)
        fpn_err_dn = float(np.sqrt(np.mean(((fpn - fpn.mean()) - (tf - tf.mean())) ** 2)))
        fpn_err = fpn_err_dn / (np.std(tf) or 1.0)

    # known alpha: sliding windows over the whole sequence, without and with FPN correction
    say(f"{label}: least squares, known alpha ({T} frames, window {w})")
    plain = reconstruct_measurement(meas, "lsq", window=w, fpn="none", level_free=True)
    add("lsq, no FPN correction", plain.seconds, "window", plain.outputs, plain.x1s, plain.x2s, plain.metrics)
    lsq = reconstruct_measurement(meas, "lsq", window=w, fpn=fpn, level_free=True)
    add("lsq (known alpha)", lsq.seconds + t_fpn / max(lsq.outputs, 1), "window", lsq.outputs, lsq.x1s, lsq.x2s,
        lsq.metrics, extra={"condition_max": float(np.max(lsq.reconstruction.info.get("condition", [np.nan])))})
    # TV denoising of the LSQ images, timed on every len/8-th window
    t = time.perf_counter()
    k_tv = list(range(0, lsq.outputs, max(1, lsq.outputs // 8)))
    d1 = np.stack([denoise(lsq.x1s[k], "tv") for k in k_tv])
    d2 = np.stack([denoise(lsq.x2s[k], "tv") for k in k_tv])
    secs = (time.perf_counter() - t) * lsq.outputs / len(k_tv)
    t1, t2 = meas.truth_over([lsq.spans[k] for k in k_tv])
    add("lsq + TV denoise", secs, "window", lsq.outputs, d1, d2, score((d1, d2), t1, t2, level_free=True))

    # unknown alpha: alternating minimisation with the foveal gauge, on windows spread over the sequence
    n_alt = max(1, min(opts.alternating_windows, T - w + 1))
    alt_starts = np.linspace(0, T - w, n_alt).round().astype(int).tolist()
    say(f"{label}: alternating minimisation, unknown alpha ({n_alt} windows)")
    alt = reconstruct_measurement(meas, "alternating", window=w, starts=alt_starts, fpn=fpn, progress=opts.progress,
                                  solver={"strict": False}, level_free=True)
    add("alternating (unknown alpha)", alt.seconds, "window", alt.outputs, alt.x1s, alt.x2s, alt.metrics,
        alt.alpha_mae, {"alpha_identified_windows": int(sum(alt.reconstruction.info["window_alpha_identified"]))})

    # double deep image prior, small network (the paper's is 128 channels and thousands of steps), warm
    # started from the classical solver: x_k = x_alternating_k + zero-mean network correction, each image
    # normalised by its own range, alternating's alpha held (the paper's random start needs ~1000 steps to come
    # within 1 dB of the classical solver: an offline method, benchmarks/bench_dip.py)
    if run_dip:
        say(f"{label}: deep image prior, warm start ({opts.dip_channels} channels, {opts.dip_steps} steps)")
        # the same windows as the alternating row, so that the two rows compare
        d = reconstruct_measurement(meas, "dip", window=w, starts=alt_starts, fpn=fpn, level_free=True,
                                    progress=opts.progress,
                                    solver={"channels": opts.dip_channels, "steps": opts.dip_steps, "rng": opts.seed,
                                            "init": "classical"})
        add(f"dip (warm start from alternating, {opts.dip_channels} ch, {opts.dip_steps} steps)", d.seconds,
            "window", d.outputs, d.x1s, d.x2s, d.metrics, d.alpha_mae,
            {"steps": opts.dip_steps, "channels": opts.dip_channels, "init": "classical"})

    # single snapshot: one frame near alpha = 0.5, scored against that frame's truth
    k = int(np.argmin(np.abs(meas.alpha - 0.5)))
    say(f"{label}: single-frame snapshot (frame {k}, alpha {meas.alpha[k]:.2f})")
    snap = reconstruct_measurement(meas, "snapshot", frame=k, known_alpha=True, fpn=fpn, level_free=True,
                                   progress=opts.progress,
                                   solver={"iterations": opts.snapshot_iterations})
    add("snapshot (one frame)", snap.seconds, "frame", 1, snap.x1s, snap.x2s, snap.metrics)
    # the unseparated frame as the floor a snapshot method has to beat
    y = (meas.frames[k] - fpn).astype(np.float32).astype(np.float64)
    t1, t2 = (t if t.ndim == 2 else t[0] for t in meas.truth_over([(k, k + 1)]))
    add("no separation (frame as both images)", 0.0, "frame", 1, y[None], y[None],
        score((y, y), t1, t2, level_free=True))
    truth = tuple(np.asarray(t if t.ndim == 2 else t[0]) for t in meas.truth_over([(0, w)]))
    say(f"{label}: PSF-aware separation and deconvolution (known alpha, all {T} frames)")
    # the FPN estimate's error (its own estimate from the shutter frames: SURE of the shrinkage) counts in the
    # deconvolution's noise
    scene_rows = deconvolution_rows(meas, fpn, label, fpn_error_dn=finfo.get("error_rms_dn") or 0.0)
    return {"rows": rows, "images": images, "truth": truth, "scene_rows": scene_rows,
            "alternating_alpha": alt.reconstruction.alpha_per_frame(T),
            "fpn": {"identified": finfo.get("identified"), "rank": finfo.get("rank"),
                    "relative_rms_error": fpn_err, "seconds": t_fpn,
                    "estimated_error_rms_dn": finfo.get("error_rms_dn"), "true_error_rms_dn": fpn_err_dn,
                    "error_rms_from": finfo.get("error_rms_from"), "rank_rule": finfo.get("rank_rule")}}


def deconvolution_rows(meas: Measurement, fpn: np.ndarray, label: str,
                       methods: tuple[str, ...] = ("wavelet", "wiener"),
                       fpn_error_dn: float = 0.0) -> list[dict[str, Any]]:
    """The PSF-aware rows of case ``label``: each method of :func:`metafovea.reconstruct.deconvolve_measurement`
    (known alpha, all frames, ``fpn`` subtracted) scored against the scene through a perfect lens, with the Wiener
    bound and the hazy images' own scores; [] for a scene without that truth (video)."""
    from metafovea.reconstruct import deconvolve_measurement

    if "scene_x1" not in meas.extras or meas.alpha is None:
        return []
    rows = []
    for method in methods:
        d = deconvolve_measurement(meas, fpn=fpn, method=method, fpn_error_dn=fpn_error_dn)
        sc = d.info["scores"]
        rows.append({"case": label, "method": f"psf-aware {method}", "seconds": d.info["seconds"],
                     **{k: v for k, v in sc.items() if isinstance(v, float)},
                     "prior_fit": d.info.get("prior_fit"), "tv_weight": d.info.get("tv_weight")})
    return rows


def _heldout_rows(system: SystemDesign, opts: ValidateOptions, say: Callable[[str], None]) -> list[dict[str, Any]]:
    """The PSF-aware rows of the generator's first ``opts.heldout_scenes`` held-out scenes in every spectral case:
    simulated as a user records them, the fixed pattern from their shutter frames (:func:`deconvolution_rows`)."""
    from metafovea.imaging.generator import held_out_scenes
    from metafovea.reconstruct.fpn import estimate_fpn
    from metafovea.studies.heldout import HeldOutCase, simulate_case

    rows: list[dict[str, Any]] = []
    for name, _ in held_out_scenes(opts.heldout_scenes) if opts.heldout_scenes > 0 else []:
        for filt in opts.filters:
            label = f"{name}, 10 um filter" if filt else f"{name}, 8-14 um"
            say(f"psf-aware on a held-out scene: {label}, {opts.heldout_frames} frames")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                meas = simulate_case(system, HeldOutCase(name, filt, frames=opts.heldout_frames,
                                                         calibration_frames=opts.calibration_frames,
                                                         seed=opts.seed, psf=opts.psf))
                fpn, info = estimate_fpn(calibration=meas.extras["calibration"])
                rows.extend(deconvolution_rows(meas, fpn, label, fpn_error_dn=info.get("error_rms_dn") or 0.0))
    return rows


def format_scene_table(rows: list[dict[str, Any]]) -> str:
    """The PSF-aware rows as text: PSNR against the scene (x1, x2), the Wiener bound's, the hazy images', and the
    brightness-temperature RMSE."""
    head = (f"  {'case':<28} {'method':<20} {'s':>6} {'PSNR x1':>8} {'bound':>7} {'hazy':>6} {'PSNR x2':>8} "
            f"{'bound':>7} {'hazy':>6} {'T rms x1':>9} {'T rms x2':>9}")
    lines = [head]
    for r in rows:
        def f(k: str, w: int, d: int = 2, r: dict[str, Any] = r) -> str:
            v = r.get(k)
            return f"{v:>{w}.{d}f}" if isinstance(v, float) else " " * w
        lines.append(f"  {r['case']:<28} {r['method']:<20} {r['seconds']:>6.1f} {f('psnr_x1', 8)} "
                     f"{f('wiener_bound_psnr_x1', 7)} {f('psnr_x1_hazy_image', 6)} {f('psnr_x2', 8)} "
                     f"{f('wiener_bound_psnr_x2', 7)} {f('psnr_x2_hazy_image', 6)} "
                     f"{f('temperature_rmse_x1_k', 7)} K {f('temperature_rmse_x2_k', 7)} K")
    return "\n".join(lines)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metafovea.plotting import iron_colormap

    return plt, iron_colormap()


def _figure(label: str, res: dict[str, Any]) -> bytes:
    """The first window of every method beside the truth, iron palette, one colour bar (DN) per channel row."""
    from metafovea.report import fig_to_png

    plt, iron = _plt()
    names = ["truth"] + [m for m in res["images"] if not m.startswith("no separation")]
    fig, axes = plt.subplots(2, len(names), figsize=(2.3 * len(names) + 1.0, 5), squeeze=False,
                             constrained_layout=True)
    t1, t2 = res["truth"]
    for i, ref in enumerate((t1, t2)):
        lo, hi = np.percentile(ref, 0.5), np.percentile(ref, 99.5)
        if hi <= lo:
            lo, hi = lo - 1.0, hi + 1.0
        im = None
        for j, name in enumerate(names):
            img = ref if name == "truth" else res["images"][name][i]
            ax = axes[i, j]
            im = ax.imshow(img, cmap=iron, vmin=lo, vmax=hi)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(textwrap.fill(name, 20), fontsize=8)
        axes[i, 0].set_ylabel("foveal x1" if i == 0 else "perifoveal x2")
        fig.colorbar(im, ax=axes[i, :].tolist(), shrink=0.85, label="DN")
    fig.suptitle(f"{label}: first window, colour range from the truth")
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _frames_figure(meas: Measurement, n: int = 6) -> bytes:
    """The first ``n`` measured frames (iron, DN colour bar), each titled with its true alpha."""
    from metafovea.report import fig_to_png

    plt, iron = _plt()
    n = min(n, meas.shape[0])
    fr = np.asarray(meas.frames[:n], dtype=np.float64)
    lo, hi = np.percentile(fr, 0.5), np.percentile(fr, 99.5)
    fig, axes = plt.subplots(1, n, figsize=(2.0 * n + 1.0, 2.6), squeeze=False, constrained_layout=True)
    im = None
    for k in range(n):
        ax = axes[0, k]
        im = ax.imshow(fr[k], cmap=iron, vmin=lo, vmax=hi if hi > lo else lo + 1)
        ax.set_xticks([])
        ax.set_yticks([])
        a = "" if meas.alpha is None else f", alpha {meas.alpha[k]:.2f}"
        ax.set_title(f"frame {k}{a}", fontsize=8)
    fig.colorbar(im, ax=axes[0, :].tolist(), shrink=0.9, label="DN")
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _alpha_figure(meas: Measurement, estimated: np.ndarray | None) -> bytes:
    """alpha(t): the file's (true) and the unknown-alpha solver's estimate on the frames it solved."""
    from metafovea.report import fig_to_png

    plt, _ = _plt()
    fig, ax = plt.subplots(figsize=(7, 2.6), constrained_layout=True)
    t = np.asarray(meas.times_s)
    if meas.alpha is not None:
        ax.plot(t, meas.alpha, "-", color="0.5", label="true")
    if estimated is not None:
        e = np.asarray(estimated, dtype=np.float64)
        ok = np.isfinite(e)
        ax.plot(t[ok], e[ok], "o", ms=3, color="C3", label="estimated (alternating, unknown alpha)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("alpha (mixing ratio)")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(fontsize=7, loc="upper right")
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _psf_figure(curves: dict[str, Any]) -> bytes:
    """Each lens' fabricated on-axis PSF at 10 um (central +-5 Airy radii, um axes, colour bar) and both lenses'
    MTFs (continuous and fabricated) against spatial frequency."""
    from metafovea.report import fig_to_png

    plt, _ = _plt()
    names = list(curves)
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(4.0 * (len(names) + 1), 3.4), constrained_layout=True)
    for ax, name in zip(axes, names):
        p = curves[name]["real"]
        img = np.asarray(p.intensity)
        H, W = img.shape
        r = curves[name]["airy_um"] * 3.0
        n = max(4, min(W // 2, int(math.ceil(r / p.pitch_um))))
        cy, cx = int(np.argmax(img.max(axis=1))), int(np.argmax(img.max(axis=0)))
        img = img[max(0, cy - n):cy + n + 1, max(0, cx - n):cx + n + 1]
        peak = float(img.max()) or 1.0
        half = 0.5 * img.shape[1] * p.pitch_um
        im = ax.imshow(img / peak, cmap="magma", extent=(-half, half, -half, half), origin="lower")
        ax.set_xlabel("x (um)")
        ax.set_ylabel("y (um)")
        ax.set_title(f"{name}: PSF, fabricated posts (+-3 Airy radii)", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.85, label="intensity / peak")
    ax = axes[-1]
    for i, name in enumerate(names):
        c = curves[name]
        ax.plot(c["nu"], c["mtf"], "-", color=f"C{i}", label=f"{name}, continuous phase")
        ax.plot(c["nu"], c["mtf_real"], "--", color=f"C{i}", label=f"{name}, fabricated")
    ax.set_xlabel("spatial frequency (cycles/mm)")
    ax.set_ylabel("MTF")
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=7)
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def validate_system(system: SystemDesign, opts: ValidateOptions | None = None,
                    out_dir: Path | None = None) -> dict[str, Any]:
    """Run every stage on ``system``; returns a JSON-serialisable report (and writes it to ``out_dir``)."""
    from metafovea.imaging import simulate
    from metafovea.library import platform_post_sets

    opts = opts or ValidateOptions()
    say = _progress(opts.progress)
    report: dict[str, Any] = {"created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
                              "options": dataclasses.asdict(opts), "system": {"expansion": system.expansion},
                              "stages": {}}
    t_all = time.perf_counter()

    say("library: RCWA scatterer library of the platform (cached after the first run) and post sets")
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post_sets, lib = platform_post_sets(system.platform, system.foveal.levels,
                                            grid_step_um=opts.library_grid_step_um,
                                            harmonics=opts.library_harmonics, progress=opts.progress)
    report["stages"]["library"] = {
        "seconds": time.perf_counter() - t, "from_cache": bool(lib.meta.get("from_cache")),
        "posts": int(lib.wx_um.size * lib.wy_um.size), "max_error_estimate": lib.meta.get("max_error_estimate"),
        "post_sets": {pol: {k: ps.info.get(k) for k in ("expected_focusing_efficiency", "max_abs_phase_error_rad",
                                                         "pass_phase_spread_rad", "pass_coherent_transmission")}
                      for pol, ps in post_sets.items()}}

    say("design: both lenses")
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lenses = {lens.name: summarize(lens, post_set=post_sets.get(lens.polarization), rng=opts.seed)
                  for lens in (system.foveal, system.perifoveal)}
    report["stages"]["design"] = {"seconds": time.perf_counter() - t,
                                  "lenses": {k: summary_dict(v) for k, v in lenses.items()}}

    say("psf: on-axis PSFs of both lenses")
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        curves: dict[str, Any] = {}
        psf_res = _psf_stage(system, post_sets, lenses, curves)
    report["stages"]["psf"] = {"seconds": time.perf_counter() - t, "lenses": psf_res}
    figs_psf = _psf_figure(curves)

    cases: dict[str, Any] = {}
    rows: list[dict[str, Any]] = []
    scene_rows: list[dict[str, Any]] = []
    figs: dict[str, Any] = {"psf": figs_psf}
    for i_case, filt in enumerate(opts.filters):
        label = (f"{opts.scene}, 10 um filter" if filt else f"{opts.scene}, 8-14 um")
        say(f"simulate: {label}, {opts.frames} frames + {opts.calibration_frames} calibration frames")
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            meas = simulate(system, opts.scene, rng=opts.seed, frames=opts.frames, filter_enabled=filt,
                            psf_cache_dir=opts.cache_dir, calibration_frames=opts.calibration_frames,
                            psf=opts.psf, posts=post_sets, polarizer_mode=opts.polarizer_mode,
                            scene_unit=opts.scene_unit)
        t_sim = time.perf_counter() - t
        t = time.perf_counter()
        run_dip = opts.dip_cases == "all" or (opts.dip_cases == "last" and i_case == len(opts.filters) - 1)
        with blas_threads(1):
            res = reconstruction_table(meas, opts, label, run_dip=run_dip, say=say)
        cases[label] = {"simulate_seconds": t_sim, "reconstruct_seconds": time.perf_counter() - t,
                        "frames": list(np.shape(meas.frames)),
                        "haze_fraction": {ch: ((meas.meta.get("psf") or {}).get(ch) or {}).get("haze", {})
                                          .get("fraction") for ch in ("foveal", "perifoveal")},
                        "netd_effective_k": meas.meta.get("netd_effective_k"), "fpn": res["fpn"],
                        "foveal_constraint": meas.meta.get("foveal_constraint"),
                        "optical_train": meas.meta.get("optical_train")}
        rows.extend(res["rows"])
        scene_rows.extend(res["scene_rows"])
        alt_alpha = res.get("alternating_alpha")
        figs[label] = {"montage": _figure(label, res), "frames": _frames_figure(meas),
                       "alpha": _alpha_figure(meas, alt_alpha)}
    report["stages"]["simulate_reconstruct"] = cases
    scene_rows.extend(_heldout_rows(system, opts, say))
    report["table"] = rows
    report["scene_table"] = scene_rows
    report["seconds_total"] = time.perf_counter() - t_all
    report["_summaries"] = lenses
    if out_dir is not None:
        _write_report(report, figs, out_dir)
    say(f"done in {report['seconds_total']:.1f} s")
    return report


TABLE_COLUMNS = ("case", "method", "ms_per_unit", "unit", "psnr_x1", "psnr_x1_level_free", "psnr_x2", "ssim_x1",
                 "ssim_x2", "alpha_mae")


def _table_rows(rows: list[dict[str, Any]]) -> list[list[Any]]:
    return [[r.get(c, float("nan")) for c in TABLE_COLUMNS] for r in rows]


def verdict(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Each stage against its reference: ``{stage, check, value, reference, passed}`` items (the report's top)."""
    items: list[dict[str, Any]] = []
    for name, v in report["stages"]["psf"]["lenses"].items():
        got, want = v["peak_ratio_fabricated_vs_continuous"], v["expected_peak_ratio_from_design"]
        items.append({"stage": "psf", "check": f"{name}: fabricated/continuous peak against the design-stage estimate",
                      "value": f"{got:.3f}", "reference": f"{want:.3f} +- 5 %",
                      "passed": bool(abs(got - want) <= 0.05 * abs(want))})
    rows = report["table"]
    for label in report["stages"]["simulate_reconstruct"]:
        r = {x["method"].split(" (")[0]: x for x in rows if x["case"] == label}
        if "lsq" in r and "lsq, no FPN correction" in r:
            a, b = r["lsq"]["psnr_x1"], r["lsq, no FPN correction"]["psnr_x1"]
            items.append({"stage": "reconstruct", "check": f"{label}: FPN from the shutter frames helps (x1)",
                          "value": f"{a:.2f} dB", "reference": f"> {b:.2f} dB without", "passed": bool(a > b)})
        fp = (report["stages"]["simulate_reconstruct"][label] or {}).get("fpn") or {}
        est, true = fp.get("estimated_error_rms_dn"), fp.get("true_error_rms_dn")
        if isinstance(est, float) and isinstance(true, float) and true > 0:
            how = "SURE" if fp.get("error_rms_from") == "sure" else "split halves"
            items.append({"stage": "reconstruct", "check": f"{label}: the FPN estimate's error, estimated ({how}) "
                          "against the true", "value": f"{est:.3f} DN", "reference": f"{true:.3f} DN +- 25 %",
                          "passed": bool(abs(est / true - 1) <= 0.25)})
        alt = r.get("alternating")
        if alt is not None and alt.get("alpha_mae") is not None:
            items.append({"stage": "reconstruct", "check": f"{label}: unknown alpha, mean abs error",
                          "value": f"{alt['alpha_mae']:.2g}", "reference": "<= 2e-3",
                          "passed": bool(alt["alpha_mae"] <= 2e-3)})
        # like with like: alternating's TV prior against known-alpha least squares with the same TV denoising
        ref = "lsq + TV denoise" if "lsq + TV denoise" in r else "lsq"
        if alt is not None and ref in r and "filter" in label:
            d = alt["psnr_x1"] - r[ref]["psnr_x1"]
            items.append({"stage": "reconstruct",
                          "check": f"{label}: unknown-alpha foveal image against known alpha ({ref})",
                          "value": f"{d:+.2f} dB", "reference": ">= -0.5 dB", "passed": bool(d >= -0.5)})
    from metafovea.reconstruct.deconvolve import DEFAULT_DECONVOLUTION

    for sr in report.get("scene_table", []):
        if sr["method"] != f"psf-aware {DEFAULT_DECONVOLUTION}":  # the linear rows are shown, not judged
            continue
        # a held-out scene may fall short of the bound by the issue's floor (the bound is a reference, not a
        # limit: a linear estimate knowing the scene's true spectrum)
        floor = HELDOUT_FLOOR_DB if sr["case"].startswith("gen:") else 0.0
        for i in (1, 2):
            got, bound = sr.get(f"psnr_x{i}"), sr.get(f"wiener_bound_psnr_x{i}")
            if isinstance(got, float) and isinstance(bound, float):
                items.append({"stage": "psf-aware",
                              "check": f"{sr['case']}: x{i} scene PSNR ({DEFAULT_DECONVOLUTION}) against the "
                                       "Wiener bound",
                              "value": f"{got:.2f} dB ({got - bound:+.2f})",
                              "reference": f">= {bound - floor:.2f} dB" + (f" (bound - {floor} dB)" if floor else ""),
                              "passed": bool(got >= bound - floor)})
    return items


#: how far below the Wiener bound a held-out scene's PSF-aware row may fall and pass (dB): issue 31's floor
HELDOUT_FLOOR_DB = 0.3

#: the HTML table's columns: (key, header with unit)
HTML_COLUMNS = (("method", "method"), ("time", "time"), ("psnr_x1", "PSNR x1 (dB)"),
                ("psnr_x1_level_free", "PSNR x1, level-free (dB)"), ("psnr_x2", "PSNR x2 (dB)"),
                ("ssim_x1", "SSIM x1"), ("ssim_x2", "SSIM x2"), ("alpha_mae", "alpha mean abs error"))
#: rows that are baselines, not methods
BASELINES = ("no separation", "lsq, no FPN correction")


def _case_table(html: HtmlReport, rows: list[dict[str, Any]]) -> None:
    """One case's speed-against-error table: units in the headers, the best PSNR/SSIM of the methods marked,
    baselines marked."""
    body, base = [], []
    for i, r in enumerate(rows):
        body.append([r["method"], f"{r['ms_per_unit']:.3g} ms/{r['unit']}"]
                    + [r.get(k) for k, _ in HTML_COLUMNS[2:]])
        if r["method"].startswith(BASELINES):
            base.append(i)
    best = []
    for j, (k, _) in enumerate(HTML_COLUMNS):
        if k.startswith(("psnr", "ssim")):
            vals = [(r.get(k), i) for i, r in enumerate(rows) if i not in base and isinstance(r.get(k), float)]
            if vals:
                best.append((max(vals)[1], j))
    html.table([h for _, h in HTML_COLUMNS], body, best=best, baseline_rows=base)


def _write_report(report: dict[str, Any], figs: dict[str, Any], out_dir: Path) -> None:
    from metafovea.design_report import summary_rows
    from metafovea.report import HtmlReport, fmt

    rep = {k: v for k, v in report.items() if not k.startswith("_")}
    atomic_write_json(out_dir / "validate.json", rep)
    html = HtmlReport("metafovea validate: end-to-end validation")
    html.verdict(verdict(report))
    html.paragraph(f"created {report['created_utc']} UTC; total {report['seconds_total']:.1f} s; field expansion "
                   f"f1/f2 = {report['system']['expansion']:g}x")
    html.heading("Design")
    for name, s in report["_summaries"].items():
        html.heading(name, 3)
        html.key_values(summary_rows(s))
        for msg in s.warnings:
            html.paragraph(f"warning: {msg}", note=True)
    lib = report["stages"]["library"]
    html.heading("Scatterer library and post sets")
    html.paragraph(f"{lib['posts']} posts, {lib['seconds']:.1f} s{' (from cache)' if lib['from_cache'] else ''}, "
                   f"largest convergence estimate {fmt(lib['max_error_estimate'])}")
    html.table(["focuses", "expected efficiency", "max phase error (rad)", "pass-through phase spread (rad)",
                "pass-through transmission"],
               [[p, *v.values()] for p, v in lib["post_sets"].items()])
    html.heading("On-axis PSFs at the design wavelength")
    ps = report["stages"]["psf"]["lenses"]
    html.table(["lens", "EE in 17 um", "EE in 17 um, paraxial Airy", "EE in 24 um", "EE in 24 um, paraxial Airy",
                "MTF at 10 cycles/mm", "MTF at 29.4 cycles/mm", "peak, fabricated / continuous",
                "design-stage estimate", "engine", "time (s)"],
               [[n, v["ee17"], v["ee17_paraxial_airy"], v["ee24"], v["ee24_paraxial_airy"], v["mtf_10"],
                 v["mtf_29p4"], v["peak_ratio_fabricated_vs_continuous"], v["expected_peak_ratio_from_design"],
                 v["engine"], v["seconds"]] for n, v in ps.items()])
    if figs.get("psf"):
        html.image(figs["psf"], "On-axis PSFs with the RCWA posts (8 levels, 4 um lattice) and the MTFs of both lenses")
    html.heading("Reconstruction: speed against error")
    html.paragraph("PSNR/SSIM against the simulator's noise-free images (data range = the truth's range); the "
                   "level-free x1 PSNR removes the mean error first (what is left when the alpha gauge is off); "
                   "time per window of 8 frames, or per frame for the single-frame rows. Bold: the best method of "
                   "the case; grey italic: baselines. The foveal channel is mostly haze without the filter, so "
                   "its contrast against the 50 mK NETD is low: compare methods within a case.", note=True)
    for label, fg in ((k, v) for k, v in figs.items() if k != "psf"):
        c = report["stages"]["simulate_reconstruct"][label]
        html.heading(label, 3)
        hz = c.get("haze_fraction") or {}
        html.key_values([("frames (T, H, W)", " x ".join(str(v) for v in c["frames"])),
                         ("simulate", f"{c['simulate_seconds']:.1f} s"),
                         ("reconstruct (every row)", f"{c['reconstruct_seconds']:.1f} s"),
                         ("haze fraction of the light (foveal, perifoveal)",
                          f"{fmt(hz.get('foveal'))}, {fmt(hz.get('perifoveal'))}"),
                         ("fixed pattern from the shutter frames",
                          f"{fmt(c['fpn'].get('identified'))}, rank {fmt(c['fpn'].get('rank'))}, relative rms error "
                          f"{fmt(c['fpn'].get('relative_rms_error'))}")])
        if isinstance(c.get("optical_train"), list):
            html.pre("\n".join(throughput_lines(c["optical_train"])))
        _case_table(html, [r for r in report["table"] if r["case"] == label])
        html.image(fg["frames"], f"{label}: the first measured frames")
        html.image(fg["alpha"], f"{label}: alpha(t), true and estimated without knowing it")
        html.image(fg["montage"], f"{label}: every method's first window beside the truth")
        atomic_write_bytes(out_dir / f"reconstruction_{label.replace(' ', '_').replace(',', '')}.png", fg["montage"])
    if report.get("scene_table"):
        html.heading("PSF-aware reconstruction: the scene itself")
        html.paragraph("Joint separation and deconvolution with the channels' PSFs (metafovea.reconstruct.deconvolve), "
                       "known alpha, all frames, scored against the scene through a perfect lens; bound: the best "
                       "stationary linear (Wiener) reconstruction from the true PSFs, noise and scene spectrum; hazy: "
                       "the simulator's noise-free sensor image against the same scene; temperatures are brightness "
                       "temperatures through the radiometric calibration.", note=True)
        html.table(["case", "method", "time (s)", "PSNR x1 (dB)", "x1 bound (dB)", "x1 hazy (dB)", "PSNR x2 (dB)",
                    "x2 bound (dB)", "x2 hazy (dB)", "temperature rms x1 (K)", "temperature rms x2 (K)"],
                   [[r["case"], r["method"], r["seconds"], r.get("psnr_x1"), r.get("wiener_bound_psnr_x1"),
                     r.get("psnr_x1_hazy_image"), r.get("psnr_x2"), r.get("wiener_bound_psnr_x2"),
                     r.get("psnr_x2_hazy_image"), r.get("temperature_rmse_x1_k"), r.get("temperature_rmse_x2_k")]
                    for r in report["scene_table"]], text_columns=(0, 1))
    html.write(out_dir / "validate.html")


#: the terminal table's columns: (header, value of a row as text), right-aligned after the first two
_TEXT_COLUMNS = (
    ("case", lambda r: r["case"]),
    ("method", lambda r: r["method"]),
    ("time", lambda r: f"{r['ms_per_unit']:.2f} ms/{r['unit']}"),
    ("PSNR x1 (dB)", lambda r: f"{r['psnr_x1']:.2f}"),
    ("level-free x1 (dB)", lambda r: f"{r['psnr_x1_level_free']:.2f}"),
    ("PSNR x2 (dB)", lambda r: f"{r['psnr_x2']:.2f}"),
    ("SSIM x1", lambda r: f"{r['ssim_x1']:.3f}"),
    ("SSIM x2", lambda r: f"{r['ssim_x2']:.3f}"),
    ("alpha MAE", lambda r: "" if r.get("alpha_mae") is None else f"{r['alpha_mae']:.4f}"),
)


def format_table(rows: list[dict[str, Any]]) -> str:
    """The speed-against-error rows as an aligned text table (units in the headers, time per window or frame)."""
    cells = [[fn(r) for _, fn in _TEXT_COLUMNS] for r in rows]
    heads = [h for h, _ in _TEXT_COLUMNS]
    widths = [max([len(h)] + [len(c[j]) for c in cells]) for j, h in enumerate(heads)]

    def line(vals: list[str]) -> str:
        return "  " + " ".join(v.ljust(w) if j < 2 else v.rjust(w) for j, (v, w) in enumerate(zip(vals, widths)))

    return "\n".join([line(heads).rstrip()] + [line(c).rstrip() for c in cells])


def format_report(rep: dict[str, Any], summaries: dict[str, Any], system: str, out_dir: Path) -> str:
    """The text ``metafovea validate`` prints: the system, both lenses' design summaries, the library, the PSFs and
    the speed-against-error table of :func:`validate_system`'s report ``rep`` (written to ``out_dir``)."""
    lines = [f"system: {system}, field expansion f1/f2 = {rep['system']['expansion']:g}x"]
    for name, s in summaries.items():
        lines += [f"\n== design: {name} ==", format_summary(s)]
    lib = rep["stages"]["library"]
    cached = " (cache)" if lib["from_cache"] else ""
    lines.append(f"\n== library: {lib['posts']} posts, {lib['seconds']:.1f} s{cached} ==")
    for pol, v in lib["post_sets"].items():
        lines.append(f"  post set {pol}: expected efficiency {v['expected_focusing_efficiency']:.3f}, max phase error "
                     f"{v['max_abs_phase_error_rad']:.3f} rad, pass-through spread "
                     f"{v['pass_phase_spread_rad']:.3f} rad")
    lines.append("\n== psf (on axis, 10 um) ==")
    for n, v in rep["stages"]["psf"]["lenses"].items():
        lines.append(f"  {n}: EE17 {v['ee17']:.4f} (paraxial Airy {v['ee17_paraxial_airy']:.4f}), "
                     f"EE24 {v['ee24']:.4f}, "
                     f"MTF@10 {v['mtf_10']:.4f}, MTF@29.4 {v['mtf_29p4']:.4f}; fabricated/continuous peak "
                     f"{v['peak_ratio_fabricated_vs_continuous']:.3f} "
                     f"(design estimate {v['expected_peak_ratio_from_design']:.3f})")
    for label, c in rep["stages"]["simulate_reconstruct"].items():
        lines.append(f"\n== optical train ({label}) ==")
        lines += [f"  {ln}" for ln in throughput_lines(c["optical_train"])]
    if rep.get("scene_table"):
        lines += ["\n== PSF-aware reconstruction against the scene (known alpha, all frames; 'bound': the Wiener "
                  "bound from the true PSFs, noise and spectrum; 'hazy': the noise-free sensor image) ==",
                  format_scene_table(rep["scene_table"])]
    checks = verdict(rep)
    n_fail = sum(1 for c in checks if not c["passed"])
    lines += ["\n== verdict: " + (f"all {len(checks)} checks pass" if not n_fail else
                                  f"{n_fail} of {len(checks)} checks fail") + " =="]
    lines += [f"  {'pass' if c['passed'] else 'FAIL'}  {c['stage']}: {c['check']}: {c['value']} "
              f"(reference {c['reference']})" for c in checks]
    lines += ["\n== reconstruction: speed against error ==", format_table(rep["table"]),
              f"\nreport: {out_dir / 'validate.html'} (and validate.json); total {rep['seconds_total']:.1f} s"]
    return "\n".join(lines)
