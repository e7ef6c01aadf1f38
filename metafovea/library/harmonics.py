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
estimate is :data:`STEP_SAFETY` times the largest phase change to the truncations below,
``max(|arg t(M)/t(M-2)|, |arg t(M)/t(M-4)|)``, over the probes (posts whose ``|t|^2`` is below :data:`T_FLOOR` left
out: their phase is not used by a lens) -- the phase form of :func:`metafovea.rcwa.posts.convergence_bound`, which
bounds each post by three times that change of its own; here the largest change over posts spread across the grid
stands for the largest error over the library's other posts (the step to M - 2 alone does not: near a resonance the
truncations converge in steps, and a post between the probes is then off by three times the probes' largest step).
The smallest M whose estimate is at most the tolerance is chosen; ``tests/library/test_harmonics.py`` checks it
against a converged run on posts that are not probes, ``benchmarks/bench_harmonics_choice.py`` on more.

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

#: the estimate is this times the largest phase change to M - 2 or M - 4 over the probes. On 108 random posts of the
#: paper's platform (0.5-3.5 um; 3 seeds x 12 posts at 8, 10 and 12 um) against M = 20, the largest true error at
#: M = 8..17 was 0.29-1.10 times that change over the 27 default probes (and 1.5-3.1 times the step to M - 2 alone)
STEP_SAFETY = 1.5
#: probes whose zero-order efficiency is below this are left out of the estimate (a lens does not use their phase)
T_FLOOR = 0.1
#: the smallest and largest truncation tried (the change to M - 4 needs M - 4 >= 3, the smallest post solve)
MIN_CHOICE_HARMONICS = 7
MAX_CHOICE_HARMONICS = 24
#: probe widths per axis (``n x n`` probe posts per wavelength)
PROBES_PER_AXIS = 3


@dataclass(frozen=True)
class HarmonicsChoice:
    """The truncation :func:`choose_harmonics` chose for a phase-error tolerance, and why.

    ``rows``: one per M tried, ``{'harmonics', 'step_rad', 'step4_rad', 'estimate_rad', 'seconds_per_post'}`` (the
    largest phase change to M - 2 and to M - 4 over the probes, :data:`STEP_SAFETY` times the larger, and the probes'
    mean solve time at M);
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
        return (f"harmonics {self.harmonics}: max phase change to M-2, M-4 {self.step_rad:.2g} rad x "
                f"{STEP_SAFETY:g} = {self.estimate_rad:.2g} rad <= {self.tolerance_rad:g} on {len(self.probes)} "
                f"probe posts" + (f" (M = {self.harmonics - 1}: {self.rows[-2]['estimate_rad']:.3g} rad)"
                                  if len(self.rows) > 1 else ""))

    def summary(self) -> dict[str, Any]:
        """The choice as JSON: the stage, the tolerance and its unit, what was chosen, the estimate, why."""
        return {"stage": "library", "tolerance_rad": self.tolerance_rad, "chose": {"harmonics": self.harmonics},
                "estimate_rad": self.estimate_rad, "why": self.why,
                "estimate": f"{STEP_SAFETY:g} x the largest zero-order phase change to M - 2 or M - 4 over the "
                            f"probe posts (|t|^2 >= {T_FLOOR:g})",
                "rows": [dict(r) for r in self.rows],
                "probes": [{"wx_um": a, "wy_um": b, "wavelength_um": w} for a, b, w in self.probes],
                "seconds": self.seconds, "sweep_seconds_expected": self.sweep_seconds}

    def lines(self) -> list[str]:
        """What ``metafovea library --tolerance-rad`` prints."""
        out = [f"harmonics chosen for a phase error of {self.tolerance_rad:g} rad: {self.why}; chosen in "
               f"{self.seconds:.1f} s" + (f", the sweep ~{self.sweep_seconds:.0f} s" if self.sweep_seconds else "")]
        out += ["  M   to M-2 (rad)  to M-4 (rad)  estimate (rad)  s per post"]
        out += [f"  {r['harmonics']:<3d} {r['step_rad']:12.3g}  {r['step4_rad']:12.3g}  {r['estimate_rad']:14.3g}  "
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
        for M in range(MIN_CHOICE_HARMONICS - 4, top + 1):
            t1 = time.perf_counter()
            ts[M] = np.ravel(post_response(pr[:, 0], pr[:, 1], pr[:, 2], harmonics=M, **kw).t_x)
            per_post = (time.perf_counter() - t1) / len(pr)
            if M < MIN_CHOICE_HARMONICS:
                continue
            used = np.abs(ts[M]) ** 2 >= T_FLOOR
            s2, s4 = (float(np.max(np.abs(np.angle(ts[M][used] / ts[M - k][used])), initial=0.0)) for k in (2, 4))
            rows.append({"harmonics": M, "step_rad": s2, "step4_rad": s4, "estimate_rad": STEP_SAFETY * max(s2, s4),
                         "seconds_per_post": per_post})
            if rows[-1]["estimate_rad"] <= tol:
                break
    last = rows[-1]
    if last["estimate_rad"] > tol:
        raise InputError("tolerance_rad", tolerance_rad, f"a phase error the probe posts reach by M = {top} "
                         f"(estimate there {last['estimate_rad']:.2g} rad)")
    chosen = replace(opts, harmonics=last["harmonics"])
    expected = _expected_seconds(_checked_sweep(sweep.widths_um, None, sweep.wavelengths, chosen),
                                 _workers(chosen.workers))
    return HarmonicsChoice(tol, last["harmonics"], last["estimate_rad"], max(last["step_rad"], last["step4_rad"]),
                           tuple(rows),
                           tuple(tuple(float(v) for v in p) for p in pr), time.perf_counter() - t0, expected)


def _workers(workers: int | None) -> int:
    from metafovea.parallel import default_workers

    return workers or default_workers()
