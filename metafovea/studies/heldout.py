"""The PSF-aware reconstruction judged on held-out generated scenes: what ``benchmarks/bench_generalise.py`` runs
per case.

A case (:class:`HeldOutCase`) is a scene of :mod:`metafovea.imaging.generator` (``gen:KIND:SEED``, test seeds)
simulated as a user records it (:func:`simulate_case`: :data:`CASE_FRAMES` frames and
:data:`CASE_CALIBRATION_FRAMES` closed-shutter frames through a system design, one band: the whole 8-14 um or the
narrow filter, one NETD); :func:`score_psf_aware` then estimates the fixed pattern from the shutter frames
(:func:`~metafovea.reconstruct.fpn.estimate_fpn`, its estimated error counted as noise), runs each PSF-aware
method of :func:`~metafovea.reconstruct.deconvolve.deconvolve_measurement` on that one measurement and scores
both channels against the scene beside the linear Wiener bound (:func:`~metafovea.reconstruct.metrics.
wiener_bound`, computed once per measurement). :func:`run_case` is both, for a process pool.
:func:`~metafovea.reconstruct.metrics.margin_summary` summarises the margins over a set of cases.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from metafovea.config import SystemDesign, load_system
from metafovea.measurement import Measurement

#: frames of a case's recording and its closed-shutter frames: a user's 4 s recording at 12 frames/s and the shutter
#: frames ``metafovea simulate`` writes by default
CASE_FRAMES = 48
CASE_CALIBRATION_FRAMES = 16
#: the channels, in the order of a Deconvolution's ``scene`` (x1, x2)
CHANNELS = ("foveal", "perifoveal")


@dataclass(frozen=True)
class HeldOutCase:
    """One case: ``scene`` (a name, ``gen:KIND:SEED``), the band (``filter_enabled``), the NETD (K; None: the
    system's), the frames, the simulation's seed and its PSF provider (``'auto'``: the lenses' optics, as a user's
    ``metafovea simulate``; ``'airy'`` for a fast check)."""

    scene: str
    filter_enabled: bool
    netd_k: float | None = None
    frames: int = CASE_FRAMES
    calibration_frames: int = CASE_CALIBRATION_FRAMES
    seed: int = 0
    psf: str = "auto"


def simulate_case(system: SystemDesign, case: HeldOutCase) -> Measurement:
    """The case's recording, as ``metafovea simulate`` makes it (known alpha, shutter frames in ``calibration``).

    Parameters
    ----------
    system : SystemDesign
    case : HeldOutCase

    Returns
    -------
    Measurement
        With the scene truth (``scene_x1``, ``scene_x2``) the scores need.
    """
    from metafovea.imaging.simulate import simulate

    return simulate(system, case.scene, frames=case.frames, calibration_frames=case.calibration_frames,
                    filter_enabled=case.filter_enabled, netd_k=case.netd_k, psf=case.psf, rng=case.seed)


def score_psf_aware(m: Measurement, methods: Sequence[str] | None = None,
                    options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Each PSF-aware method on one measurement, both channels against the scene and the Wiener bound.

    Parameters
    ----------
    m : Measurement
        Static, with known alpha, closed-shutter frames (``calibration``) and the scene truth.
    methods : sequence of str, optional
        Names passed to :func:`~metafovea.reconstruct.deconvolve.deconvolve_measurement` as ``method``, unchanged;
        None: one run with its default method.
    options : dict, optional
        Further keyword arguments of every method's run (e.g. ``{"wavelet": "db2"}``), passed unchanged.

    Returns
    -------
    dict
        ``fpn_error_dn`` (the pattern's estimated rms error, DN), ``bound_seconds`` and ``rows``: per method and
        channel ``method``, ``channel`` (:data:`CHANNELS`), ``psnr_db``, ``bound_db`` (the Wiener bound's PSNR),
        ``margin_db`` (their difference), ``hazy_db`` (the noise-free sensor image's PSNR against the scene) and
        ``seconds`` (the method alone: the bound's time left out).
    """
    from metafovea.reconstruct.deconvolve import deconvolve_measurement
    from metafovea.reconstruct.fpn import estimate_fpn
    from metafovea.reconstruct.metrics import psnr

    fpn, info = estimate_fpn(calibration=m.extras["calibration"])
    fe = float(info.get("error_rms_dn") or 0.0)
    truth = m.scene_truth
    out: dict[str, Any] = {"fpn_error_dn": fe, "rows": []}
    ref = None  # (bound, hazy) PSNRs per channel, from the first method's scores
    for method in ([None] if methods is None else list(methods)):
        kw = dict(options or {}) if method is None else {**(options or {}), "method": method}
        t0 = time.perf_counter()
        d = deconvolve_measurement(m, fpn=fpn, fpn_error_dn=fe, score_truth=ref is None, **kw)
        seconds = time.perf_counter() - t0
        if ref is None:
            sc = d.info["scores"]
            seconds -= sc["wiener_bound_seconds"]
            out["bound_seconds"] = sc["wiener_bound_seconds"]
            ref = [(sc[f"wiener_bound_psnr_x{i}"], sc.get(f"psnr_x{i}_hazy_image")) for i in (1, 2)]
        name = method if method is not None else str(d.info.get("method", "default"))
        for i, channel in enumerate(CHANNELS):
            p = psnr(d.scene[i], truth[i])
            out["rows"].append({"method": name, "channel": channel, "psnr_db": p, "bound_db": ref[i][0],
                                "margin_db": p - ref[i][0], "hazy_db": ref[i][1], "seconds": seconds})
    return out


def run_case(system: SystemDesign | str | Path, case: HeldOutCase, methods: Sequence[str] | None = None, *,
             threads: int | None = None, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """:func:`simulate_case` then :func:`score_psf_aware`: a process pool's task.

    Parameters
    ----------
    system : SystemDesign, str or Path
        A design or its TOML file.
    case : HeldOutCase
    methods, options : optional
        As :func:`score_psf_aware`.
    threads : int, optional
        BLAS threads inside the case (1 when the cases run one per core); None: the library's.

    Returns
    -------
    dict
        The case's fields, ``simulate_seconds`` and :func:`score_psf_aware`'s result.
    """
    return simulate_and_score(system, case, lambda m: score_psf_aware(m, methods, options), threads=threads)


def simulate_and_score(system: SystemDesign | str | Path, case: HeldOutCase,
                       score: Callable[[Measurement], dict[str, Any]], *, threads: int | None = None) -> dict[str, Any]:
    """:func:`simulate_case` then ``score`` of the recording, with ``threads`` BLAS threads (None: the library's):
    the case's fields, ``simulate_seconds`` and the score's entries (the body of every study's ``run_case``)."""
    import contextlib

    from metafovea.parallel import blas_threads

    design = system if isinstance(system, SystemDesign) else load_system(system)
    with blas_threads(threads) if threads else contextlib.nullcontext():
        t0 = time.perf_counter()
        m = simulate_case(design, case)
        sim_s = time.perf_counter() - t0
        res = score(m)
    return {**asdict(case), "simulate_seconds": sim_s, **res}
