"""Error-budgeted simulation: what each effect of the camera model contributes to a scene's sensor image, and the
cheapest model that stays within a tolerance (``simulate(..., tolerance_k=T)``, ``metafovea simulate --tolerance-k``).

The error measure
-----------------
A model's error is the rms difference of each channel's noise-free sensor image (``truth_x1``, ``truth_x2``, DN)
from the full model's, referred to the scene in kelvin with the channel's DN per kelvin at the scene temperature of
the system design (``SystemDesign.scene_temperature_k``)::

    dT_i = dDN_i / D_i,     D_i = counts_per_k * g_i * (dL/dT)(T_scene) / (dL/dT)(300 K)

(``g_i`` the full model's channel gain, so ``D_i`` is the ``dn_per_k_300K`` of the metadata at a 300 K scene); the
larger of the two channels' values counts (a frame is a mixture of the two images, so its error in its own DN per
kelvin is no larger). Effects that act on the frames only (polariser extinction and lag, the sensor's noise terms)
are counted on the frames with the frame's DN per kelvin, ``counts_per_k (a' G_1 + (1 - a') G_2)`` times the same
ratio (``G_i`` the gains with the extinction's ``1 + e``, ``a'`` the frame's effective mixing ratio).

The effects (:data:`EFFECTS`) and what a reduced model puts in their place
--------------------------------------------------------------------------
================ ============================================= ======================================================
effect           the full model                                the reduced model
================ ============================================= ======================================================
spectral         31 PSF wavelength bins (kernel and haze)      11 bins
supersample      s x s scene samples per pixel (3; video 2)     1 sample per pixel, the kernels binned s x s (exactly
                                                               the full model's PSF and haze, sampled per pixel)
far_sampling     far haze and glare: 3 x 3 samples per coarse   1 sample per coarse sample
                 sample
haze             chromatic haze: the power outside the PSF's    dropped (the power is lost)
                 window as blur disks
glare            the other lens' pass-through ripple: disks     a uniform level of the same power over the crop
                 of mm on their own coarse grids                (the crop's mean radiance)
train            the optical train (wafers, the other lens,     each lens alone (``optical_train=False``)
                 its ring): throughput, glare, field factor
train_field      the other lens' ring and the posts at          ``cos^4`` alone
                 oblique incidence, in relative illumination
relative_        ``cos^4`` times the train's field factor       none
illumination
field_patches    n x n field patches (when asked)              the on-axis kernel (shift-invariant)
extinction       the polariser's leak ``e`` (when > 0)         0
bolometer_lag    the bolometer's time constant (when > 0)      0
noise, fpn,      temporal noise, fixed pattern, ADC            off
quantisation
================ ============================================= ======================================================

The planner (:func:`plan_model`)
--------------------------------
1. A pilot: the full model's camera and optics, rendered at 1 sample per pixel (the kernels binned) and 1 sample per
   coarse sample of the far components (the cheapest sampling), once (a video: at its first, middle and last frame,
   each estimate the largest of the three).
   Its parts (kernel image, each far component, relative illumination; :meth:`ChannelRenderer.components`) give
   each effect's change of the image by recombination, without another render.
2. Estimates. Effects whose change the pilot computes (haze, glare, train, train_field, relative illumination, field
   patches, the polariser's) get ``(1 + SAFETY)`` times the pilot's rms change plus the pilot's own sampling error
   carried through the effect. Sampling effects: the scene sampled where the full model samples it, each pixel's
   ``s x s`` samples (``s`` the full model's samples per pixel), their mean minus the pilot's centre sample through
   the (binned) kernel, or where larger the mean of a pair of samplings shifted by ``(s - 1) / s`` of a pixel along a
   diagonal minus the centre sample (it reaches the neighbouring pixels' samples: a step at the crop's edge), times
   ``SAMPLING_SAFETY`` (for the kernel's shape within a pixel, which the binned kernel does not see); the far
   components rendered as the full model renders them (3 x 3 samples per coarse sample, on its own coarse grid,
   interpolated and clamped as it does), their change computed (a sub-pixel hot wire that the full model's samples
   see and the pilot's coarse grid straddles is counted). Glare components whose bound (twice their weight times the
   scene's range) is below ``SMALL_SHARE`` of the tolerance are bounded, not rendered. Spectral sampling: the far
   haze with 11 bins computed, the kernel's own change bounded by ``(|K| + |K'|) * |L - L_haze|`` with
   ``sum K' <= (1 + SAFETY) sum K``. The sensor's terms are analytic (NETD, the fixed pattern's largest value, the
   ADC's step; the rounding difference of two quantised frames, ``1/sqrt(6)`` DN rms, included).
3. Budget: an effect may be replaced only where its alternative saves work; the planner keeps the set of
   replacements that saves most work with the sum of their estimates (by the triangle inequality, the rms of a sum
   of changes is at most the sum of their rms) at most ``BUDGET_SHARE * T``; the rest of ``T`` is the margin for
   what the estimates leave out (the changes' interaction, structure below a sample). The sensor's noise terms are
   the camera's, not approximations: they are estimated and kept.
4. Cost: the rendering work of each part in scene samples and interpolated pixels (the fine grid, each far
   component's coarse grid, the glare's interpolation into the PSF that the file stores), as a share of the full
   model's.

Structure that falls between the full model's own samples (narrower than a third of a pixel, between its samples) is
seen by neither model: the full model is the reference, not the scene.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.errors import InputError, check_range
from metafovea.imaging.channel import relative_illumination_map
from metafovea.imaging.kernels import fftconvolve, resample_optics
from metafovea.imaging.render import ChannelRenderer

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from metafovea.imaging.kernels import ChannelOptics
    from metafovea.imaging.scene import Scene


@dataclass(frozen=True)
class Effect:
    """One effect of the camera model: its name in the plan table, what the full model does and what a reduced
    model puts in its place."""

    label: str
    full: str
    alternative: str
    kind: str  # 'optics' (the channel images), 'frames' (the polariser), 'sensor' (noise terms, kept)


#: every effect the planner estimates, in the plan table's order (see the module docstring)
EFFECTS: dict[str, Effect] = {
    "spectral": Effect("spectral sampling", "31 PSF wavelength bins", "11 bins", "optics"),
    "supersample": Effect("supersampling", "s x s scene samples per pixel", "1 per pixel, kernels binned", "optics"),
    "far_sampling": Effect("far haze and glare sampling", "3 x 3 samples per coarse sample", "1 per coarse sample",
                           "optics"),
    "haze": Effect("PSF window and chromatic haze", "power outside the window as blur disks", "dropped", "optics"),
    "glare": Effect("glare (other lens' pass-through)", "disks of mm on coarse grids", "uniform level over the crop",
                    "optics"),
    "train": Effect("optical train (other lens, wafers)", "throughput, glare, ring", "each lens alone", "optics"),
    "train_field": Effect("ring and oblique incidence", "in relative illumination", "cos^4 alone", "optics"),
    "relative_illumination": Effect("relative illumination", "cos^4 x the train's field factor", "none", "optics"),
    "field_patches": Effect("field variation", "n x n field patches", "on-axis kernel", "optics"),
    "extinction": Effect("polariser extinction", "leak e", "0", "frames"),
    "bolometer_lag": Effect("bolometer lag", "time constant tau", "0", "frames"),
    "noise": Effect("temporal noise", "NETD", "off", "sensor"),
    "fpn": Effect("fixed-pattern noise", "low-rank pattern", "off", "sensor"),
    "quantisation": Effect("ADC quantisation", "rounding and clipping", "off", "sensor"),
}
#: effects whose alternative saves rendering work: the ones a plan may replace
REDUCIBLE = ("supersample", "far_sampling", "glare", "field_patches")
#: PSF wavelength bins of the ``spectral`` alternative (the full model: the kernels' 31)
REDUCED_PSF_WAVELENGTHS = 11
#: the share of the tolerance the replaced effects' estimates may use together; the rest is margin
BUDGET_SHARE = 0.8
#: relative margin on estimates that the pilot computes (its sampling is not the full model's)
SAFETY = 0.1
#: a glare component whose bound (twice its weight times the scene's radiance range) is below this share of the
#: tolerance is estimated by that bound instead of being rendered in the pilot
SMALL_SHARE = 0.02
#: the largest tolerance (K rms) a plan accepts
MAX_TOLERANCE_K = 100.0


def check_effects(reduce: Sequence[str] | str | None) -> tuple[str, ...]:
    """``reduce`` as a tuple of effect names (:data:`EFFECTS`), each once, in the table's order."""
    if reduce is None:
        return ()
    names = (reduce,) if isinstance(reduce, str) else tuple(reduce)
    for n in names:
        if n not in EFFECTS:
            raise InputError("reduce", n, "effects among " + ", ".join(EFFECTS))
    return tuple(e for e in EFFECTS if e in names)


def check_tolerance(tolerance_k: Any) -> float:
    """The tolerance in kelvin rms, ``0 < tolerance_k <= 100``."""
    return check_range("tolerance_k", tolerance_k, 0.0, MAX_TOLERANCE_K, unit="K")


# ----------------------------------------------------------------------------------------------
# the plan
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanRow:
    """One effect in a plan: its estimated contribution (K rms; None where the full model does not have it), whether
    the reduced model keeps it (None: not in the full model), the share of the full model's rendering work its
    alternative saves, and why."""

    effect: str
    estimate_k: float | None
    included: bool | None
    cost: float
    why: str

    def summary(self) -> dict[str, Any]:
        e = EFFECTS[self.effect]
        return {"effect": self.effect, "label": e.label, "full_model": e.full, "alternative": e.alternative,
                "estimate_k_rms": self.estimate_k, "included": self.included, "relative_cost": self.cost,
                "why": self.why}


@dataclass(frozen=True)
class Plan:
    """What :func:`plan_model` chose: the rows (one per effect of :data:`EFFECTS`), the effects replaced
    (``reduce``), the tolerance and the share of it the replacements may use, their summed estimate, the reduced
    model's rendering work as a share of the full model's, the planner's seconds and the scene temperature (K) the
    DN-to-kelvin conversion uses."""

    tolerance_k: float
    rows: tuple[PlanRow, ...]
    reduce: tuple[str, ...]
    budget_k: float
    estimated_error_k: float
    work_fraction: float
    seconds: float
    scene_temperature_k: float
    notes: tuple[str, ...] = ()
    #: per channel, the pilot's parts a reduced model reuses (a static scene): ``fine`` the kernel image at 1 sample
    #: per pixel, ``samples`` its fine samples, ``far`` and ``far_full`` the far components (the haze first, then the
    #: glare the pilot rendered) at 1 and at 3 x 3 samples per coarse sample, ``n_haze`` (1 with a far haze),
    #: ``glare_complete`` (the pilot rendered every glare component), ``ri`` the relative illumination map
    pilot: tuple[dict[str, Any], ...] | None = field(default=None, compare=False, repr=False)

    def reusable(self, i: int) -> dict[str, Any]:
        """Keywords of :meth:`~metafovea.imaging.render.ChannelRenderer.render_static` for channel ``i`` of the model
        this plan chose: the pilot's fine image where the model samples 1 per pixel with the pilot's kernels; its far
        components at the model's far sampling (the pilot rendered both), the haze alone where the model spreads the
        glare as a uniform level, all of them where the pilot rendered every glare component."""
        if self.pilot is None:
            return {}
        p, out = self.pilot[i], {}
        if "supersample" in self.reduce and "field_patches" not in self.reduce:
            out.update(fine=p["fine"], samples=p["samples"])
        far = p["far"] if "far_sampling" in self.reduce else p["far_full"]
        if "glare" in self.reduce:
            out["far"] = list(far[:p["n_haze"]])
        elif p["glare_complete"]:
            out["far"] = list(far)
        return out

    def illumination(self, i: int) -> np.ndarray | None:
        """Channel ``i``'s relative illumination map of the full model (``cos^4`` times the train's field factor), as
        the pilot computed it (None without a pilot or relative illumination)."""
        return None if self.pilot is None else self.pilot[i].get("ri")

    def row(self, effect: str) -> PlanRow:
        return next(r for r in self.rows if r.effect == effect)

    def estimates(self) -> dict[str, float | None]:
        return {r.effect: r.estimate_k for r in self.rows}

    def summary(self) -> dict[str, Any]:
        """The plan as JSON (the Measurement's ``meta['model']['plan']``, the ``--json`` summary)."""
        return {"model": "REDUCED" if self.reduce else "full (every effect matters within the tolerance)",
                "tolerance_k_rms": self.tolerance_k, "budget_k_rms": self.budget_k, "reduce": list(self.reduce),
                "estimated_error_k_rms": self.estimated_error_k, "render_work_fraction": self.work_fraction,
                "planner_seconds": self.seconds, "scene_temperature_k": self.scene_temperature_k,
                "error_measure": "rms of each channel's noise-free image minus the full model's, DN divided by the "
                                 "channel's DN per kelvin at the scene temperature (larger channel)",
                "rows": [r.summary() for r in self.rows], "notes": list(self.notes)}

    def lines(self) -> list[str]:
        """The plan table as text (what ``metafovea simulate --tolerance-k`` prints)."""
        return plan_lines(self.summary())


def plan_cells(summary: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    """Each row of the plan table as text: ``(effect, estimate in K rms or '-', included 'yes' / 'NO' / 'n/a',
    cost as a percentage of the full model's)``, from :meth:`Plan.summary`."""
    return [(r["label"], "-" if r["estimate_k_rms"] is None else f"{r['estimate_k_rms']:.3g}",
             "n/a" if r["included"] is None else ("yes" if r["included"] else "NO"),
             f"{100 * r['relative_cost']:.1f}%") for r in summary["rows"]]


def plan_lines(summary: dict[str, Any], why: bool = True) -> list[str]:
    """The plan table as text lines, from :meth:`Plan.summary` (so a stored plan prints the same); ``why=False``:
    without the reasons and notes (a figure's glance: they are most of the text)."""
    s = summary
    head = ("REDUCED MODEL" if s["reduce"] else "FULL MODEL") + \
        f" for a tolerance of {s['tolerance_k_rms']:g} K rms (replaced effects' estimates <= " \
        f"{s['budget_k_rms']:.3g} K in all: {s['estimated_error_k_rms']:.3g} K); rendering work " \
        f"{100 * s['render_work_fraction']:.0f} % of the full model's; planned in {s['planner_seconds']:.2f} s"
    out = [head, f"  {'effect':34s} {'estimate K rms':>14s}  {'included':8s} {'cost':>6s}" + ("  why" if why else "")]
    for r, (label, est, inc, cost) in zip(s["rows"], plan_cells(s)):
        out.append(f"  {label:34s} {est:>14s}  {inc:8s} {cost:>6s}" + (f"  {r['why']}" if why else ""))
    if why:
        out += [f"  note: {n}" for n in s.get("notes", [])]
    return out


# ----------------------------------------------------------------------------------------------
# the pilot: the full model's parts at the cheapest sampling
# ----------------------------------------------------------------------------------------------
def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a, dtype=np.float64))))


def _conv(img: np.ndarray, k: np.ndarray, mode: str = "valid") -> np.ndarray:
    return img * k[0, 0] if k.shape == (1, 1) else fftconvolve(img, k, mode=mode)


#: the symmetric pair of shifted samplings of the supersampling estimate, as (row, column) signs of the offset
FINE_PAIRS = (((1, -1), (-1, 1)),)
#: the factor on the supersampling estimate (the full model's s x s samples of each pixel, their mean less the centre
#: sample, through the binned kernel: the factor covers the kernel's shape within a pixel, which the binned kernel
#: does not see)
SAMPLING_SAFETY = 1.5


@dataclass
class _Pilot:
    """One channel's pilot at one time: its parts, the maps, and its sampling estimates."""

    rd: ChannelRenderer
    comps: dict[str, Any]
    ri: np.ndarray  # (H, W) relative illumination of the full model (ones when off)
    cos4: np.ndarray
    n_haze: int  # 1 when the first far component is the chromatic haze
    fine_err: np.ndarray  # (H, W) estimated supersampling error of the image (radiance, ri included, rms of offsets)
    far_err: list[float] = field(default_factory=list)  # per far component: the estimated rms of its sampling error
    bounded: float = 0.0  # the bound (radiance) of the glare components not rendered
    has_glare: bool = False  # the full model's optics have far glare components
    full_far: list[np.ndarray] = field(default_factory=list)  # the far components as the full model samples them

    @property
    def image(self) -> np.ndarray:
        c = self.comps
        ped = self.rd.optics.pedestal_weight * c["pedestal"]
        return (c["fine"] + sum(c["far"], np.zeros_like(c["fine"])) + ped) * self.ri


def _pilot(scene: Scene, optics: ChannelOptics, radiance: Any, ri_on: bool, field_factor: Any, t: float,
           small: float) -> _Pilot:
    """The channel at 1 sample per pixel and per coarse sample, and the changes of its image with the full model's
    sampling: the scene at the full model's ``s x s`` samples of each pixel (``s`` its samples per pixel), their mean
    minus the pilot's centre sample, through the kernel, or where larger that of a pair shifted by ``(s - 1) / s`` of a
    pixel along a diagonal (:data:`FINE_PAIRS`), times :data:`SAMPLING_SAFETY` (an estimate: the kernel is binned);
    each far component rendered as the full model renders it (3 x 3 samples per coarse sample on its own
    grid), its difference from the pilot's (computed, so only :data:`SAFETY`). A glare component whose bound ``2 w R``
    (``R``: the scene's radiance range over the haze's and the widest glare's coarse grids) is below ``small``
    (radiance) is not rendered: its bound stands for it."""
    o1 = resample_optics(optics, 1) if optics.ss > 1 else optics
    ch = optics.channel
    H, W = ch.shape
    p = ch.focal_pitch_um
    n_haze = 1 if optics.far_kernel is not None and optics.far_weight > 0 else 0
    glare = list(o1.extra_far)
    bounded = 0.0
    if glare:
        f = ch.focal_length_um
        grids = ([(o1.far_kernel.shape[0] // 2, o1.far_coarse)] if n_haze else []) + \
            [max(((k.shape[0] // 2, q) for _, k, q in glare), key=lambda g: g[0] * g[1])]
        r_lo, r_hi = math.inf, -math.inf
        for km, q in grids:
            x = _scene_radiance(scene, radiance, ch.positions_um(H, 1, km, coarse=q) / f,
                                ch.positions_um(W, 1, km, coarse=q) / f, t)
            r_lo, r_hi = min(r_lo, float(x.min())), max(r_hi, float(x.max()))
        kept = tuple(g for g in glare if 2 * g[0] * (r_hi - r_lo) > small)
        bounded = sum(2 * g[0] * (r_hi - r_lo) for g in glare if 2 * g[0] * (r_hi - r_lo) <= small)
        o1 = replace(o1, extra_far=kept)
    rd = ChannelRenderer(scene, o1, radiance, ri_on, field_factor, sub=1)
    comps = rd.components(t)
    ri = rd.ri if rd.ri is not None else np.ones((H, W))
    cos4 = relative_illumination_map(ch) if ri_on else np.ones((H, W))
    m = rd.optics.margin
    s = optics.ss
    fine_err = np.zeros((H, W))
    if s > 1:
        # the full model's s x s samples in each pixel, their mean minus the pilot's centre sample, through the kernel
        # (it sees structure at any of the samples' phases: a point between the pilot's samples), and the pair of
        # samplings shifted by (s - 1) / s of a pixel along a diagonal (it sees the neighbouring pixels' samples:
        # a step at the crop's edge), whichever is larger
        py, px = ch.positions_um(H, 1, m), ch.positions_um(W, 1, m)
        offs = [((a + 0.5) / s - 0.5) * p for a in range(s)]
        e = sum(rd.radiance_at(py + oy, px + ox, t) for oy in offs for ox in offs) / (s * s) - comps["L"]
        fine_err = np.abs(rd.kernel_image(e) * ri)
        d = (s - 1) / s * p
        ms = np.zeros((H, W))
        for pair in FINE_PAIRS:
            e = 0.5 * sum(rd.radiance_at(py + sy * d, px + sx * d, t) for sy, sx in pair) - comps["L"]
            ms += np.square(rd.kernel_image(e) * ri) / len(FINE_PAIRS)
        fine_err = SAMPLING_SAFETY * np.maximum(fine_err, np.sqrt(ms))
    pilot = _Pilot(rd, comps, ri, cos4, n_haze, fine_err, bounded=bounded, has_glare=bool(glare))
    # the far components as the full model samples them (3 x 3 samples per coarse sample, on its own coarse grid,
    # interpolated and clamped as it does): their difference from the pilot's is the far sampling's change itself
    pilot.full_far = ChannelRenderer(scene, o1, radiance, False, sub=ChannelRenderer.SUB).far_images(t)
    for f_full, f_pilot in zip(pilot.full_far, comps["far"]):
        pilot.far_err.append((1.0 + SAFETY) * _rms(f_full - f_pilot))
    return pilot


def _scene_radiance(scene: Scene, radiance: Any, tan_y: np.ndarray, tan_x: np.ndarray, t: float) -> np.ndarray:
    """The scene's in-band radiance on the grid ``tan_y`` x ``tan_x`` (tangents of the field angles) at ``t``."""
    ay, ax = np.meshgrid(np.arctan(tan_y), np.arctan(tan_x), indexing="ij")
    temp, eps = scene.sample(ax, ay, t)
    return radiance.apparent(temp, eps, scene.reflected_k)


def _envelope(kernels: Sequence[np.ndarray]) -> np.ndarray:
    """The element-wise largest of centred square kernels (absolute values), on the largest one's grid."""
    n = max(k.shape[0] for k in kernels)
    out = np.zeros((n, n))
    for k in kernels:
        p = (n - k.shape[0]) // 2
        out[p:p + k.shape[0], p:p + k.shape[1]] = np.maximum(out[p:p + k.shape[0], p:p + k.shape[1]], np.abs(k))
    return out


# ----------------------------------------------------------------------------------------------
# estimates, per channel (radiance units: divided by dL/dT at the scene temperature later)
# ----------------------------------------------------------------------------------------------
def _far_err(p: _Pilot, which: str = "all") -> float:
    """The far components' estimated sampling error (radiance): the haze's, the glare's (with the bound of the
    components not rendered) or all."""
    parts = range(len(p.far_err)) if which == "all" else range(p.n_haze) if which == "haze" \
        else range(p.n_haze, len(p.far_err))
    return float(sum(p.far_err[j] for j in parts)) + (p.bounded if which != "haze" else 0.0)


def _fidelity(p: _Pilot) -> np.ndarray:
    """The pilot image's estimated error against the full model's sampling, per pixel (after ri)."""
    return p.fine_err + _far_err(p) * p.ri


def _estimates_optics(p: _Pilot, extra: dict[str, Any]) -> dict[str, float]:
    """Each optics effect's estimated rms change (radiance) of this channel's image at this time."""
    c, o = p.comps, p.rd.optics
    k = 1.0 + SAFETY
    fid = _fidelity(p)
    img = p.image
    est: dict[str, float] = {"supersample": _rms(p.fine_err), "far_sampling_haze": _far_err(p, "haze"),
                             "far_sampling_glare": _far_err(p, "glare")}
    glare = sum(c["far"][p.n_haze:], np.zeros_like(img))
    w_glare = float(sum(part["weight"] for part in p.rd.parts[p.n_haze:]))
    if p.has_glare:
        est["glare"] = k * (_rms((glare - w_glare * c["pedestal"]) * p.ri) + _far_err(p, "glare"))
    # relative illumination and the train's field factor: the image times (1 / r - 1)
    for name, r in (("relative_illumination", p.ri), ("train_field", p.ri / p.cos4)):
        f = 1.0 / np.maximum(r, 1e-12) - 1.0
        est[name] = k * (_rms(img * f) + _rms(fid * np.abs(f)))
    # haze dropped: the far haze and the near haze folded into the kernel
    if extra.get("nohaze_fine") is not None:
        far_h = c["far"][0] if p.n_haze else 0.0
        est["haze"] = k * (_rms((c["fine"] - extra["nohaze_fine"] + far_h) * p.ri) + _rms(fid))
    if extra.get("patch0_fine") is not None:
        est["field_patches"] = k * (_rms((c["fine"] - extra["patch0_fine"]) * p.ri)
                                    + extra["patch_ratio"] * _rms(p.fine_err))
    if extra.get("throughput") is not None:
        # train off: gain / throughput, no field factor, no glare (the kernel/haze split's change is in SAFETY)
        t = extra["throughput"]
        ffac = np.maximum(p.ri / p.cos4, 1e-12)
        off = (img / ffac - glare * p.cos4) / t
        est["train"] = k * (_rms(off - img) + _rms(fid / (t * ffac)))
    if "spectral_far" in extra:
        # the far haze with 11 bins (computed), and the kernel's own change bounded by (|K| + |K'|) * |L - L_haze|
        d_far = extra["spectral_far"]
        kn = _envelope(o.kernels)
        ksum = float(kn.sum())
        far31 = c["far"][0] if p.n_haze else None
        lh = far31 / o.far_weight if far31 is not None else np.full_like(img, float(np.mean(c["L"])))
        m = o.margin
        L1 = c["L"][m:c["L"].shape[0] - m, m:c["L"].shape[1] - m]
        b_kernel = _conv(np.abs(L1 - lh), kn / max(ksum, 1e-300), mode="same")
        est["spectral"] = k * (d_far + _far_err(p, "haze")) + _rms((2 + SAFETY) * ksum * b_kernel * p.ri)
    return est


# ----------------------------------------------------------------------------------------------
# the planner
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanInputs:
    """What :func:`plan_model` needs from :func:`~metafovea.imaging.simulate.simulate` (built the same way as the
    full model's): the camera, the laid-out scene, the frame times, each channel's full optics, the options'
    switches, a builder of variant optics (``optics_for(haze=False)``, ``optics_for(field_patches=1)``,
    ``optics_for(n_psf_wavelengths=11)``: the same provider; None where the planner shall not call it), the
    polariser's random stream (a copy) and the scene temperature of the design (K)."""

    camera: Any
    scene: Scene
    times: np.ndarray
    optics: Sequence[ChannelOptics]
    relative_illumination: bool
    optics_for: Callable[..., Sequence[ChannelOptics]] | None
    polarizer_rng: np.random.Generator
    scene_temperature_k: float
    noise: bool = True
    quantize: bool = True


def _channel_extras(inp: PlanInputs) -> list[dict[str, Any]]:
    """Per channel: the variant optics the estimates need (built once for all times)."""
    extras: list[dict[str, Any]] = [{}, {}]
    trains = inp.camera.trains
    for i in range(2):
        if trains is not None:
            extras[i]["throughput"] = float(trains[i].throughput)
    if inp.optics_for is None:
        return extras
    nohaze = inp.optics_for(haze=False, no_glare=True)
    spectral = inp.optics_for(n_psf_wavelengths=REDUCED_PSF_WAVELENGTHS, kernel_from_full=True, no_glare=True)
    patch0 = inp.optics_for(field_patches=1) if any(o.n_patches > 1 for o in inp.optics) else None
    for i in range(2):
        extras[i]["nohaze"] = nohaze[i]
        extras[i]["spectral"] = spectral[i]
        extras[i]["patch0"] = None if patch0 is None else patch0[i]
    return extras


def _crop(a: np.ndarray, m_from: int, m_to: int) -> np.ndarray:
    """``a`` (a grid with a margin of ``m_from`` samples) with a margin of ``m_to <= m_from``."""
    d = m_from - m_to
    return a[d:a.shape[0] - d, d:a.shape[1] - d] if d else a


def _fine_with(optics: ChannelOptics, p: _Pilot, scene: Scene, radiance: Any, t: float) -> np.ndarray:
    """The kernel image of ``optics`` (a variant of the pilot's, at 1 sample per pixel) from the pilot's samples."""
    o1 = resample_optics(optics, 1) if optics.ss > 1 else optics
    m, m1 = p.rd.optics.margin, o1.margin
    if o1.n_patches == 1 and m1 <= m:
        return _conv(_crop(p.comps["L"], m, m1), o1.kernels[0])
    return ChannelRenderer(scene, o1, radiance, False, sub=1).components(t)["fine"]


def _spectral_far(optics: ChannelOptics, p: _Pilot, scene: Scene, radiance: Any, t: float) -> float:
    """The rms change (radiance) of the far haze with the variant ``optics``' bins, on the pilot's coarse grid when
    both share it (else both on the pixels)."""
    o = p.rd.optics
    n_h = 1 if optics.far_kernel is not None and optics.far_weight > 0 else 0
    if not p.n_haze and not n_h:
        return 0.0
    if p.n_haze and n_h and optics.far_coarse == o.far_coarse:
        km, km1 = o.far_kernel.shape[0] // 2, optics.far_kernel.shape[0] // 2
        if km1 <= km:
            Lc = p.comps["Lc"][0]
            d = o.far_weight * _conv(Lc, o.far_kernel) - optics.far_weight * _conv(_crop(Lc, km, km1),
                                                                                   optics.far_kernel)
            return _rms(d)
    o1 = resample_optics(optics, 1) if optics.ss > 1 else optics
    far = ChannelRenderer(scene, replace(o1, extra_far=()), radiance, False, sub=1).far_images(t)
    return _rms((far[0] if n_h else 0.0) - (p.comps["far"][0] if p.n_haze else 0.0))


def _pilot_extras(p: _Pilot, ex: dict[str, Any], scene: Scene, radiance: Any, t: float) -> dict[str, Any]:
    """The variant optics' images at time ``t`` (from the pilot's samples where they share its grid)."""
    out = dict(ex)
    if ex.get("nohaze") is not None:
        out["nohaze_fine"] = _fine_with(ex["nohaze"], p, scene, radiance, t)
    if ex.get("patch0") is not None:
        out["patch0_fine"] = _fine_with(ex["patch0"], p, scene, radiance, t)
        # the supersampling error of the difference kernel: the pilot's, scaled by |K_p - K_0| / |K_0|
        k0 = _envelope([(resample_optics(ex["patch0"], 1) if ex["patch0"].ss > 1 else ex["patch0"]).kernels[0]])
        n = max([k0.shape[0]] + [k.shape[0] for k in p.rd.optics.kernels])
        pad = [np.pad(k, (n - k.shape[0]) // 2) for k in [k0, *p.rd.optics.kernels]]
        out["patch_ratio"] = max(float(np.abs(k - pad[0]).sum()) for k in pad[1:]) / max(float(pad[0].sum()), 1e-300)
    if ex.get("spectral") is not None:
        out["spectral_far"] = _spectral_far(ex["spectral"], p, scene, radiance, t)
    return out


def _frame_estimates(inp: PlanInputs, dn: list[np.ndarray], fid_dn: list[np.ndarray],
                     d_k: Callable[[np.ndarray], np.ndarray]) -> dict[str, float | None]:
    """The polariser's and the sensor's effects on the frames (K rms; None where the full model has none).
    ``dn``: each channel's pilot image in DN (the full gains), ``fid_dn`` its error bound in DN, ``d_k(a_eff)``: the
    frames' DN per kelvin."""
    cam = inp.camera
    pol, sensor = cam.polarizer, cam.sensor
    theta, _ = pol.angles(inp.times, inp.polarizer_rng)
    _, a_eff, gain = pol.mixing(theta)
    inv_d = 1.0 / d_k(a_eff)  # (T,)
    x1, x2 = dn
    k = 1.0 + SAFETY
    out: dict[str, float | None] = {}
    for name, other in (("extinction", replace(pol, extinction=0.0)), ("bolometer_lag", replace(pol, tau_s=0.0))):
        if other == pol:
            out[name] = None
            continue
        _, b_eff, b_gain = other.mixing(theta)
        # frames: a' x1 + (1 - a') x2 with x_i = dark + (gain-scaled signal); the other model's images scale
        # their signal by b_gain / gain
        dark = sensor.dark_dn
        s = b_gain / gain
        y1, y2 = dark + (x1 - dark) * s, dark + (x2 - dark) * s
        ms = [np.mean(np.square(a * x1 + (1 - a) * x2 - (b * y1 + (1 - b) * y2))) * w ** 2
              for a, b, w in zip(a_eff, b_eff, inv_d)]
        fid = max(_rms(fid_dn[0]), _rms(fid_dn[1])) * (float(np.max(np.abs(a_eff - b_eff))) + abs(1 - s))
        out[name] = k * math.sqrt(float(np.mean(ms))) + fid * float(np.max(inv_d))
    rms_inv = math.sqrt(float(np.mean(inv_d ** 2)))
    q = 1.0 / 6.0 if inp.quantize else 0.0  # the rms^2 of the difference of two roundings
    sig = sensor.netd_k * sensor.counts_per_k
    out["noise"] = k * math.sqrt(sig ** 2 + q) * rms_inv if inp.noise and sig > 0 else None
    rng_dn = max(float(np.ptp(x1)), float(np.ptp(x2))) * k
    fmax = sensor.fpn_amplitude * max(rng_dn, sensor.counts_per_k) * (1 + sensor.fpn_drift)
    out["fpn"] = math.sqrt(fmax ** 2 + q) * rms_inv if sensor.fpn_rank and sensor.fpn_amplitude > 0 else None
    if inp.quantize:
        mix = np.stack([a * x1 + (1 - a) * x2 for a in a_eff[:: max(1, a_eff.size // 8)]])
        clip = np.maximum(mix - sensor.full_scale_dn, 0) + np.maximum(-mix, 0)
        out["quantisation"] = (1.0 / math.sqrt(12.0) * k + _rms(clip) + 3 * sig * float(np.mean(clip > 0))) * rms_inv
    else:
        out["quantisation"] = None
    return out


def _work(optics: Sequence[ChannelOptics], reduce: Sequence[str]) -> float:
    """The rendering work (scene samples and interpolated pixels) of a model, both channels: the fine grid, the scene
    seen through a perfect lens (the file's ``scene_x``), each far component's coarse grid and its interpolation to
    the pixels, the glare's disks interpolated into the file's pixel PSF (without the haze's or the train's, the
    work of their far components)."""
    w = 0.0
    for o in optics:
        H, W = o.channel.shape
        ss = 1 if "supersample" in reduce else o.ss
        sub = 1 if "far_sampling" in reduce else ChannelRenderer.SUB
        n_k = max(k.shape[0] for k in o.kernels) * ss // o.ss
        w += (H * ss + n_k) * (W * ss + n_k) * (o.n_patches ** 2 if "field_patches" not in reduce else 1)
        w += H * W * ss * ss
        for j, (_, kernel, q) in enumerate(o.far_parts()):
            glare = j >= (1 if o.far_kernel is not None and o.far_weight > 0 else 0)
            if (glare and ("glare" in reduce or "train" in reduce)) or (not glare and "haze" in reduce):
                continue
            km = kernel.shape[0] // 2
            w += (round(H * sub / q) + 2 * km * sub) * (round(W * sub / q) + 2 * km * sub) + H * W
            if glare:
                w += (2 * min((km + 1) * q, max(H, W) + q) + 1) ** 2
    return w


def _choose(estimates: dict[str, float], works: dict[tuple[str, ...], float], candidates: Sequence[str],
            budget: float) -> tuple[str, ...]:
    """The set of replacements with the least work whose estimates sum to at most ``budget`` (ties: the smaller sum)."""
    best: tuple[float, float, tuple[str, ...]] = (works[()], 0.0, ())
    for n in range(1, len(candidates) + 1):
        for combo in itertools.combinations(candidates, n):
            s = sum(_combo_estimate(estimates, combo, c) for c in combo)
            if s <= budget and (works[combo], s) < best[:2]:
                best = (works[combo], s, combo)
    return best[2]


def _combo_estimate(estimates: dict[str, float], combo: Sequence[str], effect: str) -> float:
    """An effect's estimate within a set of replacements (the far sampling of the glare goes with the glare)."""
    if effect == "far_sampling":
        return estimates["far_sampling_haze"] + (0.0 if "glare" in combo else estimates["far_sampling_glare"])
    return estimates[effect]


def _present(inp: PlanInputs, est: dict[str, float | None], ss_full: int) -> dict[str, bool]:
    """Which effects the full model has."""
    o = inp.optics
    trains = inp.camera.trains
    haze = any(float(x.info.get("haze", {}).get("fraction", 0.0)) > 0 for x in o)
    return {"spectral": True, "supersample": ss_full > 1, "far_sampling": any(x.far_parts() for x in o),
            "haze": haze, "glare": any(x.extra_far for x in o), "train": trains is not None,
            "train_field": trains is not None and inp.relative_illumination,
            "relative_illumination": inp.relative_illumination, "field_patches": any(x.n_patches > 1 for x in o),
            **{e: est.get(e) is not None for e in ("extinction", "bolometer_lag", "noise", "fpn", "quantisation")}}


def _why(effect: str, included: bool | None, est: float | None, budget_left: float, reducible: bool,
         budget: float) -> str:
    """The plan table's reason for an effect's row."""
    e = EFFECTS[effect]
    if included is None:
        return "not in the full model (its options)"
    if not included:
        return f"replaced by: {e.alternative} (its estimate fits the budget)"
    if e.kind == "sensor":
        return "kept: the camera's own noise, not a model approximation (costs little)"
    if effect == "spectral":
        return "kept: the PSFs are computed once at 31 bins and cached; fewer bins would not reuse them"
    if reducible:
        return f"kept: {est:.3g} K rms exceeds what the budget leaves ({max(budget_left, 0.0):.3g} K)"
    if est is not None and est > budget:
        return f"kept: {est:.3g} K rms, beyond the budget (a plan does not replace it: {e.alternative})"
    return f"kept: a plan does not replace it ({e.alternative} saves little)"


def plan_model(inp: PlanInputs, tolerance_k: float, ss_full: int) -> Plan:
    """The cheapest model of :func:`~metafovea.imaging.simulate.simulate` whose error against the full model is
    within ``tolerance_k`` (K rms; see the module docstring for the measure, the estimates and the budget).

    Parameters
    ----------
    inp : PlanInputs
        The full model's camera, scene, times and optics (as :func:`~metafovea.imaging.simulate.simulate` builds
        them).
    tolerance_k : float, K
        The accuracy asked, rms of the sensor image referred to the scene, ``0 < tolerance_k <= 100``.
    ss_full : int
        The full model's scene samples per pixel and axis.

    Returns
    -------
    Plan
        One row per effect of :data:`EFFECTS` (estimate, included, cost, why) and the replacements (``reduce``) that
        ``simulate(..., reduce=plan.reduce)`` applies.
    """
    t_start = time.perf_counter()
    tol = check_tolerance(tolerance_k)
    cam, scene = inp.camera, inp.scene
    radiance, sensor = cam.radiance, cam.sensor
    n = inp.times.size
    ts = [float(inp.times[0])] if scene.static else [float(inp.times[i]) for i in sorted({0, n // 2, n - 1})]
    dldt = radiance.derivative(inp.scene_temperature_k)
    dldt300 = radiance.derivative(300.0)
    extras = _channel_extras(inp)
    small = SMALL_SHARE * tol * dldt
    ff = [None if cam.trains is None else tr.field_factor for tr in (cam.trains or (None, None))]
    per_channel: list[dict[str, list[float]]] = [{}, {}]
    pilots: list[_Pilot] = []
    reuse: list[dict[str, Any]] = []
    dn, fid_dn = [], []
    for t in ts:
        for i in range(2):
            p = _pilot(scene, inp.optics[i], radiance, inp.relative_illumination, ff[i], t, small)
            ex = _pilot_extras(p, extras[i], scene, radiance, t)
            for e, v in _estimates_optics(p, ex).items():
                per_channel[i].setdefault(e, []).append(v)
            if t == ts[0]:
                pilots.append(p)
                reuse.append({"fine": p.comps["fine"], "samples": p.comps["L"], "far": p.comps["far"],
                              "far_full": p.full_far, "n_haze": p.n_haze, "ri": p.rd.ri,
                              "glare_complete": len(p.rd.optics.extra_far) == len(inp.optics[i].extra_far)})
                scale = sensor.counts_per_k * cam.gains[i] / dldt300
                dn.append(sensor.to_dn(p.image, cam.gains[i], dldt300))
                fid_dn.append(_fidelity(p) * scale)
    est: dict[str, float | None] = {}
    for e in set(per_channel[0]) | set(per_channel[1]):
        # a video: the largest of its pilot times (the frames between them may change more than the rms of three)
        est[e] = max(float(np.max(per_channel[i].get(e, [0.0]))) for i in range(2)) / dldt
    g1, g2 = (sensor.counts_per_k * g * dldt / dldt300 for g in cam.gains)
    est.update(_frame_estimates(inp, dn, fid_dn, lambda a: a * g1 + (1 - a) * g2))
    present = _present(inp, est, ss_full)
    est["far_sampling"] = est.get("far_sampling_haze", 0.0) + est.get("far_sampling_glare", 0.0)
    candidates = [e for e in REDUCIBLE if present[e]]
    combos = [c for k in range(len(candidates) + 1) for c in itertools.combinations(candidates, k)]
    works = {c: _work(inp.optics, c) for c in combos + [("haze",), ("train",)]}
    budget = BUDGET_SHARE * tol
    chosen = _choose({k: v for k, v in est.items() if v is not None}, works, candidates, budget)
    spent = sum(_combo_estimate(est, chosen, c) for c in chosen)
    full_work = works[()]
    rows = []
    for e in EFFECTS:
        inc = None if not present[e] else e not in chosen
        saved = (full_work - works[(e,)]) / full_work if present[e] and (e,) in works else 0.0
        value = est.get(e) if present[e] else None
        rows.append(PlanRow(e, value, inc, saved, _why(e, inc, value, budget - spent, e in candidates, budget)))
    notes = (f"pilot: 1 sample per pixel and per coarse sample, at {len(ts)} time(s); estimates in K at the "
             f"design's scene temperature {inp.scene_temperature_k:g} K",
             "the sampling estimates sample the scene where the full model does (s x s per pixel, 3 x 3 per coarse "
             "sample): structure that falls between the full model's own samples is seen by neither")
    return Plan(tol, tuple(rows), chosen, budget, spent, works[chosen] / full_work, time.perf_counter() - t_start,
                float(inp.scene_temperature_k), notes, tuple(reuse) if scene.static else None)
