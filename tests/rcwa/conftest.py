"""Stacks shared by the RCWA tests (the paper's Si posts on a Si wafer under air, 4 um lattice)."""

from __future__ import annotations

import pytest

from metafovea.rcwa import Layer, Rectangle, Stack

NSI = 3.42


@pytest.fixture
def post_stack():
    """``post_stack(wx, wy, n_sub=3.42, h=10.0, cx=0.0, cy=0.0)``: one Si post of height h on the wafer."""
    def make(wx, wy, n_sub=NSI, h=10.0, cx=0.0, cy=0.0):
        return Stack(4.0, 4.0, [Layer(h, 1.0, [Rectangle(wx, wy, NSI, cx, cy)])], n_sub, 1.0)
    return make


@pytest.fixture
def two_layer_asymmetric():
    """Two patterned layers with off-centre rectangles on a 4 x 3 um cell: no mirror symmetry, x-y coupling."""
    return Stack(4.0, 3.0, [Layer(1.5, 1.0, [Rectangle(1.7, 1.1, NSI, 0.4, -0.3)]),
                            Layer(2.0, 1.5, [Rectangle(2.5, 0.9, 2.2, -0.9, 0.5)])], NSI, 1.0)
