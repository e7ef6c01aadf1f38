"""PSF/MTF reports: :func:`psf_report` writes the PNG figures, JSON numbers and one self-contained HTML page of
one lens; :func:`psf_reports` is the ``metafovea psf`` pipeline (checks, several lenses in worker processes);
:func:`lens_lines` and :func:`timing_line` are its summary for people (what the command prints)."""

from __future__ import annotations

import contextlib
import logging
import math
import time
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from metafovea.config import PAPER_BAND_UM, PAPER_PIXEL_PITCH_UM, LensDesign, SystemDesign, load_lens
from metafovea.errors import InputError, NotConvergedWarning, check_choice, check_int, check_positive
from metafovea.io import atomic_write_bytes, atomic_write_json, dropped_if_empty, file_stem, prepare_output
from metafovea.library import POST_SOURCES, ObliqueResponse, PostSet, oblique_response, rcwa_post_sets, system_post_sets
from metafovea.parallel import DaskExecutor, StoppableThreadPool, blas_threads, default_workers
from metafovea.radiometry import psf_wavelengths
from metafovea.report import HtmlReport, fig_to_png, fmt

from .mtf import (
    diffraction_mtf,
    encircled_energy,
    focusing_efficiency,
    fwhm_um,
    mtf_slices,
    pixel_mtf,
    pupil_mtf,
    strehl,
)
from .propagate import SamplingError
from .psf import PSF, defocus_note, depth_of_focus_um, diffraction_radius_um, encircled_energy_on_axis, psf
from .pupil import EVANESCENT_MARGIN, design_na, max_field_deg
from .sensor import sensor_psf
from .sweep import sensor_psf_sweep
from .train import POSTS_NOTE_IDEAL, system_trains, throughput_lines

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------
# one lens
# ----------------------------------------------------------------------------------------------
def psf_report(lens: LensDesign, out_dir: str | Path, *, fields_deg: list[float] | None = None,
               band_um: tuple[float, float] = PAPER_BAND_UM, filter_um: tuple[float, float] | None = None,
               temperature_k: float = 300.0, n_wavelengths: int = 61, pixel_pitch_um: float = PAPER_PIXEL_PITCH_UM,
               error: float = 1e-4, post_set: PostSet | None = None, wavelength_um: float | None = None,
               window_um: float | None = None, relay_magnification: float = 1.0,
               z_um: float | None = None, progress: bool = False, position: int = 0,
               trains: list[dict[str, Any]] | None = None, oblique: ObliqueResponse | None = None,
               executor: Executor | DaskExecutor | None = None) -> dict[str, Any]:
    """Compute the report numbers and write figures, ``psf_report.json`` and ``psf_report.html``.

    Geometry: ``pixel_pitch_um`` is the sensor's pixel pitch; behind a relay of ``relay_magnification`` a pixel
    covers ``pixel_pitch_um / relay_magnification`` of the lens' focal plane (the pitch the sensor PSFs and the
    pixel-radius encircled energy use). ``z_um``: the lens-to-sensor (focal-plane) distance (default: the focal
    length); a distance beyond the depth of focus is warned about and the PSFs are those of the defocused plane.

    ``wavelength_um``: the monochromatic PSFs' wavelength (default: the design wavelength); ``window_um``:
    full width of the fine monochromatic PSF windows (default: sized from the rays; a given window that
    truncates the PSF above ``error`` raises :class:`metafovea.optics.propagate.SamplingError`).
    An error about the wavelengths of a monochromatic PSF names ``wavelength_um`` when it was given.
    ``progress``: a progress bar (on a terminal) per step, at line ``position``. ``post_set``: the lens' posts (None:
    ideal posts, a simplified model the page says it is). ``trains``: the camera's optical-train summaries
    (:meth:`metafovea.optics.train.ChannelTrain.summary`), shown and stored with the report. ``oblique``: the
    posts' :class:`~metafovea.library.ObliqueResponse`; an off-axis PSF uses the posts at its field when that
    changes its focusing order's power by more than ``error`` (the change is reported per field either way).
    ``executor``: where the sensor PSFs across the field run (:func:`~metafovea.optics.sweep.sensor_psf_sweep`;
    default two local threads), e.g. a :class:`metafovea.parallel.DaskExecutor`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = time.perf_counter()
    stem = file_stem(lens.name)
    relay = check_positive("relay_magnification", relay_magnification, hi=10.0)
    sensor_pixel_um = pixel_pitch_um
    pixel_pitch_um = sensor_pixel_um / relay  # at the focal plane
    z = lens.f_um if z_um is None else check_positive("z_um", z_um, "um")
    mono_wl = [lens.wavelength_um if wavelength_um is None else float(wavelength_um)]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if fields_deg is None:
        fmax = min(max_field_deg(lens, band_um[1]), math.degrees(math.atan(6800.0 / lens.f_um)))
        fields_deg = list(np.linspace(0.0, fmax, 9))
    cut = 2 * lens.na / lens.wavelength_um * 1000
    res: dict[str, Any] = {"mono_wavelength_um": mono_wl[0], "lens": lens.name, "f_mm": lens.f_mm,
                           "diameter_mm": lens.diameter_mm, "na": lens.na, "wavelength_um": lens.wavelength_um,
                           "polarization": lens.polarization, "mtf_cutoff_cyc_per_mm": cut,
                           "requested_error": error, "warnings": [], "accuracy": [], "z_um": z,
                           "defocus_um": z - lens.f_um,
                           "sensor_pixel_um": sensor_pixel_um, "relay_magnification": relay,
                           "posts": "ideal" if post_set is None else post_set.source,
                           "optical_train": trains}
    if lens.phase_poly_rad:
        res["phase_poly_rad"] = list(lens.phase_poly_rad)  # the phase beyond the hyperbola (rad)
        res["warnings"].append(
            "phase_poly_rad: the on-axis encircled energies, the through-focus curves and the MTF curves of this lens "
            "come from the direction-sine (Debye) model, which is not bounded for a lens with a phase beyond the "
            "hyperbola (a lens whose rays cross has none: the report stops with an error); the PSF panels and the "
            "sensor PSFs use the exact engine within their cost budgets, with their own error estimates")
    if post_set is None:
        res["warnings"].append(f"{POSTS_NOTE_IDEAL} (the PSFs of a lens the platform's RCWA post set was not "
                               "chosen for, or posts=ideal)")
    note = defocus_note(lens, z)
    if note:
        res["warnings"].append(note)
    posts_at = _field_posts(lens, post_set, oblique, error, res)
    from tqdm.auto import tqdm

    bar = tqdm(total=4 + len(fields_deg), desc=f"psf {lens.name}", unit="step", position=position, leave=True,
               disable=None if progress else True)

    def tick(what: str) -> None:
        bar.set_postfix_str(what, refresh=False)
        bar.update(1)

    try:
        # single-threaded steps first, the fine off-axis PSFs (two threads) last: when two lenses run side by
        # side the cores are free by then
        wl, w = psf_wavelengths(band_um, design_um=lens.wavelength_um, temperature_k=temperature_k,
                                filter_um=filter_um, n=n_wavelengths)
        res["spectral"] = {"n_wavelengths": int(wl.size), "band_um": band_um, "filter_um": filter_um,
                           "temperature_k": temperature_k}
        ee_png = _sensor(plt, lens, res, fields_deg, mono_wl, wl, w, posts_at, error, pixel_pitch_um, z, tick,
                         executor)
        mtf_png = _mtf(plt, lens, res, fields_deg, cut, z, pixel_pitch_um)
        tick("MTF")
        focus_png = _through_focus(plt, lens, res, mono_wl, wl, w, post_set, pixel_pitch_um, z)
        figs = {"psf_mono.png": _monochromatic(plt, lens, res, fields_deg, mono_wl, posts_at, error, window_um,
                                               pixel_pitch_um, z, tick),
                "mtf.png": mtf_png, "ee_field.png": ee_png, "through_focus.png": focus_png,
                "wavefront.png": _wavefront(plt, lens, res, post_set)}
    except InputError as e:
        bar.close()
        if e.parameter == "wavelengths_um" and wavelength_um is not None:
            raise InputError("wavelength_um", wavelength_um, e.allowed) from None
        raise
    bar.close()
    res["pixel_pitch_um"] = pixel_pitch_um
    res["seconds"] = time.perf_counter() - t0
    res["tolerance"] = tolerance_summary(res)
    for name, data in figs.items():
        atomic_write_bytes(out / f"{stem}_{name}", data)
    atomic_write_json(out / f"{stem}_psf_report.json", res)
    _page(res, figs).write(out / f"{stem}_psf_report.html")
    return res


def _field_posts(lens: LensDesign, post_set: PostSet | None, oblique: ObliqueResponse | None, error: float,
                 res: dict[str, Any]) -> Callable[[float], PostSet | None]:
    """``field_deg -> posts`` for the PSFs: ``post_set`` at normal incidence, or the posts at the field (along +x)
    where that moves the focusing order's power by more than ``error``; each decision goes to
    ``res['oblique_incidence']``."""
    from .pupil import order_coefficients

    res["oblique_incidence"] = {}
    if post_set is None or oblique is None:
        res["oblique_incidence"]["note"] = "not modelled (ideal posts or no oblique response)"
        return lambda fd: post_set
    tau = post_set.t_focus
    c0 = abs(complex(order_coefficients(tau, lens.levels, np.array([1]))[0])) ** 2
    cache: dict[float, Any] = {}

    def at(fd: float) -> PostSet | None:
        fd = float(fd)
        if fd not in cache:
            obl = oblique.post_set_at(post_set, abs(fd), 0.0)
            c = abs(complex(order_coefficients(obl.t_focus, lens.levels, np.array([1]))[0])) ** 2
            use = abs(c / c0 - 1) > error
            cache[fd] = obl if use else post_set
            res["oblique_incidence"][f"{fd:.4f}"] = {"field_deg": fd, "focusing_power_factor": c / c0, "applied": use}
        return cache[fd]
    return at


def _monochromatic(plt: ModuleType, lens: LensDesign, res: dict[str, Any], fields_deg: list[float],
                   mono_wl: list[float], posts_at: Callable[[float], PostSet | None], error: float,
                   window_um: float | None, pixel_pitch_um: float, z: float, tick: Callable[[str], None]) -> bytes:
    """Monochromatic PSFs (fabricated lens) on axis, at mid-field and at the last field: ``res['monochromatic']``
    and the figure. A PSF too aberrated for the fine grid is shown on a pixel grid of a quarter pitch instead."""
    mono = []
    r_d = diffraction_radius_um(lens)
    fig, axs = plt.subplots(1, 3, figsize=(13, 4.0))
    for ax, fd in zip(axs, [0.0, fields_deg[len(fields_deg) // 2], fields_deg[-1]]):
        with warnings.catch_warnings(record=True) as ws:
            warnings.simplefilter("always")
            try:
                P = psf(lens, field_deg=fd, quantize=True, lattice=True, post_set=posts_at(fd), error=error,
                        wavelengths_um=mono_wl, window_um=window_um, z_um=z)
            except SamplingError as e:  # the aberrated PSF needs too large a window: pixel grid instead
                if window_um is not None:
                    raise SamplingError(e.parameter, e.value, e.allowed.replace(
                        "(pass allow_truncation=True to accept)", "(or a larger error)")) from None
                P = sensor_psf(lens, pixel_pitch_um=pixel_pitch_um / 4, field_deg=fd, post_set=posts_at(fd),
                               error=max(error, 1e-3), wavelengths_um=mono_wl, z_um=z)
                res["warnings"].append(f"field {fd:.3g} deg: fine PSF not computed ({e}); pixel-grid PSF shown")
        res["warnings"] += [str(w.message) for w in ws if not _on_the_result(w)]
        res["accuracy"] += [P.info["accuracy"]] if "accuracy" in P.info else []
        fine = "diffraction_limited_peak_fraction" in P.info
        xs, ys = P.coords()
        im = ax.imshow(P.intensity / P.pitch_um ** 2, origin="lower", extent=[xs[0], xs[-1], ys[0], ys[-1]],
                       cmap="magma")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03).set_label("fraction of incident power per um^2", fontsize=7)
        grid = "optical, fine grid" if fine else f"pixel grid {P.pitch_um:.3g} um"
        bound = "edge diffraction not bounded" if "model_note" in P.info else f"err {P.error_estimate:.1g}"
        ax.set_title(f"{fd:.2f} deg, {lens.levels}-level + lattice ({grid})\n{P.engine}, {bound}, "
                     f"{P.energy_fraction:.0%} of incident power in window", fontsize=8)
        ax.set_xlabel("x at the focal plane (um)")
        mono.append({"field_deg": fd, "engine": P.engine, "error_estimate": P.error_estimate,
                     "pitch_um": P.pitch_um, "samples": P.shape[0], "energy_fraction": P.energy_fraction,
                     "grid": "fine" if fine else "pixel", "model_note": P.info.get("model_note"),
                     "peak_fraction_per_um2": float(P.intensity.max() / P.pitch_um ** 2),
                     "strehl": strehl(P) if fine else None,
                     "focusing_efficiency": focusing_efficiency(P) if fine else None,
                     "fwhm_um": list(fwhm_um(P)) if fine else None,
                     **_encircled(lens, P, fd, r_d, mono_wl, posts_at, z, fine),
                     "seconds": P.info.get("seconds")})
        tick(f"PSF {fd:.2f} deg")
    axs[0].set_ylabel("y at the focal plane (um)")
    fig.tight_layout()
    res["monochromatic"] = mono
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _encircled(lens: LensDesign, P: PSF, fd: float, r_um: float, mono_wl: list[float],
               posts_at: Callable[[float], PostSet | None], z: float, fine: bool) -> dict[str, Any]:
    """Encircled energy (fraction of the incident power) within ``r_um`` (the first dark ring of the Airy pattern,
    0.61 lambda0 / NA): on axis the exact radial integral, off axis the fine PSF's about its centroid."""
    if fd == 0.0:
        ee = encircled_energy_on_axis(lens, r_um, wavelengths_um=mono_wl, post_set=posts_at(0.0), z_um=z)
        how = "exact"
    elif fine:
        ee, how = float(encircled_energy(P, r_um)[0]), "fine PSF, about its centroid"
    else:
        ee, how = None, None
    return {"ee_radius_um": r_um, "ee": ee, "ee_method": how}


def _on_the_result(w: warnings.WarningMessage) -> bool:
    """A result's NotConvergedWarning with data: its ``info['accuracy']`` holds the same (kept once, as data)."""
    return isinstance(w.message, NotConvergedWarning) and bool(w.message.data)


def _wavefront(plt: ModuleType, lens: LensDesign, res: dict[str, Any], post_set: PostSet | None) -> bytes:
    """Phase error of the fabricated lens (posts on the lattice, N levels, the post set's phases) against the
    continuous design phase (hyperbola plus ``phase_poly_rad``), on 120 um patches at the centre and at the rim,
    sampled at a sixteenth of the period (so the hold over each 4 um cell shows): ``res['wavefront']`` (rms and max
    after the common phase is removed). Ideal posts (no post set): quantisation and lattice only, rms ~ pi / (N
    sqrt 3)."""
    from metafovea.lens import design_phase, quantize_phase  # lens stage (above optics): allowed

    p, n = lens.period_um, lens.levels
    o = 0.0 if lens.lattice == "integer" else 0.5
    if post_set is not None:
        target = 2 * np.pi * np.arange(n) / n
        ph = np.angle(post_set.t_focus)
        level_ph = target + np.angle(np.exp(1j * (ph - target)))
    else:
        level_ph = 2 * np.pi * np.arange(n) / n
    half = 60.0
    ax1 = np.arange(-half, half, p / 16) + p / 32
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.2))
    out: dict[str, Any] = {"sampling_um": p / 16, "patch_um": 2 * half,
                           "post_set": "ideal posts" if post_set is None else getattr(post_set, "source", "post set")}
    for axp, (name, cx) in zip(axs, (("centre", 0.0), ("rim", lens.radius_um - half - p))):
        X, Y = cx + ax1[None, :], ax1[:, None] + 0.0 * ax1[None, :]
        cont = design_phase(lens, X, Y)
        xs = (np.floor(X / p - o + 0.5) + o) * p
        ys = (np.floor(Y / p - o + 0.5) + o) * p
        fab = level_ph[quantize_phase(design_phase(lens, xs, ys), n)]
        d = np.exp(1j * (fab - cont))
        err = np.angle(d * np.exp(-1j * np.angle(d.mean())))  # common phase removed
        out[name] = {"center_um": [cx, 0.0], "rms_rad": float(np.sqrt(np.mean(err ** 2))),
                     "max_rad": float(np.abs(err).max())}
        lim = max(out[name]["max_rad"], 1e-3)
        im = axp.imshow(err, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim,
                        extent=[X.min() - p / 32, X.max() + p / 32, ax1[0] - p / 32, ax1[-1] + p / 32])
        fig.colorbar(im, ax=axp, fraction=0.046, pad=0.03).set_label("phase error (rad)", fontsize=8)
        axp.set_title(f"{name}: rms {out[name]['rms_rad']:.3f} rad, max {out[name]['max_rad']:.2f} rad", fontsize=9)
        axp.set_xlabel("x on the lens (um)")
    axs[0].set_ylabel("y on the lens (um)")
    fig.suptitle(f"{lens.levels}-level lens on the {p:g} um lattice ({out['post_set']}) against the continuous "
                 "phase", fontsize=9)
    fig.tight_layout()
    res["wavefront"] = out
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _through_focus(plt: ModuleType, lens: LensDesign, res: dict[str, Any], mono_wl: list[float], wl: np.ndarray,
                   w: np.ndarray, post_set: PostSet | None, pixel_pitch_um: float, z: float) -> bytes:
    """On-axis through-focus curves of the fabricated lens (exact radial integrals, optical PSF): the power within
    one focal-plane pixel pitch of the axis at the design wavelength and over the band, against the focal-plane
    distance, f +- 3 depths of focus, with the sensor's plane marked: ``res['through_focus']``."""
    dof = depth_of_focus_um(lens)
    span = min(3 * dof, 0.5 * lens.f_um)  # slow lenses (F/50: dof of tens of mm) stay at positive distances
    lo, hi = min(lens.f_um - span, z - span / 3), max(lens.f_um + span, z + span / 3)
    lo = max(lo, 0.25 * min(lens.f_um, z))
    zs = np.linspace(lo, hi, 41)
    zb = zs[::4]
    mono = [float(encircled_energy_on_axis(lens, pixel_pitch_um, wavelengths_um=mono_wl, post_set=post_set, z_um=v,
                                           n=96)) for v in zs]
    band = [float(encircled_energy_on_axis(lens, pixel_pitch_um, wavelengths_um=wl, weights=w, post_set=post_set,
                                           z_um=v, n=96)) for v in zb]
    r_d = diffraction_radius_um(lens)
    core = [float(encircled_energy_on_axis(lens, r_d, wavelengths_um=mono_wl, post_set=post_set, z_um=v, n=96))
            for v in zs]
    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    ax.semilogy((zs - lens.f_um), mono, label=f"{mono_wl[0]:g} um, r = pixel pitch {pixel_pitch_um:.3g} um")
    ax.semilogy((zs - lens.f_um), core, label=f"{mono_wl[0]:g} um, r = first zero {r_d:.3g} um")
    ax.semilogy((zb - lens.f_um), band, "s--", label=f"band (Planck-weighted), r = {pixel_pitch_um:.3g} um")
    ax.axvline(z - lens.f_um, color="k", lw=0.8, ls=":", label="sensor plane")
    ax.axvspan(-dof, dof, color="0.9", label=f"depth of focus +-{dof:.0f} um")
    ax.set_xlabel("focal-plane distance - f (um)")
    ax.set_ylabel("power within r of the axis (of incident)")
    ax.set_title(f"through focus, on axis, {lens.levels}-level + lattice (optical PSF, exact)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    res["through_focus"] = {"defocus_um": zs - lens.f_um, "mono": mono, "mono_core": core, "core_radius_um": r_d,
                            "band_defocus_um": zb - lens.f_um,
                            "band": band, "radius_um": pixel_pitch_um, "depth_of_focus_um": dof}
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _mtf(plt: ModuleType, lens: LensDesign, res: dict[str, Any], fields_deg: list[float], cut: float, z: float,
         pixel_pitch_um: float) -> bytes:
    """MTF of the focusing order (exact pupil autocorrelation, design wavelength, at the plane ``z``): the
    continuous-phase and the fabricated (8-level + lattice) lens on axis, the fabricated lens times the pixel
    aperture, and the continuous lens at two fields: ``res['mtf']``. Haze (other orders) is not in these curves:
    it lowers every frequency above 0 by the focusing order's share of the power."""
    nu = np.linspace(0, cut, 41)
    nu_f = nu[::2]  # the field curves (pupil autocorrelations of aberrated pupils: seconds each)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    paraxial_cut = lens.diameter_um / (lens.wavelength_um * lens.f_um) * 1000
    nu_p = np.clip(nu, 0, paraxial_cut)
    ax.plot(nu_p, diffraction_mtf(nu_p, paraxial_cut), "k--", lw=1,
            label=f"paraxial diffraction limit (cutoff D/(lambda f) = {paraxial_cut:.1f}/mm)")
    cont = pupil_mtf(lens, nu, z_um=z)
    fab = pupil_mtf(lens, nu, quantize=True, lattice=True, z_um=z)
    pix = pixel_mtf(nu, pixel_pitch_um)
    ax.plot(nu, cont, label="on axis, continuous phase (optical)")
    ax.plot(nu, fab, label=f"on axis, {lens.levels}-level + lattice (optical)")
    ax.plot(nu, fab * pix, label=f"on axis, {lens.levels}-level x {pixel_pitch_um:.3g} um pixel")
    mt = {"nu_cyc_per_mm": nu, "nu_field_cyc_per_mm": nu_f, "on_axis": cont, "on_axis_fabricated": fab,
          "on_axis_fabricated_pixel": fab * pix,
          "paraxial_cutoff_cyc_per_mm": paraxial_cut, "z_um": z}
    fields = [fd for fd in dict.fromkeys((fields_deg[len(fields_deg) // 2], fields_deg[-1])) if fd != 0]
    with blas_threads(1), StoppableThreadPool(2) as ex:  # four independent autocorrelations, two at a time
        jobs = {(fd, a): ex.submit(pupil_mtf, lens, nu_f, field_deg=fd, angle_rad=a, z_um=z)
                for fd in fields for a in (0.0, math.pi / 2)}
        for fd in fields:
            try:
                t, s = jobs[(fd, 0.0)].result(), jobs[(fd, math.pi / 2)].result()
            except (InputError, ValueError, FloatingPointError) as e:
                res["warnings"].append(f"MTF at {fd:.3g} deg not computed: {e}")
                continue
            ax.plot(nu_f, t, label=f"{fd:.2f} deg tangential (continuous)")
            ax.plot(nu_f, s, ":", label=f"{fd:.2f} deg sagittal (continuous)")
            mt[f"{fd:.3f}_tangential"], mt[f"{fd:.3f}_sagittal"] = t, s
    ax.set_xlabel("spatial frequency at the focal plane (cycles/mm)")
    ax.set_ylabel("MTF (focusing order)")
    ax.legend(fontsize=6.5)
    fig.tight_layout()
    res["mtf"] = mt
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _sensor(plt: ModuleType, lens: LensDesign, res: dict[str, Any], fields_deg: list[float], mono_wl: list[float],
            wl: np.ndarray, w: np.ndarray, posts_at: Callable[[float], PostSet | None], error: float,
            pixel_pitch_um: float, z: float, tick: Callable[[str], None],
            executor: Executor | DaskExecutor | None = None) -> bytes:
    """Encircled energy and broadband sensor PSFs over the field: ``res['on_axis_ee_pixel_radius']`` (power within
    one pixel pitch of the axis, exact radial integral, no pixel grid), ``res['sensor']`` and the figure."""
    post_set = posts_at(0.0)
    res["on_axis_ee_pixel_radius"] = {
        "radius_um": pixel_pitch_um,
        "mono": encircled_energy_on_axis(lens, pixel_pitch_um, wavelengths_um=mono_wl, post_set=post_set, z_um=z),
        "band": encircled_energy_on_axis(lens, pixel_pitch_um, wavelengths_um=wl, weights=w, post_set=post_set,
                                         z_um=z)}
    radii = np.linspace(0, 6 * diffraction_radius_um(lens) + 2 * pixel_pitch_um, 40)
    fig, ax = plt.subplots(1, 3, figsize=(16, 4))
    nyq = 1000.0 / (2 * pixel_pitch_um)  # cycles/mm at the focal plane
    nu_m = np.array([0.5 * nyq, nyq])
    sens = []

    # every field at the design wavelength and over the band, one sweep through the project's executor: two
    # local threads (numpy releases the GIL in the engines), or the Dask cluster ``executor``; each warning names
    # its field
    with contextlib.ExitStack() as stack:
        ex = executor if executor is not None else stack.enter_context(StoppableThreadPool(2))
        sweep = sensor_psf_sweep(lens, fields_deg, [(mono_wl, None), (wl, w)], pixel_pitch_um=pixel_pitch_um,
                                 post_sets=[posts_at(fd) for fd in fields_deg], error=error, z_um=z, executor=ex,
                                 on_field=lambda fd: tick(f"sensor PSFs {fd:.2f} deg"))
    res["warnings"] += sweep.warnings
    res["accuracy"] += sweep.accuracy()
    for fd, (mono_s, poly) in zip(fields_deg, sweep.psfs):
        c = tuple(s // 2 for s in poly.shape)
        cm = tuple(s // 2 for s in mono_s.shape)
        sens.append({"field_deg": fd, "mono_center_pixel": float(mono_s.intensity[cm]),
                     "poly_center_pixel": float(poly.intensity[c]), "poly_energy_fraction": poly.energy_fraction,
                     "poly_engine": poly.engine, "poly_error_estimate": poly.error_estimate,
                     "mono_engine": mono_s.engine, "mono_error_estimate": mono_s.error_estimate,
                     "size_px": poly.shape[0], "seconds": poly.info["seconds"] + mono_s.info["seconds"]})
        # MTF of the pixel-integrated PSFs (pixel aperture included; normalised to the light in the window)
        for key, P in (("mono", mono_s), ("poly", poly)):
            m = mtf_slices(P, nu_m)
            sens[-1][f"{key}_mtf"] = {"nu_cyc_per_mm": nu_m.tolist(), "tangential": m["tangential"].tolist(),
                                      "sagittal": m["sagittal"].tolist()}
        if fd == 0.0:  # on axis the exact radial integral of the optical PSF (no pixels)
            r_ee = radii[1:]
            ee = encircled_energy_on_axis(lens, r_ee, wavelengths_um=mono_wl, post_set=post_set, z_um=z, n=48)
            eep = encircled_energy_on_axis(lens, r_ee, wavelengths_um=wl, weights=w, post_set=post_set, z_um=z, n=48)
            ax[0].plot(r_ee, ee, label=f"on axis, {mono_wl[0]:g} um (optical, exact)")
            ax[0].plot(r_ee, eep, "--", label="on axis, band (optical, exact)")
        elif fd == fields_deg[-1]:
            ee = encircled_energy(mono_s, radii, center_um=mono_s.center_um)
            ax[0].plot(radii, ee, label=f"{fd:.2f} deg, {mono_wl[0]:g} um (pixel-integrated)")
            eep = encircled_energy(poly, radii, center_um=poly.center_um)
            ax[0].plot(radii, eep, "--", label=f"{fd:.2f} deg, band (pixel-integrated)")
    ax[0].set_xlabel("radius at the focal plane (um)")
    ax[0].set_ylabel("encircled energy (of incident)")
    ax[0].legend(fontsize=7)
    ax[1].semilogy([s["field_deg"] for s in sens], [s["mono_center_pixel"] for s in sens], "o-",
                   label=f"{mono_wl[0]:g} um")
    ax[1].semilogy([s["field_deg"] for s in sens], [s["poly_center_pixel"] for s in sens], "s-", label="band")
    ax[1].set_xlabel("field (deg)")
    ax[1].set_ylabel(f"power in the chief-ray pixel ({pixel_pitch_um:.3g} um)")
    ax[1].legend()
    fd_all = [s["field_deg"] for s in sens]
    for j, (ls, what) in enumerate(((":", "Nyquist/2"), ("-", "Nyquist"))):
        ax[2].plot(fd_all, [s["mono_mtf"]["tangential"][j] for s in sens], ls, marker="o", color="C0",
                   label=f"{mono_wl[0]:g} um tangential, {nu_m[j]:.1f}/mm ({what})")
        ax[2].plot(fd_all, [s["mono_mtf"]["sagittal"][j] for s in sens], ls, marker="^", color="C1",
                   label=f"{mono_wl[0]:g} um sagittal, {nu_m[j]:.1f}/mm")
        ax[2].plot(fd_all, [s["poly_mtf"]["tangential"][j] for s in sens], ls, marker="s", color="C2",
                   label=f"band tangential, {nu_m[j]:.1f}/mm")
    ax[2].set_xlabel("field (deg)")
    ax[2].set_ylabel("MTF (pixel-integrated PSF, pixel aperture included)")
    ax[2].set_ylim(0, 1.02)
    ax[2].legend(fontsize=6)
    fig.tight_layout()
    res["sensor"] = sens
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _page(res: dict[str, Any], figs: dict[str, bytes]) -> HtmlReport:
    """The HTML page of one lens' report."""
    sp, ee = res["spectral"], res["on_axis_ee_pixel_radius"]
    page = HtmlReport(f"PSF / MTF report: {res['lens']}")
    fu = sp["filter_um"]
    filt = "none" if not fu else f"{fu[0]:g} um (FWHM {fu[1]:g} um)"
    page.paragraph(
        f"f = {res['f_mm']:g} mm, D = {res['diameter_mm']:g} mm, NA = {res['na']:.4f}, design wavelength "
        f"{res['wavelength_um']:g} um, polarisation {res['polarization']}; MTF cutoff 2NA/lambda = "
        f"{res['mtf_cutoff_cyc_per_mm']:.2f} cycles/mm. Requested error {res['requested_error']:g} (max abs / peak). "
        "Scalar thin-element model: Hankel / direction-sine integral on axis, exact Rayleigh-Sommerfeld integral over "
        "the hard-edged aperture off axis; lattice sampling and N-level quantisation included in the PSFs; "
        f"spectral weights: Planck at {sp['temperature_k']:g} K, band {sp['band_um'][0]:g}-{sp['band_um'][1]:g} um, "
        f"filter {filt}, "
        f"{sp['n_wavelengths']} wavelength bins (geometric around the design wavelength).")
    page.heading("Monochromatic PSFs (engine, sampling, error estimate)")
    r_ee = res["monochromatic"][0]["ee_radius_um"]
    page.table(["field (deg)", "engine", "grid", "error estimate (of peak)", "pitch (um)", "power in window",
                "Strehl ratio", "peak / ideal continuous lens", "FWHM x / y (um)", f"EE within {r_ee:.4g} um"],
               [[f"{m['field_deg']:.3f}", m["engine"], m["grid"],
                 "not bounded (edge diffraction)" if m.get("model_note") else f"{m['error_estimate']:.2g}",
                 f"{m['pitch_um']:.3g}",
                 f"{m['energy_fraction']:.4f}", "-" if m["strehl"] is None else f"{m['strehl']:.4f}",
                 "-" if m["focusing_efficiency"] is None else f"{m['focusing_efficiency']:.4f}",
                 "-" if m["fwhm_um"] is None else f"{m['fwhm_um'][0]:.4g} / {m['fwhm_um'][1]:.4g}",
                 "-" if m["ee"] is None else f"{m['ee']:.4f}"]
                for m in res["monochromatic"]])
    page.paragraph("Strehl ratio: peak over the aberration-free peak of the same pupil amplitude (posts, levels and "
                   "lattice included); peak / ideal continuous lens (the focusing efficiency printed by the command): "
                   "what quantisation, lattice and posts cost at the focus on top of the aberrations (sinc^2(pi/N) "
                   "for N ideal levels in focus). FWHM through the peak (band-limited interpolation); EE: fraction of "
                   f"the incident power within the Airy pattern's first dark ring 0.61 lambda0/NA = {r_ee:.4g} um "
                   "(0.838 of a perfect lens' power), on axis by the exact radial integral, off axis from the fine "
                   "PSF about its centroid. 'pixel' rows are PSFs too aberrated for the fine grid, shown on a pixel "
                   "grid (no Strehl).")
    page.paragraph(f"On axis, power within r = {ee['radius_um']:g} um (exact radial integral): "
                   f"{res['mono_wavelength_um']:g} um {ee['mono']:.4f}, band {ee['band']:.4g} "
                   "(fractions of the incident power).")
    page.paragraph(f"Geometry: lens to focal plane {res['z_um'] / 1000:g} mm (defocus {res['defocus_um']:+.1f} um "
                   "from f); "
                   f"sensor pixels of {res['sensor_pixel_um']:g} um behind a {res['relay_magnification']:g}x relay: "
                   f"{res['pixel_pitch_um']:.4g} um at the focal plane (the pixel the sensor PSFs integrate over).")
    page.heading(f"Sensor PSFs ({res['sensor_pixel_um']:g} um sensor pixels = {res['pixel_pitch_um']:.4g} um at the "
                 "focal plane) across the field")
    page.table(["field deg", "chief-ray pixel, design wl", "chief-ray pixel, band", "band power in window", "engines",
                "error est."],
               [[f"{s['field_deg']:.3f}", f"{s['mono_center_pixel']:.4g}", f"{s['poly_center_pixel']:.4g}",
                 f"{s['poly_energy_fraction']:.4g}", s["poly_engine"], f"{s['poly_error_estimate']:.2g}"]
                for s in res["sensor"]])
    for name, png in figs.items():
        page.image(png, name)
    obl = {k: v for k, v in res.get("oblique_incidence", {}).items() if k != "note"}
    page.heading("Posts at oblique incidence (the field along x, light entering through the wafer)")
    if obl:
        page.table(["field (deg)", "focusing-order power vs normal incidence", "used for the PSFs"],
                   [[f"{v['field_deg']:.3f}", f"{v['focusing_power_factor']:.5f}", "yes" if v["applied"] else
                     f"no (change below the requested {res['requested_error']:g})"]
                    for v in sorted(obl.values(), key=lambda v: v["field_deg"])])
    else:
        page.paragraph(res.get("oblique_incidence", {}).get("note", "not modelled"))
    if res.get("optical_train"):
        page.heading("Optical train: throughput per channel (wafers, both lenses' posts, aperture ring)")
        page.pre("\n".join(throughput_lines(res["optical_train"])))
        page.paragraph("The PSFs above are this lens' own (its posts included), relative to the power reaching it; "
                       "the throughput is what the camera's channels deliver to the focal plane (the PSF's power "
                       "times the wafers, the other lens' coherent pass-through and its ring); the glare is the "
                       "other lens' pass-through ripple (leakage), spread over the disks listed.")
    page.heading("Warnings")
    for w in [*dict.fromkeys(res["warnings"]), *(a["message"] for a in res["accuracy"])] or ["none"]:
        page.paragraph(w)
    page.paragraph(f"Computed in {res['seconds']:.1f} s.")
    return page


# ----------------------------------------------------------------------------------------------
# several lenses: the ``metafovea psf`` pipeline
# ----------------------------------------------------------------------------------------------
def psf_reports(designs: Sequence[str | Path | LensDesign], out_dir: str | Path, *, force: bool = False,
                fields_deg: list[float] | None = None, band_um: tuple[float, float] = PAPER_BAND_UM,
                filter_um: tuple[float, float] | None = None, temperature_k: float = 300.0,
                n_wavelengths: int = 61, pixel_pitch_um: float = PAPER_PIXEL_PITCH_UM, error: float = 1e-4,
                wavelength_um: float | None = None, window_um: float | None = None,
                jobs: int | None = None, relay_magnification: float = 1.0,
                distances_um: dict[str, float] | None = None, progress: bool = False,
                system: SystemDesign | None = None, posts: str = "rcwa",
                scheduler: str | None = None, say: Callable[[str], None] | None = None) -> dict[str, dict[str, Any]]:
    """:func:`psf_report` of every lens (TOML paths or :class:`LensDesign`) into ``out_dir``, one process per lens.

    Everything that can be refused is refused before any work and before ``out_dir`` is made: a band, filter
    and scene temperature that give no light; two lenses whose names make the same file stem (their reports
    would overwrite each other); wavelengths that leave a lens' rim evanescent even on axis; fields outside a
    lens' field at the longest wavelength used. ``out_dir`` must be new or empty unless ``force``. ``jobs``
    (processes, one lens each) defaults to one per core, never more than the lenses. ``pixel_pitch_um`` is the
    sensor pitch behind a relay of ``relay_magnification``; ``distances_um`` maps a lens name to its lens-to-sensor
    distance (default: its focal length). ``posts``: 'rcwa' (each lens gets the platform's RCWA post set for its
    polarisation and levels: the fabricated lens; the library is computed once and cached) or 'ideal' (a simplified
    model). ``system``
    (default: the paper's camera): the platform of the posts and the optical train whose per-channel throughput
    every report shows (the same numbers ``simulate`` and ``validate`` print). Returns, per lens name, the keys
    :data:`SUMMARY_KEYS` of its report (its seconds, monochromatic rows with the key figures, sensor rows,
    warnings, ``accuracy``: the results that missed ``error``, why and what would change that) and the path of its
    HTML page; under ``"optical_train"`` the trains' summaries; under ``"timing"`` the output folder and the
    whole run's seconds by stage (``posts``, ``oblique``, ``optical_train``, ``reports``, ``total``). ``scheduler``
    (a Dask scheduler address, or ``local:N``): the lenses are reported one after the other and each one's sensor
    PSFs across the field (every field, at the design wavelength and over the band) are spread over the cluster;
    the workers write nothing (the figures and pages are written here). ``say``: called with one line per stage
    as it starts (progress for a person: :func:`metafovea.cli.options.stage_printer`).
    """
    _check_light(band_um, filter_um, temperature_k)
    lenses = [d if isinstance(d, LensDesign) else load_lens(d) for d in designs]
    _check_distinct_names([str(d) if not isinstance(d, LensDesign) else f"lens '{d.name}'" for d in designs], lenses)
    for lens in lenses:
        _check_wavelengths_and_fields(lens, band_um, filter_um, wavelength_um, fields_deg)
    jobs = min(default_workers(), len(lenses)) if jobs is None else check_int("jobs", jobs, 1, 4096)
    check_positive("relay_magnification", relay_magnification, hi=10.0)
    dist = dict(distances_um or {})
    for name, z in dist.items():
        check_positive(f"distance of lens '{name}'", z, "um")
    check_choice("posts", posts, POST_SOURCES)
    system = system or SystemDesign.paper()
    with contextlib.ExitStack() as stack:
        # a bad --scheduler is refused before out_dir is made; a late error (a window too small for the PSF, found
        # seconds in) leaves no empty folder
        stack.enter_context(dropped_if_empty(out_dir))
        from metafovea.parallel import get_executor

        ex = stack.enter_context(get_executor(scheduler=scheduler)) if scheduler else None
        return _run_reports(lenses, out_dir, force, system, posts, dist, jobs, progress, ex, say or (lambda m: None),
                            dict(fields_deg=fields_deg, band_um=band_um, filter_um=filter_um,
                                 temperature_k=temperature_k, n_wavelengths=n_wavelengths,
                                 pixel_pitch_um=pixel_pitch_um, error=error, wavelength_um=wavelength_um,
                                 window_um=window_um, relay_magnification=relay_magnification))


def _run_reports(lenses: list[LensDesign], out_dir: str | Path, force: bool, system: SystemDesign, posts: str,
                 dist: dict[str, float], jobs: int, progress: bool, ex: DaskExecutor | None, say: Callable[[str], None],
                 kw: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """:func:`psf_reports` after its checks: the output folder, the posts, then each lens' report (in a process
    per lens, or here with the sensor PSFs on the cluster ``ex``)."""
    t0 = time.perf_counter()
    seconds: dict[str, float] = {}

    def lap(stage: str) -> None:
        seconds[stage] = time.perf_counter() - t0 - sum(seconds.values())

    out = prepare_output(out_dir, force, is_dir=True, name="out_dir")
    post_sets: dict[tuple[str, int], Any] = {}
    if posts == "rcwa":
        say("posts: the platform's RCWA library and post sets (the default platform's ships with metafovea; "
            "another's is computed on its first run, about a minute on 2 cores, then cached)")
        # one selection for the lenses reported and the camera's two (the optical train), not one each
        post_sets = rcwa_post_sets(system.platform, [*lenses, system.foveal, system.perifoveal])
        lap("posts")
        say("posts at oblique incidence: RCWA off axis for each post set (shipped for the default platform; "
            "otherwise ~10 s of CPU each on a first run, then cached)")
    # the lenses' own and the optical train's (both channels' posts)
    keys = {(lens.polarization, lens.levels) for lens in (*lenses, system.foveal, system.perifoveal)}
    with blas_threads(1):  # small RCWA eigenproblems: 7x the CPU time with OpenBLAS' threads (system_trains)
        obliques = {key: oblique_response(post_sets[key], system.platform) for key in sorted(keys & set(post_sets))}
    if obliques:
        lap("oblique")
    train_sets = ({lens.polarization: post_sets[(lens.polarization, lens.levels)]
                   for lens in (system.foveal, system.perifoveal)} if posts == "rcwa" else posts)
    say("optical train: throughput and glare of both channels")
    trains = [t.summary() for t in system_trains(system, *system_post_sets(system, train_sets))]
    lap("optical_train")
    kws = [{**kw, "z_um": dist.get(lens.name), "progress": progress, "position": i, "trains": trains,
            "post_set": post_sets.get((lens.polarization, lens.levels)),
            "oblique": obliques.get((lens.polarization, lens.levels))} for i, lens in enumerate(lenses)]
    names = ", ".join(f"'{lens.name}'" for lens in lenses)
    if ex is not None:
        say(f"reports of {names}: PSFs, MTF, encircled energy, sensor PSFs across the field (on the cluster)")
        outcomes = [_report_one(lens, str(out), {**k, "executor": ex}) for lens, k in zip(lenses, kws)]
    elif jobs > 1 and len(lenses) > 1:
        # one process per lens (the report of a lens is single-threaded), through the project's executor
        # (forkserver workers: a process that has started JAX's threads must not fork)
        # (run_tasks ends the running reports on Ctrl-C rather than waiting for them)
        from metafovea.parallel import run_tasks

        say(f"reports of {names} in {min(jobs, len(lenses))} processes: PSFs, MTF, encircled energy, sensor PSFs "
            "across the field")
        done = dict(run_tasks(_report_item, [(lens, str(out), k) for lens, k in zip(lenses, kws)],
                              workers=min(jobs, len(lenses))))
        outcomes = [done[i] for i in range(len(lenses))]
    else:
        outcomes = []
        for lens, k in zip(lenses, kws):
            say(f"report of '{lens.name}': PSFs, MTF, encircled energy, sensor PSFs across the field")
            outcomes.append(_report_one(lens, str(out), k))
    lap("reports")
    summary = {}
    for lens, (kind, val) in zip(lenses, outcomes):
        if kind == "input_error":
            cls, parameter, value, allowed, source, detail = val
            raise cls(parameter, value, allowed, source=source, detail=detail)
        summary[lens.name] = {**val, "html": str(Path(out) / f"{file_stem(lens.name)}_psf_report.html")}
    summary["optical_train"] = trains
    seconds["total"] = time.perf_counter() - t0
    summary["timing"] = {"seconds": seconds, "out_dir": str(out)}
    return summary


def _report_item(item: tuple[LensDesign, str, dict[str, Any]]) -> tuple[str, Any]:
    """:func:`_report_one` of one ``(lens, out, kw)`` task."""
    return _report_one(*item)


def _report_one(lens: LensDesign, out: str, kw: dict[str, Any]) -> tuple[str, Any]:
    """One lens' report, run in a worker: an InputError comes back as data (its class and fields), because an
    InputError does not survive pickling."""
    try:
        res = psf_report(lens, out, **kw)
    except InputError as e:
        return "input_error", (type(e), e.parameter, e.value, e.allowed, e.source, e.detail)
    return "ok", {k: res[k] for k in SUMMARY_KEYS}


#: what :func:`psf_reports` returns of each lens' report (the whole report is its JSON file)
SUMMARY_KEYS = ("lens", "f_mm", "diameter_mm", "na", "wavelength_um", "mono_wavelength_um", "polarization", "posts",
                "seconds", "monochromatic", "sensor", "on_axis_ee_pixel_radius", "warnings", "accuracy",
                "pixel_pitch_um", "sensor_pixel_um", "z_um", "defocus_um", "relay_magnification", "requested_error",
                "spectral", "tolerance")


def _check_light(band: tuple[float, float], filt: tuple[float, float] | None, temperature_k: float) -> None:
    """The band, filter and scene temperature must give some light (clear errors before any work)."""
    lo, hi = band
    if filt is not None and not (lo - 1.5 * filt[1] < filt[0] < hi + 1.5 * filt[1]):
        raise InputError("filter_um", list(filt), f"a filter overlapping the band {lo:g}-{hi:g} um "
                         "(centre within 1.5 widths of it)")
    with warnings.catch_warnings(), np.errstate(over="ignore", under="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            psf_wavelengths(band, design_um=0.5 * (lo + hi), n=5, temperature_k=temperature_k, filter_um=filt)
        except InputError as e:
            if e.parameter != "band_um":
                raise
            raise InputError("temperature_k", temperature_k, f"a scene temperature at which the scene emits in "
                             f"the band {lo:g}-{hi:g} um (its Planck radiance there underflows to 0)") from None


def _check_distinct_names(sources: list[str], lenses: list[LensDesign]) -> None:
    """The report files are named after the lens: two lenses with one file stem would overwrite each other."""
    seen: dict[str, str] = {}
    for d, lens in zip(sources, lenses):
        if file_stem(lens.name) in seen:
            raise InputError("designs", d, f"lenses with distinct names: {seen[file_stem(lens.name)]} is also named "
                             f"'{lens.name}' (as a file name) and its report files would be overwritten "
                             "(change 'name' in one)")
        seen[file_stem(lens.name)] = d


def _check_wavelengths_and_fields(lens: LensDesign, band: tuple[float, float], filt: tuple[float, float] | None,
                                  wavelength_um: float | None, fields_deg: list[float] | None) -> None:
    """Every field must lie inside the lens' field at the longest wavelength used, and that wavelength below the
    one at which the rim's first order turns evanescent even on axis (the error names the option that sets it)."""
    wl_max = max(band[1] if filt is None else min(band[1], filt[0] + 1.5 * filt[1]),
                 wavelength_um or lens.wavelength_um)
    wl_lim = lens.wavelength_um * (1.0 - EVANESCENT_MARGIN) / design_na(lens)
    if not wl_max < wl_lim:
        if wavelength_um is not None and wavelength_um >= wl_max:
            opt, val = "wavelength_um", wavelength_um
        elif filt is not None:
            opt, val = "filter_um", list(filt)
        else:
            opt, val = "band_um", list(band)
        raise InputError(opt, val, f"wavelengths below {wl_lim:.4g} um for lens '{lens.name}' (NA {lens.na:.4f}, "
                         f"lambda0 {lens.wavelength_um:g} um): longer ones leave the rim of the lens evanescent")
    lim = max_field_deg(lens, wl_max)
    for fd in fields_deg or []:
        if not abs(fd) <= lim:
            raise InputError("field_deg", fd, f"|field| <= {lim:.3f} deg for lens '{lens.name}' "
                             f"(NA {lens.na:.4f}) at {wl_max:g} um")


# ----------------------------------------------------------------------------------------------
# the summary for people (what ``metafovea psf`` prints)
# ----------------------------------------------------------------------------------------------
def _frac(v: float | None) -> str:
    """A fraction (Strehl ratio, efficiency, encircled energy) to three decimals, ``-`` when not computed."""
    return "-" if v is None else f"{v:.3f}" if abs(v) >= 0.01 else f"{v:.2g}"


def lens_lines(name: str, s: dict[str, Any]) -> list[str]:
    """The key figures of one lens' report, for people: per field (the monochromatic PSFs) Strehl ratio, focusing
    efficiency, FWHM and encircled energy within the first dark ring; on axis the energy within one pixel; the
    sensor PSFs across the field; the report's page (``s``: one lens of :func:`psf_reports`' summary)."""

    sp = s["spectral"]
    band = (f"the filter {sp['filter_um'][0]:g} um (FWHM {sp['filter_um'][1]:g} um)" if sp["filter_um"] else
            f"{sp['band_um'][0]:g}-{sp['band_um'][1]:g} um")
    lines = [f"{name}: f {s['f_mm']:g} mm, D {s['diameter_mm']:g} mm (NA {s['na']:.4f}), {s['polarization']}-"
             f"polarised, {s['posts']} posts; sensor at {s['z_um'] / 1000:g} mm"
             + (f" ({s['defocus_um']:+.1f} um from f)" if abs(s["defocus_um"]) > 1e-6 else "")
             + f"; pixels {fmt(s['pixel_pitch_um'])} um at the focal plane ({s['sensor_pixel_um']:g} um / "
             f"{s['relay_magnification']:g}x relay)"]
    mono = list({m["field_deg"]: m for m in s["monochromatic"]}.values())  # a field once (few fields repeat)
    r_ee = mono[0]["ee_radius_um"]
    rows = [["field", "Strehl", "focusing eff.", "FWHM x / y", f"EE r {fmt(r_ee)} um", "PSF (error of peak)"]]
    for m in mono:
        fw = "-" if m["fwhm_um"] is None else f"{fmt(m['fwhm_um'][0])} / {fmt(m['fwhm_um'][1])} um"
        err = "not bounded" if m.get("model_note") else f"{m['error_estimate']:.1g}"
        grid = m["engine"] if m["grid"] == "fine" else f"pixel grid {fmt(m['pitch_um'])} um, {m['engine']}"
        rows.append([fmt(m["field_deg"], "deg"), _frac(m["strehl"]), _frac(m["focusing_efficiency"]), fw,
                     _frac(m["ee"]), f"{grid} ({err})"])
    widths = [max(len(r[j]) for r in rows) for j in range(len(rows[0]))]
    lines += ["  " + "  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in rows]
    lines.append(f"  (at {fmt(s['mono_wavelength_um'])} um. Strehl: peak / aberration-free peak of the same pupil; "
                 "focusing efficiency: peak / ideal continuous lens' peak;")
    lines.append(f"   EE: fraction of the incident power within the first dark ring 0.61 lambda0/NA = {fmt(r_ee)} um)")
    ee = s["on_axis_ee_pixel_radius"]
    lines.append(f"  on axis within one pixel pitch (r {fmt(ee['radius_um'])} um): {_frac(ee['mono'])} at "
                 f"{fmt(s['mono_wavelength_um'])} um, {_frac(ee['band'])} over {band} (exact)")
    sens = s["sensor"]
    fd = [r["field_deg"] for r in sens]
    peak = [r["poly_center_pixel"] for r in sens]
    lines.append(f"  sensor PSFs at {len(sens)} field{'s' if len(sens) > 1 else ''} ({fmt(min(fd))}-{fmt(max(fd))} "
                 f"deg, {sp['n_wavelengths']} wavelength bins): the chief-ray pixel holds {min(peak):.3g}-"
                 f"{max(peak):.3g} of the incident power over the band")
    if s.get("tolerance"):
        lines.append(f"  {s['tolerance']['why']}")
    warn = len(set(s["warnings"])) + len(s["accuracy"])
    lines.append(f"  report {s['html']} ({s['seconds']:.1f} s)"
                 + (f"  [{warn} warning{'s' if warn > 1 else ''}, on stderr]" if warn else ""))
    return lines


def tolerance_summary(res: dict[str, Any]) -> dict[str, Any]:
    """The report's PSFs in the words every stage's tolerance uses (``docs/tolerances.md``): the accuracy asked
    (``requested_error``: max abs error relative to the peak, ``metafovea psf --tolerance``), the engines each PSF's
    error chose (:func:`~metafovea.optics.psf.psf` and :func:`~metafovea.optics.sensor.sensor_psf` pick engine and
    sampling for it, within their cost budgets), the largest error estimate, the PSFs whose error is not bounded
    (the direction-sine model's edge diffraction) and those that missed the tolerance (``accuracy``), and why."""
    tol = float(res["requested_error"])
    mono, sens = res.get("monochromatic", []), res.get("sensor", [])
    bounded = [m["error_estimate"] for m in mono if not m.get("model_note") and m["error_estimate"] is not None]
    bounded += [r[k] for r in sens for k in ("poly_error_estimate", "mono_error_estimate") if r[k] is not None]
    chose = {"monochromatic": sorted({str(m["engine"]) for m in mono}),
             "sensor": sorted({str(r[k]) for r in sens for k in ("poly_engine", "mono_engine")})}
    est = max(bounded) if bounded else None
    unbounded = sum(1 for m in mono if m.get("model_note"))
    missed = len(res.get("accuracy", []))
    why = (f"tolerance {tol:g} of the peak (--tolerance, --error): engines {', '.join(chose['monochromatic'])} "
           f"(fine PSFs), {', '.join(chose['sensor'])} (sensor PSFs); largest error estimate "
           + ("none" if est is None else f"{est:.2g}")
           + (f", {unbounded} PSF(s) not bounded" if unbounded else "")
           + (f"; {missed} result(s) above the tolerance (on stderr)" if missed else "; every bounded PSF within it"))
    return {"stage": "psf", "tolerance_of_peak": tol, "chose": chose, "estimate_of_peak": est,
            "not_bounded": unbounded, "above_tolerance": missed, "why": why}


def timing_line(timing: dict[str, Any]) -> str:
    """The whole run's wall time (``timing['seconds']['total']``; the command's sets it from its own start) and its
    stages, for people (``timing``: :func:`psf_reports`' ``"timing"``)."""
    total_s = timing["seconds"]["total"]
    sec = {k: v for k, v in timing["seconds"].items() if k != "total"}
    names = {"posts": "posts (RCWA library)", "oblique": "posts at oblique incidence", "optical_train": "optical train",
             "reports": "reports"}
    split = [f"{names.get(k, k)} {v:.1f} s" for k, v in sec.items()]
    split.append(f"start and checks {max(0.0, total_s - sum(sec.values())):.1f} s")
    return f"{total_s:.1f} s in all ({', '.join(split)}); files in {timing['out_dir']}"
