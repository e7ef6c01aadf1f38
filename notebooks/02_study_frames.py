# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Study: frames per window on a moving scene
#
# The paper's point 2 (`metafovea study frames`): the waving hand through the camera, reconstructed with windows
# of 4 to 24 frames. Too few frames leave the channels mixed (alpha cannot be identified), too many blur the
# motion. `METAFOVEA_NOTEBOOK_SMALL=1` (what the test sets) runs the study's `--fast` size.

# %%
import os
import tempfile
from pathlib import Path

from metafovea.studies import StudyOptions, run_study

SMALL = os.environ.get("METAFOVEA_NOTEBOOK_SMALL") == "1"
OUT = Path(os.environ.get("METAFOVEA_NOTEBOOK_OUT") or tempfile.mkdtemp(prefix="metafovea-nb02-")) / "frames"
res = run_study("frames", StudyOptions(fast=SMALL, seed=0), OUT, force=True)
print(res.modelled)

# %% [markdown]
# ## The numbers: PSNR against the scene at each output's time

# %%
print(f"{'frames':>6} {'foveal':>8} {'perifoveal':>10} {'alpha error':>11}")
for r in res.results["windows"]:
    a = r["alternating"]
    print(f"{r['window']:>6} {a['psnr_x1']:>8.2f} {a['psnr_x2']:>10.2f} {a['alpha_mae']:>11.4f}")
print("paper:", res.trend["expected"])
print("here: ", res.trend["observed"], "->", "holds" if res.trend["holds"] else "differs")

# %% [markdown]
# ## The figure (also in the study's HTML page)

# %%
try:  # inside Jupyter; run as a plain script (the test) it only names the files
    from IPython.display import Image, display

    display(Image(res.figure))
except ImportError:
    pass
print("files:", ", ".join(str(p) for p in res.files.values()))
