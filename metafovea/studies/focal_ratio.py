"""``metafovea study focal-ratio``: the foveal expansion f1/f2 from 2 to 8 at a fixed foveal lens (paper point 1).

Each case is the paper's camera with the perifoveal lens at ``f2 = f1 / k`` (F/1 kept, RCWA posts, the optical
train of both wafers) and a picture of fixed angular size: it spans the perifoveal field at the largest expansion,
so the foveal channel sees the same part of it at every k while the perifoveal one sees more of it as k grows (its
texture grows). 10 frames with varying alpha (a free-running polariser: alpha unknown to the solver) are separated
by the unknown-alpha solver (alternating minimisation with the foveal gauge, as the camera must) and, as the
reference, by least squares with the true alpha; PSNR of both images is averaged over the scenes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from metafovea.studies.common import (
    FILTER,
    Stopwatch,
    StudyOptions,
    StudyResult,
    camera,
    figure,
    machine,
    measure,
    rounded,
    sweep,
)

NAME = "focal-ratio"
FULL = {"expansions": [2, 3, 4, 5, 6, 7, 8], "scenes": ["astronaut", "camera", "coffee"], "crop": [290, 290],
        "frames": 10}
FAST = {"expansions": [2, 5, 8], "scenes": ["camera"], "crop": [64, 64], "frames": 10}
METHODS = ("alternating", "lsq")


def _texture(img: np.ndarray) -> float:
    """Mean gradient magnitude over the image's range: how much structure a channel's truth holds per pixel."""
    g = np.hypot(*np.gradient(np.asarray(img, dtype=np.float64)))
    return float(g.mean() / max(float(np.ptp(img)), 1e-12))


def run_case(item: dict[str, Any]) -> dict[str, Any]:
    """One expansion and scene: simulate, separate both ways, score (a task of the sweep)."""
    from metafovea.imaging.channel import channels_for
    from metafovea.imaging.scene import SceneGeometry, image_scene
    from metafovea.reconstruct import reconstruct_measurement

    system = item["system"]
    fovea_half = channels_for(system)[0].half_fov_rad[1]
    # the picture spans the perifoveal field of the largest expansion: a fixed angular size for every k
    scene = image_scene(item["scene"], SceneGeometry(fov_rad=2 * fovea_half * item["k_max"], expansion=item["k"]))
    meas, fpn = measure(system, scene, item["frames"], item["seed"], item["psf"])
    out: dict[str, Any] = {"k": item["k"], "scene": item["scene"], "texture_x1": _texture(meas.truth_x1),
                           "texture_x2": _texture(meas.truth_x2), "psf": meas.meta["psf"]["provider"]}
    for method in METHODS:
        solver = {"strict": False} if method == "alternating" else None
        r = reconstruct_measurement(meas, method, window=meas.shape[0], fpn=fpn, solver=solver)
        out[method] = {k: r.metrics[k] for k in ("psnr_x1", "psnr_x2", "ssim_x1", "ssim_x2")}
        if r.alpha_mae is not None:
            out[method]["alpha_mae"] = r.alpha_mae
        out[method]["seconds"] = r.seconds
    return out


def _summary(cases: list[dict[str, Any]], ks: list[int]) -> dict[str, Any]:
    by_k = {}
    for k in ks:
        cs = [c for c in cases if c["k"] == k]
        by_k[str(k)] = {m: {q: float(np.mean([c[m][q] for c in cs])) for q in ("psnr_x1", "psnr_x2", "ssim_x1",
                                                                               "ssim_x2")} for m in METHODS}
        by_k[str(k)]["texture_x2"] = float(np.mean([c["texture_x2"] for c in cs]))
        by_k[str(k)]["texture_x1"] = float(np.mean([c["texture_x1"] for c in cs]))
    return by_k


def _trend(by_k: dict[str, Any], ks: list[int]) -> dict[str, Any]:
    p1 = np.array([by_k[str(k)]["alternating"]["psnr_x1"] for k in ks])
    p2 = np.array([by_k[str(k)]["alternating"]["psnr_x2"] for k in ks])
    s1 = float(np.polyfit(ks, p1, 1)[0])
    s2 = float(np.polyfit(ks, p2, 1)[0])
    flat = abs(s1) * (ks[-1] - ks[0]) < 1.5
    falls = s2 < 0
    return {"expected": "foveal PSNR nearly flat over f1/f2 = 2..8, perifoveal PSNR falling",
            "observed": f"foveal slope {s1:+.2f} dB per unit of f1/f2 (change {s1 * (ks[-1] - ks[0]):+.2f} dB), "
                        f"perifoveal slope {s2:+.2f} dB per unit",
            "holds": bool(flat and falls), "foveal_slope_db": s1, "perifoveal_slope_db": s2,
            "note": "unknown-alpha (alternating) reconstruction; 'flat' means a change under 1.5 dB over the range."
                    + ("" if falls else " The perifoveal PSNR does not fall here: these solvers separate pixel by "
                       "pixel (alternating adds only the foveal gauge), so their error is the sensor noise through "
                       "the 2 x 2 separation and does not grow with texture, while the PSNR's peak (the truth's "
                       "range) grows as the perifoveal field takes in more of the picture. The paper's fall comes "
                       "with its deep-prior reconstruction, whose error grows with the texture it must represent.")}


def _figure(by_k: dict[str, Any], ks: list[int], trend: dict[str, Any]) -> bytes:
    from metafovea.report import fig_to_png

    fig, ax = figure(1, 2, (11, 4))
    for m, style in (("alternating", "o-"), ("lsq", "s--")):
        label = "unknown alpha" if m == "alternating" else "known alpha (reference)"
        ax[0, 0].plot(ks, [by_k[str(k)][m]["psnr_x1"] for k in ks], style, color="tab:red", label=f"foveal, {label}")
        ax[0, 0].plot(ks, [by_k[str(k)][m]["psnr_x2"] for k in ks], style, color="tab:blue",
                      label=f"perifoveal, {label}")
    ax[0, 0].set_xlabel("foveal expansion f1 / f2")
    ax[0, 0].set_ylabel("PSNR (dB)")
    ax[0, 0].legend(fontsize=8)
    ax[0, 0].set_title("PSNR of both reconstructions (mean over scenes)", fontsize=10)
    ax[0, 1].plot(ks, [by_k[str(k)]["texture_x2"] for k in ks], "o-", color="tab:blue", label="perifoveal truth")
    ax[0, 1].plot(ks, [by_k[str(k)]["texture_x1"] for k in ks], "o-", color="tab:red", label="foveal truth")
    ax[0, 1].set_xlabel("foveal expansion f1 / f2")
    ax[0, 1].set_ylabel("mean |gradient| / range (1/px)")
    ax[0, 1].set_title("texture per pixel of each channel", fontsize=10)
    ax[0, 1].legend(fontsize=8)
    return fig_to_png(fig)


def run(options: StudyOptions) -> StudyResult:
    sw = Stopwatch()
    p = FAST if options.fast else FULL
    ks = list(p["expansions"])
    items = [{"system": camera(options, p["crop"], k), "k": k, "k_max": max(ks), "scene": s, "frames": p["frames"],
              "seed": options.seed, "psf": options.psf} for k in ks for s in p["scenes"]]
    with sw("sweep"):
        cases = sweep(run_case, items, options, "focal-ratio cases")
    by_k = _summary(cases, ks)
    trend = _trend(by_k, ks)
    rows = [[k, by_k[str(k)]["alternating"]["psnr_x1"], by_k[str(k)]["alternating"]["psnr_x2"],
             by_k[str(k)]["lsq"]["psnr_x1"], by_k[str(k)]["lsq"]["psnr_x2"], by_k[str(k)]["texture_x2"]] for k in ks]
    timing = {"seconds_total": sw.total(), **{f"seconds_{k}": v for k, v in sw.seconds.items()}, **machine(),
              "workers": options.workers}
    return StudyResult(
        name=NAME, title="foveal expansion f1/f2",
        modelled=f"The paper's camera (RCWA posts, both wafers' optical train, 10 um filter, NETD and FPN corrected "
                 f"from shutter frames) with the perifoveal lens at f2 = f1/k, D2 = f2 for k in {ks}; "
                 f"{p['frames']} frames of a free-running polariser on {len(p['scenes'])} scikit-image picture(s) "
                 f"({', '.join(p['scenes'])}) of fixed angular size, crop {p['crop'][0]} x {p['crop'][1]}; "
                 f"separated without alpha (alternating, foveal gauge) and with it (least squares).",
        why="A fixed foveal lens keeps the foveal view identical; keeping the perifoveal lens at F/1 keeps its "
            "blur and radiometry, so only its field (and the texture per pixel it must separate) changes with k. "
            "The picture's angular size is fixed so that a larger k shows more of it to the perifoveal channel, "
            "as a real scene would." + (" --fast: one scene, three expansions, a 64 x 64 crop." if options.fast
                                        else ""),
        paper="PSNR of the foveal reconstruction nearly flat over f1/f2 = 2..8; the perifoveal one falls with the "
              "expansion because its texture grows.",
        parameters={**p, "seed": options.seed, "filter": FILTER, "polarizer": "free-running (alpha unknown)",
                    "psf": sorted({c["psf"] for c in cases})},
        results=rounded({"by_expansion": by_k, "cases": [{k: v for k, v in c.items()
                                                          if k not in ("psf",)} for c in cases]}),
        trend=rounded(trend), figure=_figure(by_k, ks, trend),
        caption="PSNR against f1/f2 (left) and the texture per pixel of each channel's truth (right)",
        tables=[{"caption": "mean PSNR over the scenes (dB) and the perifoveal texture",
                 "header": ["f1/f2", "foveal, unknown alpha", "perifoveal, unknown alpha", "foveal, known alpha",
                            "perifoveal, known alpha", "perifoveal texture (1/px)"], "rows": rows}],
        timing=timing)
