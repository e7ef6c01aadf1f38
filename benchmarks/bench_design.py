"""Speed against error of the design-stage estimates.

Lattice focusing efficiency: sampled estimator (seeded random sites) against the exact sum over every
site, for a lens small enough to sum exactly; exact post count timing for the paper's lenses.

    python benchmarks/bench_design.py
"""

import platform
import time

from metafovea.config import LensDesign
from metafovea.lens import count_posts, lattice_efficiency


def main() -> None:
    print(f"machine: {platform.machine()} {platform.processor() or ''} python {platform.python_version()}")
    d = LensDesign("f25-d4", 25_000.0, 4_000.0)
    t = time.perf_counter()
    ref = lattice_efficiency(d, exact=True)
    t_ref = time.perf_counter() - t
    print("| method | sites | seconds | efficiency | |error| vs exact | reported stderr |")
    print("|---|---|---|---|---|---|")
    print(f"| exact sum | {ref.sites:,} | {t_ref:.3f} | {ref.value:.6f} | 0 | 0 |")
    for s in (1 << 14, 1 << 17, 1 << 20):
        t = time.perf_counter()
        e = lattice_efficiency(d, exact=False, samples=s, rng=0)
        dt = time.perf_counter() - t
        print(f"| sampled | {s:,} | {dt:.3f} | {e.value:.6f} | {abs(e.value - ref.value):.1e} | {e.stderr:.1e} |")
    for lens in (LensDesign.foveal(), LensDesign.perifoveal()):
        t = time.perf_counter()
        n = count_posts(lens)
        print(f"exact post count {lens.name}: {n:,} in {time.perf_counter() - t:.3f} s")


if __name__ == "__main__":
    import argparse

    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    main()
