"""The paper's studies as functions (``metafovea study NAME``): each simulates the camera through the real chain
(RCWA posts, both lenses' optical trains, the sensor), reconstructs, and writes a figure, its numbers as JSON and
an HTML page that says what was modelled, why, and how the outcome compares with the paper.

Files:

- ``common``: :class:`StudyOptions`, :class:`StudyResult`, the camera a study varies (:func:`camera`), the sweep
  through the project's executor (:func:`sweep`) and the output files (:func:`write_study`).
- ``focal_ratio``: foveal expansion f1/f2 = 2..8 at a fixed foveal lens: PSNR of both reconstructions.
- ``frames``: frames per window 4..24 on the waving-hand video: too few mix the channels, too many blur motion.
- ``realtime``: known-alpha least squares against the unknown-alpha solver on one video: frames/s and error.
- ``resolution``: Siemens star at 9:1: contrast against line pairs per pixel, intensity along circles.
- ``gallery``: the paper's scene types, with and without the 10 um filter.
- ``ablation``: each component of the multi-frame and snapshot reconstructions removed in turn (one measurement).
- ``heldout``: one case of the held-out generated scenes (``benchmarks/bench_generalise.py``): simulated as a user
  records it, the PSF-aware methods scored against the scene and the Wiener bound (not a ``metafovea study``).

Use :func:`run_study` (``run_study('frames', StudyOptions(fast=True), out_dir)``); :data:`STUDIES` names them.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from metafovea.errors import InputError
from metafovea.studies.common import StudyOptions, StudyResult, write_study

#: study name (the CLI's word) -> (module under metafovea.studies, one line)
STUDIES: dict[str, tuple[str, str]] = {
    "focal-ratio": ("focal_ratio", "foveal expansion f1/f2 from 2 to 8: PSNR of both reconstructions (paper point 1)"),
    "frames": ("frames", "4 to 24 frames per window on the waving hand at 2 Hz / 12 fps (paper point 2)"),
    "realtime": ("realtime", "least squares with known alpha against the unknown-alpha solver: frames/s and error "
                             "(paper point 7)"),
    "compare": ("compare", "at equal sensor: this system against two lenses side by side, Risley-prism shifts and "
                           "single-image super-resolution (paper point 3)"),
    "resolution": ("resolution", "Siemens star at 9:1, contrast against line pairs per pixel (paper point 4)"),
    "transients": ("transients", "heater on/off (5, 10, 20 s): time series at three points against the truth "
                                 "(paper point 6)"),
    "gallery": ("gallery", "the paper's scene types simulated and reconstructed, with and without the filter "
                           "(paper point 8)"),
    "ablation": ("ablation", "each reconstruction component removed in turn: multi-frame (alpha initialisation, "
                             "exclusion loss, deep prior vs TV vs none, warm/random start, FPN) and snapshot "
                             "(n1 = D^T y, exclusion loss, deep prior) (paper point 5)"),
}

__all__ = ["STUDIES", "StudyOptions", "StudyResult", "run_study", "write_study", "study_module"]


def study_module(name: str):
    """The module of study ``name`` (an :class:`InputError` naming the studies for an unknown one)."""
    key = str(name).strip().lower()
    if key not in STUDIES:
        raise InputError("study", name, "one of " + ", ".join(STUDIES))
    return importlib.import_module(f"metafovea.studies.{STUDIES[key][0]}")


def run_study(name: str, options: StudyOptions | None = None, out_dir: str | Path | None = None, *,
              force: bool = False) -> StudyResult:
    """Run study ``name`` and, with ``out_dir``, write its files there (checked before the run starts)."""
    from metafovea.io import prepare_output

    mod = study_module(name)
    if out_dir is not None:
        prepare_output(out_dir, force, is_dir=True)
    res = mod.run(options or StudyOptions())
    if out_dir is not None:
        res.files = write_study(res, out_dir, force=True)
    return res
