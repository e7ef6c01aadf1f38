from pathlib import Path

import numpy as np
import pytest

from metafovea.errors import InputError
from metafovea.io import atomic_open, atomic_save_npz, atomic_write_text, load_npz, prepare_output


def test_atomic_write_leaves_no_partial_file(tmp_path):
    p = tmp_path / "a.txt"
    atomic_write_text(p, "old")
    with pytest.raises(RuntimeError):
        with atomic_open(p, "w") as fh:
            fh.write("new partial")
            raise RuntimeError("crash")
    assert p.read_text() == "old"
    assert [x.name for x in tmp_path.iterdir()] == ["a.txt"]


def test_npz_roundtrip(tmp_path):
    p = tmp_path / "x.npz"
    atomic_save_npz(p, {"k": 1.5}, a=np.arange(4, dtype=np.float32))
    arrays, meta = load_npz(p)
    assert arrays["a"].dtype == np.float32 and meta["k"] == 1.5 and meta["schema_version"] == 1


def test_prepare_output_refuses_overwrite(tmp_path):
    f = tmp_path / "f.txt"
    f.write_text("x")
    with pytest.raises(InputError, match="force=True"):
        prepare_output(f)
    assert prepare_output(f, force=True) == f
    d = tmp_path / "d"
    d.mkdir()
    assert prepare_output(d, is_dir=True) == d  # empty dir is fine
    (d / "x").write_text("1")
    with pytest.raises(InputError, match="force=True"):
        prepare_output(d, is_dir=True)


def test_prepare_output_unwritable(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where a directory should be")
    with pytest.raises(InputError, match="writable"):
        prepare_output(blocker / "sub" / "f.txt")


def test_atomic_files_get_umask_permissions(tmp_path):
    import os
    p = atomic_write_text(tmp_path / "perm.txt", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert (p.stat().st_mode & 0o777) == (0o666 & ~mask)


@pytest.mark.parametrize("content", [b"", b"not a zip", b"PK\x03\x04truncated"])
def test_load_npz_bad_files_are_input_errors(tmp_path, content):
    p = tmp_path / "bad.npz"
    p.write_bytes(content)
    with pytest.raises(InputError, match="readable .npz"):
        load_npz(p)
    np.save(tmp_path / "single.npy", np.arange(3))
    with pytest.raises(InputError):
        load_npz(tmp_path / "single.npy")


def test_jsonable_is_the_one_json_policy():
    """numpy values become JSON types and every non-finite float becomes null (valid JSON, 'not available')."""
    import json
    import math

    from metafovea.io import jsonable, to_json

    obj = {1: np.float32(0.5), "a": np.arange(3), "nan": float("nan"), "inf": np.float64(np.inf),
           "arr": np.array([1.0, np.nan]), "c": 1 + 2j, "p": Path("x/y"), "t": (np.int64(3), np.bool_(True))}
    out = jsonable(obj)
    assert out == {"1": 0.5, "a": [0, 1, 2], "nan": None, "inf": None, "arr": [1.0, None], "c": {"re": 1.0, "im": 2.0},
                   "p": "x/y", "t": [3, True]}
    text = to_json(obj)
    assert json.loads(text) == out and "NaN" not in text and "Infinity" not in text
    assert type(jsonable(np.int32(2))) is int and jsonable(np.bool_(False)) is False
    assert math.isclose(json.loads(to_json(np.float64(1e-300))), 1e-300)


def test_cache_dir_is_one_folder_per_stage(tmp_path, monkeypatch):
    from metafovea.io import cache_dir

    monkeypatch.setenv("METAFOVEA_CACHE", str(tmp_path / "c"))
    assert cache_dir("library") == tmp_path / "c" / "library"
    assert cache_dir("psf") == tmp_path / "c" / "psf"
    monkeypatch.delenv("METAFOVEA_CACHE")
    assert cache_dir("psf") == Path.home() / ".cache" / "metafovea" / "psf"


def test_file_stem_cannot_name_a_path():
    from metafovea.io import file_stem

    assert file_stem("../../x") == "_.._x" and file_stem("a/b") == "a_b" and file_stem("..") == "lens"


def test_cache_lock_serialises_two_holders(tmp_path):
    """Two workers that miss the same cache entry: the second waits until the first has written it."""
    import threading
    import time

    from metafovea.io import cache_lock

    events = []

    def hold(name, delay):
        time.sleep(delay)
        with cache_lock(tmp_path / "entry.npz"):
            events.append((name, "in"))
            time.sleep(0.2)
            events.append((name, "out"))

    a = threading.Thread(target=hold, args=("a", 0.0))
    b = threading.Thread(target=hold, args=("b", 0.05))
    a.start(), b.start()
    a.join(), b.join()
    assert events == [("a", "in"), ("a", "out"), ("b", "in"), ("b", "out")]
    assert (tmp_path / "entry.npz.lock").is_file()


_DIP_IN_A_PROCESS = """
import numpy as np
from metafovea.reconstruct.deep_prior import dip
rng = np.random.default_rng(0)
Y = rng.random((2, 16, 16)).astype(np.float32)
r = dip(Y, alpha=[0.3, 0.7], steps=2, rng=0, depth=1, channels=4)
print(r.info["traces"])
"""
#: the folder's choice alone: the cache asked for, then one small program compiled
_JIT_IN_A_PROCESS = """
from metafovea.io import use_jax_cache
use_jax_cache()
import jax
print(jax.jit(lambda x: 2.0 * x + 1.0)(1.0))
"""


def _jax_env(tmp_path):
    """The environment of a fresh process: the cache root in ``tmp_path / 'c'``, no user folder, every program kept."""
    import os

    env = {**os.environ, "METAFOVEA_CACHE": str(tmp_path / "c"), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    return env


@pytest.mark.parametrize("user_folder", [False, True])
def test_jax_programs_are_kept_in_the_cache_folder_unless_the_user_chose_one(tmp_path, user_folder):
    """A DIP fitted in a fresh process leaves its compiled step in ``$METAFOVEA_CACHE/jax`` (JAX's persistent
    compilation cache); with ``JAX_COMPILATION_CACHE_DIR`` set, a program goes to the user's folder, nowhere else."""
    import subprocess
    import sys

    env = _jax_env(tmp_path)
    if user_folder:
        env["JAX_COMPILATION_CACHE_DIR"] = str(tmp_path / "mine")
    program = _JIT_IN_A_PROCESS if user_folder else _DIP_IN_A_PROCESS
    out = subprocess.run([sys.executable, "-c", program], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    ours, mine = tmp_path / "c" / "jax", tmp_path / "mine"
    kept, empty = (mine, ours) if user_folder else (ours, mine)
    assert kept.is_dir() and any(kept.iterdir())
    assert not empty.exists()


def test_an_unwritable_jax_cache_folder_leaves_the_cache_off_quietly(tmp_path):
    """A cache folder that cannot be written (here a file stands where the folder would be): JAX would warn at
    every program it could not keep (27 warnings for a small DIP); the cache is left off and nothing is said."""
    import subprocess
    import sys

    (tmp_path / "c").write_text("a file, not a folder")
    env = _jax_env(tmp_path)
    program = _JIT_IN_A_PROCESS + "print(jax.config.jax_compilation_cache_dir)\n"
    out = subprocess.run([sys.executable, "-W", "always", "-c", program], env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-1] == "None" and "cache" not in out.stderr.lower(), out.stderr
