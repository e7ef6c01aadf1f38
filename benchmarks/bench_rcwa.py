"""RCWA benchmark: zero-order phase error versus harmonics versus time per geometry for the paper's
post (p = 4 um, h = 10 um, 2.0 x 2.0 um Si post (n = 3.42) on Si, air above, lambda = 10 um, light
from the substrate), for our Li and Laurent factorisations and for fmmax's formulations, all in the
same process against ONE common reference.

    taskset -c 0 python benchmarks/bench_rcwa.py [--quick] [--fmmax-M 4 6 8 10]
        [--fmmax-formulations FFT JONES_DIRECT POL] [--fmmax-extra-M 12]
        [--fmmax-truncation PARALLELOGRAMIC|CIRCULAR] [--fmmax-grid 400] [--library]
        [--pairs 9 5 --pairs 10 5 ...] [--broadband-wavelengths 13] [--out BENCH.json]

Ours runs the parity-adapted path of ``post_response`` (the post is centred, light at normal incidence: x and y
polarisations solved separately in bases of even/odd harmonics). Rows ``metafovea li AxB`` use
``harmonics=(A, B)``: orders up to A along the incident E-field, B across it. The broadband lines time one
batched call on 8 random rectangles x 13 wavelengths over 8-14 um (both polarisations) per post and wavelength,
what a broadband library pays; compare them with fmmax's time per solve (fmmax's cost per wavelength is that of
a single solve: nothing carries over between wavelengths).

Fairness: one BLAS/OpenMP thread for numpy and one XLA thread for fmmax (env vars below, set before
numpy/jax load); run it under ``taskset -c 0`` to pin the whole process (both solvers) to one core.

How fmmax's amplitudes map onto ours (pinned down with a uniform slab, a free-standing slab and a
single interface, see tests/rcwa/test_fmmax.py):

* same time convention, exp(-i omega t) (forward waves exp(+i q z), Im q > 0): no conjugation;
* ``stack_s_matrix(...)``: **s11 is the forward transmission** (first layer -> last layer) and s21
  the reflection back into the first layer (Whittaker & Culshaw's ordering, not the "S21 =
  transmission" of network theory). Reading s21 as transmission is what made fmmax's phase "not line
  up" (2.6 rad for the post: that was the reflection);
* reference planes: forward amplitudes are referenced at the START of each layer, backward ones at
  its END. With zero-thickness ambient layers that is our layer faces; a first-layer thickness d1
  multiplies s11 by exp(i k0 n1 d1), a last-layer thickness leaves s11 unchanged (it enters s22);
* uniform-layer eigenvectors are the identity on the (hx, hy) Fourier amplitudes: amplitudes are
  **H-field** amplitudes. Index ``i`` (first half) is hx, i.e. y-polarised E; ``N + i`` is hy, i.e.
  x-polarised E. So ``t_x(ours, power normalised) = s11[N + i0, N + i0] * sqrt(n_in / n_out)``
  (t_H = t_E n_out / n_in), and co-polarised reflections change sign (r_H = -r_E);
* fmmax's FFT formulation is the plain Laurent rule with [[eps]]^-1 for eps_z: with a PARALLELOGRAMIC
  truncation of (2M+1)^2 terms (= our rectangular set) it reproduces our 'laurent' result to ~1e-6.
  Li's factorisation has no fmmax counterpart; its vector formulations (JONES_DIRECT, POL, ...) are
  the closest.

"CPU/geometry" is the best process CPU time (time.process_time) of one post, both polarisations
(ours: x plus the swapped post; fmmax: one jitted solve, after compilation, which gives both); it is
what the speed-up uses, because the wall time on a shared, loaded machine mostly measures the other
jobs. The best wall time is printed as well.
"""

from __future__ import annotations

import os

# one thread per process, set before numpy and jax load their BLAS and XLA runtimes
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")

import argparse
import json
import platform
import resource
import time

import numpy as np

from metafovea.rcwa.posts import post_response

P, H, WL, W, NSI = 4.0, 10.0, 10.0, 2.0, 3.42
TOL = 0.01


def ours(M, factorization: str, repeat: int = 3, pols=("x", "y")):
    """Our zero-order x transmission of the post and the best wall and CPU time of one call; ``M`` an integer or
    a pair (M_along, M_across). Both polarisations are two solves (x, and x of the post turned by 90 degrees),
    also for this square post, so the time is that of any rectangle."""
    post_response(W, W, WL, harmonics=M, factorization=factorization, polarizations=pols)
    best = best_cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        r = post_response(W, W, WL, harmonics=M, factorization=factorization, polarizations=pols)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return complex(r.t_x), best, best_cpu


def fmmax_t00(M: int, formulation: str, *, width=W, grid: int = 400, truncation: str = "PARALLELOGRAMIC",
              repeat: int = 2):
    """fmmax's zero-order x transmission of the post, converted to our convention (power-normalised,
    reference planes at the layer faces), with its best time per solve after jit compilation.

    The post is rasterised on a ``grid`` x ``grid`` pixel map whose pixel edges fall on the post edges
    (2.0 um = 200 pixels of 0.01 um), so the only discretisation left is the DFT's, ~(pi m/grid)^2/6
    relative in the m-th Fourier coefficient.
    """
    import jax
    jax.config.update("jax_enable_x64", True)
    import fmmax
    import jax.numpy as jnp

    plv = fmmax.LatticeVectors(u=fmmax.basis.X * P, v=fmmax.basis.Y * P)
    exp = fmmax.generate_expansion(primitive_lattice_vectors=plv, approximate_num_terms=(2 * M + 1) ** 2,
                                   truncation=getattr(fmmax.Truncation, truncation))
    x = (np.arange(grid) + 0.5) * P / grid - P / 2
    X, Y = np.meshgrid(x, x, indexing="ij")
    eps = jnp.asarray(np.where((np.abs(X) < width / 2) & (np.abs(Y) < width / 2), NSI ** 2, 1.0) + 0j)
    form = getattr(fmmax.Formulation, formulation)
    kw = dict(wavelength=jnp.asarray(WL), in_plane_wavevector=jnp.zeros((2,)),
              primitive_lattice_vectors=plv, expansion=exp)

    def s11(perm):
        sub = fmmax.eigensolve_isotropic_media(permittivity=jnp.full((1, 1), NSI ** 2 + 0j),
                                               formulation=fmmax.Formulation.FFT, **kw)
        lay = fmmax.eigensolve_isotropic_media(permittivity=perm, formulation=form, **kw)
        air = fmmax.eigensolve_isotropic_media(permittivity=jnp.ones((1, 1), complex),
                                               formulation=fmmax.Formulation.FFT, **kw)
        return fmmax.stack_s_matrix([sub, lay, air], [jnp.asarray(0.0), jnp.asarray(H), jnp.asarray(0.0)]).s11

    run = jax.jit(s11)
    t0 = time.perf_counter()
    s = run(eps).block_until_ready()
    t_compile = time.perf_counter() - t0
    best = best_cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        s = run(eps).block_until_ready()
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    n = exp.num_terms
    i0 = int(np.flatnonzero(np.all(np.asarray(exp.basis_coefficients) == 0, axis=1))[0])
    t_x = complex(np.asarray(s)[n + i0, n + i0]) * np.sqrt(NSI / 1.0)   # H-field -> power normalised
    return t_x, best, best_cpu, n, t_compile


def broadband(M, n_posts: int = 8, n_wl: int = 13, repeat: int = 2, grid: bool = False) -> tuple[float, float]:
    """Best (wall, CPU) seconds per post and wavelength, both polarisations, of one batched call on ``n_posts``
    random rectangles (0.5-3.5 um sides) at ``n_wl`` wavelengths over 8-14 um (what a broadband library does).

    ``grid``: the library's way instead: a square grid of ``n_posts`` x ``n_posts`` widths, x-polarised light only,
    since ``t_y(wx, wy) = t_x(wy, wx)`` is another point of the same grid (one solve per post and wavelength)."""
    rng = np.random.default_rng(0)
    if grid:
        wx = np.linspace(0.5, 3.5, n_posts)[:, None, None]
        wy = wx[None, :, 0]
        pols, count = ("x",), n_posts * n_posts * n_wl
    else:
        wx, wy = rng.uniform(0.5, 3.5, (2, n_posts, 1))
        pols, count = ("x", "y"), n_posts * n_wl
    wl = np.linspace(8.0, 14.0, n_wl)
    best = best_cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        post_response(wx, wy, wl, harmonics=M, polarizations=pols)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return best / count, best_cpu / count


def _row(rows, solver, nh, t, dt, cpu, ph_ref, **extra):
    row = dict(solver=solver, harmonics=int(nh), phase=float(np.angle(t)), T=float(abs(t) ** 2),
               err=abs(float(np.angle(t)) - ph_ref), wall_s=float(dt), time_s=float(cpu), **extra)
    rows.append(row)
    print(f"{solver:34s} {nh:9d} {row['phase']:12.5f} {row['err']:12.5f} {cpu:13.4f} {dt:12.4f}", flush=True)
    return row


def _best_at_tol(rows, solver):
    """The fastest row within TOL of ``solver`` (a name, or a predicate on names)."""
    match = solver if callable(solver) else (lambda name: name == solver)
    ok = [r for r in rows if match(r["solver"]) and r["err"] <= TOL]
    return min(ok, key=lambda r: r["time_s"]) if ok else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small truncations only (smoke test)")
    ap.add_argument("--fmmax-M", nargs="*", type=int, default=[4, 6, 8, 10],
                    help="fmmax truncations M ((2M+1)^2 terms, square = our set)")
    ap.add_argument("--fmmax-formulations", nargs="*", default=["FFT", "JONES_DIRECT", "POL"])
    ap.add_argument("--fmmax-extra-M", nargs="*", type=int, default=[],
                    help="further M for the first vector formulation only (expensive)")
    ap.add_argument("--fmmax-truncation", default="PARALLELOGRAMIC", choices=["PARALLELOGRAMIC", "CIRCULAR"],
                    help="PARALLELOGRAMIC = our square harmonic set; CIRCULAR = fmmax's default")
    ap.add_argument("--fmmax-grid", type=int, default=400, help="pixels per period of fmmax's permittivity map")
    ap.add_argument("--ref-M", type=int, default=20)
    ap.add_argument("--pairs", nargs="*", type=int, action="append", default=None,
                    help="(M_along M_across) truncations of ours, e.g. --pairs 10 5 --pairs 12 6")
    ap.add_argument("--broadband-wavelengths", type=int, default=13,
                    help="wavelengths 8-14 um of the broadband sweep timing")
    ap.add_argument("--library", action="store_true", help="also time a 31 x 31 library at M = 10")
    ap.add_argument("--out", default=None, help="write the numbers as JSON")
    a = ap.parse_args()
    a.pairs = a.pairs if a.pairs is not None else [[9, 5], [10, 5], [12, 6]]
    if any(len(p) != 2 for p in a.pairs):
        ap.error("--pairs takes two integers (M_along M_across)")
    Ms_li = [4, 6, 8, 10, 12] if not a.quick else [4, 6]
    Ms_la = [4, 6, 8, 10, 12] if not a.quick else [4, 6]
    ref_M = a.ref_M if not a.quick else 12
    fm_Ms = a.fmmax_M if not a.quick else [4]
    rows: list[dict] = []
    t_ref, dt_ref, _ = ours(ref_M, "li", repeat=1, pols=("x",))
    t_lo, _, _ = ours(ref_M - 4, "li", repeat=1, pols=("x",))
    q = (ref_M / (ref_M - 4)) ** 2          # Richardson with error ~ M^-2
    ph_ext = np.angle(t_ref) + (np.angle(t_ref) - np.angle(t_lo)) / (q - 1)
    ph_ref = float(np.angle(t_ref))
    aff = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "?"
    print(f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus, affinity {aff}, "
          f"load average {os.getloadavg()[0]:.2f}; 1 BLAS thread (numpy), 1 XLA thread (fmmax)")
    print(f"# common reference: ours Li M={ref_M} ({(2 * ref_M + 1) ** 2} plane waves): phase {ph_ref:.5f} rad, "
          f"|t|^2 {abs(t_ref) ** 2:.5f} ({dt_ref:.1f} s, x only); Richardson limit {ph_ext:.5f} rad")
    print(f"{'solver':34s} {'harmonics':>9s} {'phase (rad)':>12s} {'|err| (rad)':>12s} {'CPU/geom (s)':>13s} "
          f"{'wall/geom (s)':>12s}")
    ours_t = {}
    for fact, Ms in (("li", Ms_li), ("laurent", Ms_la)):
        for M in Ms:
            t, dt, cpu = ours(M, fact)
            ours_t[(fact, M)] = t
            _row(rows, f"metafovea {fact}", (2 * M + 1) ** 2, t, dt, cpu, ph_ref, M=M)
    for M in ([8, 10] if not a.quick else [6]):
        t, dt, cpu = ours(M, "li", pols=("x",))
        _row(rows, "metafovea li (x only, library)", (2 * M + 1) ** 2, t, dt, cpu, ph_ref, M=M)
    # more harmonics along the E-field than across it (post_response's harmonics=(M_along, M_across))
    for Mp in ([tuple(p) for p in a.pairs] if not a.quick else [(6, 3)]):
        t, dt, cpu = ours(Mp, "li")
        _row(rows, f"metafovea li {Mp[0]}x{Mp[1]}", (2 * Mp[0] + 1) * (2 * Mp[1] + 1), t, dt, cpu, ph_ref, M=list(Mp))
    bb = {}
    for M in ([8, 10] + [tuple(p) for p in a.pairs] if not a.quick else [4, (6, 3)]):
        dt, cpu = broadband(M, n_wl=a.broadband_wavelengths)
        bb[str(M)] = dict(wall_s=dt, time_s=cpu)
        print(f"# broadband sweep, harmonics {M}: 8 random posts x {a.broadband_wavelengths} wavelengths 8-14 um in "
              f"one call: {cpu:.4f} s CPU ({dt:.4f} s wall) per post and wavelength, both polarisations", flush=True)
    for M in ([8, 10] if not a.quick else [4]):
        dt, cpu = broadband(M, n_posts=5, n_wl=a.broadband_wavelengths, repeat=1, grid=True)
        bb[f"grid {M}"] = dict(wall_s=dt, time_s=cpu)
        print(f"# broadband library grid, harmonics {M}: 5 x 5 widths x {a.broadband_wavelengths} wavelengths, x only "
              f"(y from the transposed grid point): {cpu:.4f} s CPU ({dt:.4f} s wall) per post and wavelength, both "
              f"polarisations", flush=True)
    # before fmmax/jax is imported: the library forks worker processes
    lib_time = lib_cpu = None
    if a.library:
        import tempfile

        from metafovea.library import compute_library, width_grid
        w = width_grid(P, 0.1, 0.5)
        aff0 = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
        if aff0 is not None:     # the library uses 2 worker processes: undo taskset for it
            os.sched_setaffinity(0, range(os.cpu_count() or 1))
        with tempfile.TemporaryDirectory() as d:
            c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            compute_library(w, None, [WL], harmonics=10, cache_dir=d, use_cache=False, workers=2,
                            progress=False)  # not the shipped seed library (metafovea/data): the sweep itself
            lib_time = time.perf_counter() - t0
            c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if aff0 is not None:
            os.sched_setaffinity(0, aff0)
        lib_cpu = (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)
        # workers started by a forkserver are its children, not ours: their CPU time is not seen here
        lib_cpu = lib_cpu if lib_cpu > 0 else None
        cpu_text = "worker CPU not seen (forkserver workers)" if lib_cpu is None else f"{lib_cpu:.1f} s worker CPU"
        print(f"# library 31 x 31, M = 10 (+ M = 8 estimate), 2 workers: {lib_time:.1f} s wall, {cpu_text} "
              f"(load average {os.getloadavg()[0]:.2f})", flush=True)
    try:
        import fmmax
        have_fmmax = True
    except ImportError:
        have_fmmax = False
        print("# fmmax not installed: pip install fmmax")
    if have_fmmax:
        vec = [f for f in a.fmmax_formulations if f != "FFT"]
        for form in a.fmmax_formulations:
            Ms = list(fm_Ms) + (list(a.fmmax_extra_M) if vec and form == vec[0] and not a.quick else [])
            for M in Ms:
                t, dt, cpu, nt, tc = fmmax_t00(M, form, repeat=2 if M > 9 else 3, grid=a.fmmax_grid,
                                           truncation=a.fmmax_truncation)
                extra = dict(M=M, compile_s=tc)
                if form == "FFT" and ("laurent", M) in ours_t and a.fmmax_truncation == "PARALLELOGRAMIC":
                    extra["diff_vs_ours_laurent"] = abs(t - ours_t[("laurent", M)])
                trunc = "" if a.fmmax_truncation == "PARALLELOGRAMIC" else " circular"
                _row(rows, f"fmmax {fmmax.__version__} {form}{trunc}", nt, t, dt, cpu, ph_ref, **extra)
        fft = [r for r in rows if r["solver"].endswith(" FFT") and "diff_vs_ours_laurent" in r]
        if fft:
            print(f"# fmmax FFT vs ours Laurent at identical harmonics: max |t_fmmax - t_ours| = "
                  f"{max(r['diff_vs_ours_laurent'] for r in fft):.2e}")
    # speed-up at equal accuracy: ours with the square truncation (the default), and with the best of all ours
    # (the pairs included); both polarisations per geometry
    summary = {}
    def any_li(name):
        return name == "metafovea li" or (name.startswith("metafovea li ") and "x only" not in name)

    for label, ours_name in (("square", "metafovea li"), ("any", any_li)):
        li = _best_at_tol(rows, ours_name)
        if label == "any" and (li is None or li["solver"] == "metafovea li"):
            continue
        ours_name = "metafovea li" if label == "square" else "metafovea li (M_along, M_across)"
        print(f"# at |err| <= {TOL} rad: {li['solver'] if li else ours_name} needs {li['harmonics'] if li else '-'} "
              f"plane waves, {li['time_s'] if li else float('nan'):.4f} s CPU per geometry")
        for solver in sorted({r["solver"] for r in rows if r["solver"].startswith("fmmax")}):
            b = _best_at_tol(rows, solver)
            key = f"{solver} vs {li['solver'] if li else ours_name}"
            if b is not None and li is not None:
                s = b["time_s"] / li["time_s"]
                summary[key] = dict(reached=True, harmonics=b["harmonics"], time_s=b["time_s"], speedup=s,
                                    ours_time_s=li["time_s"])
                print(f"# {solver}: reaches {TOL} rad at {b['harmonics']} terms, {b['time_s']:.3f} s CPU "
                      f"-> speed-up {s:.0f}x")
            elif li is not None:
                last = max((r for r in rows if r["solver"] == solver), key=lambda r: r["harmonics"])
                s = last["time_s"] / li["time_s"]
                summary[key] = dict(reached=False, harmonics=last["harmonics"], err=last["err"],
                                    time_s=last["time_s"], speedup_lower_bound=s, ours_time_s=li["time_s"])
                print(f"# {solver}: not within {TOL} rad up to {last['harmonics']} terms (err {last['err']:.4f}, "
                      f"{last['time_s']:.3f} s CPU) -> speed-up > {s:.0f}x (lower bound)")
    print(f"# load average at the end {os.getloadavg()[0]:.2f}")
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(dict(reference_phase=ph_ref, richardson_phase=float(ph_ext), ref_M=ref_M, rows=rows,
                           speedup=summary, broadband_per_post_and_wavelength=bb,
                           library_31x31_s=lib_time, library_31x31_cpu_s=lib_cpu,
                           load_average=os.getloadavg()),
                      fh, indent=1, default=float)


if __name__ == "__main__":
    main()
