"""Post selection under a +-50 nm edge bias: the nominal selection (the default, `bias_weight=0`) against the joint
search over the -delta / 0 / +delta cases (`select_posts(..., bias_weight=w)`), each set's posts solved by RCWA at
-delta, 0, +delta per side (`bias_table`).

    python benchmarks/bench_tolerance.py [--weights 0 0.5 1 2] [--polarization x]

The last column compares the library's own figures for the chosen posts (`info['tolerance']`, which the search
optimises) with the RCWA table: on the paper's 0.1 um grid the biased widths are grid points, so they agree.
"""

from __future__ import annotations

import argparse
import os
import time

from metafovea.config import PlatformDesign
from metafovea.library import bias_table, platform_post_sets, select_posts

KEYS = ("expected_focusing_efficiency", "rms_phase_error_rad", "max_abs_phase_error_rad", "pass_phase_spread_rad")


def per_bias(pb: dict, key: str) -> str:
    """One table cell: `key` of the -delta / 0 / +delta cases of `bias_table`'s `per_bias`."""
    return " / ".join(f"{pb[c][key]:.3f}" for c in ("-", "0", "+"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0, 0.5, 1.0, 2.0])
    ap.add_argument("--polarization", default="x", choices=("x", "y"))
    a = ap.parse_args()
    plat = PlatformDesign()
    _, lib = platform_post_sets(plat)
    d = plat.edge_bias_um
    print(f"{time.strftime('%Y-%m-%d %H:%M %Z')}; {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f}; "
          f"edge bias +-{1000 * d:.0f} nm per side (widths +-{2000 * d:.0f} nm); lens focusing {a.polarization}")
    print("| bias_weight | efficiency -/0/+ | phase error rms -/0/+ (rad) | max (rad) -/0/+ | pass spread -/0/+ (rad) "
          "| selection (s) | library vs RCWA (max diff) |")
    print("|---|---|---|---|---|---|---|")
    for w in a.weights:
        t0 = time.perf_counter()
        ps = select_posts(lib, a.polarization, 8, platform=plat, bias_weight=w)
        sel_s = time.perf_counter() - t0
        pb = bias_table(lib, ps.widths_um, a.polarization, d)["per_bias"]
        cases = ps.info["tolerance"]["cases"]
        diff = max(abs(pb[c][k] - cases[c][k]) for c in ("-", "0", "+") for k in KEYS if cases[c] is not None)
        cols = " | ".join(per_bias(pb, key) for key in KEYS)
        print(f"| {w:g}{' (default)' if w == 0 else ''} | {cols} | {sel_s:.1f} | {diff:.1e} |")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
