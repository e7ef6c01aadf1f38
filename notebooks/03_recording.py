# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A camera recording, end to end: 16-bit TIFF stack -> import -> foveal and perifoveal videos in kelvin
#
# The recipe of the README's "Reconstructing a real recording", with the library functions `metafovea import`
# and `metafovea reconstruct` call. Here the recording comes from the simulator: the paper's camera (both
# metalenses, the rotating polariser, NETD noise, 14-bit ADC) filming the waving hand, written as a camera would
# write it: a 16-bit TIFF stack with the frame times and the polariser's encoder angles in its description, plus
# two recordings of a blackbody filling the field (20 and 50 C) for the two-point calibration. With a real
# camera, start at step 2 with its files.
#
# `METAFOVEA_NOTEBOOK_SMALL=1` (what the test sets) shrinks the sizes; outputs go to a temporary folder unless
# `METAFOVEA_NOTEBOOK_OUT` names one. Open as a notebook with `jupytext --to notebook notebooks/03_recording.py`.

# %%
import os
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import tifffile
from matplotlib.figure import Figure

import metafovea as mf
from metafovea.imaging.scene import make_scene
from metafovea.plotting import iron_colormap
from metafovea.reconstruct.deconvolve import temperatures
from metafovea.recordings import ImportOptions, import_recording
from metafovea.report import fig_to_png

SMALL = os.environ.get("METAFOVEA_NOTEBOOK_SMALL") == "1"
OUT = Path(os.environ.get("METAFOVEA_NOTEBOOK_OUT") or tempfile.mkdtemp(prefix="metafovea-nb03-"))
OUT.mkdir(parents=True, exist_ok=True)
system = mf.SystemDesign.paper()
system = replace(system, sensor=replace(system.sensor, crop=(64, 64) if SMALL else (128, 128)))
FRAMES = 24 if SMALL else 48
print("output folder:", OUT)

# %% [markdown]
# ## 1. The camera's files: the recording and two blackbody recordings, 16-bit TIFF stacks
#
# The simulator's frames are in DN of a 14-bit ADC; a camera writes them as 16-bit integers. The fixed-pattern
# noise is left out (`fpn_amplitude=0`): a camera's own non-uniformity correction has removed it, and the
# blackbody recordings could not share the simulator's scene-dependent pattern. The frame times (s) and the
# polariser angles (rad) go into the TIFF's JSON description, one value per frame.

# %%
sim = dict(posts="ideal", fpn_amplitude=0.0)  # ideal posts: a quick PSF; "rcwa" (default) is the fabricated lens
m_true = mf.simulate(system, "hand", frames=FRAMES, rng=0, **sim)
rec = OUT / "rec.tif"
tifffile.imwrite(rec, np.round(m_true.frames).astype(np.uint16), photometric="minisblack",
                 metadata={"times_s": m_true.times_s.tolist(), "theta_rad": m_true.extras["theta_rad"].tolist()})
blackbody = {}
for t_k, seed in ((293.15, 1), (323.15, 2)):  # 12 frames = 2 polariser turns: both channels seen equally
    bb = mf.simulate(system, make_scene("uniform", temperature_k=t_k), frames=12, rng=seed, **sim)
    blackbody[t_k] = OUT / f"bb_{t_k:.2f}K.tif"
    tifffile.imwrite(blackbody[t_k], np.round(bb.frames).astype(np.uint16), photometric="minisblack")
print(f"{rec.name}: {m_true.frames.shape} uint16, {m_true.times_s[-1]:.2f} s; blackbodies:",
      ", ".join(p.name for p in blackbody.values()))

# %% [markdown]
# ## 2. Import: times and polariser from the file, counts to kelvin through the two blackbodies
#
# `--foveal-gain` is the channels' flat-field ratio `G_1 / G_2` (for this camera `(NA_1 / NA_2)^2` times the
# trains' throughputs: 0.294, what `metafovea simulate` prints), `--scale` the focal-length ratio; with them the
# blackbody's gain over both channels is split into each channel's, and the foveal constraint fixes the gauge of
# the unknown-alpha reconstruction.

# %%
fc = m_true.meta["foveal_constraint"]
opts = ImportOptions(times="times_s", polarizer_key="theta_rad", polarizer_unit="rad",
                     calibration=f"two-point:293.15={blackbody[293.15]},323.15={blackbody[323.15]}",
                     band_um=(8.0, 14.0), foveal_gain=round(fc["gain"], 3), scale=fc["scale"])
meas_path, summary = import_recording(rec, OUT / "rec.npz", opts, force=True)
print({k: summary[k] for k in ("frames", "shape", "times_from", "frame_rate_hz", "n_dropped", "uniform_timing",
                               "alpha_known", "theta_rad", "units")})
print("calibration:", summary["calibration"], "warnings:", summary["warnings"])
m = mf.Measurement.load(meas_path)
print("DN per K at 300 K:", {k: round(v, 2) for k, v in m.meta["dn_per_k_300K"].items()},
      "(the simulator's camera:", {k: round(v, 2) for k, v in m_true.meta["dn_per_k_300K"].items()}, ")")

# %% [markdown]
# ## 3. Separate the channels, alpha unknown, over sliding 8-frame windows: foveal and perifoveal videos

# %%
step = 4
r = mf.reconstruct_measurement(m, "alternating", window=8, stride=step, solver={"strict": False},
                               score_truth=False)
print(f"{len(r.x1s)} windows of 8 frames, every {step} frames; {r.seconds:.2f} s")

# %% [markdown]
# ## 4. In kelvin, against the scene the simulator filmed
#
# `temperatures` applies the file's calibration (`dark_dn`, each channel's DN per kelvin, the band's radiance).
# The truth is the simulator's noise-free channel images in the same units; the difference is the separation's
# noise, what the 8-frame window blurs of the moving hand, and the calibration: temperatures come from absolute
# radiance, so a 1 % error in a channel's gain is 0.65 K at 300 K (`L / (dL/dT)` = 65 K in 8-14 um). At full
# size (128 x 128, 48 frames) this run gave DN per K within 1 % of the simulator's camera, foveal median error
# +1.1 K (RMS 1.6 K), perifoveal +0.55 K (RMS 0.67 K).

# %%
foveal_k, perifoveal_k = temperatures((np.asarray(r.x1s), np.asarray(r.x2s)), m.meta["dark_dn"], m.meta)
centre = np.array([(a + b) // 2 for a, b in r.spans])  # each window's middle frame
tx1 = m_true.truth_x1 if m_true.truth_x1.ndim == 3 else np.broadcast_to(m_true.truth_x1, m_true.frames.shape)
tx2 = m_true.truth_x2 if m_true.truth_x2.ndim == 3 else np.broadcast_to(m_true.truth_x2, m_true.frames.shape)
true1, true2 = temperatures((tx1[centre], tx2[centre]), m_true.meta["dark_dn"], m_true.meta)
for name, got, ref in (("foveal", foveal_k, true1), ("perifoveal", perifoveal_k, true2)):
    err = got - ref
    print(f"{name:10s} {got.min():.1f}-{got.max():.1f} K, median error {np.median(err):+.2f} K, "
          f"RMS {np.sqrt(np.mean(err ** 2)):.2f} K")
    assert np.all(np.isfinite(got)) and 250.0 < np.median(got) < 350.0
tifffile.imwrite(OUT / "foveal_K.tif", foveal_k.astype(np.float32))
tifffile.imwrite(OUT / "perifoveal_K.tif", perifoveal_k.astype(np.float32))

# %%
picks = np.unique(np.linspace(0, len(centre) - 1, 4).round().astype(int))
fig = Figure(figsize=(2.6 * len(picks) + 1.0, 5.4), layout="constrained")
axs = fig.subplots(2, len(picks), squeeze=False)
for row, (name, video) in enumerate((("foveal", foveal_k), ("perifoveal", perifoveal_k))):
    lo, hi = np.percentile(video, [0.5, 99.5])
    for ax, i in zip(axs[row], picks):
        im = ax.imshow(video[i], cmap=iron_colormap(), vmin=lo, vmax=hi)
        ax.set_title(f"{name}, t = {m.times_s[centre[i]]:.2f} s", fontsize=8)
        ax.set_axis_off()
    fig.colorbar(im, ax=axs[row].tolist(), label="temperature (K)", shrink=0.9)
(OUT / "videos_kelvin.png").write_bytes(fig_to_png(fig))
print("wrote", OUT / "videos_kelvin.png", "and the videos foveal_K.tif, perifoveal_K.tif (K, float32)")
