"""The library of a platform as a report: numbers (JSON, a table), the paper's Fig. 7b/7c and the files
``metafovea library`` writes.

:func:`library_report` sweeps (or loads from the cache) the library of a :class:`~metafovea.library.PlatformSweep`
and selects both post sets; :meth:`LibraryReport.write` writes library.npz (``Library.save``), postset_x.npz
(foveal lens, focuses x), postset_y.npz (perifoveal lens, focuses y), fig7b_phase_maps.png,
fig7c_selected_posts.png and library.json.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.io import atomic_write_bytes, atomic_write_json
from metafovea.report import fig_to_png

from .harmonics import HarmonicsChoice
from .platform import PlatformSweep
from .postset import PostSet, postset_table
from .select import bias_table
from .sweep import Library, _stack

#: the lens each post set is for (each lens focuses its own polarisation and passes the other)
LENS_OF = {"x": "foveal", "y": "perifoveal"}
#: figures of merit of a post set reported per lens (keys of ``PostSet.info``)
POST_SET_NUMBERS = ("expected_focusing_efficiency", "pass_coherent_transmission", "max_abs_phase_error_rad",
                    "rms_phase_error_rad", "pass_phase_spread_rad", "pass_phase_rms_rad", "mean_T_focus",
                    "mean_T_pass", "phase_offset_focus_rad", "phase_offset_pass_rad")


@dataclass(frozen=True)
class LibraryReport:
    """A platform's library, both post sets (``{'x': foveal, 'y': perifoveal}``), the wavelength they were
    chosen at (um) and the seconds the library took (computed or loaded from the cache)."""

    library: Library
    post_sets: dict[str, PostSet]
    design_wavelength_um: float
    elapsed_s: float
    edge_bias: dict[str, Any] = field(default_factory=dict)  #: pol -> :func:`metafovea.library.bias_table`
    bound: dict[str, Any] = field(default_factory=dict)  #: :func:`convergence_bounds`
    #: what :func:`~metafovea.library.harmonics.choose_harmonics` chose (``--tolerance-rad``), or None
    harmonics_choice: HarmonicsChoice | None = None

    def numbers(self) -> dict[str, Any]:
        """The JSON numbers: library size, solver settings, convergence estimates, and per lens its post set's
        figures of merit and per-level table."""
        lib, meta = self.library, self.library.meta
        M = int(meta["harmonics"])
        choice = {} if self.harmonics_choice is None else {"harmonics_choice": self.harmonics_choice.summary()}
        return {**choice,
            "library": {"n_wx": int(lib.wx_um.size), "n_wy": int(lib.wy_um.size),
                        "wavelengths_um": lib.wavelengths_um, "harmonics": M, "plane_waves": (2 * M + 1) ** 2,
                        "factorization": meta.get("factorization"), "incidence": meta.get("incidence"),
                        "elapsed_s": self.elapsed_s, "from_cache": bool(meta.get("from_cache")),
                        "max_error_estimate": meta.get("max_error_estimate"),
                        "median_error_estimate": meta.get("median_error_estimate"), "key": meta.get("key"),
                        "conventions": meta.get("conventions")},
            "design_wavelength_um": self.design_wavelength_um,
            "convergence_bound": self._bound_numbers(),
            "post_sets": {pol: {"lens": LENS_OF[pol], "focuses": pol, "levels": postset_table(ps),
                                **{k: ps.info[k] for k in POST_SET_NUMBERS}, "edge_bias": self.edge_bias.get(pol),
                                "bias_weight": ps.info.get("bias_weight", 0.0), "selection": ps.info.get("method"),
                                "selection_tolerance": ps.info.get("tolerance"),
                                "fabrication_rules": ps.info.get("fabrication_rules")}
                          for pol, ps in self.post_sets.items()}}

    def _bound_numbers(self) -> dict[str, Any] | None:
        if not self.bound:
            return None
        lib, arrays = self.library, self.bound["arrays"]
        il = int(np.argmin(np.abs(lib.wavelengths_um - self.design_wavelength_um)))
        chosen = {}
        for pol, ps in self.post_sets.items():
            ix = [int(np.argmin(np.abs(lib.wx_um - w))) for w in ps.widths_um[:, 0]]
            iy = [int(np.argmin(np.abs(lib.wy_um - w))) for w in ps.widths_um[:, 1]]
            chosen[pol] = float(max(max(arrays["x"][il, a, b], arrays["y"][il, a, b]) for a, b in zip(ix, iy)))
        return {k: v for k, v in self.bound.items() if k != "arrays"} | {"chosen": chosen}

    def format(self) -> str:
        """The human-readable table ``metafovea library`` prints."""
        d = self.numbers()
        lb = d["library"]
        lines = [f"library: {lb['n_wx']} x {lb['n_wy']} posts x {self.library.wavelengths_um.size} wavelength(s), "
                 f"M = {lb['harmonics']} ({lb['plane_waves']} plane waves, {lb['factorization']}), light from the "
                 f"{lb['incidence']}, {lb['elapsed_s']:.1f} s{' (cache)' if lb['from_cache'] else ''}; "
                 f"step |t(M) - t(M-2)| max {lb['max_error_estimate']:.3g}, median {lb['median_error_estimate']:.3g}"]
        if self.harmonics_choice is not None:
            lines = self.harmonics_choice.lines() + lines
        bd = d.get("convergence_bound")
        if bd:
            lines.append(f"truncation-error bound 3 max(|t(M) - t(M-2)|, |t(M) - t(M-4)|): max {bd['max']:.3g}, "
                         f"median {bd['median']:.3g}"
                         + (f", {100 * bd['above_tol']:.0f} % of the posts above tol={bd['tol']:g}"
                            if bd.get("above_tol") is not None else "")
                         + "; chosen posts: " + ", ".join(f"{pol} up to {v:.3g}" for pol, v in bd["chosen"].items()))
        for pol, p in d["post_sets"].items():
            lines += ["", f"{p['lens']} lens (focuses {pol}, posts chosen at {self.design_wavelength_um:g} um): "
                          f"expected focusing efficiency {p['expected_focusing_efficiency']:.3f}, max phase error "
                          f"{p['max_abs_phase_error_rad']:.3f} rad, pass-through phase spread "
                          f"{p['pass_phase_spread_rad']:.3f} rad, pass-through transmission "
                          f"{p['pass_coherent_transmission']:.3f}",
                      "  level  wx_um  wy_um  target  phase_f  T_f    phase_p  T_p"]
            lines += [f"  {r['level']:5d}  {r['wx_um']:5.2f}  {r['wy_um']:5.2f}  {r['target_phase_rad']:6.3f}  "
                      f"{r['phase_focus_rad']:7.3f}  {r['T_focus']:.3f}  {r['phase_pass_rad']:7.3f}  {r['T_pass']:.3f}"
                      for r in p["levels"]]
            eb = p.get("edge_bias")
            if eb:
                lines += _bias_lines(eb, p["bias_weight"])
        return "\n".join(lines)

    #: what :meth:`write` writes, in its order (``library.json`` last: a folder without it is a stopped write)
    FILES = ("library.npz", "postset_x.npz", "postset_y.npz", "fig7b_phase_maps.png", "fig7c_selected_posts.png",
             "library.json")

    @classmethod
    def stopped_write(cls, out_dir: str | Path) -> bool:
        """Whether ``out_dir`` holds some of :data:`FILES` and nothing else, without the ``library.json`` written
        last: a Ctrl-C during :meth:`write` (each file atomic, the set not), which a rerun completes."""
        p = Path(out_dir)
        names = {q.name for q in p.iterdir()} if p.is_dir() else set()
        return bool(names) and names <= set(cls.FILES) - {"library.json"}

    def write(self, out_dir: Path) -> list[Path]:
        """Write the library, both post sets, Fig. 7b/7c and library.json into ``out_dir`` (which must exist)."""
        out_dir = Path(out_dir)
        lib = self.library
        if self.harmonics_choice is not None:  # the file says why it has its harmonics
            lib = Library(lib.wx_um, lib.wy_um, lib.wavelengths_um, lib.arrays,
                          dict(lib.meta, harmonics_choice=self.harmonics_choice.summary()))
        written = [lib.save(out_dir / "library.npz")]
        written += [ps.save(out_dir / f"postset_{pol}.npz") for pol, ps in self.post_sets.items()]
        il = self.library.index_of_wavelength(self.design_wavelength_um)
        written.append(atomic_write_bytes(out_dir / "fig7b_phase_maps.png", phase_maps_png(self.library, il)))
        written.append(atomic_write_bytes(out_dir / "fig7c_selected_posts.png",
                                          selected_posts_png(self.library, il, self.post_sets)))
        written.append(atomic_write_json(out_dir / "library.json", self.numbers()))
        return written


def library_report(sweep: PlatformSweep, *, harmonics_choice: HarmonicsChoice | None = None) -> LibraryReport:
    """Compute (or load from the cache) the library of ``sweep`` and select both post sets; ``harmonics_choice``
    (:func:`~metafovea.library.harmonics.choose_harmonics`, already applied to ``sweep``) is reported with it."""
    t0 = time.perf_counter()
    lib = sweep.library()
    elapsed = time.perf_counter() - t0
    from metafovea.parallel import heartbeat

    # the library may come from the cache in no time; what follows solves posts directly (the convergence bound's
    # extra sweep, the edge-bias table, not cached): a line every 10 s says so
    with heartbeat("library: post selection, convergence bound and edge-bias table (direct RCWA solves)",
                   enabled=sweep.options.progress):
        sets = sweep.select(lib)
        bound = convergence_bounds(lib, sweep)
        delta = sweep.platform.edge_bias_um
        il = int(np.argmin(np.abs(lib.wavelengths_um - sweep.design_wavelength_um)))
        bias = {pol: bias_table(lib, ps.widths_um, pol, delta, il) for pol, ps in sets.items()} if delta > 0 else {}
    return LibraryReport(lib, sets, sweep.design_wavelength_um, elapsed, bias, bound, harmonics_choice)


def convergence_bounds(lib: Library, sweep: PlatformSweep) -> dict[str, Any]:
    """The library's truncation-error bound (:func:`metafovea.rcwa.posts.convergence_bound`) for every post: its
    step to M - 2 (stored with it) and to M - 4 (a small extra sweep at M - 4, cached like the library), max,
    median, the posts above the warning tolerance, and the bound of each chosen post."""
    from dataclasses import replace

    from metafovea.rcwa.posts import BOUND_FACTOR, MIN_POST_HARMONICS

    from .sweep import compute_library

    M = int(lib.meta["harmonics"])
    if M - 4 < MIN_POST_HARMONICS or not np.all(np.isfinite(lib.err_x)):
        return {}
    opts = replace(sweep.options.with_platform(sweep.platform), harmonics=M - 4, estimate=False, tol=None,
                   progress=False)
    low = compute_library(lib.wx_um, lib.wy_um, tuple(lib.wavelengths_um.tolist()), options=opts)
    b = {q: BOUND_FACTOR * np.maximum(lib.arrays[f"err_{q}"], np.abs(lib.arrays[f"t_{q}"] - low.arrays[f"t_{q}"]))
         for q in ("x", "y")}
    allb = np.concatenate([b["x"].ravel(), b["y"].ravel()])
    tol = sweep.options.tol
    return {"max": float(np.nanmax(allb)), "median": float(np.nanmedian(allb)), "harmonics": M,
            "above_tol": None if tol is None else float(np.mean(allb > tol)), "tol": tol,
            "arrays": b}


def _duty_cycle_extent(lib: Library) -> tuple[float, list[float]]:
    p = float(_stack(lib, "period_um"))
    return p, [lib.wy_um[0] / p, lib.wy_um[-1] / p, lib.wx_um[0] / p, lib.wx_um[-1] / p]


def phase_maps_png(lib: Library, il: int) -> bytes:
    """Fig. 7b: phase and |t|^2 of the zero order for x- and y-polarised light over the (wx, wy) grid."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, ext = _duty_cycle_extent(lib)
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
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def selected_posts_png(lib: Library, il: int, post_sets: dict[str, PostSet]) -> bytes:
    """Fig. 7c: each lens' posts on the phase map of its polarisation, and their phases and efficiencies."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p, ext = _duty_cycle_extent(lib)
    fig, axs = plt.subplots(2, 2, figsize=(10, 8))
    for j, (pol, ps) in enumerate(post_sets.items()):
        t = getattr(lib, f"t_{pol}")[il]
        im = axs[0, j].imshow(np.angle(t) % (2 * np.pi), origin="lower", extent=ext, cmap="twilight", vmin=0,
                              vmax=2 * np.pi, aspect="auto")
        fig.colorbar(im, ax=axs[0, j], label=f"phase of t_{pol} (rad)")
        axs[0, j].plot(ps.widths_um[:, 1] / p, ps.widths_um[:, 0] / p, "o", mfc="none", mec="k", ms=9)
        for k, (a, b) in enumerate(ps.widths_um):
            axs[0, j].annotate(str(k), (b / p, a / p), textcoords="offset points", xytext=(5, 5), fontsize=8)
        axs[0, j].set_xlabel("wy / p")
        axs[0, j].set_ylabel("wx / p")
        axs[0, j].set_title(f"{LENS_OF[pol]} lens posts on phase of t_{pol}")
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
    png = fig_to_png(fig)
    plt.close(fig)
    return png


def _bias_lines(eb: dict[str, Any], bias_weight: float = 0.0) -> list[str]:
    """The +-delta edge-bias table of one post set, beside the nominal column (:func:`metafovea.library.bias_table`),
    and how the posts were chosen (``bias_weight`` > 0: jointly over the three cases)."""
    d = eb["delta_um"]
    pb = eb["per_bias"]
    cols = (("-", f"-{1000 * d:.0f} nm"), ("0", "nominal"), ("+", f"+{1000 * d:.0f} nm"))
    chosen = (f"posts chosen jointly over the three cases (bias_weight {bias_weight:g}: each biased case weighted "
              f"{bias_weight:g}, the nominal 1)" if bias_weight > 0
              else "posts chosen for the nominal case (bias_weight 0)")
    lines = [f"  edge bias +-{1000 * d:.0f} nm per side (widths +-{2000 * d:.0f} nm), RCWA, common shift removed;",
             f"  {chosen}:",
             "    " + " " * 34 + "".join(f"{name:>10}" for _, name in cols)]
    for key, label in (("rms_phase_error_rad", "focusing phase error rms (rad)"),
                       ("max_abs_phase_error_rad", "focusing phase error max (rad)"),
                       ("expected_focusing_efficiency", "expected focusing efficiency"),
                       ("pass_phase_spread_rad", "pass-through phase spread (rad)"),
                       ("common_shift_rad", "common focusing shift (rad)")):
        lines.append(f"    {label:<34}" + "".join(f"{pb[c][key]:>10.3f}" for c, _ in cols))
    rows = {r["bias"]: r for r in eb["levels"]}
    lines.append("    level  phase error -/0/+ (rad)        pass-through phase -/0/+ (rad)")
    for k in range(len(rows["0"]["phase_error_rad"])):
        pe = "/".join(f"{rows[c]['phase_error_rad'][k]:+.3f}" for c, _ in cols)
        pp = "/".join(f"{rows[c]['pass_phase_rad'][k]:+.3f}" for c, _ in cols)
        lines.append(f"    {k:5d}  {pe:<30} {pp}")
    return lines
