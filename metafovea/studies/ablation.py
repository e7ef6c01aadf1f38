"""``metafovea study ablation``: what each component of the reconstruction contributes (paper point 5).

One static scene (the sunlit rooftop: an HVAC grille in the fovea) through the paper's camera (RCWA posts, both
wafers' optical train, NETD noise, low-rank FPN, a free-running 2 Hz polariser so that alpha is unknown, 12
frames/s, 10 um filter). Every row is a real reconstruction of that one measurement, scored (PSNR, SSIM of both
images; alpha error where alpha is estimated) against the simulator's noise-free images and against the row's
*full method*, from which it removes one component:

Multi-frame (all frames one window). Full method: the double deep image prior (two skip-U-Nets) warm-started
from the classical unknown-alpha estimate (alternating: subspace alpha, polariser/foveal gauge, TV prior; its
alpha held), TV and exclusion terms in the DIP loss, FPN from the shutter frames subtracted. Rows: alpha from the
frame means (the paper's initialisation) instead of the classical estimate; alpha not initialised (random);
no exclusion loss; the TV prior alone (the classical estimate: no deep prior); no prior at all (least squares in
the fixed gauge); the paper's random network start (alpha held from the classical estimate); FPN not removed.
A single deep prior (one network for both images) is not ablated: :func:`metafovea.reconstruct.dip` has no such
switch.

Snapshot (the one frame whose alpha is nearest 0.5, with that alpha). Full method: the paper's snapshot separation
(``separation='paper'``: ``n1 = D^T y`` initialisation, foveal term, TV, exclusion loss) refined by the double
deep prior fitted to the frame (warm start from the snapshot, its alpha held, the foveal term in the loss). Rows: the
unseparated frame as start (``init='frame'``) instead of ``n1 = D^T y``; no exclusion loss (snapshot and DIP); no
deep prior.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from metafovea.measurement import FovealConstraint, Measurement
from metafovea.studies.common import (
    FILTER,
    Stopwatch,
    StudyOptions,
    StudyResult,
    figure,
    machine,
    rounded,
    simulated,
    sweep,
)

if TYPE_CHECKING:
    from metafovea.reconstruct.result import Reconstruction

NAME = "ablation"
#: DIP step budgets: ``warm_steps`` after a warm start (the default stopping rule may end it earlier),
#: ``random_steps`` for the paper's random start; ``channels`` per network (the DIP's default 16)
FULL = {"scene": "rooftop", "crop": [96, 96], "frames": 12, "warm_steps": 500, "random_steps": 2000, "channels": 16}
FAST = {"scene": "rooftop", "crop": [64, 64], "frames": 12, "warm_steps": 30, "random_steps": 60, "channels": 16}
QUANTITIES = ("psnr_x1", "ssim_x1", "psnr_x2", "ssim_x2")

#: multi-frame rows: key -> (label, the component removed or replaced)
MULTI: dict[str, tuple[str, str]] = {
    "full": ("full: double DIP from the classical estimate, TV + exclusion, FPN removed", "none"),
    "alpha_frame_means": ("alpha from frame means (the paper's init) instead of the classical estimate",
                          "initialisation"),
    "alpha_random": ("alpha not initialised (random, seeded)", "initialisation"),
    "no_exclusion": ("no exclusion loss", "exclusion loss"),
    "tv_only": ("TV prior alone (classical alternating): no deep prior", "deep prior"),
    "no_prior": ("no prior (least squares in the fixed gauge)", "deep prior and TV"),
    "random_start": ("the paper's random network start (alpha held from the classical estimate)", "warm start"),
    "fpn_off": ("FPN not removed", "FPN estimation"),
}
#: snapshot rows
SNAP: dict[str, tuple[str, str]] = {
    "full": ("full: snapshot (n1 = D^T y, TV, exclusion) + deep prior", "none"),
    "init_frame": ("start from the unseparated frame instead of n1 = D^T y", "initialisation"),
    "no_exclusion": ("no exclusion loss (snapshot and DIP)", "exclusion loss"),
    "no_deep_prior": ("no deep prior (the snapshot separation alone)", "deep prior"),
}


def _row(key: str, labels: dict[str, tuple[str, str]], metrics: dict[str, float], alpha_mae: float | None,
         info: dict[str, Any] | None, seconds: float) -> dict[str, Any]:
    info = info or {}
    return {"variant": key, "label": labels[key][0], "removed": labels[key][1],
            **{q: float(metrics[q]) for q in QUANTITIES}, "alpha_mae": alpha_mae,
            "dip_steps_run": info.get("steps_run"), "dip_stopped": info.get("stopped"),
            "dip_tv_weight": info.get("tv_weight"), "seconds": seconds}


def run_multi(item: dict[str, Any]) -> dict[str, Any]:
    """One multi-frame variant (a task of the sweep)."""
    from metafovea.reconstruct import reconstruct_measurement
    from metafovea.reconstruct.alternating import frame_mean_alpha

    meas, key, p, seed = item["measurement"], item["key"], item["p"], item["seed"]
    T = meas.shape[0]
    fpn = item["fpn"] if key != "fpn_off" else "none"
    dip = {"steps": p["warm_steps"], "rng": seed, "channels": p["channels"], "init": "classical"}
    if key in ("tv_only", "no_prior"):
        method, solver = "alternating", {"strict": False, **({"prior": None} if key == "no_prior" else {})}
    else:
        method, solver = "dip", dict(dip)
        if key == "alpha_frame_means":  # least-squares start with the paper's alpha (learned at lr / 10)
            solver.update(init="lsq", alpha_init=frame_mean_alpha(np.asarray(meas.frames, np.float64)))
        elif key == "alpha_random":
            solver.update(init="lsq", alpha_init=np.random.default_rng(seed).uniform(0.0, 1.0, T))
        elif key == "no_exclusion":
            solver.update(exclusion_weight=0.0)
        elif key == "random_start":
            solver.update(init="random", alpha_init="classical", steps=p["random_steps"])
    r = reconstruct_measurement(meas, method, window=T, fpn=fpn, solver=solver)
    info = r.reconstruction.info if method == "dip" else None
    return _row(key, MULTI, r.metrics, r.alpha_mae, info, r.seconds) | {
        "images": (np.asarray(r.reconstruction.x1, np.float32), np.asarray(r.reconstruction.x2, np.float32))}


def _snapshot_dip(y: np.ndarray, a: float, start: tuple[np.ndarray, np.ndarray], fc: FovealConstraint,
                  p: dict[str, Any], seed: int, exclusion: bool) -> Reconstruction:
    """The double deep prior fitted to one frame (given twice: :func:`~metafovea.reconstruct.dip` needs two frames;
    the loss, a mean over frames, is the one frame's), warm-started from ``start``, alpha held, the foveal term
    on (weight 1, as the snapshot's)."""
    from metafovea.reconstruct import dip

    kw = {} if exclusion else {"exclusion_weight": 0.0}
    return dip(np.stack([y, y]).astype(np.float32), alpha=np.array([a, a]), init=start, steps=p["warm_steps"],
               rng=seed, channels=p["channels"], foveal_weight=1.0, **fc.as_kwargs(), **kw)


def run_snapshot(item: dict[str, Any]) -> dict[str, Any]:
    """One snapshot variant (a task of the sweep)."""
    import time

    from metafovea.reconstruct import reconstruct_measurement
    from metafovea.reconstruct.metrics import score

    meas, key, p, seed, k = item["measurement"], item["key"], item["p"], item["seed"], item["frame"]
    t0 = time.perf_counter()
    solver = {"init": "frame"} if key == "init_frame" else {"exclusion_weight": 0.0} if key == "no_exclusion" else {}
    # the paper's loss (its initialisation and exclusion term are what is ablated), not the default separation
    r = reconstruct_measurement(meas, "snapshot", frame=k, fpn=item["fpn"], solver={**solver, "separation": "paper"})
    x1, x2 = (np.asarray(v, np.float64) for v in (r.reconstruction.x1, r.reconstruction.x2))
    metrics, info = r.metrics, None
    if key != "no_deep_prior":
        y = np.asarray(meas.frames[k], np.float64) - item["fpn"]
        d = _snapshot_dip(y, float(meas.alpha[k]), (x1, x2), meas.foveal_constraint, p, seed, key != "no_exclusion")
        x1, x2, info = np.asarray(d.x1, np.float64), np.asarray(d.x2, np.float64), d.info
        metrics = score((x1, x2), meas.truth_x1, meas.truth_x2)
    return _row(key, SNAP, metrics, None, info, time.perf_counter() - t0) | {
        "images": (x1.astype(np.float32), x2.astype(np.float32))}


def start_evidence(multi: list[dict[str, Any]], meas: Measurement) -> dict[str, float]:
    """How far the warm-started DIP (the full row) moves from the TV prior alone (the classical estimate it starts
    from, alpha held), against that estimate's own error and the DIP's: RMS differences in DN per image."""
    full, tv = (next(r for r in multi if r["variant"] == k) for k in ("full", "tv_only"))
    out: dict[str, float] = {}
    for i, (name, truth) in enumerate((("x1", meas.truth_x1), ("x2", meas.truth_x2))):
        f, s, t = (np.asarray(v, np.float64) for v in (full["images"][i], tv["images"][i], truth))
        out[f"rms_dip_minus_tv_{name}"] = float(np.sqrt(np.mean((f - s) ** 2)))
        out[f"rms_error_tv_{name}"] = float(np.sqrt(np.mean((s - t) ** 2)))
        out[f"rms_error_dip_{name}"] = float(np.sqrt(np.mean((f - t) ** 2)))
    return out


def _deltas(rows: list[dict[str, Any]]) -> None:
    """Each row's PSNR/SSIM minus the full method's (negative: the component helps)."""
    full = rows[0]
    for r in rows:
        for q in QUANTITIES:
            r[f"delta_{q}"] = r[q] - full[q]


def _helps(row: dict[str, Any], tol_db: float) -> bool:
    """Removing the component lowers the mean PSNR of both images by more than ``tol_db``."""
    return 0.5 * (row["delta_psnr_x1"] + row["delta_psnr_x2"]) < -tol_db


def _trend(multi: list[dict[str, Any]], snap: list[dict[str, Any]], ev: dict[str, float], fast: bool) -> dict[str, Any]:
    tol = 0.1
    verdict = {f"multi-frame {r['variant']}": _helps(r, tol) for r in multi[1:]}
    verdict.update({f"snapshot {r['variant']}": _helps(r, tol) for r in snap[1:]})
    helps = [k for k, v in verdict.items() if v]
    not_helps = [k for k, v in verdict.items() if not v]

    def d(rows: list[dict[str, Any]], key: str) -> str:
        r = next(x for x in rows if x["variant"] == key)
        return f"{r['delta_psnr_x1']:+.2f} / {r['delta_psnr_x2']:+.2f} dB"

    tv, none = (next(x for x in multi if x["variant"] == k) for k in ("tv_only", "no_prior"))
    full, rs = multi[0], next(x for x in multi if x["variant"] == "random_start")
    full_tv = (tv["delta_psnr_x1"], tv["delta_psnr_x2"])

    return {"expected": "each component helps: removing any one lowers the reconstruction's quality (the paper's "
                        "ablation)",
            "observed": f"{len(helps)} of {len(verdict)} removals lower the mean PSNR of both images by more than "
                        f"{tol} dB; they do not for: {', '.join(not_helps) or 'none'}",
            "holds": not not_helps, "component_helps": verdict,
            "note": "Change of foveal / perifoveal PSNR against the full method when one component is removed: "
                    f"multi-frame FPN {d(multi, 'fpn_off')}, frame-mean alpha {d(multi, 'alpha_frame_means')}, "
                    f"random alpha {d(multi, 'alpha_random')}, exclusion {d(multi, 'no_exclusion')}, deep prior "
                    f"(TV alone) {d(multi, 'tv_only')}, every prior {d(multi, 'no_prior')}, warm start (random "
                    f"network start) {d(multi, 'random_start')}; snapshot init {d(snap, 'init_frame')}, exclusion "
                    f"{d(snap, 'no_exclusion')}, deep prior {d(snap, 'no_deep_prior')}. "
                    "Frame-mean alpha: the brighter frames are labelled foveal, but the foveal channel (F/2) is the "
                    "darker one (foveal gain ~0.29 against the F/1 perifoveal channel), so the start is the swapped "
                    "mixture, which the DIP loss (blind to alpha's gauge) keeps. The deep prior warm-started from "
                    "the classical estimate keeps that estimate's level (its residual parameterisation cannot move "
                    f"it) and its alpha (alternating's, held: passed to the loss as data): in {full['dip_steps_run']} "
                    f"steps its images moved {ev['rms_dip_minus_tv_x1']:.3g} / {ev['rms_dip_minus_tv_x2']:.3g} DN RMS "
                    f"from the TV prior alone's, against that estimate's own error of {ev['rms_error_tv_x1']:.3g} / "
                    f"{ev['rms_error_tv_x2']:.3g} DN RMS (the DIP's: {ev['rms_error_dip_x1']:.3g} / "
                    f"{ev['rms_error_dip_x2']:.3g} DN), so what the deep prior adds to TV is "
                    f"{-full_tv[0]:+.2f} / {-full_tv[1]:+.2f} dB. The random network start's TV weight is the DIP's "
                    f"data-driven default ({rs['dip_tv_weight']:.3g}). Measured against each other, the TV "
                    f"prior beats no prior by {tv['psnr_x1'] - none['psnr_x1']:+.2f} / "
                    f"{tv['psnr_x2'] - none['psnr_x2']:+.2f} dB." + (
                        " --fast: DIP step budgets of a few tens of steps; the random network start is far from "
                        "converged (it needs ~1,000 steps at 64 x 64), so its row shows the budget, not the method."
                        if fast else "")}


def _figure(multi: list[dict[str, Any]], snap: list[dict[str, Any]], meas: Measurement) -> bytes:
    from metafovea.plotting import iron_colormap
    from metafovea.report import fig_to_png

    fig, ax = figure(2, 4, (17, 8))
    for row, (rows, title) in enumerate(((multi, "multi-frame"), (snap, "snapshot"))):
        y = np.arange(len(rows))
        a = ax[row, 0]
        a.barh(y - 0.2, [r["psnr_x1"] for r in rows], 0.4, color="tab:red", label="foveal")
        a.barh(y + 0.2, [r["psnr_x2"] for r in rows], 0.4, color="tab:blue", label="perifoveal")
        a.set_yticks(y)
        a.set_yticklabels([r["variant"] for r in rows], fontsize=8)
        a.invert_yaxis()
        a.set_xlabel("PSNR (dB)")
        a.set_title(f"{title}: PSNR per variant", fontsize=9)
        a.legend(fontsize=7)
        cmap = iron_colormap()
        truth1 = np.asarray(meas.truth_x1, np.float64)
        lo, hi = np.percentile(truth1, [0.5, 99.5])
        worst = min(rows[1:], key=lambda r: r["psnr_x1"])
        for c, (img, name) in enumerate(((truth1, "foveal truth"), (rows[0]["images"][0], "foveal, full"),
                                         (worst["images"][0], f"foveal, {worst['variant']}")), start=1):
            im = ax[row, c].imshow(np.asarray(img), cmap=cmap, vmin=lo, vmax=max(hi, lo + 1e-9),
                                   interpolation="nearest")
            cb = fig.colorbar(im, ax=ax[row, c], fraction=0.046, pad=0.03)
            cb.set_label("DN", fontsize=7)
            cb.ax.tick_params(labelsize=6)
            ax[row, c].set_title(f"{title}: {name}", fontsize=9)
            ax[row, c].set_axis_off()
    return fig_to_png(fig)


def _table(rows: list[dict[str, Any]], alpha: bool) -> list[list[Any]]:
    return [[r["label"], r["psnr_x1"], r["ssim_x1"], r["psnr_x2"], r["ssim_x2"], r["delta_psnr_x1"],
             r["delta_psnr_x2"]] + ([r["alpha_mae"]] if alpha else []) + [r["dip_steps_run"] or "-"] for r in rows]


def run(options: StudyOptions) -> StudyResult:
    sw = Stopwatch()
    p = FAST if options.fast else FULL
    meas, fpn = simulated(options, p, sw, FILTER)
    frame = int(np.argmin(np.abs(np.asarray(meas.alpha) - 0.5)))
    base = {"measurement": meas, "fpn": fpn, "p": p, "seed": options.seed, "frame": frame}
    with sw("multi_frame"):
        multi = sweep(run_multi, [{**base, "key": k} for k in MULTI], options, "ablation: multi-frame variants")
    with sw("snapshot"):
        snap = sweep(run_snapshot, [{**base, "key": k} for k in SNAP], options, "ablation: snapshot variants")
    for rows in (multi, snap):
        _deltas(rows)
    fig = _figure(multi, snap, meas)
    seconds = {f"{kind} {r['variant']}": r.pop("seconds") for kind, rows in (("multi", multi), ("snapshot", snap))
               for r in rows}
    evidence = start_evidence(multi, meas)
    for r in multi + snap:
        r.pop("images")
    trend = _trend(multi, snap, evidence, options.fast)
    header = ["variant", "foveal PSNR", "foveal SSIM", "perifoveal PSNR", "perifoveal SSIM", "d foveal PSNR",
              "d perifoveal PSNR"]
    return StudyResult(
        name=NAME, title="ablation of the reconstruction's components",
        modelled=f"The rooftop scene, {p['frames']} frames at 12 frames/s (a 2 Hz free-running polariser, alpha "
                 f"unknown to the multi-frame solvers), crop {p['crop'][0]} x {p['crop'][1]}, the paper's camera "
                 f"(RCWA posts, optical train, 10 um filter, NETD noise, low-rank FPN removed with the shutter "
                 f"frames' estimate). Multi-frame (all {p['frames']} frames, one window), full method: the double "
                 f"DIP ({p['channels']} channels per network, depth 3) warm-started from the classical unknown-alpha "
                 f"estimate, its alpha held, TV and exclusion weights 0.001, at most {p['warm_steps']} Adam steps "
                 f"(the DIP's stopping rule may end it earlier); each other row removes or replaces one component: "
                 f"alpha from the frame means (the paper's initialisation) or random instead of the classical "
                 f"estimate (least-squares start, alpha learned), no exclusion loss, the TV prior alone (no deep "
                 f"prior), no prior, the paper's random network start ({p['random_steps']} steps at most; its TV "
                 f"weight the DIP's default for a random start, from the data by a MAP rule), FPN not "
                 f"removed. Snapshot (frame {frame}, alpha {float(meas.alpha[frame]):.3f}, given): full method = the "
                 f"snapshot separation (n1 = D^T y start, foveal term, TV, exclusion) refined by the double DIP on "
                 f"that frame (warm start, alpha held, foveal term weight 1, {p['warm_steps']} steps at most); rows: "
                 f"the unseparated frame as start, no exclusion loss, no deep prior. Not ablated: a single deep "
                 f"prior (one network for both images): the DIP in metafovea.reconstruct has no such switch.",
        why="One measurement for every row, so that the differences are the components' and not the noise's. The "
            "full method is the toolkit's best version of the paper's: the DIP from a random start with alpha from "
            "the frame means converges to the swapped channels in this camera (the foveal F/2 channel is the darker "
            "one), and a random start needs ~1,000-1,500 steps (20-40 ms each at 64 x 64 on 2 cores), so the deep "
            "prior is warm-started from the classical estimate, and the paper's initialisation and random start are "
            "rows of their own. The snapshot's deep prior is the same double DIP fitted to the one frame (given "
            "twice: the DIP takes at least two frames; the mean over identical frames is the one frame's loss) with "
            "the foveal term, because metafovea's snapshot solver has a TV prior, not a deep one. Sizes: "
            + ("--fast: 64 x 64, DIP budgets of 30 (warm) and 60 (random start) steps, to run in about a minute on "
               "2 cores; the random-start row is then far from converged." if options.fast else
               "96 x 96 (a 290 x 290 DIP step takes ~0.7 s on the 2-core machine: 2,000 steps would be ~25 minutes "
               "per row), 500 warm / 2,000 random-start steps at most (the DIP's default budget), the paper's "
               "window of 12 frames."),
        paper="Each component of the reconstruction helps: in the multi-frame solver the initialisation from frame "
              "means, the exclusion loss, the double deep image prior (against a single prior and against TV) and "
              "the FPN estimation; in the snapshot solver the initialisation n1 = D^T y, the exclusion loss and the "
              "deep prior.",
        parameters={**p, "seed": options.seed, "filter": FILTER, "snapshot_frame": frame,
                    "snapshot_alpha": float(meas.alpha[frame]), "psf": meas.meta["psf"]["provider"],
                    "not_ablated": "single deep prior (no switch in metafovea.reconstruct.dip)"},
        results=rounded({"multi_frame": multi, "snapshot": snap, "warm_start_evidence": evidence}),
        trend=rounded(trend), figure=fig,
        caption="PSNR of both images per variant (left; top multi-frame, bottom snapshot), the foveal truth, the "
                "full method's foveal image and the foveal image of the variant with the lowest foveal PSNR",
        tables=[{"caption": "Multi-frame: PSNR (dB) / SSIM against the noise-free images, change against the full "
                            "method (d), alpha mean absolute error, DIP steps run",
                 "header": header + ["alpha error", "DIP steps"], "rows": _table(multi, True)},
                {"caption": "Snapshot (one frame, its alpha given): PSNR (dB) / SSIM, change against the full "
                            "method, DIP steps run",
                 "header": header + ["DIP steps"], "rows": _table(snap, False)}],
        timing={"seconds_total": sw.total(), **{f"seconds_{k}": v for k, v in sw.seconds.items()},
                "reconstruct_seconds": seconds, **machine(), "workers": options.workers})
