"""RCWA benchmark: zero-order phase error versus harmonics versus time per geometry for the paper's
post (p = 4 um, h = 10 um, 2.0 x 2.0 um Si post on Si, air above, lambda = 10 um, light from the
substrate), for our Li and Laurent factorisations and for fmmax (run in the same process, same
machine, one thread each).

    python benchmarks/bench_rcwa.py [--quick] [--fmmax-terms 97 193 293 437 593] [--out BENCH.json]
                                    [--library]

The reference is our Li result at M = 20 (1681 plane waves); the Richardson-extrapolated limit is
also printed. "time/geometry" is the wall time of one post (both x and y polarisation) after warm-up
(fmmax: the jitted solve after compilation; its zero-order phase is
calibrated with an empty layer so that both solvers use the same reference planes). With --library the 31 x 31 library (M = 10) is also timed.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from metafovea.rcwa.posts import post_response  # noqa: E402

P, H, WL, W, NSI = 4.0, 10.0, 10.0, 2.0, 3.42


def ours(M: int, factorization: str, repeat: int = 3, pols=("x", "y")):
    post_response(W, W, WL, harmonics=M, factorization=factorization, polarizations=pols)
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        r = post_response(W, W, WL, harmonics=M, factorization=factorization, polarizations=pols)
        best = min(best, time.perf_counter() - t0)
    return complex(r.t_x), best


def fmmax_run(n_terms: int, formulation: str = "JONES_DIRECT", grid: int = 200, repeat: int = 2):
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import fmmax

    plv = fmmax.LatticeVectors(u=fmmax.basis.X * P, v=fmmax.basis.Y * P)
    exp = fmmax.generate_expansion(primitive_lattice_vectors=plv, approximate_num_terms=n_terms,
                                   truncation=fmmax.Truncation.CIRCULAR)
    x = (np.arange(grid) + 0.5) * P / grid - P / 2
    X, Y = np.meshgrid(x, x, indexing="ij")
    eps = jnp.asarray(np.where((np.abs(X) < W / 2) & (np.abs(Y) < W / 2), NSI ** 2, 1.0) + 0j)
    form = getattr(fmmax.Formulation, formulation)

    kw = dict(wavelength=jnp.asarray(WL), in_plane_wavevector=jnp.zeros((2,)),
              primitive_lattice_vectors=plv, expansion=exp)

    def stack(perm, formulation):
        sub = fmmax.eigensolve_isotropic_media(permittivity=jnp.full((1, 1), NSI ** 2 + 0j),
                                               formulation=fmmax.Formulation.FFT, **kw)
        lay = fmmax.eigensolve_isotropic_media(permittivity=perm, formulation=formulation, **kw)
        air = fmmax.eigensolve_isotropic_media(permittivity=jnp.ones((1, 1), complex),
                                               formulation=fmmax.Formulation.FFT, **kw)
        return fmmax.stack_s_matrix([sub, lay, air], [jnp.asarray(0.0), jnp.asarray(H), jnp.asarray(0.0)]).s21

    run = jax.jit(lambda perm: stack(perm, form))
    t = run(eps).block_until_ready()   # compile
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        t = run(eps).block_until_ready()
        best = min(best, time.perf_counter() - t0)
    n = exp.num_terms
    i0 = int(np.flatnonzero(np.all(np.asarray(exp.basis_coefficients) == 0, axis=1))[0])
    # fmmax's modal amplitudes do not use our reference planes/normalisation (its uniform-slab phase
    # differs from the Airy phase), so its accuracy is judged by self-convergence (see main()).
    return complex(np.asarray(t)[i0, i0]), best, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small truncations only (smoke test)")
    ap.add_argument("--fmmax-terms", nargs="*", type=int, default=[97, 193, 293, 437])
    ap.add_argument("--fmmax-formulation", default="JONES_DIRECT")
    ap.add_argument("--ref-M", type=int, default=20)
    ap.add_argument("--library", action="store_true", help="also time a 31 x 31 library at M = 10")
    ap.add_argument("--out", default=None, help="write the numbers as JSON")
    a = ap.parse_args()
    Ms_li = [4, 6, 8, 10, 12] if not a.quick else [4, 6, 8]
    Ms_la = [4, 6, 8, 10, 12] if not a.quick else [4, 6]
    ref_M = a.ref_M if not a.quick else 12
    rows = []
    t_ref, dt_ref = ours(ref_M, "li", repeat=1, pols=("x",))
    t_lo, _ = ours(ref_M - 4, "li", repeat=1, pols=("x",))
    # Richardson with error ~ M^-2
    q = (ref_M / (ref_M - 4)) ** 2
    ph_ext = np.angle(t_ref) + (np.angle(t_ref) - np.angle(t_lo)) / (q - 1)
    ph_ref = float(np.angle(t_ref))
    print(f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus, 1 thread per solver")
    print(f"# reference: ours Li M={ref_M} ({(2 * ref_M + 1) ** 2} plane waves): phase {ph_ref:.5f} rad, "
          f"|t|^2 {abs(t_ref) ** 2:.5f} ({dt_ref:.1f} s, x only); Richardson limit {ph_ext:.5f} rad")
    print(f"{'solver':28s} {'harmonics':>9s} {'phase (rad)':>12s} {'|err| (rad)':>12s} {'time/geom (s)':>14s}")
    for fact, Ms in (("li", Ms_li), ("laurent", Ms_la)):
        for M in Ms:
            t, dt = ours(M, fact)
            row = dict(solver=f"metafovea {fact}", M=M, harmonics=(2 * M + 1) ** 2, phase=float(np.angle(t)),
                       err=abs(float(np.angle(t)) - ph_ref), time_s=dt)
            rows.append(row)
            print(f"{row['solver']:28s} {row['harmonics']:9d} {row['phase']:12.5f} {row['err']:12.5f} {dt:14.4f}",
                  flush=True)
    # x-only (what the library uses: y from the swapped post)
    for M in ([8, 10] if not a.quick else [6]):
        t, dt = ours(M, "li", pols=("x",))
        rows.append(dict(solver="metafovea li (x only)", M=M, harmonics=(2 * M + 1) ** 2, phase=float(np.angle(t)),
                         err=abs(float(np.angle(t)) - ph_ref), time_s=dt))
        r = rows[-1]
        print(f"{r['solver']:28s} {r['harmonics']:9d} {r['phase']:12.5f} {r['err']:12.5f} {dt:14.4f}", flush=True)
    try:
        import fmmax  # noqa: F401
        have_fmmax = True
    except ImportError:
        have_fmmax = False
        print("# fmmax not installed: pip install fmmax")
    if have_fmmax:
        fm = []
        for n in (a.fmmax_terms if not a.quick else [97]):
            t, dt, nt = fmmax_run(n, a.fmmax_formulation, repeat=1 if n > 300 else 2)
            fm.append((nt, t, dt))
            print(f"# fmmax {a.fmmax_formulation.lower()} {nt} terms: raw phase {np.angle(t):.5f}, {dt:.3f} s", flush=True)
        # error = change of the phase relative to fmmax's own largest truncation (self-convergence,
        # a lower bound of its true error; its phase convention differs from ours by an offset)
        t_last = fm[-1][1]
        for nt, t, dt in fm:
            row = dict(solver=f"fmmax {a.fmmax_formulation.lower()}", M=None, harmonics=nt,
                       phase=float(np.angle(t)), err=abs(float(np.angle(t / t_last))), time_s=dt,
                       err_kind="self-convergence vs largest fmmax run")
            rows.append(row)
            print(f"{row['solver']:28s} {nt:9d} {row['phase']:12.5f} {row['err']:12.5f}* {dt:13.4f}", flush=True)
        print("# * fmmax error: relative to its own largest truncation (lower bound of the true error)")
    lib_time = None
    if a.library:
        import tempfile
        from metafovea.library import compute_library, width_grid
        w = width_grid(P, 0.1, 0.5)
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            compute_library(w, None, [WL], harmonics=10, cache_dir=d, workers=2, progress=False)
            lib_time = time.perf_counter() - t0
        print(f"# library 31 x 31, M = 10, 2 workers: {lib_time:.1f} s")
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(dict(reference_phase=ph_ref, richardson_phase=float(ph_ext), ref_M=ref_M, rows=rows,
                           library_31x31_s=lib_time), fh, indent=1)


if __name__ == "__main__":
    main()
