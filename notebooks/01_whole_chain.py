# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # The whole chain at small size
#
# design -> scatterer library (RCWA posts) -> a layout patch -> PSF report -> a simulated measurement ->
# reconstruction, with the library functions the CLI calls. `METAFOVEA_NOTEBOOK_SMALL=1` (what the test sets)
# shrinks the sizes further; outputs go to a temporary folder unless `METAFOVEA_NOTEBOOK_OUT` names one.
# Open as a notebook with `jupytext --to notebook notebooks/01_whole_chain.py` (outputs are not committed).

# %%
import os
import tempfile
from dataclasses import replace
from pathlib import Path

from matplotlib.figure import Figure

import metafovea as mf
from metafovea.layout.export import ExportOptions, export_file
from metafovea.layout.tiling import load_spec
from metafovea.optics.report import psf_report
from metafovea.plotting import iron_colormap
from metafovea.report import fig_to_png

SMALL = os.environ.get("METAFOVEA_NOTEBOOK_SMALL") == "1"
OUT = Path(os.environ.get("METAFOVEA_NOTEBOOK_OUT") or tempfile.mkdtemp(prefix="metafovea-nb01-"))
OUT.mkdir(parents=True, exist_ok=True)
system = mf.SystemDesign.paper()
system = replace(system, sensor=replace(system.sensor, crop=(64, 64) if SMALL else (128, 128)))
print("output folder:", OUT)

# %% [markdown]
# ## 1. Design: both lenses' numbers

# %%
for lens in (system.foveal, system.perifoveal):
    s = mf.summarize(lens)
    print(mf.format_summary(s).splitlines()[0])
    print(f"  NA {lens.na:.4f}, posts {s.posts_in_aperture:,}")

# %% [markdown]
# ## 2. Scatterer library: the two birefringent post sets (RCWA, cached after the first run)

# %%
posts, library = mf.platform_post_sets(system.platform)
for pol, ps in posts.items():
    first = [tuple(round(float(v), 2) for v in w) for w in ps.widths_um][:3]
    print(f"focuses {pol}: {len(ps.widths_um)} posts, widths (um) {first} ...")

# %% [markdown]
# ## 3. A layout patch of the foveal lens (GDSII, 0.2 mm wide at the rim), checked by reading it back

# %%
r_mm = system.foveal.diameter_mm / 2 - 0.2
spec = load_spec(system.foveal, posts["x"], patch_mm=(r_mm, 0.0, 0.1 if SMALL else 0.2))
res = export_file(spec, OUT / "foveal_patch.gds", "gds", ExportOptions(force=True))
print({k: res[k] for k in ("path", "posts") if k in res})

# %% [markdown]
# ## 4. PSF report of the perifoveal lens (on axis, the 10 um filter, few wavelengths)

# %%
rep = psf_report(system.perifoveal, OUT / "psf", fields_deg=[0.0], filter_um=(10.0, 0.5),
                 n_wavelengths=3 if SMALL else 9, post_set=posts["y"], relay_magnification=system.relay_magnification)
print(sorted(rep)[:10])

# %% [markdown]
# ## 5. A measurement of the Siemens star through the camera, then its reconstruction
#
# Known alpha (least squares) and unknown alpha (alternating minimisation with the foveal gauge).

# %%
# closed-shutter frames let the reconstruction remove the fixed-pattern noise (10 % of the scene's range)
m = mf.simulate(system, "siemens-star", frames=12 if SMALL else 24, rng=0, posts=posts, filter_enabled=True,
                calibration_frames=16)
print(m.summary())
for method in ("lsq", "alternating"):
    r = mf.reconstruct_measurement(m, method, fpn="calibration",
                                   solver={"strict": False} if method == "alternating" else None)
    print(f"{method:12s} PSNR x1 {r.metrics['psnr_x1']:.2f} dB, x2 {r.metrics['psnr_x2']:.2f} dB, "
          f"{r.seconds * 1e3:.1f} ms")
    assert r.metrics["psnr_x2"] > 20.0

# %%
fig = Figure(figsize=(9, 3))
for ax, img, title in zip(fig.subplots(1, 3), (m.frames[0], r.x1s[0], r.x2s[0]),
                          ("measured frame", "foveal (reconstructed)", "perifoveal (reconstructed)")):
    ax.imshow(img, cmap=iron_colormap())
    ax.set_title(title, fontsize=9)
    ax.set_axis_off()
(OUT / "reconstruction.png").write_bytes(fig_to_png(fig))
print("wrote", OUT / "reconstruction.png")
