"""Tests of the posts' oblique-incidence response (metafovea.library.oblique)."""

from __future__ import annotations

import numpy as np

from metafovea.library import PostSet


def test_oblique_response_against_direct_solves_at_unseen_angles(tmp_path):
    """The posts off axis: the interpolated ratio t(theta) / t(0) and its error estimate against direct RCWA solves
    at angles and azimuths the response was not computed at, with more Fourier orders (the converged side)."""
    import math

    from metafovea.library import oblique_response
    from metafovea.rcwa.geometry import Layer, Rectangle, Stack
    from metafovea.rcwa.solve import solve

    widths = np.array([[1.3, 2.9], [2.7, 1.1]])  # two birefringent posts of the paper's range
    ps = PostSet("x", 4.0, 10.0, 10.0, widths, np.ones(2), np.ones(2), source="rcwa")
    ob = oblique_response(ps, cache_dir=tmp_path)
    assert np.allclose(ob.factor("x", 0.0, 0.3), 1.0) and np.allclose(ob.factor("y", 0.0, 1.1), 1.0)
    assert 0 < ob.error < 0.1
    stacks = [Stack(4.0, 4.0, (Layer(10.0, 1.0, (Rectangle(wx, wy, 3.42),)),), 3.42, 1.0) for wx, wy in widths]
    normal = [solve(st, 10.0, harmonics=7, check_energy=False).t00("substrate") for st in stacks]
    for theta, az in ((4.3, 0.0), (9.7, 0.5 * math.pi), (14.2, 0.0), (15.6, 0.5 * math.pi)):
        for k, (st, j0) in enumerate(zip(stacks, normal)):
            th_si = math.degrees(math.asin(math.sin(math.radians(theta)) / 3.42))
            j = solve(st, 10.0, harmonics=7, theta_deg=th_si, phi_deg=math.degrees(az), incidence="substrate",
                      check_energy=False).t00("substrate")
            tx, ty = (j[0, 0], j[1, 1]) if az == 0.0 else (j[1, 1], j[0, 0])
            assert abs(ob.factor("x", theta, az)[k] - tx / j0[0, 0]) <= ob.error
            assert abs(ob.factor("y", theta, az)[k] - ty / j0[1, 1]) <= ob.error
    # cached: the same numbers from the file
    again = oblique_response(ps, cache_dir=tmp_path)
    assert again.error == ob.error and np.array_equal(again.ratio["x"], ob.ratio["x"])
