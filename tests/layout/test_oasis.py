"""OASIS writer: integers as SEMI P39 encodes them, the vectorised placement encoder against the per-band loop."""

from __future__ import annotations

import numpy as np

from metafovea.layout import oasis


def test_integers_encode_as_semi_p39():
    """Unsigned integers: 7 bits per byte, low group first, high bit = more bytes follow; signed: the sign in
    the lowest bit of the magnitude shifted by one (SEMI P39, section 7.2)."""
    assert oasis.uint(0) == b"\x00" and oasis.uint(127) == b"\x7f"
    assert oasis.uint(128) == b"\x80\x01" and oasis.uint(16383) == b"\xff\x7f" and oasis.uint(16384) == b"\x80\x80\x01"
    assert oasis.sint(0) == b"\x00" and oasis.sint(1) == b"\x02" and oasis.sint(-1) == b"\x03"
    assert oasis.sint(-64) == b"\x81\x01"
    v = np.array([0, 1, 127, 128, 300, 16383, 16384, 2**31 - 1, 2**40], dtype=np.int64)
    enc, nb = oasis.uints(v)
    assert enc.tobytes() == b"".join(oasis.uint(int(x)) for x in v)
    assert nb.tolist() == [len(oasis.uint(int(x))) for x in v]


def test_oasis_vectorised_placements_match_loop(spec):
    # the +y side of a task equals the per-band loop encoder on the same rows
    t = spec.tasks()[2]
    parts, c = oasis.encode_task_oas(spec, 0, t)
    old, c_old = oasis.encode_band_oas(spec, 0, (t[1], t[2], t[3], t[4]))
    assert parts[0][:len(old)] == old and len(parts[0]) == 2 * len(old)
    assert c.sum() == 2 * c_old.sum()
