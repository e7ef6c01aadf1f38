"""What a co-design run writes: the co-designed design files (the same format as ``designs/``: ``psf``,
``simulate``, ``export`` and ``validate`` take them unchanged), the production check of each co-designed lens, the
JSON summary and an HTML report (PSFs, MTF against the line bound, the optimisation's history, the limits).

Production check (:func:`production_check`): the co-designed and the hyperbolic lens re-propagated by the
production engine (:func:`metafovea.optics.sensor.sensor_psf`, 'auto': the exact Rayleigh-Sommerfeld engine for a
lens with an added phase) over the same wavelengths, weights, post set and pixel grid, without the train (the
production PSF's normalisation); their MTF areas beside the differentiable model's and the largest difference of
the two band PSFs relative to the peak.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import platform_toml, system_toml
from metafovea.design_report import design_toml
from metafovea.io import atomic_write_json, atomic_write_text, dropped_if_empty
from metafovea.report import HtmlReport, fig_to_png

from .run import CodesignResult, LensResult, band_weights

#: the production engine's error budget in the check (relative to the peak: issue 33's 1e-3 agreement)
CHECK_ERROR = 1e-3


def production_check(system: Any, r: LensResult, posts: str) -> dict[str, Any]:
    """The production engine's band PSF of the co-designed and the hyperbolic lens against the differentiable
    model's (see the module docstring)."""
    from metafovea.library.platform import system_post_sets
    from metafovea.optics import jaxpsf
    from metafovea.optics.sensor import sensor_psf

    z = float(system.lens_to_sensor_um[0 if r.sampling["channel"] == "foveal" else 1])
    post_sets, _ = system_post_sets(system, posts)
    ps = post_sets[r.lens.polarization]
    n = r.sampling["wavelengths"]
    band = r.limit.band_um
    wl = np.linspace(*band, n)
    w = band_weights(wl, system, band)
    out: dict[str, Any] = {}
    with jaxpsf.x64():
        for key, lens in (("codesigned", r.lens), ("hyperbolic", r.hyperbolic)):
            prod = sensor_psf(lens, pixel_pitch_um=r.pitch_um, wavelengths_um=wl, weights=w, post_set=ps,
                              size_px=r.sampling["size_px"], z_um=z, error=CHECK_ERROR)
            model = jaxpsf.imaging_model(lens, wavelengths_um=wl, weights=w, pitch_um=r.pitch_um,
                                         size=r.sampling["size_px"], sensor=True, z_um=z)
            tf = jaxpsf.level_table(lens, ps, lens.polarization, wl)
            mine = np.asarray(model.band_psf(None, tf))
            peak = float(prod.intensity.max())
            out[key] = {"engine": prod.engine, "error_estimate": float(prod.error_estimate),
                        "mtf_area_production": float(jaxpsf.mtf_area(prod.intensity, r.pitch_um, 0.5 / r.pitch_um)),
                        "mtf_area_model": float(jaxpsf.mtf_area(mine, r.pitch_um, 0.5 / r.pitch_um)),
                        "max_difference_of_peak": float(np.max(np.abs(mine - prod.intensity)) / peak)}
    out["gain_production"] = out["codesigned"]["mtf_area_production"] / out["hyperbolic"]["mtf_area_production"]
    return out


def _figures(r: LensResult) -> dict[str, bytes]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs: dict[str, bytes] = {}
    fig, axs = plt.subplots(1, 2, figsize=(8.8, 3.6))
    half = 0.5 * r.psf.shape[0] * r.pitch_um / 1000
    vmax = float(max(r.psf.max(), r.psf_hyperbolic.max()))
    for ax, img, title in zip(axs, (r.psf_hyperbolic, r.psf), ("hyperbolic", "co-designed")):
        im = ax.imshow(np.log10(np.maximum(img, vmax * 1e-5)), extent=(-half, half, -half, half), origin="lower",
                       cmap="inferno", vmin=math.log10(vmax) - 5, vmax=math.log10(vmax))
        ax.set(title=f"{r.lens.name}: {title} band PSF", xlabel="x on the focal plane (mm)", ylabel="y (mm)")
        fig.colorbar(im, ax=ax, label="log10 power fraction per pixel")
    figs["psf"] = fig_to_png(fig)
    plt.close(fig)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(8.8, 3.4))
    nu = r.bound.nu_cyc_per_mm
    for img, label in ((r.psf_hyperbolic, "hyperbolic"), (r.psf, "co-designed")):
        otf = np.abs(np.fft.fft2(img, s=(4 * img.shape[0],) * 2)) / img.sum()
        f = np.fft.fftfreq(4 * img.shape[0], r.pitch_um) * 1e3
        keep = (f >= 0) & (f <= nu[-1])
        a1.plot(f[keep], otf[0, keep], label=label)
    a1.plot(nu, r.bound.bound, "k--", label="line bound (any phase)")
    a1.set(xlabel="spatial frequency on the focal plane (cyc/mm)", ylabel="MTF of the band PSF", yscale="log",
           title="band MTF (x) to the sensor's Nyquist")
    a1.legend(fontsize=7)
    h = r.optimization.history
    a2.plot(np.arange(h["loss"].size), -h["loss"])
    a2.set(xlabel="step", ylabel="band MTF area to Nyquist", title="optimisation")
    figs["mtf"] = fig_to_png(fig)
    plt.close(fig)
    return figs


def write_codesign(result: CodesignResult, out_dir: str | Path, *, check: bool = True) -> list[Path]:
    """Write the co-designed design files, ``codesign.json`` and ``report.html`` into ``out_dir`` (atomically;
    the caller checked that nothing is overwritten without consent). ``check``: run :func:`production_check`."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = result.system
    written = [atomic_write_text(out / "platform.toml", platform_toml(s.platform)),
               atomic_write_text(out / "foveal.toml", design_toml(s.foveal)),
               atomic_write_text(out / "perifoveal.toml", design_toml(s.perifoveal)),
               atomic_write_text(out / "system.toml", system_toml(s, name="codesigned"))]
    summary = result.summary()
    rep = HtmlReport(f"metafovea codesign: {', '.join(result.lenses)} ({result.options.objective})")
    for name, r in result.lenses.items():
        if check:
            summary["lenses"][name]["production_check"] = production_check(s, r, result.options.posts)
        d = summary["lenses"][name]
        rep.heading(f"{name} lens")
        for line in d["bandwidth_limit"]:
            rep.paragraph(line, note=True)
        rows = [("added phase a_j (rad)", ", ".join(f"{x:.4g}" for x in d["phase_poly_rad"])),
                ("band MTF area to Nyquist: hyperbolic", d["mtf_area_hyperbolic"]),
                ("band MTF area to Nyquist: co-designed", d["mtf_area"]),
                ("gain (line bound: at most)", f"{d['gain']:.3f} ({d['line_bound_gain_limit']:.3f})"),
                ("per-wavelength MTF area: hyperbolic / co-designed",
                 f"{d['mtf_area_per_wavelength_hyperbolic']:.4g} / {d['mtf_area_per_wavelength']:.4g}"),
                ("spectral sampling", d["sampling"]["why"]), ("steps", d["steps"])]
        if "production_check" in d:
            pc = d["production_check"]
            rows += [("production engine: gain", f"{pc['gain_production']:.3f}"),
                     ("production vs model, co-designed (max |diff| / peak)",
                      f"{pc['codesigned']['max_difference_of_peak']:.2e} ({pc['codesigned']['engine']})")]
        rep.key_values(rows)
        for key, png in _figures(r).items():
            rep.image(png, f"{name}: {key}")
    written.append(atomic_write_json(out / "codesign.json", summary))
    written.append(rep.write(out / "report.html"))
    return written



#: what a finished run leaves in its folder (a folder holding any of them is only replaced with force)
OUTPUT_FILES = ("codesign.json", "report.html", "system.toml", "foveal.toml", "perifoveal.toml", "platform.toml")


def _prepare(out: Path, force: bool) -> None:
    """A fresh or empty folder starts a run; one holding only this command's checkpoints resumes it, and so does one
    whose final writes a Ctrl-C stopped (checkpoints and some of :data:`OUTPUT_FILES`, without the page written
    last: the rerun writes them again); anything else (a finished run, other files) needs ``force``, which also
    drops the old checkpoints."""
    from metafovea.errors import InputError
    from metafovea.io import prepare_output

    if out.is_dir() and any(out.iterdir()):
        names = {p.name for p in out.iterdir()}
        ckpt = {n for n in names if n.startswith("checkpoint_") and n.endswith(".npz")}
        only_checkpoints = names == ckpt or (bool(ckpt) and names - ckpt <= set(OUTPUT_FILES) - {"report.html"})
        if force:
            for p in out.glob("checkpoint_*.npz"):
                p.unlink()
        elif not only_checkpoints:
            raise InputError("out", str(out), "an empty folder, or one holding only a stopped codesign run's "
                             "checkpoints (to resume it); pass force=True (--force) to start afresh")
        return
    prepare_output(out, force, is_dir=True)


def run_codesign(system_file: str | Path | None, options: Any, out_dir: str | Path, *, force: bool = False,
                 check: bool = True) -> dict[str, Any]:
    """Load the system (a system TOML, or the built-in paper prototype for None), co-design it
    (:func:`metafovea.codesign.run.codesign`, checkpoints in ``out_dir``: a stopped run resumes), write everything
    (:func:`write_codesign`) and return the summary."""
    from metafovea.config import SystemDesign, load_system
    from metafovea.errors import InputError

    from .run import codesign

    system = SystemDesign.paper() if system_file is None else load_system(system_file)
    out = Path(out_dir)
    if system_file is not None and Path(system_file).resolve().parent == out.resolve():  # --force included
        raise InputError("out", str(out), f"a folder other than the input's ({system_file}): the run writes "
                         "system.toml and the lens files there, over the files it reads")
    with dropped_if_empty(out):  # refused before any step (a cap, a bad band): no empty folder left
        _prepare(out, force)
        result = codesign(system, options, checkpoint_dir=out)
    write_codesign(result, out, check=check)
    import json

    return json.loads((out / "codesign.json").read_text())
