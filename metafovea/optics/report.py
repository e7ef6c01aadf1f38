"""PSF/MTF report of one lens: PNG figures, JSON numbers and one self-contained HTML page."""

from __future__ import annotations

import base64
import html
import io
import logging
import math
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import LensDesign
from metafovea.io import atomic_write_bytes, atomic_write_json, atomic_write_text

from .mtf import diffraction_mtf, encircled_energy, pupil_mtf, strehl
from .psf import diffraction_radius_um, encircled_energy_on_axis, psf, sensor_psf
from .pupil import max_field_deg
from metafovea.radiometry import psf_wavelengths

log = logging.getLogger(__name__)


def file_stem(name: str) -> str:
    """A lens name made safe as a file-name stem: no path separators or '..' (a name like '../x' wrote
    outside the output directory), no shell-hostile characters; letters, digits, '-', '_' and '.' kept."""
    stem = "".join(ch if (ch.isalnum() or ch in "-_.") else "_" for ch in str(name)).lstrip(".")
    return stem or "lens"


def psf_report(lens: LensDesign, out_dir: str | Path, *, fields_deg: list[float] | None = None,
               band_um: tuple[float, float] = (8.0, 14.0), filter_um: tuple[float, float] | None = None,
               temperature_k: float = 300.0, n_wavelengths: int = 61, pixel_pitch_um: float = 17.0,
               error: float = 1e-4, post_set: Any = None, wavelength_um: float | None = None,
               window_um: float | None = None) -> dict[str, Any]:
    """Compute the report numbers and write figures, ``psf_report.json`` and ``psf_report.html``.

    ``wavelength_um``: the monochromatic PSFs' wavelength (default: the design wavelength); ``window_um``:
    full width of the fine monochromatic PSF windows (default: sized from the rays; a given window that
    truncates the PSF above ``error`` raises :class:`metafovea.optics.propagate.SamplingError`).
    """
    import matplotlib

    from .propagate import SamplingError
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = time.perf_counter()
    stem = file_stem(lens.name)
    mono_wl = [lens.wavelength_um if wavelength_um is None else float(wavelength_um)]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if fields_deg is None:
        fmax = min(max_field_deg(lens, band_um[1]), math.degrees(math.atan(6800.0 / lens.f_um)))
        fields_deg = list(np.linspace(0.0, fmax, 9))
    cut = 2 * lens.na / lens.wavelength_um * 1000
    nu = np.linspace(0, cut, 41)
    figs: dict[str, bytes] = {}
    res: dict[str, Any] = {"mono_wavelength_um": mono_wl[0], "lens": lens.name, "f_mm": lens.f_mm, "diameter_mm": lens.diameter_mm, "na": lens.na,
                           "wavelength_um": lens.wavelength_um, "polarization": lens.polarization,
                           "mtf_cutoff_cyc_per_mm": cut, "requested_error": error, "warnings": []}
    # monochromatic PSFs, on and off axis (continuous and fabricated)
    mono = []
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, fd in zip(axs, [0.0, fields_deg[len(fields_deg) // 2], fields_deg[-1]]):
        with warnings.catch_warnings(record=True) as ws:
            warnings.simplefilter("always")
            try:
                P = psf(lens, field_deg=fd, quantize=True, lattice=True, post_set=post_set, error=error,
                        wavelengths_um=mono_wl, window_um=window_um)
            except SamplingError as e:  # the aberrated PSF needs too large a window: pixel grid instead
                if window_um is not None:
                    raise
                P = sensor_psf(lens, pixel_pitch_um=pixel_pitch_um / 4, field_deg=fd, post_set=post_set,
                               error=max(error, 1e-3), wavelengths_um=mono_wl)
                res["warnings"].append(f"field {fd:.3g} deg: fine PSF not computed ({e}); pixel-grid PSF shown")
        res["warnings"] += [str(w.message) for w in ws]
        xs, ys = P.coords()
        ax.imshow(P.intensity, origin="lower", extent=[xs[0], xs[-1], ys[0], ys[-1]], cmap="magma")
        ax.set_title(f"{fd:.2f} deg, {P.engine}, err {P.error_estimate:.1g}", fontsize=9)
        ax.set_xlabel("x (um)")
        mono.append({"field_deg": fd, "engine": P.engine, "error_estimate": P.error_estimate,
                     "pitch_um": P.pitch_um, "samples": P.shape[0], "energy_fraction": P.energy_fraction,
                     "peak_fraction_per_um2": float(P.intensity.max() / P.pitch_um ** 2),
                     "strehl": strehl(P) if "ideal_peak_fraction" in P.info else None,
                     "seconds": P.info.get("seconds")})
    axs[0].set_ylabel("y (um)")
    fig.tight_layout()
    figs["psf_mono.png"] = _png(fig)
    res["monochromatic"] = mono
    # MTF against the diffraction limit (exact pupil autocorrelation, design wavelength)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(nu, diffraction_mtf(nu, cut), "k--", label="paraxial diffraction limit")
    ax.plot(nu, pupil_mtf(lens, nu), label="on axis (non-paraxial, continuous)")
    mt = {"nu_cyc_per_mm": nu, "on_axis": pupil_mtf(lens, nu)}
    for fd in (fields_deg[len(fields_deg) // 2], fields_deg[-1]):
        if fd == 0:
            continue
        try:
            t = pupil_mtf(lens, nu, field_deg=fd, angle_rad=0.0)
            s = pupil_mtf(lens, nu, field_deg=fd, angle_rad=math.pi / 2)
            ax.plot(nu, t, label=f"{fd:.2f} deg tangential")
            ax.plot(nu, s, ":", label=f"{fd:.2f} deg sagittal")
            mt[f"{fd:.3f}_tangential"], mt[f"{fd:.3f}_sagittal"] = t, s
        except Exception as e:
            res["warnings"].append(f"MTF at {fd:.3g} deg not computed: {e}")
    ax.set_xlabel("cycles/mm"); ax.set_ylabel("MTF"); ax.legend(fontsize=7); fig.tight_layout()
    figs["mtf.png"] = _png(fig)
    res["mtf"] = mt
    # encircled energy and broadband sensor PSFs over the field
    wl, w = psf_wavelengths(band_um, design_um=lens.wavelength_um, temperature_k=temperature_k, filter_um=filter_um,
                            n=n_wavelengths)
    res["spectral"] = {"n_wavelengths": int(wl.size), "band_um": band_um, "filter_um": filter_um,
                       "temperature_k": temperature_k}
    # on-axis power within one pixel pitch of the axis, exact (radial profiles, no pixel grid)
    res["on_axis_ee_pixel_radius"] = {
        "radius_um": pixel_pitch_um,
        "mono": encircled_energy_on_axis(lens, pixel_pitch_um, wavelengths_um=mono_wl, post_set=post_set),
        "band": encircled_energy_on_axis(lens, pixel_pitch_um, wavelengths_um=wl, weights=w, post_set=post_set)}
    radii = np.linspace(0, 6 * diffraction_radius_um(lens) + 2 * pixel_pitch_um, 40)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    sens = []
    for fd in fields_deg:
        with warnings.catch_warnings(record=True) as ws:
            warnings.simplefilter("always")
            mono_s = sensor_psf(lens, pixel_pitch_um=pixel_pitch_um, field_deg=fd, post_set=post_set, error=error,
                                wavelengths_um=mono_wl)
            poly = sensor_psf(lens, pixel_pitch_um=pixel_pitch_um, field_deg=fd, wavelengths_um=wl, weights=w,
                              post_set=post_set, error=error)
        res["warnings"] += [f"field {fd:.3g} deg: {x.message}" for x in ws]
        c = tuple(s // 2 for s in poly.shape)
        cm = tuple(s // 2 for s in mono_s.shape)
        sens.append({"field_deg": fd, "mono_center_pixel": float(mono_s.intensity[cm]),
                     "poly_center_pixel": float(poly.intensity[c]), "poly_energy_fraction": poly.energy_fraction,
                     "poly_engine": poly.engine, "poly_error_estimate": poly.error_estimate,
                     "mono_engine": mono_s.engine, "mono_error_estimate": mono_s.error_estimate,
                     "size_px": poly.shape[0], "seconds": poly.info["seconds"] + mono_s.info["seconds"]})
        if fd in (fields_deg[0], fields_deg[-1]):
            ee = encircled_energy(mono_s, radii, center_um=mono_s.center_um)
            ax[0].plot(radii, ee, label=f"{fd:.2f} deg, {mono_wl[0]:g} um")
            eep = encircled_energy(poly, radii, center_um=poly.center_um)
            ax[0].plot(radii, eep, "--", label=f"{fd:.2f} deg, polychromatic")
    ax[0].set_xlabel("radius (um)"); ax[0].set_ylabel("encircled energy (of incident)"); ax[0].legend(fontsize=7)
    ax[1].semilogy([s["field_deg"] for s in sens], [s["mono_center_pixel"] for s in sens], "o-",
                   label=f"{mono_wl[0]:g} um")
    ax[1].semilogy([s["field_deg"] for s in sens], [s["poly_center_pixel"] for s in sens], "s-", label="band")
    ax[1].set_xlabel("field (deg)"); ax[1].set_ylabel("power in the chief-ray pixel"); ax[1].legend()
    fig.tight_layout()
    figs["ee_field.png"] = _png(fig)
    res["sensor"] = sens
    res["pixel_pitch_um"] = pixel_pitch_um
    res["seconds"] = time.perf_counter() - t0
    for name, data in figs.items():
        atomic_write_bytes(out / f"{stem}_{name}", data)
    atomic_write_json(out / f"{stem}_psf_report.json", res)
    atomic_write_text(out / f"{stem}_psf_report.html", _html(res, figs))
    return res


def _png(fig: Any) -> bytes:
    import matplotlib.pyplot as plt
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def _html(res: dict[str, Any], figs: dict[str, bytes]) -> str:
    rows = "".join(f"<tr><td>{m['field_deg']:.3f}</td><td>{m['engine']}</td><td>{m['error_estimate']:.2g}</td>"
                   f"<td>{m['pitch_um']:.3g}</td><td>{m['energy_fraction']:.4f}</td>"
                   f"<td>{'' if m['strehl'] is None else format(m['strehl'], '.4f')}</td></tr>" for m in res["monochromatic"])
    srows = "".join(f"<tr><td>{s['field_deg']:.3f}</td><td>{s['mono_center_pixel']:.4g}</td>"
                    f"<td>{s['poly_center_pixel']:.4g}</td><td>{s['poly_energy_fraction']:.4g}</td>"
                    f"<td>{html.escape(s['poly_engine'])}</td><td>{s['poly_error_estimate']:.2g}</td></tr>"
                    for s in res["sensor"])
    imgs = "".join(f"<h3>{html.escape(n)}</h3><img src='data:image/png;base64,{base64.b64encode(d).decode()}'/>"
                   for n, d in figs.items())
    warn = "".join(f"<li>{html.escape(w)}</li>" for w in dict.fromkeys(res["warnings"]))
    return f"""<!doctype html><html><head><meta charset='utf-8'><title>PSF report {html.escape(res['lens'])}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}td,th{{border:1px solid #ccc;padding:2px 6px}}</style>
</head><body><h1>PSF / MTF report: {html.escape(res['lens'])}</h1>
<p>f = {res['f_mm']:g} mm, D = {res['diameter_mm']:g} mm, NA = {res['na']:.4f}, design wavelength
{res['wavelength_um']:g} um, polarisation {res['polarization']}; MTF cutoff 2NA/lambda = {res['mtf_cutoff_cyc_per_mm']:.2f}
cycles/mm. Requested error {res['requested_error']:g} (max abs / peak). Scalar Debye (direction-sine) model,
lattice sampling and N-level quantisation included in the PSFs; spectral weights: Planck at
{res['spectral']['temperature_k']:g} K, band {res['spectral']['band_um']}, filter {res['spectral']['filter_um']},
{res['spectral']['n_wavelengths']} wavelength bins (geometric around the design wavelength).</p>
<h2>Monochromatic PSFs (engine, sampling, error estimate)</h2>
<table><tr><th>field deg</th><th>engine</th><th>error est.</th><th>pitch um</th><th>energy in window</th><th>Strehl</th></tr>{rows}</table>
<p>On axis, power within r = {res['on_axis_ee_pixel_radius']['radius_um']:g} um (exact radial integral):
{res['mono_wavelength_um']:g} um {res['on_axis_ee_pixel_radius']['mono']:.4f}, band {res['on_axis_ee_pixel_radius']['band']:.4g}
(fractions of the incident power).</p>
<h2>Sensor PSFs ({res['pixel_pitch_um']:g} um pixels) across the field</h2>
<table><tr><th>field deg</th><th>chief-ray pixel, design wl</th><th>chief-ray pixel, band</th><th>band power in window</th>
<th>engines</th><th>error est.</th></tr>{srows}</table>
{imgs}
<h2>Warnings</h2><ul>{warn or '<li>none</li>'}</ul>
<p>Computed in {res['seconds']:.1f} s.</p></body></html>
"""
