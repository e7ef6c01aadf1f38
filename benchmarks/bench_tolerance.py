"""Post selection under a +-50 nm edge bias: the nominal selection (the default) against the tolerance-weighted one
(`select_posts(..., bias_weight=w)`), each set's posts solved by RCWA at -delta, 0, +delta per side.

    python benchmarks/bench_tolerance.py [--weights 0 0.5 1 2]
"""

from __future__ import annotations

import argparse
import os

from metafovea.config import PlatformDesign
from metafovea.library import bias_table, platform_post_sets, select_posts


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0, 0.5, 1.0, 2.0])
    a = ap.parse_args()
    plat = PlatformDesign()
    _, lib = platform_post_sets(plat)
    d = plat.edge_bias_um
    print(f"load average {os.getloadavg()[0]:.2f}; edge bias +-{1000 * d:.0f} nm per side (widths +-{2000 * d:.0f} nm)")
    print("| bias_weight | efficiency -/0/+ | phase error rms -/0/+ (rad) | max (rad) -/0/+ | pass spread -/0/+ (rad) |")
    print("|---|---|---|---|---|")
    for w in a.weights:
        ps = select_posts(lib, "x", 8, platform=plat, bias_weight=w)
        pb = bias_table(lib, ps.widths_um, "x", d)["per_bias"]
        f = lambda key: " / ".join(f"{pb[c][key]:.3f}" for c in ("-", "0", "+"))  # noqa: E731
        print(f"| {w:g} | {f('expected_focusing_efficiency')} | {f('rms_phase_error_rad')} | "
              f"{f('max_abs_phase_error_rad')} | {f('pass_phase_spread_rad')} |")


if __name__ == "__main__":
    main()
