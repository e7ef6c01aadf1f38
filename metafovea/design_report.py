"""Designing lenses and their design bundles: numbers (JSON + TOML), radial profile (CSV) and figures (PNG).

:func:`design_lenses` summarises a list of lenses with the posts of a post set or of their platform's RCWA
library (``metafovea design`` and notebooks); :func:`write_design_bundles` writes one bundle per lens.
"""

from __future__ import annotations

import io as _io
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.config import LensDesign, PlatformDesign
from metafovea.errors import InputError
from metafovea.io import atomic_write_bytes, atomic_write_json, atomic_write_text
from metafovea.lens import (
    LensSummary,
    design_phase,
    evaluate_tile,
    paraxial_phase,
    posts_per_2pi,
    quantize_phase,
    site_index_range,
    summarize,
    wrap_phase,
    zone_width_um,
)
from metafovea.library import PostSet, platform_post_sets
from metafovea.report import fig_to_png
from metafovea.units import TWO_PI, UM_PER_MM


def shared_platform(lenses: Sequence[LensDesign]) -> PlatformDesign:
    """The platform the lenses share (one RCWA library for all): the same period, post height, wavelength and
    levels, else an :class:`InputError` on ``from_library``. Posts and wafer are of the lenses' substrate
    index; the min feature is 0.5 um, or an eighth of a finer period."""
    l0 = lenses[0]
    for lens in lenses[1:]:
        if (lens.period_um, lens.post_height_um, lens.wavelength_um, lens.levels) != \
                (l0.period_um, l0.post_height_um, l0.wavelength_um, l0.levels):
            raise InputError("from_library", True, "lenses sharing one platform (period, height, wavelength, levels)")
    return PlatformDesign(period_um=l0.period_um, post_height_um=l0.post_height_um, wavelength_um=l0.wavelength_um,
                          n_substrate=l0.n_substrate, n_post=l0.n_substrate,
                          min_feature_um=min(0.5, 0.125 * l0.period_um))


def design_lenses(lenses: Sequence[LensDesign], *, post_set: PostSet | None = None, from_library: bool = False,
                  samples: int = 1 << 20, progress: bool = False) -> list[LensSummary]:
    """Summaries of ``lenses`` (:func:`metafovea.lens.summarize`; physics warnings are in each summary's
    ``warnings``, not emitted).

    ``post_set``: the posts to list for the lens of its polarisation. One lens must focus the post set's
    polarisation (else an :class:`InputError` on ``post_set``); of several lenses (a system) the others get
    none. ``from_library``: instead, select each lens' posts from the RCWA library of the platform the lenses
    share (:func:`shared_platform`; the default platform's ships with metafovea, another is computed on first use and
    cached; ``progress`` shows a bar).
    """
    if not lenses:
        raise InputError("lenses", [], "at least one lens")
    sets: dict[str, PostSet] | None = None
    if from_library:
        if post_set is not None:
            raise InputError("post_set", post_set.source, "no post set with from_library (the library selects one)")
        sets, _ = platform_post_sets(shared_platform(lenses), lenses[0].levels, progress=progress)
    out = []
    for lens in lenses:
        ps = sets[lens.polarization] if sets is not None else post_set
        if ps is not None and ps.polarization != lens.polarization and len(lenses) > 1:
            ps = None
        out.append(summarize(lens, post_set=ps, samples=samples, emit_warnings=False))
    return out


def write_design_bundles(lenses: Sequence[LensDesign], summaries: Sequence[LensSummary], out_dir: Path) -> list[Path]:
    """The design bundle of each lens (:func:`write_design_bundle`): in ``out_dir`` for one lens, in
    ``out_dir/<lens name>`` for several."""
    written: list[Path] = []
    for lens, s in zip(lenses, summaries, strict=True):
        written += write_design_bundle(lens, s, out_dir / lens.name if len(lenses) > 1 else out_dir)
    return written


def summary_dict(s: LensSummary) -> dict[str, Any]:
    d = asdict(s)
    if not s.phase_poly_rad:  # the plain hyperbola: the same keys as before the added phase existed
        for k in ("phase_poly_rad", "narrowest_posts_per_2pi", "narrowest_zone_radius_um"):
            d.pop(k)
    else:
        d["phase_poly_rad"] = list(s.phase_poly_rad)
    d["warnings"] = list(s.warnings)
    d["posts"] = list(s.posts)
    return d


def summary_rows(s: LensSummary) -> list[tuple[str, str]]:
    """The design summary as ``(quantity, value with units)`` rows (the text table and the HTML reports)."""
    rows = [
        ("lens", f"{s.name}  (focuses {s.polarization}-polarised light)"),
        ("focal length f", f"{s.f_mm:g} mm"),
        ("diameter D", f"{s.diameter_mm:g} mm"),
        ("design wavelength", f"{s.wavelength_um:g} um"),
        ("NA", f"{s.na:.4f}"),
        ("F-number f/D", f"F/{s.f_number:.3g}"),
        ("lattice", f"{s.period_um:g} um square, sites at "
                    f"{'integer' if s.lattice == 'integer' else 'half-integer'} multiples"),
        ("posts in aperture (exact)", f"{s.posts_in_aperture:,}"),
        ("2 pi zones", f"{s.zones_2pi:.2f}  (rim phase {s.rim_phase_rad:.1f} rad)"),
        ("zone width at rim", f"{s.rim_zone_width_um:.2f} um = {s.rim_posts_per_2pi:.2f} posts per 2 pi"),
        *([("phase beyond the hyperbola", "sum_j a_j (r/R)^(2j), a = ["
            + ", ".join(f"{a:.6g}" for a in s.phase_poly_rad) + "] rad"),
           ("narrowest zone", f"{s.narrowest_posts_per_2pi:.2f} posts per 2 pi at r = "
                              f"{s.narrowest_zone_radius_um / UM_PER_MM:.4g} mm")] if s.phase_poly_rad else []),
        ("Airy first zero", f"{s.airy_first_zero_paraxial_um:.4g} um (1.22 lambda F#), "
                            f"{s.airy_first_zero_na_um:.4g} um (0.61 lambda/NA)"),
        ("PSF FWHM (0.514 lambda/NA)", f"{s.fwhm_um:.4g} um"),
        ("MTF cutoff 2 NA / lambda", f"{s.mtf_cutoff_cyc_per_mm:.2f} cycles/mm"),
        ("phase levels", f"{s.levels}"),
        ("efficiency, point-sampled", f"{s.scalar_efficiency:.4f}  (sinc^2(pi/{s.levels}))"),
        ("efficiency, on the lattice", f"{s.lattice_efficiency:.4f} +- {s.lattice_efficiency_stderr:.4f}  "
                                       f"({s.levels} levels, {s.lattice_efficiency_sites:,} sites sampled; "
                                       f"lattice sampling alone {s.lattice_sampling_efficiency:.4f})"),
    ]
    if s.post_set:
        ps = s.post_set
        if "expected_focusing_efficiency" in ps:
            rows.append(("post set", f"{ps['source']}: expected efficiency {ps['expected_focusing_efficiency']:.3f} "
                                     f"(zero order x quantisation), {ps['expected_lens_efficiency']:.3f} with lattice "
                                     f"sampling; max phase error {ps['max_abs_phase_error_rad']:.3f} rad; pass-through "
                                     f"phase spread {ps['pass_phase_spread_rad']:.3f} rad, transmission "
                                     f"{ps['pass_coherent_transmission']:.3f}"))
        else:
            rows.append(("post set", f"{ps['source']} (no RCWA figures)"))
    if s.posts:
        for p in s.posts:
            rows.append((f"post level {p['level']}",
                         f"wx {p['wx_um']:.3f} um, wy {p['wy_um']:.3f} um, |t| {p['t_focus_abs']:.3f}, "
                         f"phase {p['t_focus_phase_rad']:.3f} rad, pass-through phase {p['t_pass_phase_rad']:.3f} rad"))
    return rows


def format_summary(s: LensSummary) -> str:
    """Human-readable table."""
    rows = summary_rows(s)
    w = max(len(a) for a, _ in rows)
    lines = [f"  {a.ljust(w)}  {b}" for a, b in rows]
    for msg in s.warnings:
        lines.append(f"  WARNING: {msg}")
    return "\n".join(lines)


def design_toml(design: LensDesign) -> str:
    return (f'# written by metafovea design\nname = "{design.name}"\nf_mm = {design.f_mm!r}\n'
            f'diameter_mm = {design.diameter_mm!r}\nwavelength_um = {design.wavelength_um!r}\n'
            f'polarization = "{design.polarization}"\nperiod_um = {design.period_um!r}\n'
            f'post_height_um = {design.post_height_um!r}\nlevels = {design.levels}\nlattice = "{design.lattice}"\n'
            + (f"phase_poly_rad = [{', '.join(repr(float(a)) for a in design.phase_poly_rad)}]\n"
               if design.phase_poly_rad else ""))


def radial_profile(design: LensDesign, n: int = 2001) -> dict[str, np.ndarray]:
    """Radial samples (um) of the design phase (``phase_poly_rad`` included), its wrapped value, level, zone width
    and posts per 2 pi (from the actual local gradient)."""
    r = np.linspace(0.0, design.radius_um, n)
    phi = design_phase(design, r, 0.0)
    return {"r_um": r, "phase_rad": phi,
            "paraxial_phase_rad": paraxial_phase(r, design.f_um, design.wavelength_um, design.phase_sign),
            "wrapped_rad": wrap_phase(phi), "level": quantize_phase(phi, design.levels),
            "zone_width_um": zone_width_um(design, r), "posts_per_2pi": posts_per_2pi(design, r)}


def write_design_bundle(design: LensDesign, summary: LensSummary, out_dir: Path, patch_sites: int = 200) -> list[Path]:
    """Write summary.json, design.toml, radial_profile.csv and three figures into ``out_dir``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written = [atomic_write_json(out_dir / "summary.json", summary_dict(summary)),
               atomic_write_text(out_dir / "design.toml", design_toml(design))]
    prof = radial_profile(design)
    keys = list(prof)
    table = np.column_stack([prof[k] for k in keys])
    buf = _io.StringIO()
    np.savetxt(buf, table, delimiter=",", header=",".join(keys), comments="", fmt="%.10g")
    written.append(atomic_write_text(out_dir / "radial_profile.csv", buf.getvalue()))

    # wrapped phase of a central patch and of a patch at the rim (where zones are narrowest)
    lo, hi = site_index_range(design)
    n_c = min(patch_sites, hi - lo + 1)
    n_r = min(64, hi - lo + 1)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    for ax, (n, iy0, ix0, title) in zip(axes, [(n_c, -(n_c // 2), -(n_c // 2), "centre"),
                                               (n_r, -(n_r // 2), max(lo, hi - n_r + 1), "rim (+x edge)")]):
        t = evaluate_tile(design, iy0, ix0, n, n)
        ph = np.where(t.levels >= 0, TWO_PI * t.levels / design.levels, np.nan)
        x0 = ix0 * design.period_um / UM_PER_MM
        y0 = iy0 * design.period_um / UM_PER_MM
        ext = (x0, x0 + n * design.period_um / UM_PER_MM, y0, y0 + n * design.period_um / UM_PER_MM)
        im = ax.imshow(ph, origin="lower", extent=ext, cmap="twilight", vmin=0, vmax=TWO_PI, interpolation="nearest")
        ax.set_title(f"post phase ({design.levels} levels), {title}\n{n}x{n} posts")
        ax.set_xlabel("x (mm)")
    axes[0].set_ylabel("y (mm)")
    fig.colorbar(im, ax=axes, label="phase (rad)")
    written.append(atomic_write_bytes(out_dir / "phase_patch.png", fig_to_png(fig)))
    plt.close(fig)

    r_mm = prof["r_um"] / UM_PER_MM
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(r_mm, prof["phase_rad"] / TWO_PI, label="design (hyperbola + phase_poly_rad)" if design.phase_poly_rad
            else "hyperbolic")
    ax.plot(r_mm, prof["paraxial_phase_rad"] / TWO_PI, "--", label="paraxial (quadratic)")
    ax.set_xlabel("radius (mm)")
    ax.set_ylabel("phase / 2 pi (zones)")
    ax.set_title(f"{design.name}: f = {design.f_mm:g} mm, D = {design.diameter_mm:g} mm, NA {design.na:.3f}")
    ax.legend()
    ax.grid(alpha=0.3)
    written.append(atomic_write_bytes(out_dir / "radial_profile.png", fig_to_png(fig)))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.5, 4))
    m = r_mm > 0
    ax.semilogy(r_mm[m], prof["posts_per_2pi"][m])
    ax.axhline(4, color="r", ls="--", label="4 posts per 2 pi")
    ax.set_xlabel("radius (mm)")
    ax.set_ylabel("posts per 2 pi zone")
    ax.set_title(f"{design.name}: rim {summary.rim_posts_per_2pi:.2f} posts per 2 pi ({design.period_um:g} um lattice)")
    ax.legend()
    ax.grid(alpha=0.3, which="both")
    written.append(atomic_write_bytes(out_dir / "posts_per_2pi.png", fig_to_png(fig)))
    plt.close(fig)
    return written
