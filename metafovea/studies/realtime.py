"""``metafovea study realtime``: least squares with known alpha against the unknown-alpha solver on the same video
(paper point 7): speed (output frames per second, one output per frame from sliding windows of 8) and error.

The paper's reference: 40 frames/s at 275 x 280 pixels with known alpha. The full run uses that crop; ``--fast``
a small one, and the page gives the speed scaled to 275 x 280 by the pixel count (both solvers are per-pixel, so
their cost is linear in pixels: the scaled number is an estimate and says so). Both methods run one after the
other in this process (not through the executor): concurrent tasks would share the cores and bias the speeds.
Speeds live in the JSON's ``timing`` key (machine-dependent); errors in ``results``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from metafovea.studies.common import FILTER, Stopwatch, StudyOptions, StudyResult, figure, machine, rounded, simulated

NAME = "realtime"
PAPER_FPS, PAPER_SHAPE = 40.0, (275, 280)
FULL = {"frames": 96, "crop": [275, 280], "scene": "hand", "window": 8, "alternating_stride": 1}
FAST = {"frames": 24, "crop": [64, 64], "scene": "hand", "window": 8, "alternating_stride": 1}
METHODS = ("lsq", "alternating")


def _figure(speed: dict[str, Any], err: dict[str, Any]) -> bytes:
    from metafovea.report import fig_to_png

    fig, ax = figure(1, 2, (11, 4))
    names = ["known alpha\n(least squares)", "unknown alpha\n(alternating)"]
    fps = [speed[m]["fps_at_275x280"] for m in METHODS]
    ax[0, 0].bar(names, fps, color=["tab:green", "tab:purple"])
    ax[0, 0].axhline(PAPER_FPS, color="k", ls="--", label="paper: 40 frames/s at 275 x 280")
    ax[0, 0].set_yscale("log")
    ax[0, 0].set_ylabel("output frames/s at 275 x 280")
    ax[0, 0].legend(fontsize=8)
    x = range(len(METHODS))
    ax[0, 1].bar([i - 0.2 for i in x], [err[m]["psnr_x1"] for m in METHODS], 0.4, label="foveal", color="tab:red")
    ax[0, 1].bar([i + 0.2 for i in x], [err[m]["psnr_x2"] for m in METHODS], 0.4, label="perifoveal",
                 color="tab:blue")
    ax[0, 1].set_xticks(list(x), names)
    ax[0, 1].set_ylabel("PSNR against the window's truth (dB)")
    ax[0, 1].legend(fontsize=8)
    return fig_to_png(fig)


def run(options: StudyOptions) -> StudyResult:
    from metafovea.reconstruct import reconstruct_measurement
    from metafovea.reconstruct.metrics import score

    sw = Stopwatch()
    p = FAST if options.fast else FULL
    meas, fpn = simulated(options, p, sw, FILTER)
    H, W = meas.shape[1:]
    err: dict[str, Any] = {}
    speed: dict[str, Any] = {}
    for method in METHODS:
        solver = {"strict": False} if method == "alternating" else None
        stride = 1 if method == "lsq" else p["alternating_stride"]
        reconstruct_measurement(meas, method, window=p["window"], stride=stride, fpn=fpn, solver=solver,
                                score_truth=False)  # warm-up: imports and first-call costs out of the timing
        r = reconstruct_measurement(meas, method, window=p["window"], stride=stride, fpn=fpn, solver=solver,
                                    score_truth=False)
        # each output against its window's mean truth, PSNR peak: the channel's range over the whole sequence (a
        # window where the hand is outside the small foveal field has a near-uniform truth of its own)
        t1, t2 = meas.truth_over(r.spans)
        sc = {**score((r.x1s, r.x2s), t1, None, float(np.ptp(meas.truth_x1))),
              **score((r.x1s, r.x2s), None, t2, float(np.ptp(meas.truth_x2)))}
        err[method] = {"psnr_x1": sc["psnr_x1"], "psnr_x2": sc["psnr_x2"], "ssim_x1": sc["ssim_x1"],
                       "ssim_x2": sc["ssim_x2"], "alpha_mae": r.alpha_mae, "outputs": r.outputs}
        fps = r.outputs / max(r.seconds, 1e-9)
        speed[method] = {"seconds": r.seconds, "outputs": r.outputs, "fps": fps,
                         "fps_at_275x280": fps * H * W / (PAPER_SHAPE[0] * PAPER_SHAPE[1])}
    d1 = err["alternating"]["psnr_x1"] - err["lsq"]["psnr_x1"]
    d2 = err["alternating"]["psnr_x2"] - err["lsq"]["psnr_x2"]
    trend = {"expected": "known-alpha least squares is real-time (40 frames/s at 275 x 280); the unknown-alpha "
                         "solver is slower at a similar error",
             "observed": f"unknown alpha against known alpha: foveal {d1:+.2f} dB, perifoveal {d2:+.2f} dB, alpha "
                         f"error {err['alternating']['alpha_mae']:.2g} (speeds: the timing key)",
             "holds": bool(d1 > -3.0 and d2 > -3.0), "psnr_difference_db": {"x1": d1, "x2": d2},
             "note": "the error half of the comparison ('similar': within 3 dB); whether the speed reaches the "
                     "paper's 40 frames/s is in timing.speed_holds, since it depends on the machine"}
    lsq_fps = speed["lsq"]["fps_at_275x280"]
    timing = {"seconds_total": sw.total(), **{f"seconds_{k}": v for k, v in sw.seconds.items()},
              "speed": speed, "speed_holds": bool(lsq_fps >= PAPER_FPS),
              "speed_note": ("measured at 275 x 280" if (H, W) == PAPER_SHAPE else
                             f"measured at {H} x {W}; fps_at_275x280 scales it by the pixel count (an estimate)"),
              **machine()}
    rows = [[("known alpha (least squares)" if m == "lsq" else "unknown alpha (alternating)"), speed[m]["fps"],
             speed[m]["fps_at_275x280"], err[m]["psnr_x1"], err[m]["psnr_x2"], err[m]["alpha_mae"]] for m in METHODS]
    return StudyResult(
        name=NAME, title="real-time reconstruction: speed against error",
        modelled=f"The waving hand, {p['frames']} frames (12 frames/s, free-running 2 Hz polariser), crop {H} x {W}, "
                 f"the paper's camera (RCWA posts, optical train, 10 um filter, FPN from shutter frames); sliding "
                 f"windows of {p['window']} frames, one output per frame, by least squares with the true alpha and by "
                 f"the unknown-alpha solver (alternating, foveal gauge, polariser model), each timed after a "
                 f"warm-up run, one thread.",
        why="The same video and windows for both solvers make their speeds and errors compare; one output per "
            "frame is what a live display needs." + (" --fast: 24 frames on a 64 x 64 crop; the speed at 275 x 280 "
                                                     "is scaled by the pixel count." if options.fast else ""),
        paper="Least squares with known alpha runs in real time: 40 frames/s at 275 x 280 pixels.",
        parameters={**p, "seed": options.seed, "filter": FILTER, "psf": meas.meta["psf"]["provider"]},
        results=rounded({"error": err}), trend=rounded(trend), figure=_figure(speed, err),
        caption="Output frames per second at 275 x 280 against the paper's 40 (left, log scale) and PSNR (right)",
        tables=[{"caption": "speed (this run's machine) and error",
                 "header": ["method", "frames/s", "frames/s at 275 x 280", "PSNR x1 (dB)", "PSNR x2 (dB)",
                            "alpha error"], "rows": rows}],
        timing=rounded(timing))
