"""In-house RCWA (Fourier modal method) for 2-D periodic stacks of rectangular-post layers.

Public API
----------
* :class:`Stack`, :class:`Layer`, :class:`Rectangle` - geometry (z from substrate to superstrate).
* :func:`solve` - general solver: any stack, angle, polarisation; all orders, both entry sides.
* :func:`post_response` - fast batched zero-order response of centred posts at normal incidence
  (parity-adapted basis, x-pol only, y from the swapped post), used by :mod:`metafovea.library`.

Conventions (details in :mod:`metafovea.rcwa.solve` and :mod:`metafovea.rcwa.posts`)
------------------------------------------------------------------------------------
* ``exp(-i omega t)``; plane waves ``exp(+i k z)``; loss ``Im n > 0``.
* Reference planes of phases: the faces of the layer stack (z = 0 and z = total thickness).
* Amplitudes are power normalised (``|t|^2`` = efficiency); ``t_field = t sqrt(n_in / n_out)``.
* Polarisations 'p' (index 0) and 's' (index 1); at normal incidence with phi = 0, p = x, s = y.
* Factorisation: 'li' (Li's rules for crossed gratings: inverse rule across each discontinuity,
  Laurent along it) or 'laurent' (plain Laurent rule, for comparison).
* Default entry side for posts: the substrate (through the wafer; posts face the sensor).

Relation to fmmax (tests/rcwa/test_fmmax.py, benchmarks/bench_rcwa.py)
-----------------------------------------------------------------------
fmmax uses the same exp(-i omega t) convention. With layers [substrate, ..., superstrate] and
zero-thickness ambient layers, ``stack_s_matrix(...).s11`` (not s21, which is the reflection) is the
forward transmission between our reference planes, in H-field amplitudes: index ``N + i0`` (hy) is
x-polarised E, ``i0`` (hx) is y-polarised E, and ``t(ours) = s11 * sqrt(n_in / n_out)``; reflections
change sign (``r(ours) = -s21``). Forward amplitudes are referenced at the start of a layer, backward
ones at its end, so a first-layer thickness d adds exp(i k0 n d) to s11. fmmax's FFT formulation with a
PARALLELOGRAMIC truncation of (2M+1)^2 terms equals our 'laurent' factorisation.
"""

from metafovea.rcwa.geometry import Layer, Rectangle, Stack
from metafovea.rcwa.posts import PostResponse, post_response
from metafovea.rcwa.solve import FACTORIZATIONS, SIDES, Result, n_harmonics, solve

__all__ = ["Layer", "Rectangle", "Stack", "Result", "solve", "n_harmonics", "FACTORIZATIONS", "SIDES",
           "post_response", "PostResponse"]
