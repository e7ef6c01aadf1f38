"""The foveal constraint's linear operators (D, C and their adjoints), the image gradient and the smoothed TV:
dot-product (adjoint) tests for every linear operator first, then their values and input checks."""

from __future__ import annotations

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.reconstruct import FovealOperator, centre_crop, downsample, downsample_adjoint
from metafovea.reconstruct.operators import grad2d, grad2d_adjoint, lowpass, lowpass_noise_factor, tv_charbonnier
from metafovea.reconstruct.synthetic import scene


@pytest.mark.parametrize("shape,scale,offset", [((96, 96), 6, (0, 0)), ((64, 80), 6, (0, 0)),
                                                ((100, 90), 6.5, (1.5, -2.25)), ((290, 290), 6, (0, 0))])
def test_operator_adjoints_and_constraint(shape, scale, offset):
    """<D x, u> == <x, D^T u> and <C x, u> == <x, C^T u> (non-integer scale and sub-pixel offset included); both
    keep constants."""
    rng = np.random.default_rng(0)
    op = FovealOperator(shape, scale, offset)
    x = rng.random(shape)
    u = rng.random(op.low_shape)
    assert op.low_shape == (int(shape[0] // scale), int(shape[1] // scale))
    assert np.sum(op.D(x) * u) == pytest.approx(np.sum(x * op.DT(u)), rel=1e-12)
    assert np.sum(op.C(x) * u) == pytest.approx(np.sum(x * op.CT(u)), rel=1e-12)
    assert np.allclose(op.D(np.ones(shape)), 1.0) and np.allclose(op.C(np.ones(shape)), 1.0)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.5, -1.25)])
def test_the_crops_pseudo_inverse_is_the_least_norm_change_with_that_crop(offset):
    """C (C^+ u) == u, on and between pixels, and C^+ u is the smallest such change: it lies in C^T's range (any
    change with the same crop differs from it by a null-space part orthogonal to it); a rotated crop is refused."""
    rng = np.random.default_rng(1)
    op = FovealOperator((60, 72), 6.0, offset)
    u = rng.standard_normal(op.low_shape)
    x = op.C_pinv(u)
    assert np.allclose(op.C(x), u, atol=1e-12)
    other = x + rng.standard_normal(x.shape)
    other -= op.C_pinv(op.C(other) - u)  # another change with the same crop
    assert np.allclose(op.C(other), u, atol=1e-12) and np.sum(x * x) < np.sum(other * other)
    assert abs(np.sum(x * (other - x))) < 1e-9 * np.sum(x * x)
    with pytest.raises(InputError, match="rotation_deg"):
        FovealOperator((60, 72), 6.0, rotation_deg=1.0).C_pinv(u)


def test_operator_adjoints_on_a_batch():
    """The operators act on leading batch axes ``(K, H, W)``; the dot-product identity holds over the batch."""
    rng = np.random.default_rng(3)
    op = FovealOperator((60, 66), 5.5, (0.5, -1.0))
    x = rng.random((3, 60, 66))
    u = rng.random((3, *op.low_shape))
    assert np.vdot(op.D(x), u) == pytest.approx(np.vdot(x, op.DT(u)), rel=1e-12)
    assert np.vdot(op.C(x), u) == pytest.approx(np.vdot(x, op.CT(u)), rel=1e-12)


@pytest.mark.parametrize("shape,scale,offset,rot", [((96, 96), 6, (0, 0), 0.5), ((100, 90), 6.5, (1.5, -2.25), -2.0),
                                                    ((290, 280), 6.12, (1.5, 2.0), 0.3)])
def test_the_rotated_crop_is_adjoint_and_reads_where_the_convention_says(shape, scale, offset, rot):
    """With a rotation the crop reads ``x2`` where docs/measurement_format.md ("The foveal geometry") puts the scene
    point the foveal image's box shows: the foveal point ``p`` (``(x, y)`` from the sensor's centre, y down) shows
    ``q = centre + R(-rotation) p / scale`` (``R`` the counter-clockwise matrix on ``(x, y)``), read here by
    scipy's bilinear interpolation; the opposite sign reads elsewhere (a planted case). Adjoint, batch and float32
    kept; no rotation is the separable crop, unchanged."""
    rng = np.random.default_rng(1)
    H, W = shape
    x = rng.random((2, H, W))
    op = FovealOperator(shape, scale, offset, rotation_deg=rot)
    h, w = op.low_shape
    u = rng.random((2, h, w))
    assert np.vdot(op.C(x), u) == pytest.approx(np.vdot(x, op.CT(u)), rel=1e-12)
    assert op.C(x.astype(np.float32)).dtype == np.float32 and np.allclose(op.C(np.ones(shape)), 1.0)
    from scipy.ndimage import map_coordinates

    def reads(r_deg: float) -> np.ndarray:
        px = ((np.arange(w) - w / 2 + 0.5) * op.scale)[None, :] * np.ones((h, 1))  # the boxes' centres, (x, y)
        py = ((np.arange(h) - h / 2 + 0.5) * op.scale)[:, None] * np.ones((1, w))
        t = np.radians(-r_deg)
        qx = offset[1] + (np.cos(t) * px - np.sin(t) * py) / op.scale
        qy = offset[0] + (np.sin(t) * px + np.cos(t) * py) / op.scale
        return np.stack([map_coordinates(v, [qy + (H - 1) / 2, qx + (W - 1) / 2], order=1) for v in x])

    np.testing.assert_allclose(op.C(x), reads(rot), atol=1e-12)
    assert np.abs(op.C(x) - reads(-rot)).max() > 0.05
    plain = FovealOperator(shape, scale, offset)
    assert plain.Cs is None and FovealOperator(shape, scale, offset, rotation_deg=0.0).C(x).tobytes() == \
        plain.C(x).tobytes()
    with pytest.raises(InputError, match="rotation_deg"):
        FovealOperator(shape, scale, offset, rotation_deg=60.0)


def test_downsample_adjoint_is_the_adjoint_of_downsample():
    rng = np.random.default_rng(4)
    x = rng.random((72, 84))
    u = rng.random((12, 14))
    assert np.vdot(downsample(x, 6), u) == pytest.approx(np.vdot(x, downsample_adjoint(u, (72, 84), 6)), rel=1e-12)


def test_grad2d_adjoint_and_tv_gradient():
    """grad2d_adjoint is the adjoint of grad2d; tv_charbonnier's gradient matches a finite difference."""
    g = np.random.default_rng(0)
    z = g.normal(size=(7, 9))
    py, px = g.normal(size=(7, 9)), g.normal(size=(7, 9))
    gy, gx = grad2d(z)
    assert np.isclose((gy * py).sum() + (gx * px).sum(), (z * grad2d_adjoint(py, px)).sum())
    v, grad = tv_charbonnier(z, 0.1)
    e = np.zeros_like(z)
    e[3, 4] = 1e-6
    assert np.isclose((tv_charbonnier(z + e, 0.1)[0] - tv_charbonnier(z - e, 0.1)[0]) / 2e-6, grad[3, 4], rtol=1e-5)


def test_lowpass_is_linear_and_its_noise_factor_matches_white_noise():
    """The gauge stays a linear problem because the low-pass is linear; the variance factor it reports is what
    white noise shows after it."""
    rng = np.random.default_rng(5)
    a, b = rng.random((40, 40)), rng.random((40, 40))
    assert np.allclose(lowpass(2 * a - 3 * b, 1.2), 2 * lowpass(a, 1.2) - 3 * lowpass(b, 1.2))
    assert lowpass(a, 0) is a and lowpass_noise_factor(0, (40, 40)) == 1.0
    noise = rng.normal(size=(400, 400))
    assert np.var(lowpass(noise, 1.5)[20:-20, 20:-20]) == pytest.approx(lowpass_noise_factor(1.5, (40, 40)), rel=0.05)


def test_block_mean_and_crop_for_integer_scale():
    rng = np.random.default_rng(1)
    x = rng.random((96, 96)).astype(np.float32)
    d = downsample(x, 6)
    assert d.dtype == np.float32
    assert np.allclose(d, x.reshape(16, 6, 16, 6).mean(axis=(1, 3)), atol=1e-6)
    assert np.array_equal(centre_crop(x, 6), x[40:56, 40:56])
    assert downsample_adjoint(d, (96, 96), 6).shape == (96, 96)
    x1, x2 = scene(96)
    op = FovealOperator((96, 96), 6)
    assert np.abs(op.residual(x1, x2)).max() < 1e-12
    assert np.allclose(op.D(op.upsample(d.astype(np.float64))), d, atol=1e-6)


def test_operator_gain_and_offset(dn):
    op = FovealOperator(dn.x1.shape, 6, gain=dn.gain, bias=dn.offset)
    assert np.abs(op.residual(dn.x1, dn.x2)).max() < 1e-9
    assert np.abs(FovealOperator(dn.x1.shape, 6).residual(dn.x1, dn.x2)).max() > 100  # identity relation is far off
    for bad in (0.0, -0.3, float("nan")):
        with pytest.raises(InputError):
            FovealOperator(dn.x1.shape, 6, gain=bad)


@pytest.mark.parametrize("bad", [0.5, 0, -3, float("nan"), "six", 60])
def test_bad_scale_is_input_error(bad):
    with pytest.raises(InputError) as e:
        FovealOperator((96, 96), bad)
    assert e.value.parameter == "scale"


def test_offset_outside_frame_refused():
    with pytest.raises(InputError) as e:
        FovealOperator((96, 96), 6, (50, 0))
    assert e.value.parameter == "offset"
