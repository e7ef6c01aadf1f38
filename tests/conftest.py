import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DESIGNS = REPO / "designs"

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def designs_dir() -> Path:
    return DESIGNS


#: the ways a file is damaged in the tests: empty, cut short, replaced by junk bytes, replaced by text
DAMAGES = ("empty", "truncated", "garbage", "text")


def damage_file(src: Path, dst: Path, damage: str, *, keep: float = 0.5) -> Path:
    """Write a damaged copy of ``src`` to ``dst`` (``damage`` one of :data:`DAMAGES`; ``truncated`` keeps the
    first ``keep`` fraction of the bytes, or ``int(keep)`` bytes when ``keep >= 1``)."""
    data = Path(src).read_bytes()
    if damage == "empty":
        out = b""
    elif damage == "truncated":
        out = data[: int(keep) if keep >= 1 else int(len(data) * keep)]
    elif damage == "garbage":
        out = b"\x00junk" * max(1, len(data) // 5 // 8)
    elif damage == "text":
        out = b"this is not the file you are looking for\n"
    else:
        raise ValueError(f"damage must be one of {DAMAGES}, not {damage!r}")
    dst = Path(dst)
    dst.write_bytes(out)
    return dst


@pytest.fixture
def damaged():
    """Factory fixture: ``damaged(src, dst, damage, keep=0.5)`` writes a damaged copy of ``src`` (see
    :func:`damage_file`); parametrise a test over :data:`DAMAGES` to try each."""
    return damage_file
