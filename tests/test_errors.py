"""InputError and the validators: one line naming the parameter, the value and the allowed range."""

import numpy as np
import pytest

from metafovea.errors import InputError, as_rng, check_choice, check_int, check_positive


def test_input_error_names_parameter_value_and_range():
    e = InputError("--window", 1, "an integer >= 2", source="m.npz", detail="from the file")
    assert str(e) == "m.npz: --window = 1 is invalid; allowed: an integer >= 2 (from the file)"
    r = e.renamed("window")
    assert (r.parameter, r.value, r.allowed, r.source, r.detail) == ("window", 1, "an integer >= 2", "m.npz",
                                                                      "from the file")


def test_a_value_not_given_is_missing_not_none():
    e = InputError("frame_rate_hz", None, "the camera's frame rate in Hz", source="rec.tif")
    assert str(e) == "rec.tif: frame_rate_hz is missing; allowed: the camera's frame rate in Hz"
    assert "is missing" in str(e.renamed("--frame-rate")) and "None" not in str(e.renamed("--frame-rate"))


def test_validators():
    assert check_int("n", "7", 1, 10) == 7
    assert check_positive("x", "2.5", "um") == 2.5
    assert check_choice("p", "x", ("x", "y")) == "x"
    for bad in (lambda: check_int("n", "0", 1, 10), lambda: check_positive("x", "nan"),
                lambda: check_choice("p", "z", ("x", "y"))):
        with pytest.raises(InputError):
            bad()


def test_as_rng_is_reproducible_and_refuses_bad_seeds():
    a = as_rng(3).standard_normal(4)
    assert np.array_equal(a, as_rng("3").standard_normal(4))
    assert np.array_equal(a, np.random.default_rng(3).standard_normal(4))
    g = np.random.default_rng(1)
    assert as_rng(g) is g
    assert isinstance(as_rng(None), np.random.Generator)
    for bad in (-1, "x", 1.5, True):
        with pytest.raises(InputError, match="seed"):
            as_rng(bad)
    with pytest.raises(InputError, match="--seed"):
        as_rng(-2, name="--seed")
