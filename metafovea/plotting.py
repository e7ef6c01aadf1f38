"""Figures and notebook views of the stage types: the helpers behind ``.plot(ax=None)`` and ``._repr_html_()`` of
:class:`~metafovea.config.LensDesign`, :class:`~metafovea.library.PostSet`, :class:`~metafovea.optics.PSF`,
:class:`~metafovea.measurement.Measurement` and :class:`~metafovea.reconstruct.Reconstruction`.

Ground floor (every stage may use it): matplotlib is imported inside the functions, so importing this module
costs nothing. Thermal images are shown in :func:`iron_colormap` with a colour bar in their unit (K or DN);
every axis names its quantity and unit. PNG bytes come from :func:`metafovea.report.fig_to_png` (the one figure writer)
or, for thumbnails of one array, ``matplotlib.image.imsave`` (no figure, no pyplot state). A PostSet, PSF or
Reconstruction argument is typed ``Any``: a ground-floor module may not import their stages, not even for type
checking (``tests/test_architecture.py``).
"""

from __future__ import annotations

import base64
import html
import io as _io
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.errors import check_int

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.colors import Colormap, Normalize
    from matplotlib.figure import Figure
    from matplotlib.image import AxesImage

    from metafovea.config import LensDesign
    from metafovea.measurement import Measurement

#: the largest side of an inline thumbnail (pixels): larger arrays are shown with a stride
THUMB_PX = 160


def iron_colormap():
    """The "iron" (ironbow) palette of thermal cameras: black - indigo - magenta - orange - yellow - white."""
    from matplotlib.colors import LinearSegmentedColormap

    stops = [(0.0, "#000000"), (0.12, "#1b0c5a"), (0.28, "#6a0a8f"), (0.42, "#a51a8a"), (0.55, "#d8344e"),
             (0.68, "#f0641c"), (0.8, "#fb9d07"), (0.9, "#fdd33c"), (1.0, "#ffffe6")]
    return LinearSegmentedColormap.from_list("iron", stops, N=256)


def panels(ax: Axes | Sequence[Axes] | None, n: int, *, width: float = 4.4,
           height: float = 3.6) -> tuple[Figure, list[Axes | None]]:
    """The figure and ``n`` panels to draw into.

    Parameters
    ----------
    ax : matplotlib Axes, sequence of ``n`` Axes, or None
        None: a new pyplot figure with ``n`` panels side by side. One Axes: only the first (main) panel is drawn
        there (the others are ``None``). A sequence: one Axes per panel.
    n : int
        Number of panels of the full figure.

    Returns
    -------
    fig : matplotlib Figure
    axes : list of Axes or None, length ``n``
    """
    if ax is None:
        import matplotlib.pyplot as plt

        fig, axs = plt.subplots(1, n, figsize=(width * n, height), squeeze=False, layout="constrained")
        return fig, list(axs[0])
    if isinstance(ax, (list, tuple, np.ndarray)):
        axs = list(np.ravel(np.asarray(ax, dtype=object)))
        if len(axs) != n:
            from metafovea.errors import InputError

            raise InputError("ax", f"{len(axs)} Axes", f"one Axes or {n} Axes (one per panel)")
        return axs[0].figure, axs
    return ax.figure, [ax] + [None] * (n - 1)


def display_range(img: ArrayLike, percentiles: tuple[float, float] = (0.5, 99.5)) -> tuple[float, float]:
    """``(vmin, vmax)`` of the finite values at ``percentiles`` (the automatic gain of a thermal camera)."""
    a = np.asarray(img, dtype=np.float64)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(a, percentiles))
    return lo, hi if hi > lo else lo + 1.0


def image(ax: Axes, img: ArrayLike, *, label: str, title: str = "", extent: Sequence[float] | None = None,
          xlabel: str = "x (pixels)", ylabel: str = "y (pixels)", cmap: str | Colormap | None = None,
          vmin: float | None = None, vmax: float | None = None, norm: Normalize | None = None) -> AxesImage:
    """Draw ``img`` ``(H, W)`` (row = y, origin at the top unless ``extent`` gives y increasing upward) with a
    colour bar labelled ``label`` (quantity and unit) and labelled axes; returns the image artist.

    ``cmap`` defaults to :func:`iron_colormap` (thermal images); ``vmin``/``vmax`` to :func:`display_range`.
    """
    a = np.asarray(img, dtype=np.float64)
    if norm is None and (vmin is None or vmax is None):
        lo, hi = display_range(a)
        vmin = lo if vmin is None else vmin
        vmax = hi if vmax is None else vmax
    kw: dict[str, Any] = {"norm": norm} if norm is not None else {"vmin": vmin, "vmax": vmax}
    origin = "lower" if extent is not None else "upper"
    im = ax.imshow(a, cmap=cmap if cmap is not None else iron_colormap(), extent=extent, origin=origin,
                   interpolation="nearest", **kw)
    ax.figure.colorbar(im, ax=ax, label=label, shrink=0.85)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=10)
    return im


def thumbnail_png(img: ArrayLike, *, cmap: str | Colormap | None = None, vmin: float | None = None,
                  vmax: float | None = None, log: bool = False) -> bytes:
    """A small PNG of one array ``(H, W)`` (at most :data:`THUMB_PX` per side, strided), in ``cmap`` (default: the
    iron palette) between ``vmin`` and ``vmax`` (default :func:`display_range`); ``log``: log10 of the values
    over 4 decades below the peak."""
    from matplotlib.image import imsave

    a = np.asarray(img, dtype=np.float64)
    step = max(1, int(math.ceil(max(a.shape) / THUMB_PX)))
    a = a[::step, ::step]
    if log:
        peak = np.nanmax(a) if np.any(np.isfinite(a)) else 1.0
        a = np.log10(np.maximum(a, peak * 1e-4) / peak) if peak > 0 else np.zeros_like(a)
        vmin, vmax = -4.0, 0.0
    lo, hi = display_range(a)
    lo = lo if vmin is None else vmin
    hi = hi if vmax is None else vmax
    buf = _io.BytesIO()
    imsave(buf, np.nan_to_num(a, nan=lo), cmap=cmap if cmap is not None else iron_colormap(), vmin=lo, vmax=hi,
           format="png")
    return buf.getvalue()


def figure_png(fig: Figure, dpi: int | None = None) -> bytes:
    """A figure as PNG bytes (through :func:`metafovea.report.fig_to_png`), by default at the thumbnail
    resolution :data:`metafovea.report.THUMBNAIL_DPI`."""
    from metafovea.report import THUMBNAIL_DPI, fig_to_png

    dpi = THUMBNAIL_DPI if dpi is None else dpi

    return fig_to_png(fig, dpi=dpi)


def small_figure(n: int = 1, *, width: float = 3.2, height: float = 2.4) -> tuple[Figure, list[Axes]]:
    """A pyplot-free figure with ``n`` panels for an inline thumbnail (nothing left open in pyplot)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width * n, height), layout="constrained")
    axs = fig.subplots(1, n, squeeze=False)
    return fig, list(axs[0])


def fmt(v: Any, unit: str = "", digits: int = 4) -> str:
    """A number for a table: ``digits`` significant figures (thousands separators for integers), its unit, and
    ``n/a`` for a missing or non-finite value (never the text ``None``)."""
    if v is None:
        return "n/a"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        s = f"{int(v):,}"
    elif isinstance(v, (float, np.floating)):
        if not math.isfinite(float(v)):
            return "n/a" if math.isnan(float(v)) else str(float(v))
        s = f"{float(v):.{digits}g}"
    else:
        s = str(v)
    return f"{s} {unit}" if unit else s


def html_card(title: str, rows: Sequence[tuple[str, str]], images: Sequence[tuple[str, bytes]] = ()) -> str:
    """A small self-contained HTML view: a title, a two-column table of ``(quantity, value with unit)`` rows and
    inline PNG thumbnails ``(caption, png bytes)`` (for Jupyter's ``_repr_html_``)."""
    esc = html.escape
    trs = "".join(f"<tr><th style='text-align:left;padding-right:1em'>{esc(str(k))}</th>"
                  f"<td style='text-align:left'>{esc(str(v))}</td></tr>" for k, v in rows)
    figs = "".join(f"<figure style='display:inline-block;margin:0 0.6em 0 0'>"
                   f"<img src='data:image/png;base64,{base64.b64encode(png).decode()}' alt='{esc(cap)}'/>"
                   f"<figcaption style='font-size:smaller'>{esc(cap)}</figcaption></figure>" for cap, png in images)
    return (f"<div class='metafovea'><strong>{esc(title)}</strong>"
            f"<table style='border-collapse:collapse'>{trs}</table>{figs}</div>")


# ----------------------------------------------------------------------------------------------
# LensDesign
# ----------------------------------------------------------------------------------------------
def _lens_numbers(design: LensDesign) -> dict[str, float]:
    """Rim zone width and posts per 2 pi zone (the local zone width ``lambda sqrt(r^2 + f^2) / r``, as
    :func:`metafovea.lens.zone_width_um`, which this ground-floor module cannot import)."""
    R, f, wl = design.radius_um, design.f_um, design.wavelength_um
    zone = wl * math.hypot(R, f) / R
    return {"rim_zone_um": zone, "rim_posts": zone / design.period_um}


def plot_lens(design: LensDesign, ax: Axes | Sequence[Axes] | None = None) -> Figure:
    """Posts per 2 pi zone against radius and the quantised phase levels of a patch of posts at the rim.

    Parameters
    ----------
    design : LensDesign
    ax : Axes, sequence of 2 Axes, or None
        See :func:`panels` (one Axes: the posts-per-zone curve only).

    Returns
    -------
    matplotlib Figure
    """
    fig, (a0, a1) = panels(ax, 2)
    R, f, wl, p, N = design.radius_um, design.f_um, design.wavelength_um, design.period_um, design.levels
    r = np.linspace(R / 400, R, 400)
    a0.plot(r / 1e3, wl * np.hypot(r, f) / r / p, color="C0")
    a0.axhline(4.0, color="0.5", ls="--", lw=0.8, label="4 posts per zone")
    a0.set_yscale("log")
    a0.set_xlabel("radius (mm)")
    a0.set_ylabel("posts per 2 pi zone")
    a0.set_title(f"{design.name}: f = {design.f_mm:g} mm, D = {design.diameter_mm:g} mm, NA {design.na:.3f}",
                 fontsize=10)
    a0.legend(fontsize=8)
    if a1 is not None:
        n = 48  # posts per side of the patch, ending at the rim on the +x axis
        off = 0.5 if design.lattice == "half" else 0.0
        ix = np.floor(R / p - off) - n + 1 + np.arange(n)
        iy = np.arange(n) - n // 2
        X, Y = np.meshgrid((ix + off) * p, (iy + off) * p)
        r2 = X * X + Y * Y
        phi = design.phase_sign * (2 * np.pi / wl) * r2 / (np.sqrt(r2 + f * f) + f)  # the hyperbolic phase
        level = np.round(np.mod(phi, 2 * np.pi) / (2 * np.pi / N)) % N
        level = np.where(r2 <= R * R, level, np.nan)
        ext = (X[0, 0] - p / 2, X[0, -1] + p / 2, Y[0, 0] - p / 2, Y[-1, 0] + p / 2)
        image(a1, level, label=f"phase level k (phase 2 pi k / {N} rad)", extent=ext, cmap="twilight",
              vmin=-0.5, vmax=N - 0.5, xlabel="x (um from the lens axis)", ylabel="y (um)",
              title=f"{n} x {n} posts at the rim ({p:g} um lattice)")
    return fig


def lens_html(design: LensDesign) -> str:
    """The HTML view of a :class:`~metafovea.config.LensDesign`: its numbers and the :func:`plot_lens` figure."""
    nums = _lens_numbers(design)
    rows = [("focuses", f"{design.polarization}-polarised light"), ("focal length f", fmt(design.f_mm, "mm")),
            ("diameter D", fmt(design.diameter_mm, "mm")), ("NA", fmt(design.na)),
            ("F-number", f"F/{design.f_um / design.diameter_um:.3g}"),
            ("design wavelength", fmt(design.wavelength_um, "um")), ("lattice period", fmt(design.period_um, "um")),
            ("lattice", f"{design.lattice} (post at the centre)" if design.lattice == "integer" else design.lattice),
            ("post height", fmt(design.post_height_um, "um")), ("phase levels", fmt(design.levels)),
            ("zone width at the rim", f"{fmt(nums['rim_zone_um'], 'um')} = {nums['rim_posts']:.2f} posts per 2 pi"),
            ("substrate index", fmt(design.n_substrate))]
    fig, axs = small_figure(2)
    plot_lens(design, axs)
    return html_card(f"LensDesign '{design.name}'", rows, [("posts per zone; levels at the rim", figure_png(fig))])


# ----------------------------------------------------------------------------------------------
# PostSet
# ----------------------------------------------------------------------------------------------
def _postset_errors(ps: Any) -> dict[str, float]:
    N = ps.levels
    target = 2 * np.pi * np.arange(N) / N
    err = np.angle(ps.t_focus * np.exp(-1j * target))
    ref = np.angle(np.mean(np.exp(1j * err)))  # the common offset is not an error
    err = np.angle(np.exp(1j * (err - ref)))
    tp = np.angle(ps.t_pass)
    return {"max_phase_error": float(np.abs(err).max()), "rms_phase_error": float(np.sqrt(np.mean(err ** 2))),
            "mean_T_focus": float(np.mean(np.abs(ps.t_focus) ** 2)),
            "mean_T_pass": float(np.mean(np.abs(ps.t_pass) ** 2)),
            "pass_spread": float(np.ptp(np.angle(np.exp(1j * (tp - np.angle(np.mean(np.exp(1j * tp)))))))),
            "efficiency": float(abs(np.mean(ps.t_focus * np.exp(-1j * target))) ** 2)}


def plot_postset(ps: Any, ax: Axes | Sequence[Axes] | None = None) -> Figure:
    """Phase and power transmission of each level's post, both polarisations, and the posts' cross-sections.

    Parameters
    ----------
    ps : PostSet
    ax : Axes, sequence of 3 Axes, or None
        See :func:`panels` (one Axes: the phase panel only).

    Returns
    -------
    matplotlib Figure
    """
    fig, (a0, a1, a2) = panels(ax, 3, width=3.8)
    N = ps.levels
    k = np.arange(N)
    foc, oth = ps.polarization, "y" if ps.polarization == "x" else "x"
    a0.plot(k, 2 * np.pi * k / N, "k--", lw=0.8, label="target 2 pi k / N")
    a0.plot(k, np.mod(np.angle(ps.t_focus), 2 * np.pi), "o-", label=f"{foc} (focused)")
    a0.plot(k, np.mod(np.angle(ps.t_pass), 2 * np.pi), "s-", label=f"{oth} (passed)")
    a0.set_xlabel("level k")
    a0.set_ylabel("phase of t (rad)")
    a0.set_title(f"{ps.source} post set, focuses {foc}", fontsize=10)
    a0.legend(fontsize=8)
    if a1 is not None:
        a1.plot(k, np.abs(ps.t_focus) ** 2, "o-", label=f"{foc} (focused)")
        a1.plot(k, np.abs(ps.t_pass) ** 2, "s-", label=f"{oth} (passed)")
        a1.set_ylim(0, 1.05)
        a1.set_xlabel("level k")
        a1.set_ylabel("power transmission |t|^2")
        a1.legend(fontsize=8)
    if a2 is not None:
        from matplotlib.patches import Rectangle

        p = ps.period_um
        for i, (wx, wy) in enumerate(ps.widths_um):
            a2.add_patch(Rectangle((i * p - wx / 2, -wy / 2), wx, wy, color=f"C{i % 10}"))
            a2.text(i * p, p / 2 + 0.2, str(i), ha="center", fontsize=8)
        a2.set_xlim(-p / 2, (N - 0.5) * p)
        a2.set_ylim(-p / 2, p / 2 + 0.8)
        a2.set_aspect("equal")
        a2.set_xlabel(f"x (um), one {p:g} um cell per level")
        a2.set_ylabel("y (um)")
        a2.set_title(f"post cross-sections, height {ps.height_um:g} um", fontsize=10)
    return fig


def postset_html(ps: Any) -> str:
    """The HTML view of a :class:`~metafovea.library.PostSet`: figures of merit, one row per post and the
    :func:`plot_postset` figure."""
    e = _postset_errors(ps)
    rows = [("source", ps.source), ("focuses", f"{ps.polarization}-polarised light"), ("levels", fmt(ps.levels)),
            ("period, post height", f"{fmt(ps.period_um, 'um')}, {fmt(ps.height_um, 'um')}"),
            ("design wavelength", fmt(ps.wavelength_um, "um")),
            ("expected focusing efficiency", fmt(ps.info.get("expected_focusing_efficiency", e["efficiency"]))),
            ("phase error max / rms", f"{e['max_phase_error']:.3f} / {e['rms_phase_error']:.3f} rad"),
            ("mean |t|^2 focused / passed", f"{e['mean_T_focus']:.3f} / {e['mean_T_pass']:.3f}"),
            ("pass-through phase spread", fmt(e["pass_spread"], "rad", 3))]
    for i, (wx, wy) in enumerate(ps.widths_um):
        rows.append((f"level {i}", f"wx {wx:.3f} um, wy {wy:.3f} um, |t|^2 {abs(ps.t_focus[i]) ** 2:.3f}, "
                                   f"phase {np.mod(np.angle(ps.t_focus[i]), 2 * np.pi):.3f} rad"))
    fig, axs = small_figure(3, width=2.8)
    plot_postset(ps, axs)
    return html_card(f"PostSet ({ps.polarization}, {ps.levels} levels)", rows,
                     [("phases, |t|^2, posts", figure_png(fig))])


# ----------------------------------------------------------------------------------------------
# PSF
# ----------------------------------------------------------------------------------------------
def plot_psf(p: Any, ax: Axes | Sequence[Axes] | None = None, *, log: bool = True) -> Figure:
    """The PSF on the focal plane (fraction of the incident power per um^2; log scale over 4 decades by default)
    and its cuts through the peak.

    Parameters
    ----------
    p : PSF
    ax : Axes, sequence of 2 Axes, or None
        See :func:`panels` (one Axes: the image only).
    log : bool
        Logarithmic colour scale (4 decades below the peak); False: linear.

    Returns
    -------
    matplotlib Figure
    """
    from matplotlib.colors import LogNorm

    fig, (a0, a1) = panels(ax, 2)
    dens = np.asarray(p.intensity) / p.pitch_um ** 2
    xs, ys = p.coords()
    h = p.pitch_um / 2
    ext = (xs[0] - h, xs[-1] + h, ys[0] - h, ys[-1] + h)
    peak = float(np.nanmax(dens)) if dens.size else 1.0
    norm = LogNorm(vmin=peak * 1e-4, vmax=peak) if log and peak > 0 else None
    a0.set_aspect("equal")
    image(a0, np.maximum(dens, peak * 1e-4) if norm is not None else dens, norm=norm, vmin=0 if norm is None else None,
          vmax=peak if norm is None else None, cmap="inferno", extent=ext,
          label="intensity (fraction of incident power / um^2)", xlabel="x (um)", ylabel="y (um)",
          title=f"PSF, field {p.field_deg[0]:g}, {p.field_deg[1]:g} deg, {p.polarization}-pol., {p.engine}")
    if a1 is not None:
        iy, ix = np.unravel_index(int(np.nanargmax(dens)), dens.shape)
        a1.plot(xs - xs[ix], dens[iy], label="cut along x")
        a1.plot(ys - ys[iy], dens[:, ix], "--", label="cut along y")
        if log:
            a1.set_yscale("log")
            a1.set_ylim(peak * 1e-5, peak * 2)
        a1.set_xlabel("distance from the peak (um)")
        a1.set_ylabel("intensity (fraction / um^2)")
        a1.legend(fontsize=8)
    return fig


def psf_html(p: Any) -> str:
    """The HTML view of a :class:`~metafovea.optics.PSF`: engine, sampling, energy, Strehl ratio, error estimate,
    and an inline image (log scale)."""
    wl = np.asarray(p.wavelengths_um)
    band = f"{wl[0]:g} um" if wl.size == 1 else f"{wl.min():g}-{wl.max():g} um ({wl.size} wavelengths)"
    dl = p.info.get("diffraction_limited_peak_fraction")
    strehl = float(p.intensity.max()) / dl if dl else None
    H, W = p.shape
    rows = [("polarisation", p.polarization), ("field", f"{p.field_deg[0]:g}, {p.field_deg[1]:g} deg"),
            ("wavelengths", band), ("engine", p.engine),
            ("grid", f"{H} x {W} samples at {p.pitch_um:.4g} um ({H * p.pitch_um:.4g} um wide)"),
            ("centre on the focal plane", f"({p.center_um[0]:.4g}, {p.center_um[1]:.4g}) um"),
            ("energy in the window", fmt(p.energy_fraction, "of the incident power")),
            ("peak", fmt(float(p.intensity.max()) / p.pitch_um ** 2, "of the incident power / um^2")),
            ("Strehl ratio", fmt(strehl)), ("error estimate", fmt(p.error_estimate, "of the peak", 2))]
    if "seconds" in p.info:
        rows.append(("computed in", fmt(p.info["seconds"], "s", 3)))
    thumb = thumbnail_png(p.intensity, cmap="inferno", log=True)
    return html_card("PSF", rows, [("intensity, log scale, 4 decades", thumb)])


# ----------------------------------------------------------------------------------------------
# Measurement and Reconstruction (thermal images: iron palette, DN)
# ----------------------------------------------------------------------------------------------
def plot_measurement(m: Measurement, ax: Axes | Sequence[Axes] | None = None, *, frame: int = 0) -> Figure:
    """One frame in the iron palette (DN) and the mixing ratio alpha (or the mean frame level) against time.

    Parameters
    ----------
    m : Measurement
    ax : Axes, sequence of 2 Axes, or None
        See :func:`panels` (one Axes: the frame only).
    frame : int
        The frame shown.

    Returns
    -------
    matplotlib Figure
    """
    T = m.shape[0]
    k = check_int("frame", frame, -T, T - 1) % T  # -1: the last
    fig, (a0, a1) = panels(ax, 2)
    units = m.meta.get("units", "DN")
    title = f"frame {k} of {T}, t = {m.times_s[k]:.3f} s"
    if m.alpha is not None and np.isfinite(m.alpha[k]):
        title += f", alpha = {m.alpha[k]:.2f}"
    image(a0, m.frames[k], label=f"signal ({units})", title=title)
    if a1 is not None:
        if m.alpha_known:
            a1.plot(m.times_s, m.alpha, ".-")
            a1.set_ylabel("alpha (foveal fraction)")
            a1.set_ylim(-0.02, 1.02)
        else:
            a1.plot(m.times_s, np.nanmean(m.frames, axis=(1, 2)), ".-")
            a1.set_ylabel(f"mean frame ({units})")
        a1.axvline(m.times_s[k], color="0.6", lw=0.8)
        a1.set_xlabel("time (s)")
    return fig


def measurement_html(m: Measurement) -> str:
    """The HTML view of a :class:`~metafovea.measurement.Measurement`: size, timing, alpha, truth, the file, and
    thumbnails of the first frame (and of the truth images when stored)."""
    T, H, W = m.shape
    units = m.meta.get("units", "DN")
    fin = m.frames[np.isfinite(m.frames)]
    rows = [("frames", f"{T} of {H} x {W} pixels"),
            ("duration", fmt(float(m.times_s[-1] - m.times_s[0]) if T > 1 else 0.0, "s")),
            ("signal range", f"{fmt(float(fin.min()) if fin.size else None)} - "
                             f"{fmt(float(fin.max()) if fin.size else None, units)}")]
    if "frame_rate_hz" in m.meta:
        rows.append(("frame rate", fmt(m.meta["frame_rate_hz"], "Hz")))
    if m.alpha_known:
        rows.append(("alpha", f"known, {m.alpha.min():.3f} - {m.alpha.max():.3f}"))
    else:
        rows.append(("alpha", "unknown (estimated by the reconstruction)"))
    if isinstance(m.meta.get("scene"), str):
        rows.append(("scene", m.meta["scene"]))
    rows.append(("ground truth", "stored" if m.truth_x1 is not None else "none"))
    model = m.meta.get("model")
    if isinstance(model, dict) and model.get("reduced"):
        plan = model.get("plan") or {}
        rows.append(("model", "REDUCED: " + ", ".join(model.get("reduce", [])) + " replaced"
                     + (f" (tolerance {plan['tolerance_k_rms']:g} K rms; plan in meta['model']['plan'])"
                        if "tolerance_k_rms" in plan else "")))
    rows.append(("foveal expansion f1 / f2", fmt(m.scale)))
    if m.source:
        rows.append(("file", m.source))
    imgs = [(f"frame 0 ({units})", thumbnail_png(m.frames[0]))]
    tr = m.truth(0)
    if tr is not None:
        imgs += [(f"truth foveal ({units})", thumbnail_png(tr[0])),
                 (f"truth perifoveal ({units})", thumbnail_png(tr[1]))]
    return html_card("Measurement", rows, imgs)


def plot_reconstruction(rec: Any, ax: Axes | Sequence[Axes] | None = None, *, window: int = 0,
                        units: str = "DN") -> Figure:
    """The foveal (x1) and perifoveal (x2) images in the iron palette.

    Parameters
    ----------
    rec : Reconstruction
    ax : Axes, sequence of 2 Axes, or None
        See :func:`panels` (one Axes: the foveal image only).
    window : int
        For a video, the output shown.
    units : str
        The images' unit (the frames'; the simulator's are DN).

    Returns
    -------
    matplotlib Figure
    """
    fig, (a0, a1) = panels(ax, 2)
    x1, x2 = (np.asarray(x) for x in (rec.x1, rec.x2))
    if x1.ndim == 3:
        x1, x2 = x1[window], x2[window]
    tag = f"{rec.method}" + (f", window {window}" if rec.is_video else "")
    image(a0, x1, label=f"signal ({units})", title=f"foveal x1 ({tag})")
    if a1 is not None:
        image(a1, x2, label=f"signal ({units})", title=f"perifoveal x2 ({tag})")
    return fig


def reconstruction_html(rec: Any, units: str = "DN", extra: Sequence[tuple[str, str]] = ()) -> str:
    """The HTML view of a :class:`~metafovea.reconstruct.Reconstruction`: method, sizes, alpha, conditioning,
    timings and thumbnails of both images; ``extra`` rows (a pipeline's metrics) are appended."""
    x1 = np.asarray(rec.x1)
    K = x1.shape[0] if x1.ndim == 3 else 1
    a = np.asarray(rec.alpha, dtype=float)
    rows = [("method", rec.method), ("images", f"{K} x 2 of {x1.shape[-2]} x {x1.shape[-1]} pixels"),
            ("alpha", f"{np.nanmin(a):.3f} - {np.nanmax(a):.3f} over {a.size} frames" if np.any(np.isfinite(a))
             else "unknown")]
    info = rec.info
    if "alpha_identified" in info:
        rows.append(("alpha identified", fmt(bool(np.all(info["alpha_identified"])))))
    if "condition" in info:
        rows.append(("condition number", fmt(float(np.nanmax(np.asarray(info["condition"], dtype=float))))))
    rows.append(("fixed-pattern noise", "estimated" if rec.fpn is not None else "not estimated"))
    if rec.timings:
        rows.append(("time", ", ".join(f"{k} {fmt(float(v), 's', 3)}" for k, v in rec.timings.items())))
    rows += list(extra)
    i1, i2 = (x[0] if x.ndim == 3 else x for x in (x1, np.asarray(rec.x2)))
    return html_card("Reconstruction", rows, [(f"foveal x1 ({units})", thumbnail_png(i1)),
                                              (f"perifoveal x2 ({units})", thumbnail_png(i2))])
