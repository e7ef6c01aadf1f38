"""The optical train of the paper's camera: per-channel throughput and its breakdown, each lens' transmission
(against the paper's ~60 %), the glare, the ring and oblique incidence over the field, and what each costs to
compute (RCWA library and oblique solves cached after the first run).

    python benchmarks/bench_train.py            # the paper's camera, RCWA posts
    python benchmarks/bench_train.py --ideal    # the simplified model with ideal posts, for comparison
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from metafovea.config import SystemDesign
from metafovea.library import system_post_sets
from metafovea.optics.train import system_trains, throughput_lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ideal", action="store_true", help="ideal posts instead of the RCWA post sets")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    system = SystemDesign.paper()
    t0 = time.perf_counter()
    posts, name = system_post_sets(system, "ideal" if args.ideal else "rcwa")
    t1 = time.perf_counter()
    for filt in (False, True):
        t2 = time.perf_counter()
        trains = system_trains(system, posts, name, filter_enabled=filt)
        t3 = time.perf_counter()
        print(f"\n== {'10 um filter' if filt else '8-14 um'}: post sets {t1 - t0:.2f} s, trains {t3 - t2:.2f} s ==")
        print("\n".join(throughput_lines([t.summary() for t in trains])))
        print("relative throughput over the field (ring x oblique incidence, cos^4 not included):")
        for tr, z in zip(trains, system.lens_to_sensor_um):
            corner = math.degrees(math.atan(0.5 * math.hypot(290, 290) * 34.0 / z))
            th = np.linspace(0, corner, 5)
            t = np.tan(np.radians(th))
            row_x = tr.field_factor(t, 0 * t)
            row_d = tr.field_factor(t / math.sqrt(2), t / math.sqrt(2))
            print(f"  {tr.channel:>10}: field deg " + " ".join(f"{v:6.2f}" for v in th))
            print("              along x   " + " ".join(f"{v:6.4f}" for v in row_x))
            print("              diagonal  " + " ".join(f"{v:6.4f}" for v in row_d))


if __name__ == "__main__":
    main()
