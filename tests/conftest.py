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


def write_lens_toml(tmp_path: Path, name: str = "qa", f_mm: float = 0.8, d_mm: float = 0.4, levels: int = 8,
                    lattice: str = "integer", pol: str = "x") -> Path:
    """A small lens design file (0.8 mm focal length, 0.4 mm aperture by default: fast to export and verify)."""
    p = tmp_path / f"{name}.toml"
    p.write_text(f'name = "{name}"\nf_mm = {f_mm}\ndiameter_mm = {d_mm}\nwavelength_um = 10.0\n'
                 f'polarization = "{pol}"\nlevels = {levels}\nlattice = "{lattice}"\n')
    return p


def cli_error_line(capsys) -> str:
    """The command's stderr, stripped; never a traceback."""
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err


@pytest.fixture(scope="session")
def lens_toml():
    """Factory fixture: ``lens_toml(tmp_path, name="qa", f_mm=0.8, d_mm=0.4, levels=8, lattice="integer",
    pol="x")`` writes a small lens TOML and returns its path."""
    return write_lens_toml


@pytest.fixture(scope="session")
def cli_error():
    """Factory fixture: ``cli_error(capsys)`` returns the command's stderr and asserts it holds no traceback."""
    return cli_error_line
