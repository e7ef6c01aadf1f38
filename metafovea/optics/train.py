"""The camera as one optical train per channel: what reaches the focal plane, and where the rest goes.

Light from the scene passes, in order, the front wafer (the lens farther from the focal plane: the foveal
lens, 150 mm), the gap, the back wafer (the perifoveal lens, 25 mm), the polariser, the relay and the
sensor. Each linear polarisation is focused by one lens and passes through the other, so a channel
(polarisation ``p``, focusing lens ``L``, other lens ``O``) gets, on axis::

    throughput = T_b * T_ms,L * G_L  *  T_b * |d_0|^2 * G_O  *  V(0)

* ``T_b = 1 - R_b``, ``R_b = ((n - 1) / (n + 1))^2``: each wafer's bare silicon face (0.300 at n = 3.42).
* ``T_ms,L = sum_k p_k |t_k|^2``: the focusing lens' metasurface, zero order of each post (RCWA post set),
  ``p_k`` the fraction of the bundle's lattice sites at level k (sampled site by site over the footprint).
  Where that light goes (the focusing order, the other orders, the chromatic haze) is the PSF's business.
* ``|d_0|^2 = |sum_k p_k t_k|^2``: the coherent part of the other lens' pass-through (``PostSet.t_pass``
  seen through the other lens' zone pattern): it continues as the plane (or converging) wave the channel
  images. The rest, ``sum_k p_k |t_k|^2 - |d_0|^2``, is the pass-through *ripple*: it leaves in the other
  lens' diffraction orders ``exp(i m phi_O)``, which both lenses together bring to broad disks on the focal
  plane (:class:`Leak`: a veiling glare, radii from a paraxial trace through both lenses, the focusing lens
  taken in its focusing order; 2 % of an exact trace for ray slopes up to 0.1). The order powers follow the
  N-level series of ``t_pass`` (:func:`metafovea.optics.pupil.order_coefficients`), scaled to the footprint's
  ripple.
* ``G = A / (1 - R_b R_ms A^2)``: incoherent multiple reflections between the bare face and the metasurface
  (``R_ms = sum_k p_k R_k``, the posts' specular reflection back into the wafer), with the single-pass
  internal transmittance ``A = exp(-alpha d)``. Incoherent because a 500 um wafer is ~100 coherence lengths
  of an 8-14 um band thick; the higher reflected orders inside the wafer (4 um lattice, n = 3.42) are
  trapped by total internal reflection at the bare face and counted as lost.
* ``alpha``: free-carrier absorption of the lightly doped wafer, ``alpha = C lambda^2 N`` with
  ``C = 1.0e-18`` (electrons) or ``2.7e-18`` (holes) cm^2 um^-2 at 300 K (D. K. Schroder, R. N. Thomas and
  J. C. Swartz, "Free carrier absorption in silicon", IEEE Trans. Electron Devices 25, 254 (1978)), and
  ``N = 1 / (q rho mu)`` from the platform's resistivity with the low-doping mobilities 1400 (electrons) and
  450 (holes) cm^2/(V s) (S. M. Sze, Physics of Semiconductor Devices). Lattice (multiphonon) absorption and
  the interstitial-oxygen band of Czochralski wafers at 9.0 um are not included: ``substrate_extra_absorption_per_cm``
  of the platform adds a measured value.
* ``V``: the other lens' aperture ring clips the channel's bundle off axis: the area of the bundle's footprint
  on the other lens inside its clear aperture (the metasurface's diameter), as a fraction (circle overlap).
  The perifoveal channel's parallel bundle crosses the foveal wafer 125 mm in front of its lens, shifted by
  ``125 mm tan(field)``: it is clipped beyond ~11 deg. :meth:`ChannelTrain.clear_fraction` is a map over the
  field; ``cos^4`` is separate (:mod:`metafovea.imaging.channel`).

Every factor is averaged over the band with the PSF's wavelength weights (post phases scale as
``lambda0 / lambda``, absorption as ``lambda^2``); the throughput is the band mean of the product. The
polariser's extinction leak is the camera's (:mod:`metafovea.imaging.polarizer`); the relay's and the
polariser's own losses are common to both channels and not modelled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign, SystemDesign
from metafovea.errors import check_int, check_positive
from metafovea.lens import design_phase, quantize_phase, site_positions_um
from metafovea.library.postset import PostSet
from metafovea.parallel import blas_threads

from .pupil import level_transmissions, order_coefficients

#: free-carrier absorption coefficient / (lambda^2 N), cm^2 um^-2 at 300 K (Schroder, Thomas & Swartz 1978)
FREE_CARRIER_CM2_PER_UM2 = {"n": 1.0e-18, "p": 2.7e-18}
#: low-doping carrier mobilities at 300 K, cm^2 / (V s) (Sze, Physics of Semiconductor Devices)
MOBILITY_CM2_PER_VS = {"n": 1400.0, "p": 450.0}
ELEMENTARY_CHARGE_C = 1.602176634e-19
#: lattice sites sampled per footprint for the level fractions
FOOTPRINT_SAMPLES = 1 << 16
#: diffraction orders -LEAK_ORDERS..LEAK_ORDERS of the pass-through ripple that are followed
LEAK_ORDERS = 8
#: oblique incidence is applied where it changes a channel's throughput by more than this (relative)
OBLIQUE_MIN_EFFECT = 1e-4

POSTS_NOTE_IDEAL = ("ideal posts (exact phases, unit transmission and pass-through, no reflection): a "
                    "simplified model, not the fabricated lens")


def silicon_absorption_per_cm(wavelength_um: ArrayLike, resistivity_ohm_cm: float, dopant: str,
                              extra_per_cm: float = 0.0) -> np.ndarray:
    """Absorption coefficient (1/cm) of a lightly doped silicon wafer: free carriers (``C lambda^2 N``, see the
    module docstring) plus ``extra_per_cm``."""
    rho = check_positive("substrate_resistivity_ohm_cm", resistivity_ohm_cm, "ohm cm")
    n_carriers = 1.0 / (ELEMENTARY_CHARGE_C * rho * MOBILITY_CM2_PER_VS[dopant])
    lam = np.asarray(wavelength_um, dtype=float)
    return FREE_CARRIER_CM2_PER_UM2[dopant] * lam ** 2 * n_carriers + extra_per_cm


def wafer_transmission(t_front: ArrayLike, r_front: ArrayLike, t_back: ArrayLike, r_back: ArrayLike,
                       internal: ArrayLike) -> np.ndarray:
    """Power transmission of a thick slab with incoherent multiple reflections:
    ``T1 T2 A / (1 - R1 R2 A^2)`` (faces' transmittances T, internal reflectances R, single-pass internal
    transmittance A)."""
    t1, r1, t2, r2, a = (np.asarray(v, dtype=float) for v in (t_front, r_front, t_back, r_back, internal))
    return t1 * t2 * a / (1.0 - r1 * r2 * a * a)


def bare_face_reflectance(n: float) -> float:
    """Normal-incidence reflectance of a bare face of index ``n`` in air."""
    return ((n - 1.0) / (n + 1.0)) ** 2


def circle_overlap_fraction(r_beam: float, r_aperture: float, offset: ArrayLike) -> np.ndarray:
    """Fraction of a disk of radius ``r_beam`` centred ``offset`` away from the centre of a disk of radius
    ``r_aperture`` that lies inside it (exact circle-circle overlap area)."""
    a, b = float(r_beam), float(r_aperture)
    d = np.abs(np.asarray(offset, dtype=float))
    out = np.zeros_like(d)
    inside = d <= b - a
    out[inside] = 1.0
    if a > b:
        out[d <= a - b] = (b / a) ** 2
    part = (d > abs(b - a)) & (d < a + b)
    dd = d[part]
    c1 = np.clip((dd * dd + a * a - b * b) / (2 * dd * a), -1.0, 1.0)
    c2 = np.clip((dd * dd + b * b - a * a) / (2 * dd * b), -1.0, 1.0)
    area = (a * a * np.arccos(c1) + b * b * np.arccos(c2)
            - 0.5 * np.sqrt(np.clip((-dd + a + b) * (dd + a - b) * (dd - a + b) * (dd + a + b), 0.0, None)))
    out[part] = area / (math.pi * a * a)
    return out


def level_fractions(lens: LensDesign, radius_um: float, center_um: tuple[float, float] = (0.0, 0.0), *,
                    samples: int = FOOTPRINT_SAMPLES,
                    rng: np.random.Generator | int | None = 0) -> tuple[np.ndarray, int]:
    """Fractions ``p_k`` (N,) of the lens' lattice sites at each level inside a disk footprint (radius, centre
    in um), from ``samples`` sites drawn uniformly over it (each point snapped to its lattice site; sites
    outside the aperture are skipped), and how many sites landed inside. Standard error ~ sqrt(p / samples)."""
    n = check_int("samples", samples, 16, 1 << 26)
    g = np.random.default_rng(rng)
    r = float(radius_um) * np.sqrt(g.random(n))
    t = 2 * math.pi * g.random(n)
    x, y = center_um[0] + r * np.cos(t), center_um[1] + r * np.sin(t)
    o = 0.0 if lens.lattice == "integer" else 0.5
    ix, iy = np.round(x / lens.period_um - o), np.round(y / lens.period_um - o)
    xs, ys = site_positions_um(lens, ix, iy)
    ok = np.hypot(xs, ys) <= lens.radius_um
    k = quantize_phase(design_phase(lens, xs[ok], ys[ok]), lens.levels)
    counts = np.bincount(k, minlength=lens.levels).astype(float)
    m = int(ok.sum())
    return (counts / m if m else np.full(lens.levels, 1.0 / lens.levels)), m


def _trace(powers: tuple[float, float], gap_um: float, last_um: float) -> tuple[float, float]:
    """Paraxial ray of unit height and zero slope at the first element: (height at the second element, height
    at the focal plane). ``powers`` in 1/um (1 / focal length), ``gap_um`` between the elements, ``last_um``
    from the second element to the focal plane."""
    u = -powers[0]
    h2 = 1.0 + gap_um * u
    u -= powers[1] * h2
    return h2, h2 + last_um * u


@dataclass(frozen=True)
class Leak:
    """Light of the other lens' pass-through ripple (its diffraction order ``order``) on the focal plane: a
    uniform disk. ``power_fraction``: relative to the power incident on the focusing lens' aperture, band
    weighted (this wavelength bin's share); ``radius_um``: the disk on the focal plane."""

    order: int
    wavelength_um: float
    power_fraction: float
    radius_um: float


@dataclass(frozen=True)
class ChannelTrain:
    """One channel's optical train (see the module docstring).

    ``factors``: name -> band-weighted factor (their product is ~ ``throughput``; ``throughput`` is the band
    mean of the product). ``sources``: name -> where the value comes from. ``lens_transmission``:
    ``{'focusing' | 'other': {'lens': name, polarisation: zero-order transmission of that wafer}}`` at the design
    wavelength (the focusing lens over its aperture, the other over the bundle's footprint): what the paper's
    ~60 % per lens is.
    ``ring``: (footprint radius, clear radius, shift per tan(field)) on the other lens, um.
    """

    channel: str
    polarization: str
    posts: str
    factors: dict[str, float]
    sources: dict[str, str]
    throughput: float
    leaks: tuple[Leak, ...]
    lens_transmission: dict[str, dict[str, float]]
    ring: tuple[float, float, float]
    metasurface_transmission: float  #: T_ms of the focusing lens (what its PSF's power is relative to)
    notes: tuple[str, ...] = field(default_factory=tuple)
    #: (field angles deg, factor in the xz plane, factor in the yz plane) of oblique incidence relative to the
    #: axis, or None when not applied (see ``oblique_note``)
    oblique: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    oblique_note: str = ""

    @property
    def leak_fraction(self) -> float:
        """Power of the pass-through ripple on the focal plane / the channel's throughput."""
        return float(sum(lk.power_fraction for lk in self.leaks)) / self.throughput

    def clear_fraction(self, field_tan: ArrayLike) -> np.ndarray:
        """Unclipped fraction of the bundle at ``tan(field angle)`` (array) by the other lens' ring."""
        r_beam, r_clear, shift = self.ring
        return circle_overlap_fraction(r_beam, r_clear, shift * np.asarray(field_tan, dtype=float))

    def oblique_factor(self, tan_x: ArrayLike, tan_y: ArrayLike) -> np.ndarray:
        """Throughput at the field (tan of the angles along x and y) relative to the axis from the posts' oblique
        incidence (1 where not applied)."""
        tx, ty = np.asarray(tan_x, dtype=float), np.asarray(tan_y, dtype=float)
        if self.oblique is None:
            return np.ones(np.broadcast_shapes(tx.shape, ty.shape))
        grid, g0, g1 = self.oblique
        th = np.degrees(np.arctan(np.hypot(tx, ty)))
        c2 = np.where(th > 0, tx ** 2 / np.maximum(tx ** 2 + ty ** 2, 1e-300), 1.0)
        return c2 * np.interp(th, grid, g0) + (1 - c2) * np.interp(th, grid, g1)

    def field_factor(self, tan_x: ArrayLike, tan_y: ArrayLike) -> np.ndarray:
        """Throughput at the field relative to the axis, beyond ``cos^4``: the other lens' ring and oblique
        incidence on the posts."""
        return self.clear_fraction(np.hypot(tan_x, tan_y)) * self.oblique_factor(tan_x, tan_y)

    def clipping_starts_deg(self) -> float:
        r_beam, r_clear, shift = self.ring
        return math.degrees(math.atan(max(r_clear - r_beam, 0.0) / shift)) if shift > 0 else 90.0

    def leak_orders(self) -> list[dict[str, float]]:
        """Per order: its power (relative to the throughput) and the range of its disk radii (um)."""
        out = []
        for m in sorted({lk.order for lk in self.leaks}, key=lambda v: (abs(v), v)):
            ls = [lk for lk in self.leaks if lk.order == m]
            out.append({"order": m, "fraction": float(sum(lk.power_fraction for lk in ls)) / self.throughput,
                        "radius_min_um": min(lk.radius_um for lk in ls),
                        "radius_max_um": max(lk.radius_um for lk in ls)})
        return out

    def summary(self) -> dict[str, Any]:
        return {"channel": self.channel, "polarization": self.polarization, "posts": self.posts,
                "throughput": self.throughput, "factors": dict(self.factors), "sources": dict(self.sources),
                "leak_fraction": self.leak_fraction, "leak_orders": self.leak_orders(),
                "lens_transmission": self.lens_transmission, "ring_clipping_starts_deg": self.clipping_starts_deg(),
                "oblique_incidence": self.oblique_note, "notes": list(self.notes)}


def _wafer_terms(lens: LensDesign, post_set: PostSet, pol: str, fractions: np.ndarray, wl: np.ndarray,
                 r_bare: float, absorption: np.ndarray, thickness_um: float
                 ) -> tuple[float, np.ndarray, np.ndarray, float, str]:
    """(T_ms, coherent amplitude d_0 per wavelength, G per wavelength, R_ms, reflectance source)."""
    t_ms = float(fractions @ np.abs(post_set.transmission(pol)) ** 2)
    refl, refl_src = post_set.reflectance(pol)
    r_ms = float(fractions @ refl)
    a = np.exp(-absorption * thickness_um * 1e-4)
    g = wafer_transmission(1.0, r_bare, 1.0, r_ms, a)
    d0 = np.array([complex(fractions @ level_transmissions(lens, post_set, pol, float(w))) for w in wl])
    return t_ms, d0, g, r_ms, refl_src


def channel_train(system: SystemDesign, channel: str, post_sets: dict[str, PostSet], wavelengths_um: ArrayLike,
                  weights: ArrayLike, *, posts: str = "rcwa", samples: int = FOOTPRINT_SAMPLES,
                  oblique: dict[str, Any] | None = None, max_field_deg: float = 0.0,
                  error: float = OBLIQUE_MIN_EFFECT) -> ChannelTrain:
    """The optical train of ``channel`` ('foveal' or 'perifoveal') of ``system`` with the post sets
    ``{'x': foveal lens' set, 'y': perifoveal lens' set}``, averaged over the wavelengths with ``weights``.

    ``oblique``: ``{polarisation of a lens: ObliqueResponse of its post set}``
    (:func:`metafovea.library.oblique_response`): the posts off axis. The focusing lens and a front other lens see
    the field's plane wave; a back other lens sees the focusing lens' converging cone (on axis: angles up to
    atan(D / 2 z), averaged over the pupil; its shift with the field is left out). The field dependence is applied
    when it changes the throughput by more than ``error`` anywhere up to ``max_field_deg`` (the channel's corner),
    and its size is reported either way."""
    plat = system.platform
    lenses = {"foveal": (system.foveal, system.lens_to_sensor_um[0]),
              "perifoveal": (system.perifoveal, system.lens_to_sensor_um[1])}
    (L, zL), (O, zO) = lenses[channel], lenses["perifoveal" if channel == "foveal" else "foveal"]
    pol = L.polarization
    wl = np.atleast_1d(np.asarray(wavelengths_um, dtype=float))
    w = np.atleast_1d(np.asarray(weights, dtype=float))
    w = w / w.sum()
    r_b = bare_face_reflectance(plat.n_substrate)
    alpha = silicon_absorption_per_cm(wl, plat.substrate_resistivity_ohm_cm, plat.substrate_dopant,
                                      plat.substrate_extra_absorption_per_cm)
    d = plat.substrate_thickness_um
    front = zL > zO  # the focusing lens is the front one
    gap = abs(zL - zO)
    # footprints: the focusing lens' whole aperture; on the other lens the coherent bundle (on axis)
    pL, _ = level_fractions(L, L.radius_um, samples=samples, rng=1)
    r_foot = L.radius_um * (abs(1.0 - gap / L.f_um) if front else 1.0)
    pO, _ = level_fractions(O, min(r_foot, O.radius_um), samples=samples, rng=2)
    psL, psO = post_sets[L.polarization], post_sets[O.polarization]
    t_msL, _, gL, r_msL, srcL = _wafer_terms(L, psL, pol, pL, wl, r_b, alpha, d)
    cone = None
    if oblique and O.polarization in oblique and front:
        # the back lens sees the converging cone: ratios averaged over the pupil (uniform in h^2, both planes)
        h = L.radius_um * np.sqrt((np.arange(32) + 0.5) / 32)
        f = oblique[O.polarization].factor(pol, np.degrees(np.arctan(h / zL)), 0.0) + \
            oblique[O.polarization].factor(pol, np.degrees(np.arctan(h / zL)), 0.5 * math.pi)
        cone = 0.5 * f.mean(axis=0)
        tau = psO.transmission(pol)
        cone_power = abs(complex(pO @ (tau * cone))) ** 2 / abs(complex(pO @ tau)) ** 2
        psO = replace(psO, t_x=psO.t_x * cone) if pol == "x" else replace(psO, t_y=psO.t_y * cone)
    t_msO, d0, gO, r_msO, srcO = _wafer_terms(O, psO, pol, pO, wl, r_b, alpha, d)
    coh = np.abs(d0) ** 2
    t_b = 1.0 - r_b
    ring = (r_foot, O.radius_um, gap)
    v0 = float(circle_overlap_fraction(r_foot, O.radius_um, 0.0))
    per_wl = t_b * t_msL * gL * t_b * coh * gO * v0
    throughput = float(w @ per_wl)
    factors = {
        f"{L.name} lens: bare wafer face": t_b,
        f"{L.name} lens: metasurface zero order": t_msL,
        f"{L.name} lens: wafer reflections and absorption": float(w @ gL),
        f"{O.name} lens: bare wafer face": t_b,
        f"{O.name} lens: pass-through, coherent": float(w @ coh),
        f"{O.name} lens: wafer reflections and absorption": float(w @ gO),
        f"{O.name} lens: aperture ring (on axis)": v0,
    }
    absorb = (f"free carriers of {plat.substrate_resistivity_ohm_cm:g} ohm cm {plat.substrate_dopant}-type Si, "
              f"alpha = {float(w @ alpha):.3g} /cm band mean (Schroder et al. 1978)"
              + (f" + {plat.substrate_extra_absorption_per_cm:g} /cm given"
                 if plat.substrate_extra_absorption_per_cm else "")
              + f"; {d:g} um wafer")
    sources = {
        f"{L.name} lens: bare wafer face": f"1 - ((n - 1) / (n + 1))^2, n = {plat.n_substrate:g}",
        f"{L.name} lens: metasurface zero order": f"{posts} post set, |t|^2 over the aperture's levels",
        f"{L.name} lens: wafer reflections and absorption": f"incoherent, R_ms = {r_msL:.3f} ({srcL}); {absorb}",
        f"{O.name} lens: bare wafer face": f"1 - ((n - 1) / (n + 1))^2, n = {plat.n_substrate:g}",
        f"{O.name} lens: pass-through, coherent": (f"|sum p_k t_k|^2 over the bundle's {O.name} sites "
                                                    f"(radius {r_foot / 1000:.2f} mm); ripple "
                                                    f"{t_msO - float(w @ coh):.4f} leaks"),
        f"{O.name} lens: wafer reflections and absorption": f"incoherent, R_ms = {r_msO:.3f} ({srcO}); {absorb}",
        f"{O.name} lens: aperture ring (on axis)": (f"footprint radius {r_foot / 1000:.2f} mm on the "
                                                     f"{O.diameter_um / 1000:g} mm ring, {gap / 1000:g} mm away"),
    }
    # the ripple's orders: powers from the N-level order series of t_pass, scaled to the footprint's ripple
    ms = np.array([m for m in range(-LEAK_ORDERS, LEAK_ORDERS + 1) if m != 0])
    leaks = []
    for i, lam in enumerate(wl):
        tau = level_transmissions(O, psO, pol, float(lam))
        c = np.abs(order_coefficients(tau, O.levels, ms)) ** 2
        ripple = max(t_msO - coh[i], 0.0)
        if ripple <= 0 or c.sum() <= 0:
            continue
        c *= ripple / c.sum()
        fL = L.f_um * L.wavelength_um / lam
        for m, cm in zip(ms, c):
            fO = O.f_um * O.wavelength_um / (lam * m)
            powers = (1.0 / fL, 1.0 / fO) if front else (1.0 / fO, 1.0 / fL)
            h2, h_s = _trace(powers, gap, min(zL, zO))
            a1 = L.radius_um if front else O.radius_um
            a2 = O.radius_um if front else L.radius_um
            a_use = min(a1, a2 / abs(h2)) if h2 != 0 else a1
            # power relative to the focusing lens' aperture: the first element's usable area / L's area
            area = (a_use / L.radius_um) ** 2
            radius = max(a_use * abs(h_s), 0.61 * lam / L.na)
            p = w[i] * t_b * t_msL * gL[i] * t_b * gO[i] * cm * area
            if p > 1e-12:
                leaks.append(Leak(int(m), float(lam), float(p), float(radius)))
    lens_t = {}
    for lens, ps in ((L, psL), (O, psO)):
        fr = pL if lens is L else pO
        lam0 = np.array([lens.wavelength_um])
        a0 = silicon_absorption_per_cm(lam0, plat.substrate_resistivity_ohm_cm, plat.substrate_dopant,
                                       plat.substrate_extra_absorption_per_cm)
        role = "focusing" if lens is L else "other"
        lens_t[role] = {"lens": lens.name}
        for q in ("x", "y"):
            t_ms, _, g, _, _ = _wafer_terms(lens, ps, q, fr, lam0, r_b, a0, d)
            lens_t[role][q] = float(t_b * t_ms * g[0])
    notes = [POSTS_NOTE_IDEAL] if posts == "ideal" else []
    if cone is not None:
        sources[f"{O.name} lens: pass-through, coherent"] += (
            f"; posts at the converging cone's angles (up to {math.degrees(math.atan(L.radius_um / zL)):.1f} deg): "
            f"x{cone_power:.4f} against normal incidence")
    obl, obl_note = _oblique_field(L, O, psL, psO, pol, pL, pO, front, oblique, max_field_deg, error)
    return ChannelTrain(channel, pol, posts, factors, sources, throughput, tuple(leaks), lens_t, ring, t_msL,
                        tuple(notes), obl, obl_note)


def _oblique_field(L: LensDesign, O: LensDesign, psL: PostSet, psO: PostSet, pol: str, pL: np.ndarray,
                   pO: np.ndarray, front: bool, oblique: dict[str, Any] | None, max_field_deg: float,
                   error: float) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray] | None, str]:
    """The field factor of oblique incidence (focusing lens: its focusing order; a front other lens: its coherent
    pass-through), relative to the axis, in the xz and yz planes, and what was decided."""
    if not oblique or L.polarization not in oblique:
        return None, "not modelled (no oblique-incidence response of the posts: ideal or given posts)"
    grid = np.linspace(0.0, max(max_field_deg, 1e-3) * 1.05, 33)
    tauL = psL.transmission(pol)
    c1_0 = abs(complex(order_coefficients(tauL, L.levels, np.array([1]))[0])) ** 2
    g = []
    for az in (0.0, 0.5 * math.pi):
        fL = oblique[L.polarization].factor(pol, grid, az)
        c1 = np.abs(np.array([complex(order_coefficients(tauL * fk, L.levels, np.array([1]))[0]) for fk in fL])) ** 2
        gi = c1 / c1_0
        if not front and O.polarization in oblique:
            fO = oblique[O.polarization].factor(pol, grid, az)
            tauO = psO.transmission(pol)
            d0 = np.abs((fO * tauO[None, :]) @ pO) ** 2
            gi = gi * d0 / abs(complex(tauO @ pO)) ** 2
        g.append(gi)
    effect = float(max(np.max(np.abs(g[0] - 1)), np.max(np.abs(g[1] - 1))))
    worst = float(min(g[0][-1], g[1][-1]))
    what = (f"posts off axis (RCWA, harmonics {oblique[L.polarization].harmonics}, estimate "
            f"{oblique[L.polarization].error:.1g}): throughput x{worst:.4f} at {grid[-1] / 1.05:.1f} deg "
            f"(worse plane of incidence), up to {100 * effect:.2f} % over the field")
    if effect <= error:
        return None, f"{what}: below {error:g}, not applied"
    return (grid, g[0], g[1]), f"{what}: applied (relative illumination)"



def camera_trains(system: SystemDesign, post_sets: dict[str, PostSet], wavelengths_um: ArrayLike,
                  weights: ArrayLike, *, posts: str = "rcwa") -> tuple[ChannelTrain, ChannelTrain]:
    """(foveal, perifoveal) trains of ``system`` (see :func:`channel_train`)."""
    return (channel_train(system, "foveal", post_sets, wavelengths_um, weights, posts=posts),
            channel_train(system, "perifoveal", post_sets, wavelengths_um, weights, posts=posts))


#: wavelength bins of the band average (radiometry.psf_wavelengths; the factors vary slowly with wavelength)
TRAIN_WAVELENGTHS = 31


def system_trains(system: SystemDesign, post_sets: dict[str, PostSet], posts: str = "rcwa", *,
                  filter_enabled: bool | None = None, oblique: bool = True) -> tuple[ChannelTrain, ChannelTrain]:
    """(foveal, perifoveal) trains of ``system`` over its band (and filter, when enabled), Planck-weighted at the
    scene temperature: what ``psf``, ``simulate`` and ``validate`` all print. With RCWA posts (and ``oblique``)
    the posts' oblique-incidence response (:func:`metafovea.library.oblique_response`, cached) is included up
    to each channel's sensor corner (sensor crop, pitch, relay and distance of ``system``)."""
    from metafovea.library import oblique_response
    from metafovea.radiometry import BandRadiance

    radiance = BandRadiance.for_system(system, filter_enabled=filter_enabled)
    wl, w = radiance.psf_wavelengths(system.platform.wavelength_um, system.scene_temperature_k, TRAIN_WAVELENGTHS)
    obl = None
    if oblique and all(ps.source == "rcwa" for ps in post_sets.values()):
        # one BLAS thread: a first run's RCWA off axis (small eigenproblems) took 7x the CPU time with OpenBLAS'
        # threads on 2 cores (166 s against 22 s for both post sets)
        with blas_threads(1):
            obl = {pol: oblique_response(ps, system.platform) for pol, ps in post_sets.items()}
    half_diag = 0.5 * math.hypot(*system.sensor.crop) * system.sensor.pixel_pitch_um / system.relay_magnification
    out = []
    for channel, z in (("foveal", system.lens_to_sensor_um[0]), ("perifoveal", system.lens_to_sensor_um[1])):
        out.append(channel_train(system, channel, post_sets, wl, w, posts=posts, oblique=obl,
                                 max_field_deg=math.degrees(math.atan(half_diag / z))))
    return out[0], out[1]


def throughput_lines(summaries: list[dict[str, Any]]) -> list[str]:
    """The per-channel throughput and its breakdown as printed by ``psf``, ``simulate`` and ``validate`` (from
    :meth:`ChannelTrain.summary` dicts, so a stored run prints the same)."""
    lines = []
    for s in summaries:
        lines.append(f"{s['channel']} channel ({s['polarization']}-polarised, {s['posts']} posts): throughput "
                     f"{s['throughput']:.4f} on axis; pass-through ripple {100 * s['leak_fraction']:.2f} % of it "
                     f"as glare; the other lens' ring clips beyond {s['ring_clipping_starts_deg']:.1f} deg")
        for k, v in s["factors"].items():
            lines.append(f"    {v:.4f}  {k}  [{s['sources'][k]}]")
        big = sorted((o for o in s["leak_orders"] if o["fraction"] >= 1e-5), key=lambda o: -o["fraction"])
        if big:
            lines.append("    glare (largest orders): " + ", ".join(
                f"order {o['order']:+d} {100 * o['fraction']:.3f} % in disks of {o['radius_min_um'] / 1000:.2f}-"
                f"{o['radius_max_um'] / 1000:.2f} mm" for o in big[:3]))
        if s.get("oblique_incidence"):
            lines.append(f"    oblique incidence: {s['oblique_incidence']}")
        lines.extend(f"    note: {n}" for n in s["notes"])
    for s in summaries:
        tp = s["lens_transmission"]["focusing"]  # over its whole aperture
        lines.append(f"{tp['lens']} lens transmits {100 * tp['x']:.1f} % (x), {100 * tp['y']:.1f} % (y) at the design "
                     "wavelength, wafer included (paper: ~60 % per lens)")
    return lines
