"""Cluster export: the workers write their encoded bands as tile files, the client stitches them in band order.

With a Dask scheduler, shipping each band's encoded bytes back to the client made the export slower than two
local threads (the bytes were pickled and sent through the client: 17.9 against 43.1 M posts/s for a 25 mm lens
here, ``docs/scale.md``). Instead each task writes ``band_NNNNNNN.bin`` (its bytes, fsynced, renamed into
place) and ``band_NNNNNNN.json`` (the export's key, byte count, CRC-32, post counts per type and, for
hierarchical GDSII, its leaf structures) into a tile directory, and returns only that record. The client then
copies header, tiles in band order and footer into the part file and renames it to the final name, so the file
is the same byte for byte as the serial export's.

Assumption: the tile directory (``--tiles-dir``, default ``.<name>.tiles`` next to the output) is on a file
system that the client and every worker share (NFS, Lustre, a LocalCluster's own disk). A tile the client cannot
find, or whose size or CRC-32 differs from its record, stops the stitch with an :class:`InputError` naming the
file; the bad tile's record is removed so that a rerun computes it again. Tiles whose record matches the
export's key are kept between runs: an interrupted cluster export resumes from the tiles already written.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import zlib
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError

TILE_VERSION = 1
_TILE_RE = re.compile(r"^\.?band_\d{7}\.(bin|json)(\.\d+\.tmp)?$")
#: bytes read at a time when stitching
CHUNK = 8 << 20


def default_tiles_dir(path: Path) -> Path:
    """``.<name>.tiles`` next to the output ``path``."""
    return path.parent / f".{path.name}.tiles"


def tile_paths(d: Path, i: int) -> tuple[Path, Path]:
    return d / f"band_{i:07d}.bin", d / f"band_{i:07d}.json"


def _atomic(path: Path, data: bytes | list) -> tuple[int, int]:
    """Write ``data`` (bytes or a list of buffers) to ``path`` through a temporary file of this process (a task
    rerun elsewhere after a worker died writes its own), renamed into place. Returns (bytes, CRC-32).

    Not fsynced: on a cluster file system an fsync is a round trip to the servers per tile and record (here, on
    local ext4, 196 fsyncs of 78 kB files, a 25 mm lens' 98 bands, cost 0.51 s against 0.09 s without); a tile
    torn by a crash is caught by its CRC-32 at the stitch (and written again by the rerun), a torn record reads as
    none, and the stitched file is fsynced."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    n, crc = 0, 0
    with open(tmp, "wb") as fh:
        for piece in (data if isinstance(data, list) else [data]):
            fh.write(piece)
            n += memoryview(piece).nbytes
            crc = zlib.crc32(piece, crc)
    os.replace(tmp, path)
    return n, crc


def write_tile(enc: Callable, tiles_dir: str, key: str, item: tuple[int, Any]) -> dict[str, Any]:
    """Run on a worker: encode band ``item = (index, task)`` with ``enc`` and write its tile and record; returns
    the record (a few hundred bytes travel back, not the band)."""
    i, task = item
    pieces, counts, meta = enc(task)
    bin_path, rec_path = tile_paths(Path(tiles_dir), i)
    n, crc = _atomic(bin_path, list(pieces))
    rec = {"version": TILE_VERSION, "key": key, "band": i, "bytes": n, "crc32": crc,
           "counts": np.asarray(counts, dtype=np.int64).tolist(), "meta": None if meta is None else int(meta)}
    _atomic(rec_path, json.dumps(rec).encode())
    return rec


class TileDir:
    """The tile directory of one export (``key``: everything that fixes the file's bytes but its date)."""

    def __init__(self, d: Path, key: str, total: int):
        self.d, self.key, self.total = Path(d), key, total
        self.manifest = self.d / "manifest.json"

    def open(self, resume: bool, date: str) -> tuple[str, dict[int, dict[str, Any]]]:
        """Make the directory; with ``resume`` and a manifest of this key, the date it was started with and the
        tiles already written (record of this key, tile of the recorded size); otherwise start over (this
        export's own files only are removed: ``band_*.bin|json`` and the manifest)."""
        try:
            self.d.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise InputError("tiles_dir", str(self.d), "a directory that can be created and written",
                             detail=e.strerror or str(e)) from None
        m = _read_json(self.manifest) if resume else None
        if isinstance(m, dict) and m.get("key") == self.key and m.get("total") == self.total \
                and isinstance(m.get("date"), str):
            done = {}
            for i in range(self.total):
                rec = self.record(i)
                if rec is not None and tile_paths(self.d, i)[0].stat().st_size == rec["bytes"]:
                    done[i] = rec
            return m["date"], done
        self.clean()
        _atomic(self.manifest, json.dumps({"version": TILE_VERSION, "key": self.key, "total": self.total,
                                           "date": date}).encode())
        return date, {}

    def record(self, i: int) -> dict[str, Any] | None:
        """Band ``i``'s record when it belongs to this export and its tile exists, else None."""
        b, r = tile_paths(self.d, i)
        rec = _read_json(r)
        if not (isinstance(rec, dict) and rec.get("key") == self.key and rec.get("band") == i
                and isinstance(rec.get("bytes"), int) and isinstance(rec.get("crc32"), int)
                and isinstance(rec.get("counts"), list) and b.is_file()):
            return None
        return rec

    def run(self, enc: Callable, tasks: list[tuple[int, Any]], executor: Any, progress: bool,
            desc: str) -> dict[int, dict[str, Any]]:
        """Encode and write the tiles of ``tasks`` (``(index, task)``) on ``executor`` (a Dask cluster)."""
        from metafovea.parallel import run_tasks

        out = {}
        for _, rec in run_tasks(partial(write_tile, enc, str(self.d), self.key), tasks, executor=executor,
                                progress=progress, desc=desc):
            out[int(rec["band"])] = rec
        return out

    def stitch(self, write: Callable[[bytes | memoryview], None]) -> tuple[np.ndarray, list[Any]]:
        """Pass every tile's bytes, in band order, to ``write``; checks each against its record (size and
        CRC-32). Returns the post counts summed and each band's meta."""
        counts: np.ndarray | None = None
        metas = []
        for i in range(self.total):
            b, r = tile_paths(self.d, i)
            rec = self.record(i)
            if rec is None:
                what = "its record" if b.is_file() else "its tile"
                raise InputError("tiles_dir", str(self.d), "a directory that the client and every worker share "
                                 "(the workers write the tiles there, the client reads them)",
                                 detail=f"band {i}: {what} ({b.name if what == 'its tile' else r.name}) is missing or "
                                        "belongs to another export; rerun the command to write it again")
            n, crc = 0, 0
            with open(b, "rb") as fh:
                while chunk := fh.read(CHUNK):
                    n += len(chunk)
                    crc = zlib.crc32(chunk, crc)
                    if n <= rec["bytes"]:
                        write(chunk)
            if n != rec["bytes"] or crc != rec["crc32"]:
                with contextlib.suppress(OSError):
                    r.unlink()  # a rerun computes the band again
                raise InputError("tiles_dir", str(self.d), "tiles as the workers wrote them",
                                 detail=f"band {i}: {b.name} is corrupt ({n:,} bytes, CRC-32 {crc:08x}; its record "
                                        f"says {rec['bytes']:,} bytes, {rec['crc32']:08x}); its record was removed, "
                                        "rerun the command to write it again")
            c = np.asarray(rec["counts"], dtype=np.int64)
            counts = c if counts is None else counts + c
            metas.append(rec.get("meta"))
        return (counts if counts is not None else np.zeros(0, dtype=np.int64)), metas

    def clean(self, remove_dir: bool = False) -> None:
        """Remove this directory's tiles, records and manifest (nothing else); the directory too when
        ``remove_dir`` and it is then empty."""
        with contextlib.suppress(FileNotFoundError):
            for p in self.d.iterdir():
                if _TILE_RE.match(p.name) or p.name == "manifest.json" or re.match(r"^\.manifest\.json\.\d+\.tmp$",
                                                                                    p.name):
                    with contextlib.suppress(FileNotFoundError):
                        p.unlink()
        if remove_dir:
            with contextlib.suppress(OSError):
                self.d.rmdir()


def _read_json(p: Path) -> Any:
    try:
        with open(p) as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


__all__ = ["TileDir", "default_tiles_dir", "tile_paths", "write_tile"]
