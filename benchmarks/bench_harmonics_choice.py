"""``metafovea library --tolerance-rad``: the chosen harmonics' true phase error on posts that are not probes.

For each tolerance, :func:`metafovea.library.choose_harmonics` picks M for the paper's platform (the default 0.1 um
grid) at the wavelengths given; ``--posts`` random posts of the grid's range (seed ``--seed``), at every one of those
wavelengths, are solved at the chosen M and at ``--reference`` harmonics (x-polarised light; y is x of the turned
post). The table: the tolerance, the M chosen, the estimate, the largest true phase error over the random posts, its
ratio to the tolerance, the choice's seconds and the expected sweep time.

    python benchmarks/bench_harmonics_choice.py
    python benchmarks/bench_harmonics_choice.py --wavelengths 8 10 12 --tolerances 0.02 0.01 --posts 16
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tolerances", type=float, nargs="+", default=[0.05, 0.02, 0.01, 0.005])
    ap.add_argument("--wavelengths", type=float, nargs="+", default=[10.0])
    ap.add_argument("--posts", type=int, default=16)
    ap.add_argument("--reference", type=int, default=20)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from metafovea.library import PlatformSweep, choose_harmonics, probe_posts
    from metafovea.parallel import blas_threads
    from metafovea.rcwa.posts import post_response

    sweep = PlatformSweep(wavelengths_um=tuple(args.wavelengths))
    w = sweep.widths_um
    g = np.random.default_rng(args.seed)
    posts = np.round(g.uniform(w[0], w[-1], (args.posts, 2)), 3)
    probes = probe_posts(sweep)
    assert not any(np.allclose(p[:2], q) for p in probes for q in posts)
    wx = np.repeat(posts[:, 0], len(args.wavelengths))
    wy = np.repeat(posts[:, 1], len(args.wavelengths))
    wl = np.tile(np.asarray(args.wavelengths), args.posts)

    def t(M: int) -> np.ndarray:
        with blas_threads(1):
            return np.ravel(post_response(wx, wy, wl, harmonics=M, polarizations=("x",)).t_x)

    load0 = open("/proc/loadavg").read().split()[:3]
    ref = t(args.reference)
    rows = []
    print(f"{'tolerance':>9s} {'M':>3s} {'estimate':>9s} {'true max':>9s} {'true/tol':>8s} {'choice s':>8s} "
          f"{'sweep s':>8s}")
    for tol in args.tolerances:
        c = choose_harmonics(tol, sweep)
        err = float(np.abs(np.angle(t(c.harmonics) / ref)).max())
        rows.append({"tolerance_rad": tol, "harmonics": c.harmonics, "estimate_rad": c.estimate_rad,
                     "true_max_rad": err, "seconds": c.seconds, "sweep_seconds": c.sweep_seconds})
        print(f"{tol:9.3g} {c.harmonics:3d} {c.estimate_rad:9.3g} {err:9.3g} {err / tol:8.2f} {c.seconds:8.1f} "
              f"{c.sweep_seconds:8.0f}")
    print(f"{args.posts} random posts x {len(args.wavelengths)} wavelength(s) {args.wavelengths} um against "
          f"M = {args.reference}; load {load0} -> {open('/proc/loadavg').read().split()[:3]}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
