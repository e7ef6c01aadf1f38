"""The library's RCWA harmonics from a phase-error target: ``choose_harmonics(tolerance_rad, sweep)``,
``metafovea library --tolerance-rad T``.

The model
---------
A library sweep solves every post at one truncation M (orders ``|m|, |n| <= M``); its cost grows as about
``(2M + 1)^4.5`` (:func:`~metafovea.library.sweep.compute_library`'s cost model), its error falls with M, not
monotonically (Li's rule converges in steps near the posts' resonances). The phase of the zero order is what a lens
sees, so the target is a phase error in radians: the largest ``|arg t(M) - arg t(converged)|`` over the library's
posts.

The estimate: probe posts (``n x n`` widths spread over the sweep's width grid, at its shortest, longest and
design wavelengths: the convergence is slowest at the shortest) are solved at M = 3, 4, 5, ...; at each M the
estimate is :data:`STEP_SAFETY` times the largest phase step ``|arg(t(M) / t(M - 2))|`` over the probes (posts whose
``|t|^2`` is below :data:`T_FLOOR` left out: their phase is not used by a lens). The smallest M whose estimate is at
most the tolerance is chosen. The step is not a bound for each post (:func:`metafovea.rcwa.posts.convergence_bound`
is one, about 8 times the true phase error at M = 10), but its largest value over posts spread across the grid
tracks the largest true error over other posts; the factor covers the difference, and
``tests/library/test_harmonics.py`` checks the chosen M against a converged run on posts that are not probes.

:class:`HarmonicsChoice` holds what was chosen and why (a row per M tried), :meth:`HarmonicsChoice.summary` is its
JSON (``library.json``'s ``harmonics_choice``, the library file's meta) and :meth:`HarmonicsChoice.lines` what the
command prints.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.errors import InputError, check_int, check_range

if TYPE_CHECKING:
    from .platform import PlatformSweep

#: the estimate is this times the largest phase step to M - 2 over the probes. On 16 random posts of the paper's
#: platform (0.5-3.5 um) at 10 um against M = 22, the largest true error at M = 8..16 was 0.82-1.38 times the largest
#: step over 9 probe posts (3 x 3 widths at the grid's 1/6, 1/2, 5/6)
STEP_SAFETY = 2.0
#: probes whose zero-order efficiency is below this are left out of the estimate (a lens does not use their phase)
T_FLOOR = 0.1
#: the smallest and largest truncation tried (the library's M - 2 estimate needs M >= 5)
MIN_CHOICE_HARMONICS = 5
MAX_CHOICE_HARMONICS = 24
#: probe widths per axis (``n x n`` probe posts per wavelength)
PROBES_PER_AXIS = 3


@dataclass(frozen=True)
class HarmonicsChoice:
    """The truncation :func:`choose_harmonics` chose for a phase-error tolerance, and why.

    ``rows``: one per M tried, ``{'harmonics', 'step_rad', 'estimate_rad', 'seconds_per_post'}`` (the largest
    phase step to M - 2 over the probes, :data:`STEP_SAFETY` times it, and the probes' mean solve time at M);
    ``probes``: the probe posts ``(wx_um, wy_um, wavelength_um)``; ``sweep_seconds``: the library sweep's expected
    wall seconds at the chosen M on its workers (the sweep's cost model); ``seconds``: the choice's own."""

    tolerance_rad: float
    harmonics: int
    estimate_rad: float
    step_rad: float
    rows: tuple[dict[str, Any], ...]
    probes: tuple[tuple[float, float, float], ...]
    seconds: float
    sweep_seconds: float | None = None

    @property
    def why(self) -> str:
        return (f"harmonics {self.harmonics}: max phase step |arg t(M)/t(M-2)| {self.step_rad:.2g} rad x "
                f"{STEP_SAFETY:g} = {self.estimate_rad:.2g} rad <= {self.tolerance_rad:g} on {len(self.probes)} "
                f"probe posts" + (f" (M = {self.harmonics - 1}: {self.rows[-2]['estimate_rad']:.2g} rad)"
                                  if len(self.rows) > 1 else ""))

    def summary(self) -> dict[str, Any]:
        """The choice as JSON: the stage, the tolerance and its unit, what was chosen, the estimate, why."""
        return {"stage": "library", "tolerance_rad": self.tolerance_rad, "chose": {"harmonics": self.harmonics},
                "estimate_rad": self.estimate_rad, "why": self.why,
                "estimate": f"{STEP_SAFETY:g} x the largest zero-order phase step to M - 2 over the probe posts "
                            f"(|t|^2 >= {T_FLOOR:g})",
                "rows": [dict(r) for r in self.rows],
                "probes": [{"wx_um": a, "wy_um": b, "wavelength_um": w} for a, b, w in self.probes],
                "seconds": self.seconds, "sweep_seconds_expected": self.sweep_seconds}

    def lines(self) -> list[str]:
        """What ``metafovea library --tolerance-rad`` prints."""
        out = [f"harmonics chosen for a phase error of {self.tolerance_rad:g} rad: {self.why}; chosen in "
               f"{self.seconds:.1f} s" + (f", the sweep ~{self.sweep_seconds:.0f} s" if self.sweep_seconds else "")]
        out += ["  M   max step (rad)  estimate (rad)  s per post"]
        out += [f"  {r['harmonics']:<3d} {r['step_rad']:14.3g}  {r['estimate_rad']:14.3g}  "
                f"{r['seconds_per_post']:10.3g}" for r in self.rows]
        return out

    def applied(self, sweep: PlatformSweep) -> PlatformSweep:
        """``sweep`` at the chosen harmonics."""
        return replace(sweep, options=replace(sweep.options, harmonics=self.harmonics))


def probe_posts(sweep: PlatformSweep, per_axis: int = PROBES_PER_AXIS) -> np.ndarray:
    """The probe posts of ``sweep``: ``(n, 3)`` rows ``(wx_um, wy_um, wavelength_um)``, ``per_axis`` widths per axis
    at the centres of equal parts of the width grid (1/6, 1/2, 5/6 for 3), at the sweep's shortest, longest and
    design wavelengths."""
    n = check_int("probes", per_axis, 1, 8)
    w = sweep.widths_um
    q = np.round(np.quantile(w, (np.arange(n) + 0.5) / n), 4)
    wls = sorted({min(sweep.wavelengths), max(sweep.wavelengths), sweep.design_wavelength_um})
    return np.array([(a, b, wl) for wl in wls for a in q for b in q], dtype=float)


def choose_harmonics(tolerance_rad: float, sweep: PlatformSweep | None = None, *, probes: int = PROBES_PER_AXIS,
                     max_harmonics: int = MAX_CHOICE_HARMONICS) -> HarmonicsChoice:
    """The smallest RCWA truncation whose estimated zero-order phase error is within ``tolerance_rad``.

    Parameters
    ----------
    tolerance_rad : float, rad
        The largest phase error of the library's zero-order transmission asked (0 < T <= 1).
    sweep : PlatformSweep, optional
        The platform, width grid, wavelengths and solver settings (factorisation, entry side) of the library to be
        swept (default: the paper's, ``PlatformSweep()``); its ``harmonics`` are ignored.
    probes : int
        Probe widths per axis (``probes^2`` posts per wavelength, :func:`probe_posts`).
    max_harmonics : int
        The largest truncation tried; a tolerance not met by then is an :class:`InputError`.

    Returns
    -------
    HarmonicsChoice
        The chosen M, its estimate, a row per M tried and the probes (module docstring: the estimate).
    """
    from metafovea.parallel import blas_threads
    from metafovea.rcwa.posts import post_response

    from .platform import PlatformSweep
    from .sweep import _checked_sweep, _expected_seconds

    tol = check_range("tolerance_rad", tolerance_rad, 0.0, 1.0, unit="rad")
    top = check_int("max_harmonics", max_harmonics, MIN_CHOICE_HARMONICS, 40)
    sweep = sweep if sweep is not None else PlatformSweep()
    pr = probe_posts(sweep, probes)
    opts = sweep.options.with_platform(sweep.platform)
    kw = dict(period_um=opts.period_um, height_um=opts.height_um, n_post=opts.n_post, n_surround=opts.n_surround,
              n_substrate=opts.n_substrate, n_superstrate=opts.n_superstrate, factorization=opts.factorization,
              incidence=opts.incidence, polarizations=("x",))
    t0 = time.perf_counter()
    ts: dict[int, np.ndarray] = {}
    rows: list[dict[str, Any]] = []
    with blas_threads(1):
        for M in range(MIN_CHOICE_HARMONICS - 2, top + 1):
            t1 = time.perf_counter()
            ts[M] = np.ravel(post_response(pr[:, 0], pr[:, 1], pr[:, 2], harmonics=M, **kw).t_x)
            per_post = (time.perf_counter() - t1) / len(pr)
            if M < MIN_CHOICE_HARMONICS:
                continue
            used = np.abs(ts[M]) ** 2 >= T_FLOOR
            step = float(np.max(np.abs(np.angle(ts[M][used] / ts[M - 2][used])), initial=0.0))
            rows.append({"harmonics": M, "step_rad": step, "estimate_rad": STEP_SAFETY * step,
                         "seconds_per_post": per_post})
            if STEP_SAFETY * step <= tol:
                break
    last = rows[-1]
    if last["estimate_rad"] > tol:
        raise InputError("tolerance_rad", tolerance_rad, f"a phase error the probe posts reach by M = {top} "
                         f"(estimate there {last['estimate_rad']:.2g} rad)")
    chosen = replace(opts, harmonics=last["harmonics"])
    expected = _expected_seconds(_checked_sweep(sweep.widths_um, None, sweep.wavelengths, chosen),
                                 _workers(chosen.workers))
    return HarmonicsChoice(tol, last["harmonics"], last["estimate_rad"], last["step_rad"], tuple(rows),
                           tuple(tuple(float(v) for v in p) for p in pr), time.perf_counter() - t0, expected)


def _workers(workers: int | None) -> int:
    from metafovea.parallel import default_workers

    return workers or default_workers()
