"""Atomic, non-clobbering file output and small file-format helpers.

Every file the toolkit writes goes through :func:`atomic_write_bytes` (temporary file in the same
directory, fsync, ``os.replace``), so a crash or a full disk never leaves a partial file under the final
name. :func:`prepare_output` refuses to overwrite existing output unless ``force`` is given.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError

SCHEMA_VERSION = 1


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb") -> Iterator[Any]:
    """Open a temporary file next to ``path``; on success fsync and rename it to ``path``.

    On any exception the temporary file is removed and ``path`` is untouched. The temporary name is chosen before
    the file is created, inside the block that removes it, so that an exception raised into the thread at any
    instruction (a stopped pool task's :class:`~metafovea.parallel.TaskStopped`) leaves no file behind.
    """
    path = Path(path)
    if mode not in ("wb", "w"):
        raise ValueError("atomic_open supports modes 'wb' and 'w'")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp, fd, fh = "", -1, None
    try:
        for _ in range(100):  # O_EXCL as mkstemp: another writer's name is never reused
            tmp = str(path.parent / f".{path.name}.{secrets.token_hex(6)}.part")
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
                break
            except FileExistsError:
                tmp = ""
        else:
            raise FileExistsError(f"no free temporary name next to {path}")
        kw = {} if "b" in mode else {"encoding": "utf-8", "newline": "\n"}
        fh = os.fdopen(fd, mode, **kw)
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if fh is None and fd >= 0:
            with contextlib.suppress(OSError):
                os.close(fd)
        if tmp:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    with atomic_open(path, "w") as fh:
        fh.write(text)
    return Path(path)


def jsonable(obj: Any) -> Any:
    """A copy of ``obj`` made of JSON types: numpy arrays and scalars become lists and numbers, paths strings,
    complex numbers ``{"re", "im"}``, tuples lists, dict keys strings; **non-finite floats become None** (the
    one NaN policy of every JSON file and ``--json`` output: "not available", valid JSON)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, (complex, np.complexfloating)):
        return {"re": jsonable(obj.real), "im": jsonable(obj.imag)}
    if isinstance(obj, Path):
        return str(obj)
    return obj


def to_json(obj: Any, indent: int | None = 2) -> str:
    """JSON text of :func:`jsonable` ``(obj)`` (NaN/inf written as null)."""
    return json.dumps(jsonable(obj), indent=indent, allow_nan=False)


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    return atomic_write_text(path, to_json(obj) + "\n")


def atomic_save_npz(path: str | os.PathLike, meta: dict[str, Any] | None = None, *, compress: bool = True,
                    **arrays: np.ndarray) -> Path:
    """Save arrays plus JSON metadata under key ``__meta__`` atomically.

    ``compress=False`` stores the arrays uncompressed (noisy float32 frames hardly compress, and zlib
    costs seconds per 30 MB).
    """
    payload = dict(arrays)
    if meta is not None:
        m = dict(meta)
        m.setdefault("schema_version", SCHEMA_VERSION)
        payload["__meta__"] = np.frombuffer(to_json(m, indent=None).encode(), dtype=np.uint8)
    with atomic_open(path, "wb") as fh:  # written straight into the temporary file (no in-memory copy)
        (np.savez_compressed if compress else np.savez)(fh, **payload)
    return Path(path)


def load_npz(path: str | os.PathLike, name: str = "path") -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Load a file written by :func:`atomic_save_npz`: (arrays, meta).

    A missing, truncated, non-npz or pickled file, or unreadable metadata, is an :class:`InputError`
    naming ``name``.
    """
    import zipfile
    import zlib

    p = Path(path)
    if not p.is_file():
        raise InputError(name, str(p), "an existing .npz file")
    if not zipfile.is_zipfile(p) and not _is_npy(p):  # numpy's own message calls any other file "pickled"
        raise InputError(name, str(p), "a readable .npz file written by metafovea",
                         detail="not an .npz (zip) archive: another kind of file")
    try:
        z0 = np.load(p, allow_pickle=False)
        if not hasattr(z0, "files"):
            raise ValueError("a single .npy array, not an .npz archive")
        with z0 as z:
            arrays = {k: z[k] for k in z.files if k != "__meta__"}
            meta = json.loads(bytes(z["__meta__"]).decode()) if "__meta__" in z.files else {}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, UnicodeDecodeError, KeyError) as e:
        raise InputError(name, str(p), "a readable .npz file written by metafovea",
                         detail=str(e).splitlines()[0][:200] if str(e) else type(e).__name__) from None
    if not isinstance(meta, dict):
        raise InputError(name, str(p), "an .npz whose __meta__ is a JSON object")
    return arrays, meta


def _is_npy(p: Path) -> bool:
    """Whether ``p`` starts as a .npy file does (numpy's magic string)."""
    with open(p, "rb") as fh:
        return fh.read(6) == b"\x93NUMPY"


def file_stem(name: str) -> str:
    """A lens name made safe as a file-name stem: no path separators or '..' (a name like '../x' wrote
    outside the output directory), no shell-hostile characters; letters, digits, '-', '_' and '.' kept."""
    stem = "".join(ch if (ch.isalnum() or ch in "-_.") else "_" for ch in str(name)).lstrip(".")
    return stem or "lens"


def cache_root() -> Path:
    """Root of metafovea's caches: ``$METAFOVEA_CACHE`` or ``~/.cache/metafovea`` (one folder per stage)."""
    env = os.environ.get("METAFOVEA_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "metafovea"


def cache_dir(stage: str) -> Path:
    """The cache folder of one stage (``"library"``, ``"psf"``, ...): ``cache_root() / stage``."""
    return cache_root() / stage


def use_jax_cache() -> None:
    """Keep JAX's compiled programs on disk, in ``cache_dir("jax")``, unless a folder is already chosen
    (``JAX_COMPILATION_CACHE_DIR`` or ``jax.config``): the deep image prior's and the co-design's jitted steps
    (seconds to compile each, once per shape and switches) then compile once per machine, not once per process.
    JAX's own persistent cache (``jax_compilation_cache_dir``; programs that took at least
    ``jax_persistent_cache_min_compile_time_secs`` to compile, keyed by the program, the options and the JAX and
    XLA versions). JAX decides at a process's first compilation whether it uses the cache, so each module calls
    this before it compiles anything. A folder that cannot be made or written (a read-only file system, a file in
    its place) leaves the cache off: JAX would warn at every program it could not keep."""
    import jax

    if jax.config.jax_compilation_cache_dir is None:
        folder = cache_dir("jax")
        try:
            folder.mkdir(parents=True, exist_ok=True)
            writable = os.access(folder, os.W_OK | os.X_OK)
        except OSError:
            writable = False
        if writable:
            jax.config.update("jax_compilation_cache_dir", str(folder))


#: files shipped with the package: read-only seeds of the caches, each under its cache file's name (which holds the
#: hash of every input), so a seed serves exactly the inputs it was made from (``python -m metafovea.library.seed``)
DATA_DIR = Path(__file__).resolve().parent / "data"


def seed_file(name: str) -> Path | None:
    """The file shipped in :data:`DATA_DIR` under the cache file name ``name``, or None when none is."""
    p = DATA_DIR / name
    return p if p.is_file() else None


@contextlib.contextmanager
def cache_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold an exclusive lock on ``<path>.lock`` (made if missing): two processes that both miss a cache entry
    compute it once, the second waiting and then reading what the first wrote. Where file locks are not
    available (no ``fcntl``, or a file system that refuses them) nothing is locked and both compute."""
    lock = Path(f"{os.fspath(path)}.lock")
    try:
        import fcntl

        lock.parent.mkdir(parents=True, exist_ok=True)
        fh = open(lock, "a+")
    except (ImportError, OSError):
        yield
        return
    try:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        except OSError:
            pass
        yield
    finally:
        fh.close()  # closing releases the lock


def input_hash(obj: Any) -> str:
    """Stable short hash of JSON-serialisable inputs (cache keys)."""
    return hashlib.sha256(to_json(obj, indent=None).encode()).hexdigest()[:16]


@contextlib.contextmanager
def dropped_if_empty(path: str | os.PathLike) -> Iterator[None]:
    """Run the block; when it fails, a folder ``path`` that did not exist before it and is still empty is removed
    again (a refusal found after the output folder was made leaves nothing behind)."""
    p = Path(path)
    made = not p.exists()
    try:
        yield
    except BaseException:
        if made and p.is_dir() and not any(p.iterdir()):
            p.rmdir()
        raise


def prepare_output(path: str | os.PathLike, force: bool = False, *, is_dir: bool = False,
                   name: str = "out") -> Path:
    """Check that ``path`` can be written without clobbering anything.

    A directory is accepted if it does not exist or is empty; a file if it does not exist. With
    ``force`` existing output may be replaced. Raises :class:`InputError` otherwise, or when the
    parent cannot be created or written.
    """
    p = Path(path)
    if p.exists() and not force:
        if is_dir and p.is_dir() and not any(p.iterdir()):
            pass
        else:
            raise InputError(name, str(p), "a path that does not exist yet (or pass force=True to overwrite)")
    if is_dir and p.exists() and not p.is_dir():
        raise InputError(name, str(p), "a directory path (a file is in the way)")
    target = p if is_dir else p.parent
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(name, str(p), "a writable location", detail=e.strerror) from None
    if not os.access(target, os.W_OK):
        raise InputError(name, str(p), "a writable location", detail="permission denied")
    return p
