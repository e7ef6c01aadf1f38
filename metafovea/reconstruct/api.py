"""The top-level :func:`reconstruct` dispatcher."""

from __future__ import annotations

from typing import Any

import numpy as np

from metafovea.errors import InputError, check_choice
from metafovea.reconstruct.result import Reconstruction

METHODS = ("lsq", "alternating", "dip", "snapshot")


def reconstruct(frames: Any, alpha: Any = None, method: str = "lsq", *, fpn: Any = None,
                calibration: Any = None, **kw: Any) -> Reconstruction:
    """Separate the foveal and perifoveal images from ``frames (T, H, W)``.

    method: ``'lsq'`` (known ``alpha``), ``'alternating'`` (unknown alpha, classical), ``'dip'``
    (double deep image prior, JAX), ``'snapshot'`` (one frame).
    fpn: ``None`` (no FPN handling), an ``(H, W)`` array to subtract, ``'calibration'`` (estimate from
    ``calibration`` frames) or ``'prior'`` (low-rank prior on the separated images).
    Other keywords go to the method's function; the foveal constraint ``D x1 = foveal_gain C x2 +
    foveal_offset`` (keywords ``scale``, ``foveal_gain``, ``foveal_offset``; a Measurement's
    ``meta['foveal_constraint']``) is used by alternating, dip, snapshot and the FPN prior.
    """
    from metafovea.reconstruct.alternating import alternating
    from metafovea.reconstruct.fpn import estimate_fpn
    from metafovea.reconstruct.lsq import lsq_known_alpha
    from metafovea.reconstruct.snapshot import snapshot

    method = check_choice("method", method, METHODS)
    # the foveal constraint, kept for the FPN prior (lsq below drops these keywords)
    geo = {k: kw[k] for k in ("scale", "foveal_gain", "foveal_offset") if k in kw}
    f = None
    finfo: dict[str, Any] = {}
    fpn_kw = dict(kw.pop("fpn_kw", None) or {})
    if isinstance(fpn, str):
        mode = check_choice("fpn", fpn, ("calibration", "prior"))
        if mode == "calibration":
            if calibration is None:
                raise InputError("calibration", None, "calibration frames (T, H, W) when fpn='calibration'")
            f, finfo = estimate_fpn(calibration=calibration, **fpn_kw)
    elif fpn is not None:
        f = np.asarray(fpn, dtype=np.float64)
        finfo = {"identified": "given"}
    if f is not None:
        fr = np.asarray(frames)
        if fr.shape[-2:] != f.shape:
            raise InputError("fpn", f"array of shape {f.shape}", f"the frames' (H, W) = {fr.shape[-2:]}")
        frames = (fr - f).astype(fr.dtype if fr.dtype in (np.float32, np.float64) else np.float64)
    if method == "lsq":
        if alpha is None:
            raise InputError("alpha", None, "mixing ratios (T,) for method='lsq'; use method='alternating' or 'dip' "
                             "when they are unknown")
        kw = {k: v for k, v in kw.items() if k not in ("scale", "foveal_gain", "foveal_offset")}
        rec = lsq_known_alpha(frames, alpha, **kw)
    elif method == "alternating":
        if alpha is not None:
            raise InputError("alpha", "given", "alpha=None for method='alternating' (use method='lsq' with known alpha)")
        rec = alternating(frames, **kw)
    elif method == "dip":
        from metafovea.reconstruct.deep_prior import dip

        rec = dip(frames, alpha=alpha, **kw)
    else:
        fr = np.asarray(frames)
        if fr.ndim == 3:
            if fr.shape[0] != 1:
                raise InputError("frames", f"{fr.shape[0]} frames", "exactly one frame for method='snapshot'")
            fr = fr[0]
        a = None if alpha is None else float(np.ravel(alpha)[0])
        rec = snapshot(fr, alpha=a, **kw)
    if isinstance(fpn, str) and fpn.lower() == "prior":
        f, finfo = estimate_fpn(x1=rec.x1, x2=rec.x2, **{**geo, **fpn_kw})
        rec = Reconstruction(x1=(rec.x1 - f).astype(rec.x1.dtype), x2=(rec.x2 - f).astype(rec.x2.dtype),
                             alpha=rec.alpha, fpn=f, method=rec.method, timings=rec.timings,
                             info={**rec.info, "fpn": finfo})
    elif f is not None:
        rec = Reconstruction(x1=rec.x1, x2=rec.x2, alpha=rec.alpha, fpn=f, method=rec.method,
                             timings=rec.timings, info={**rec.info, "fpn": finfo})
    return rec
