"""Propagation engines: the band-limited angular spectrum (exact for a sampled field) as the reference for the
direction-sine engines (mft, hankel), then the engines against each other, node rules and aliasing detection.

References from /work/shared/REFERENCES.md ("PSF references").
"""

import math

import numpy as np
import pytest

from metafovea.config import LensDesign
from metafovea.optics import AliasingWarning, asm_propagate, build_pupils, mft_field
from metafovea.optics import propagate as prop

F1 = LensDesign.perifoveal()  # F/1, D = 25 mm
F2 = LensDesign.foveal()  # F/2, D = 75 mm


def test_asm_reference_against_debye_small_lens():
    # F/2, D = 4 mm: Fresnel number 100; the Debye engine and the exact ASM agree to ~1e-2 of the peak
    lens = LensDesign("small", 8000.0, 4000.0)
    pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
    u0, ax = prop.sampled_lens_field(pu, 10.0)
    res = asm_propagate(u0, 10.0, 10.0, lens.f_um, pad=2.0)
    I = np.abs(res.field) ** 2
    c = ax.size // 2
    sl = slice(c - 10, c + 11)
    ref = np.abs(mft_field(pu, ax[sl], ax[sl])) ** 2
    assert np.abs(I[sl, sl] - ref).max() / ref.max() < 3e-2
    # energy: |U|^2 dx^2 over the plane = power through the aperture
    assert (np.abs(res.field) ** 2).sum() * 100 == pytest.approx((np.abs(u0) ** 2).sum() * 100, rel=2e-2)


@pytest.mark.slow
def test_asm_full_lens_f1_agrees_with_debye():
    """Full 25 mm F/1 lens, BL-ASM vs the direction-sine engine (REFERENCES: 10 um sampling with 2x padding
    1.4e-4; 5 um 2.8e-5). Small size by default (10 um, ~0.4 GB); METAFOVEA_FULL=1: 5 um, pad 1.5 (~1 GB)."""
    import os
    dx, pad = (5.0, 1.5) if os.environ.get("METAFOVEA_FULL") else (10.0, 2.0)
    pu = build_pupils(F1, 10.0, quantize=False, lattice=False).focus
    u0, ax = prop.sampled_lens_field(pu, dx)
    res = asm_propagate(u0, dx, 10.0, F1.f_um, pad=pad)
    c = ax.size // 2
    sl = slice(c - 20, c + 21)
    ref = np.abs(mft_field(pu, ax[sl], ax[sl])) ** 2
    I = np.abs(res.field[sl, sl]) ** 2
    airy_peak = (math.pi * F1.radius_um ** 2 / (F1.wavelength_um * F1.f_um)) ** 2
    assert np.abs(I - ref).max() / airy_peak < 3e-4


def test_engines_agree_mft_hankel_on_axis():
    for lens in (F1, F2):
        pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
        xs = np.linspace(-100, 100, 101)
        a = np.abs(mft_field(pu, xs, xs, error=1e-6)) ** 2
        b = np.abs(prop.hankel_grid(pu, xs, xs, error=1e-8)) ** 2
        assert np.abs(a - b).max() / b.max() < 1e-4


def test_mft_node_rule_converged_off_axis():
    pu = build_pupils(F1, 10.0, field_deg=5.0, quantize=False, lattice=False).focus
    c = pu.chief_ray_um()
    xs = c[0] + np.arange(-100, 1201, 8.0)
    ys = np.arange(-400, 401, 8.0)
    nt, nr = prop.mft_nodes(pu, xs, ys, 1e-5)
    a = np.abs(mft_field(pu, xs, ys, nodes=(nt, nr))) ** 2
    b = np.abs(mft_field(pu, xs, ys, nodes=(int(1.6 * nt), int(1.6 * nr)))) ** 2
    assert np.abs(a - b).max() / b.max() < 1e-5


def test_mft_intensity_multi_matches_single_wavelength_engine():
    ps = [build_pupils(F2, l, field_deg=1.3).focus for l in (9.95, 10.0, 10.04)]
    c = ps[0].chief_ray_um()
    xs = c[0] + np.arange(-200, 200, 5.0)
    ys = np.arange(-150, 150, 5.0)
    w = [0.3, 0.5, 0.2]
    I = prop.mft_intensity_multi(ps, w, xs, ys, error=1e-8)
    R = sum(wk * np.abs(mft_field(p, xs, ys, error=1e-8)) ** 2 for p, wk in zip(ps, w))
    assert np.abs(I - R).max() / R.max() < 1e-9


def test_asm_aliasing_detected():
    lens = LensDesign("small", 2000.0, 2000.0)  # F/1, rim gradient 0.447/lambda -> needs pitch < 11 um
    pu = build_pupils(lens, 10.0, quantize=False, lattice=False).focus
    u0, _ = prop.sampled_lens_field(pu, 16.0)
    with pytest.warns(AliasingWarning):
        asm_propagate(u0, 16.0, 10.0, lens.f_um)
