"""`metafovea library`: compute (or load from cache) the RCWA post library, select both post sets,
write the paper's Fig. 7b/7c maps and JSON numbers.

    metafovea library [designs/platform.toml] [--wavelengths-um 10] [--grid-step-um 0.1]
                      [--levels 8] [--harmonics 10] [--out DIR] [--json] ...

Outputs in --out: library.npz (Library.save), postset_x.npz (foveal lens, focuses x) and
postset_y.npz (perifoveal lens, focuses y) for `metafovea design --post-set`, fig7b_phase_maps.png,
fig7c_selected_posts.png and library.json.
"""

from __future__ import annotations

import argparse
import io
import logging
import sys
import time
import warnings
from typing import Any

import numpy as np

from metafovea.errors import InputError, NotConvergedWarning, check_int, check_positive

log = logging.getLogger(__name__)


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("library", help="RCWA scatterer library and birefringent post selection (Fig. 7)")
    p.add_argument("platform_file", nargs="?", help="platform TOML (default: the paper's Si-post platform)")
    p.add_argument("--wavelengths-um", nargs="+", default=None,
                   help="wavelengths to sweep in um (default: the platform's design wavelength)")
    p.add_argument("--grid-step-um", default="0.1", help="width grid step in um (default 0.1: 31 x 31 posts)")
    p.add_argument("--levels", default="8", help="phase levels per lens (default 8)")
    p.add_argument("--harmonics", default="10", help="Fourier orders M, |m|,|n| <= M (default 10: 441 plane waves)")
    p.add_argument("--factorization", default="li", choices=("li", "laurent"), help="Fourier factorisation rule")
    p.add_argument("--incidence", default="substrate", choices=("substrate", "superstrate"),
                   help="side light enters from (default substrate: through the wafer, posts face the sensor)")
    p.add_argument("--tol", default="0.02", help="convergence tolerance on t for the warning (default 0.02)")
    p.add_argument("--workers", default=None, help="local worker processes (default: all cores)")
    p.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:8786) to run the sweep on")
    p.add_argument("--cache-dir", default=None, help="library cache directory (default $METAFOVEA_CACHE/library, "
                                                     "i.e. ~/.cache/metafovea/library)")
    p.add_argument("--no-cache", action="store_true", help="recompute even if a cached library exists")
    p.add_argument("--out", default=None, help="write library, post sets, figures and JSON into this directory")
    p.add_argument("--force", action="store_true", help="overwrite existing output")
    p.add_argument("--json", action="store_true", help="print JSON numbers instead of a table")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def _platform(path: str | None):
    from metafovea.config import PlatformDesign, load_platform
    return load_platform(path) if path else PlatformDesign()


def run(args: argparse.Namespace) -> int:
    from metafovea.io import atomic_write_bytes, atomic_write_json, prepare_output, to_json
    from metafovea.library import compute_library, postset_table, select_posts, width_grid

    plat = _platform(getattr(args, "platform_file", None))
    wls = ([check_positive("--wavelengths-um", w, "um", hi=1e4) for w in args.wavelengths_um]
           if args.wavelengths_um else [float(plat.wavelength_um)])
    step = check_positive("--grid-step-um", args.grid_step_um, "um")
    levels = check_int("--levels", args.levels, 2, 64)
    M = check_int("--harmonics", args.harmonics, 5, 40)
    tol = check_positive("--tol", args.tol)
    workers = None if args.workers is None else check_int("--workers", args.workers, 1, 1024)
    src = getattr(args, "platform_file", None)
    if not plat.min_feature_um < plat.period_um / 2:
        raise InputError("min_feature_um", plat.min_feature_um,
                         f"0 < min_feature_um < period_um / 2 = {plat.period_um / 2:g} um (posts and gaps both "
                         "at least the min feature)", source=src or "default platform")
    widths = width_grid(plat.period_um, step, plat.min_feature_um, name="--grid-step-um")
    out = prepare_output(args.out, args.force, is_dir=True) if args.out else None
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NotConvergedWarning)
        lib = compute_library(widths, None, wls, period_um=plat.period_um, height_um=plat.post_height_um,
                              n_post=plat.n_post, n_substrate=plat.n_substrate, n_superstrate=plat.n_superstrate,
                              harmonics=M, factorization=args.factorization, incidence=args.incidence, tol=tol,
                              cache_dir=args.cache_dir, use_cache=not args.no_cache, workers=workers,
                              scheduler=args.scheduler, progress=not args.no_progress)
    for w in caught:  # one line each (the default format adds the source line of the call)
        if issubclass(w.category, NotConvergedWarning):
            sys.stderr.write(f"metafovea library: warning: {w.message}\n")
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    elapsed = time.perf_counter() - t0
    design_wl = float(plat.wavelength_um) if float(plat.wavelength_um) in [float(w) for w in wls] else float(wls[0])
    try:
        sets = {pol: select_posts(lib, pol, levels, wavelength_um=design_wl) for pol in ("x", "y")}
    except InputError as e:
        if e.parameter != "library":
            raise
        raise InputError("--levels", levels, f"at most the {e.value} of {lib.wx_um.size} x {lib.wy_um.size} posts "
                         f"converged at {design_wl:g} um (convergence estimate <= 0.05): use more --harmonics, a "
                         "finer --grid-step-um or fewer --levels"
                         + (f" (the wavelength is not above the period {plat.period_um:g} um: the posts diffract, "
                            "not a zero-order library)" if design_wl <= plat.period_um * plat.n_superstrate else "")
                         ) from None
    payload: dict[str, Any] = {
        "library": {"n_wx": int(lib.wx_um.size), "n_wy": int(lib.wy_um.size), "wavelengths_um": lib.wavelengths_um,
                    "harmonics": M, "plane_waves": (2 * M + 1) ** 2, "factorization": args.factorization,
                    "incidence": args.incidence, "elapsed_s": elapsed, "from_cache": bool(lib.meta.get("from_cache")),
                    "max_error_estimate": lib.meta.get("max_error_estimate"),
                    "median_error_estimate": lib.meta.get("median_error_estimate"), "key": lib.meta.get("key"),
                    "conventions": lib.meta.get("conventions")},
        "design_wavelength_um": design_wl, "post_sets": {}}
    for pol, ps in sets.items():
        lens = "foveal" if pol == "x" else "perifoveal"
        keys = ("expected_focusing_efficiency", "pass_coherent_transmission", "max_abs_phase_error_rad",
                "rms_phase_error_rad", "pass_phase_spread_rad", "pass_phase_rms_rad", "mean_T_focus",
                "mean_T_pass", "phase_offset_focus_rad", "phase_offset_pass_rad")
        payload["post_sets"][pol] = {"lens": lens, "focuses": pol, "levels": postset_table(ps),
                                     **{k: ps.info[k] for k in keys}}
    if out is not None:
        lib.save(out / "library.npz")
        for pol, ps in sets.items():
            ps.save(out / f"postset_{pol}.npz")
        il = lib.index_of_wavelength(design_wl)
        atomic_write_bytes(out / "fig7b_phase_maps.png", _fig7b(lib, il))
        atomic_write_bytes(out / "fig7c_selected_posts.png", _fig7c(lib, il, sets))
        atomic_write_json(out / "library.json", payload)
        payload["files"] = sorted(p.name for p in out.iterdir())
    if args.json:
        print(to_json(payload))
    else:
        lb = payload["library"]
        print(f"library: {lb['n_wx']} x {lb['n_wy']} posts x {len(wls)} wavelength(s), M = {M} "
              f"({lb['plane_waves']} plane waves, {args.factorization}), light from the {args.incidence}, "
              f"{elapsed:.1f} s{' (cache)' if lb['from_cache'] else ''}; "
              f"convergence estimate max {lb['max_error_estimate']:.3g}, median {lb['median_error_estimate']:.3g}")
        for pol, d in payload["post_sets"].items():
            print(f"\n{d['lens']} lens (focuses {pol}, posts chosen at {design_wl:g} um): expected focusing efficiency "
                  f"{d['expected_focusing_efficiency']:.3f}, max phase error {d['max_abs_phase_error_rad']:.3f} rad, "
                  f"pass-through phase spread {d['pass_phase_spread_rad']:.3f} rad, "
                  f"pass-through transmission {d['pass_coherent_transmission']:.3f}")
            print("  level  wx_um  wy_um  target  phase_f  T_f    phase_p  T_p")
            for r in d["levels"]:
                print(f"  {r['level']:5d}  {r['wx_um']:5.2f}  {r['wy_um']:5.2f}  {r['target_phase_rad']:6.3f}  "
                      f"{r['phase_focus_rad']:7.3f}  {r['T_focus']:.3f}  {r['phase_pass_rad']:7.3f}  {r['T_pass']:.3f}")
        if out is not None:
            print(f"\nwritten to {out}")
    return 0


def _png(fig) -> bytes:
    import matplotlib.pyplot as plt
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _fig7b(lib, il: int) -> bytes:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    p = float(lib.meta.get("period_um", 4.0))
    ext = [lib.wy_um[0] / p, lib.wy_um[-1] / p, lib.wx_um[0] / p, lib.wx_um[-1] / p]
    fig, axs = plt.subplots(2, 2, figsize=(9, 8))
    for j, pol in enumerate(("x", "y")):
        t = getattr(lib, f"t_{pol}")[il]
        im = axs[0, j].imshow(np.angle(t) % (2 * np.pi), origin="lower", extent=ext, cmap="twilight",
                              vmin=0, vmax=2 * np.pi, aspect="auto")
        axs[0, j].set_title(f"phase of t_{pol} (rad)")
        fig.colorbar(im, ax=axs[0, j])
        im = axs[1, j].imshow(np.abs(t) ** 2, origin="lower", extent=ext, cmap="viridis", vmin=0, vmax=1,
                              aspect="auto")
        axs[1, j].set_title(f"|t_{pol}|^2")
        fig.colorbar(im, ax=axs[1, j])
    for ax in axs.ravel():
        ax.set_xlabel("duty cycle wy / p")
        ax.set_ylabel("duty cycle wx / p")
    fig.suptitle(f"Fig. 7b: zero-order response, lambda = {lib.wavelengths_um[il]:g} um")
    return _png(fig)


def _fig7c(lib, il: int, sets: dict) -> bytes:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    p = float(lib.meta.get("period_um", 4.0))
    ext = [lib.wy_um[0] / p, lib.wy_um[-1] / p, lib.wx_um[0] / p, lib.wx_um[-1] / p]
    fig, axs = plt.subplots(2, 2, figsize=(10, 8))
    for j, (pol, ps) in enumerate(sets.items()):
        t = getattr(lib, f"t_{pol}")[il]
        axs[0, j].imshow(np.angle(t) % (2 * np.pi), origin="lower", extent=ext, cmap="twilight", vmin=0,
                         vmax=2 * np.pi, aspect="auto")
        axs[0, j].plot(ps.widths_um[:, 1] / p, ps.widths_um[:, 0] / p, "o", mfc="none", mec="k", ms=9)
        for k, (a, b) in enumerate(ps.widths_um):
            axs[0, j].annotate(str(k), (b / p, a / p), textcoords="offset points", xytext=(5, 5), fontsize=8)
        axs[0, j].set_xlabel("wy / p")
        axs[0, j].set_ylabel("wx / p")
        lens = "foveal" if pol == "x" else "perifoveal"
        axs[0, j].set_title(f"{lens} lens posts on phase of t_{pol}")
        k = np.arange(ps.levels)
        axs[1, j].plot(k, 2 * np.pi * k / ps.levels, "k--", label="target")
        axs[1, j].plot(k, np.unwrap(np.angle(ps.t_focus)), "o-", label=f"phase t_{pol} (focus)")
        axs[1, j].plot(k, np.angle(ps.t_pass), "s-", label="phase of pass-through pol.")
        axs[1, j].bar(k, np.abs(ps.t_focus) ** 2, alpha=0.25, label="T focus")
        axs[1, j].set_xlabel("level")
        axs[1, j].set_ylabel("rad / efficiency")
        axs[1, j].legend(fontsize=7)
        axs[1, j].set_title(f"eff. {ps.info['expected_focusing_efficiency']:.2f}, pass spread "
                            f"{ps.info['pass_phase_spread_rad']:.2f} rad")
    fig.suptitle("Fig. 7c: selected birefringent posts")
    return _png(fig)


def register(subparsers: Any) -> None:
    add_parser(subparsers)
