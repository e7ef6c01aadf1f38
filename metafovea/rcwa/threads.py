"""Limit BLAS threads while solving many small RCWA problems.

The eigenproblems of a library sweep are small (a few hundred unknowns); OpenBLAS' threads then
spin more than they work (measured here: 5x more CPU time with 2 threads than with 1), and sweeps
already run one process per core. :func:`blas_threads` sets the thread count of the loaded OpenBLAS
(or, if installed, anything threadpoolctl knows) for the duration of a ``with`` block.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
from typing import Iterator

log = logging.getLogger(__name__)

_GET = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_",
        "openblas_get_num_threads")
_SET = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
        "openblas_set_num_threads")


def _openblas_libs() -> list:
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ".so" in ln})
    except OSError:
        return []
    out = []
    for p in paths:
        try:
            lib = ctypes.CDLL(p)
        except OSError:
            continue
        get = next((getattr(lib, n) for n in _GET if hasattr(lib, n)), None)
        set_ = next((getattr(lib, n) for n in _SET if hasattr(lib, n)), None)
        if get is not None and set_ is not None:
            out.append((get, set_))
    return out


@contextlib.contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Temporarily run BLAS/LAPACK with ``n`` threads (no-op if the library cannot be found)."""
    try:
        from threadpoolctl import threadpool_limits  # type: ignore
    except ImportError:
        threadpool_limits = None
    if threadpool_limits is not None:
        with threadpool_limits(limits=n, user_api="blas"):
            yield
        return
    import numpy  # noqa: F401  (make sure the BLAS is loaded)
    libs = _openblas_libs()
    old = []
    for get, set_ in libs:
        try:
            old.append(int(get()))
            set_(ctypes.c_int(n))
        except Exception:  # noqa: BLE001 - best effort
            old.append(None)
    try:
        yield
    finally:
        for (get, set_), o in zip(libs, old):
            if o is not None:
                set_(ctypes.c_int(o))
