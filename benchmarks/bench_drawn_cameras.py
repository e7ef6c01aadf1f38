"""Issue 30 on cameras drawn at random within its ranges (not the grid's corners): the reconstruction of each
recording of the independent forward model (``tests/independent/forward.py``) with unknown alpha, scored against
the truth it never reads.

    python benchmarks/bench_drawn_cameras.py [--cameras 30] [--first 100] [--json PATH]

Camera ``k`` (seeded by ``k``): each deviation of the issue's list is present with probability 0.35, drawn
uniformly within its range (jitter 0-2 deg rms, rate +-5 %, extinction 1-5 %, tau 0-12 ms, fixed pattern 0-8 DN
with a drift to 0-4 DN, vignetting 0-20 %, 0.1 % bad pixels, foveal scale +-3 %, centre +-3 px per axis, rotation
+-0.5 deg, gain ratio +-10 %, defocus 0-1/4 wave); a scene of the model's six; 280 x 290, 256 x 320 or 300 x 300
pixels of 17 or 24 um; 8-14 um or the 10 um filter (30 %); 24 or 36 frames; the file states only the schema's keys
(the polariser's rate and mode; not its extinction or lag). Per camera, the whole recording as one window:

* alpha's MAE against the truth, its stated standard error and whether it is called identified;
* what alpha's gauge leaves uncertain in the images (``images_gauge_se``) against the images' true error from it
  (least squares on the estimated alpha against least squares on the true alpha);
* each image's PSNR against the noise-free truth, minus the oracle's (least squares on the true alpha).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.measurement import Measurement
from metafovea.reconstruct import reconstruct_measurement

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_real_recordings import F  # the independent forward model (tests/independent), loaded once


def draw(k: int) -> tuple[str, Any, Any, int]:
    """Camera ``k``: ``(scene, deviations, camera, frames)``."""
    rng = np.random.default_rng(k)

    def u(lo: float, hi: float) -> float:
        return float(rng.uniform(lo, hi))

    pick = rng.random(16) < 0.35
    vals = dict(jitter_deg=u(0, 2), rate_error=u(-.05, .05), extinction=u(.01, .05), tau_s=u(0, .012),
                fpn_dn=u(0, 8), fpn_drift_dn=u(0, 4), vignetting=u(0, .2), bad_pixels=0.001,
                scale_error=u(-.03, .03), centre_px=(u(-3, 3), u(-3, 3)), rotation_deg=u(-.5, .5),
                gain_ratio_error=u(-.1, .1), defocus_waves=u(0, .25))
    chosen = {key: v for (key, v), p in zip(vals.items(), pick) if p}
    scene = str(rng.choice(sorted(F.SCENES)))
    cam = F.Camera(shape=tuple(int(v) for v in rng.choice([(280, 290), (256, 320), (300, 300)])),
                   pixel_pitch_um=float(rng.choice([17.0, 24.0])),
                   filter_um=(9.5, 10.5) if rng.random() < 0.3 else None)
    return scene, F.Deviations(**chosen), cam, int(rng.choice([24, 36]))


def psnr(est: np.ndarray, ref: np.ndarray, ok: np.ndarray) -> float:
    ref = ref.astype(np.float64)
    m = ok & np.isfinite(est)
    mse = float(np.mean((est[m].astype(np.float64) - ref[m]) ** 2))
    return float(10 * np.log10(float(ref[ok].max() - ref[ok].min()) ** 2 / mse))


def run_camera(k: int, folder: Path) -> dict[str, Any]:
    scene, dev, cam, frames = draw(k)
    rec = F.record(scene, dev, cam, frames=frames, seed=k)
    path = rec.write(folder / f"camera{k}.npz")
    m = Measurement.load(path)
    ok = np.ones(m.shape[1:], dtype=bool)
    for y, x in rec.truth["bad_pixels"]["dead"] + rec.truth["bad_pixels"]["saturated"]:
        ok[y, x] = False
    row: dict[str, Any] = {"camera": k, "scene": scene, "shape": list(cam.shape), "pixel_um": cam.pixel_pitch_um,
                           "band": "10 um filter" if cam.filter_um else "8-14 um", "frames": frames,
                           "deviations": {key: (list(v) if isinstance(v, tuple) else v)
                                          for key, v in dev.changed.items()}}
    t0 = time.perf_counter()
    try:
        res = reconstruct_measurement(m, "alternating", window=frames, stride=frames, score_truth=False)
    except Exception as e:  # noqa: BLE001 - a refusal or a crash is a result, reported with its message
        row.update(status=type(e).__name__, message=str(e).splitlines()[0][:300])
        path.unlink()
        return row
    row["seconds"] = time.perf_counter() - t0
    s, rc = res.summary(), res.reconstruction
    a = np.asarray(rc.alpha, dtype=np.float64)
    oracle = reconstruct_measurement(m, "lsq", window=frames, stride=frames, score_truth=False).reconstruction
    on_est = reconstruct_measurement(replace(m, alpha=np.clip(a, 0, 1)), "lsq", window=frames, stride=frames,
                                     score_truth=False).reconstruction
    row.update(status="ok", alpha_mae=float(np.mean(np.abs(a - m.alpha))), alpha_se_max=s.get("alpha_se_max"),
               identified=s.get("alpha_identified"), images_gauge_se=s.get("images_gauge_se"),
               calibration_applied=(s.get("calibration") or {}).get("applied"), warnings=s.get("warnings") or [])
    row["image_error"] = [float(np.sqrt(np.nanmean(((np.asarray(getattr(on_est, c), np.float64)
                                                     - np.asarray(getattr(oracle, c), np.float64))[ok]) ** 2)))
                          for c in ("x1", "x2")]
    row["db_vs_oracle"] = [psnr(np.asarray(getattr(rc, c)), getattr(m, "truth_" + c), ok)
                           - psnr(np.asarray(getattr(oracle, c)), getattr(m, "truth_" + c), ok) for c in ("x1", "x2")]
    path.unlink()
    return row


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rows if r["status"] == "ok"]
    ratio = [e / s for r in ok if r["images_gauge_se"] for e, s in zip(r["image_error"], r["images_gauge_se"])]
    ident = [r for r in ok if r["identified"]]
    return {"cameras": len(rows), "refused or crashed": len(rows) - len(ok),
            "alpha MAE <= 2e-3": sum(r["alpha_mae"] <= 2e-3 for r in ok),
            "alpha MAE <= 5e-3": sum(r["alpha_mae"] <= 5e-3 for r in ok),
            "worst alpha MAE": max((r["alpha_mae"] for r in ok), default=None),
            "identified": len(ident),
            "identified with MAE > its stated standard error x 2": sum(r["alpha_mae"] > 2 * r["alpha_se_max"]
                                                                       for r in ident),
            "images' true gauge error / stated, largest": max(ratio, default=None),
            "images within 1 dB of the oracle (both)": sum(min(r["db_vs_oracle"]) >= -1.0 for r in ok),
            "median dB vs oracle (x1, x2)": [float(np.median([r["db_vs_oracle"][i] for r in ok])) for i in (0, 1)]
            if ok else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=30)
    ap.add_argument("--first", type=int, default=100, help="the first camera's seed")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    logging.disable(logging.WARNING)
    load0 = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.first, a.first + a.cameras):
            r = run_camera(k, Path(tmp))
            rows.append(r)
            if r["status"] != "ok":
                print(f"camera {k} ({r['scene']}): {r['status']}: {r['message']}", flush=True)
                continue
            print(f"camera {k} ({r['scene']}, {len(r['deviations'])} deviations): alpha MAE {r['alpha_mae']:.1e} "
                  f"(stated se {r['alpha_se_max']:.1e}, identified {r['identified']}); images' gauge error "
                  f"{r['image_error'][0]:.3g} / {r['image_error'][1]:.3g} (stated {r['images_gauge_se'][0]:.3g} / "
                  f"{r['images_gauge_se'][1]:.3g}); dB vs oracle {r['db_vs_oracle'][0]:+.1f} / "
                  f"{r['db_vs_oracle'][1]:+.1f}", flush=True)
    s = summary(rows)
    s["load"] = [load0, os.getloadavg()[0]]
    print(json.dumps(s, indent=1))
    if a.json:
        a.json.write_text(json.dumps({"summary": s, "rows": rows}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
