"""Streamed, resumable, atomic export of a lens layout (GDSII or OASIS) and of a calibration array.

The file is written to ``.<name>.part`` next to the final path, task after task (a task is a
mirror-row band, see :meth:`LayoutSpec.tasks`; tasks are encoded serially, in local threads or
processes, or on a Dask client, at most a few in flight, and written in order by a writer thread
through :class:`DirectFile`, ``O_DIRECT`` where possible). A small journal ``.<name>.part.json``
(updated at most every 0.5 s) records the tasks finished and the byte offset (and, for hierarchical
GDSII, the leaf structures per task); a rerun with the same parameters truncates the part file to that
offset and continues. When all tasks are written the footer is added (hierarchical GDSII: the
intermediate structures and the top cell), the file is fsynced and renamed to the final name; nothing
ever appears under the final name half-written.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import json
import os
import queue
import threading
import time
from dataclasses import dataclass, field
from functools import partial
from itertools import islice
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from metafovea.errors import InputError, check_choice, check_int
from metafovea.io import input_hash, prepare_output
from metafovea.layout.tiling import LayoutSpec

FORMATS = ("gds", "oas")
JOURNAL_VERSION = 2


@dataclass
class ExportResult:
    path: Path
    format: str
    flat: bool
    posts: int
    counts: list[int]
    bytes: int
    seconds: float
    bands: int
    resumed_bands: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["path"] = str(self.path)
        d["posts_per_s"] = self.posts / self.seconds if self.seconds > 0 else None
        d["bytes_per_post"] = self.bytes / self.posts if self.posts else None
        return d


class ExportError(InputError):
    """Writing failed (disk full, not writable); nothing under the final name."""

    def __init__(self, path: Path, reason: str, detail: str | None = None):
        super().__init__("--out", str(path), reason, detail=detail)


def _ordered_map(fn: Callable, items: list, workers: int | None, scheduler: str | None,
                 inflight: int | None = None, threads: bool = True) -> Iterator[Any]:
    """``fn`` over ``items`` in order, at most ``inflight`` tasks pending (bounded memory).

    Local workers are threads by default (the encoders spend their time in numpy and zlib, which
    release the GIL, and results need no pickling); ``threads=False`` uses processes."""
    if (workers in (None, 1)) and not scheduler:
        for it in items:
            yield fn(it)
        return
    import concurrent.futures as cf

    from metafovea.parallel import get_executor

    nw = workers or 2
    ex = cf.ThreadPoolExecutor(max_workers=nw) if (threads and not scheduler) else get_executor(workers, scheduler)
    window = inflight or nw + 1
    pending: collections.deque = collections.deque()
    src = iter(items)
    try:
        for it in islice(src, window):
            pending.append(ex.submit(fn, it))
        while pending:
            res = pending.popleft().result()
            nxt = next(src, None)
            if nxt is not None:
                pending.append(ex.submit(fn, nxt))
            yield res
    finally:
        if isinstance(ex, cf.Executor):
            ex.shutdown(wait=True, cancel_futures=True)
        else:
            ex.close()


class _Writer(threading.Thread):
    """Writes band data in a background thread (overlaps disk writes with the band computation)."""

    def __init__(self, fh, on_written: Callable[[int, np.ndarray, Any], None], depth: int = 2):
        super().__init__(daemon=True)
        self.fh, self.on_written = fh, on_written
        self.q: queue.Queue = queue.Queue(maxsize=depth)
        self.exc: BaseException | None = None
        self.start()

    def run(self) -> None:
        while True:
            item = self.q.get()
            if item is None:
                return
            if self.exc is not None:
                continue
            try:
                pieces, c, meta = item
                nbytes = 0
                for data in pieces:
                    self.fh.write(data)
                    nbytes += memoryview(data).nbytes
                self.on_written(nbytes, c, meta)
            except BaseException as e:  # noqa: BLE001 - re-raised in the caller
                self.exc = e

    def put(self, pieces: list, c: np.ndarray, meta: Any = None) -> None:
        if self.exc is not None:
            raise self.exc
        self.q.put((pieces, c, meta))

    def close(self) -> None:
        self.q.put(None)
        self.join()
        if self.exc is not None:
            exc, self.exc = self.exc, None
            raise exc


class DirectFile:
    """Sequential writer with ``O_DIRECT`` (no page-cache copy: on the benchmark machine the kernel's
    buffered write path costs more CPU than the encoding) through an aligned staging buffer; falls back
    to plain writes where ``O_DIRECT`` is refused (tmpfs, some network file systems) or ``direct=False``.

    ``flush()`` makes every byte written so far part of the file (the last partial block goes through a
    buffered descriptor and is rewritten, aligned, by a later direct write), so a journal written after
    ``flush()`` is consistent. ``offset`` (resume): truncate the file there and continue."""

    BLOCK = 4096

    def __init__(self, path: Path, offset: int | None = None, *, direct: bool = True, staging: int = 32 << 20):
        import mmap

        self.path = path
        new = offset is None
        self.bfd = os.open(path, os.O_RDWR | os.O_CREAT | (os.O_TRUNC if new else 0), 0o666)
        self.dfd = -1
        self.pos = 0 if new else int(offset)
        self.buf = None
        try:
            if not new:
                os.ftruncate(self.bfd, self.pos)
            if direct and hasattr(os, "O_DIRECT"):
                try:
                    self.dfd = os.open(path, os.O_WRONLY | os.O_DIRECT)
                except OSError:
                    self.dfd = -1
            if self.dfd >= 0:
                self.cap = staging
                self.buf = mmap.mmap(-1, staging)
                self.mv = memoryview(self.buf)
                self.base = self.pos - self.pos % self.BLOCK
                self.fill = self.pos - self.base
                if self.fill:
                    self.mv[:self.fill] = os.pread(self.bfd, self.fill, self.base)
        except BaseException:
            self.close()
            raise

    @property
    def direct(self) -> bool:
        return self.dfd >= 0

    def _pwrite_all(self, fd: int, mv: memoryview, off: int) -> None:
        while len(mv):
            try:
                n = os.pwrite(fd, mv, off)
            except OSError as e:
                if fd == self.dfd and e.errno == errno.EINVAL:  # alignment refused after all: buffered
                    fd = self.bfd
                    continue
                raise
            if n <= 0:
                raise OSError(errno.EIO, "short write")
            mv, off = mv[n:], off + n
            if len(mv) and fd == self.dfd:  # short direct write (size limit): finish buffered
                fd = self.bfd

    def _drain(self, keep_tail: bool) -> None:
        a = self.fill - self.fill % self.BLOCK
        if a:
            self._pwrite_all(self.dfd, self.mv[:a], self.base)
        tail = self.fill - a
        if tail:
            self._pwrite_all(self.bfd, self.mv[a:self.fill], self.base + a)
            if not keep_tail:
                self.base += self.fill
                self.fill = 0
                return
            self.mv[:tail] = self.mv[a:self.fill]
        self.base += a
        self.fill = tail

    def write(self, data: Any) -> int:
        m = memoryview(data).cast("B")
        n = len(m)
        if self.dfd < 0:
            self._pwrite_all(self.bfd, m, self.pos)
            self.pos += n
            return n
        while len(m):
            k = min(len(m), self.cap - self.fill)
            self.mv[self.fill:self.fill + k] = m[:k]
            self.fill += k
            m = m[k:]
            if self.fill == self.cap:  # cap is a multiple of BLOCK: all aligned
                self._drain(keep_tail=False)
        self.pos += n
        return n

    def flush(self) -> None:
        if self.dfd >= 0 and self.fill:
            self._drain(keep_tail=True)

    def sync(self) -> None:
        self.flush()
        if self.dfd >= 0:
            os.fsync(self.dfd)
        os.fsync(self.bfd)

    def close(self) -> None:
        for fd in (self.dfd, self.bfd):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.dfd = self.bfd = -1
        if self.buf is not None:
            with contextlib.suppress(BufferError):
                self.mv.release()
                self.buf.close()
            self.buf = None


def part_paths(path: Path) -> tuple[Path, Path]:
    return path.parent / f".{path.name}.part", path.parent / f".{path.name}.part.json"


def _write_journal(jpath: Path, data: dict[str, Any]) -> None:
    tmp = jpath.with_name(jpath.name + ".tmp")
    with open(tmp, "w") as fh:
        json.dump(data, fh)
    os.replace(tmp, jpath)


def _load_journal(jpath: Path) -> dict[str, Any] | None:
    try:
        with open(jpath) as fh:
            j = json.load(fh)
    except (OSError, ValueError):
        return None
    # anything but a journal as _write_journal writes it (hand-edited, from another version): start over
    if not isinstance(j, dict) or not all(isinstance(j.get(k), int) and not isinstance(j.get(k), bool)
                                          for k in ("bands_done", "offset")):
        return None
    if not isinstance(j.get("counts"), list) or not isinstance(j.get("leaves", []), list):
        return None
    return j


def _gds_task(spec: LayoutSpec, flat: bool, task):
    from metafovea.layout import gds as g
    pieces, counts = g.encode_task_records(spec, flat, task)
    return pieces, counts, None


def _gds_task_hier(spec: LayoutSpec, flat: bool, max_refs: int, task):
    from metafovea.layout import gds as g
    return g.encode_task_hier(spec, flat, max_refs, task)


def _oas_task(spec: LayoutSpec, compress: int, task):
    from metafovea.layout import oasis as o
    pieces, counts = o.encode_task_oas(spec, compress, task)
    return pieces, counts, None


def export_layout(spec: LayoutSpec, path: str | os.PathLike, fmt: str = "gds", *, flat: bool = False,
                  force: bool = False, resume: bool = True, workers: int | None = 1,
                  scheduler: str | None = None, progress: bool = False, compress: int = 1,
                  inflight: int | None = None, max_refs: int | None = None, threads: bool = True,
                  direct: bool = True, _stop_after: int | None = None) -> ExportResult:
    """Write the lens (or patch) layout of ``spec`` to ``path`` as GDSII (``'gds'``) or OASIS (``'oas'``).

    ``flat`` (GDSII only): one rectangle per post instead of one reference. ``max_refs`` (GDSII only):
    hierarchical file with at most that many elements per structure (posts in leaf structures, a tree of
    intermediate structures, the top cell holding the frame and its children), e.g. 8192 for the
    Heidelberg DWL 66. ``compress``: OASIS deflate level for the per-task CBLOCKs (0 = none).
    ``workers``: local threads (``threads=False``: processes) encoding tasks while the writer thread
    writes; the output bytes do not depend on it. ``direct``: write with ``O_DIRECT`` where the file
    system allows it (see :class:`DirectFile`). ``_stop_after``: stop (as if interrupted) after that many
    tasks; for tests of resumption.
    """
    from metafovea.layout import gds as g
    from metafovea.layout import oasis as o

    fmt = check_choice("--format", fmt, FORMATS)
    if flat and fmt != "gds":
        raise InputError("--flat", True, "only with --format gds (OASIS is always hierarchical)")
    if max_refs is not None:
        if fmt != "gds":
            raise InputError("--max-refs", max_refs, "only with --format gds (OASIS has no such limit)")
        max_refs = check_int("--max-refs", max_refs, 16, 1 << 30)
    path = Path(path)
    bands = spec.tasks()
    key = input_hash({"v": JOURNAL_VERSION, "spec": spec.key(), "fmt": fmt, "flat": flat, "compress": compress,
                      "max_refs": max_refs})
    top_open, top_elements = b"", 0
    if fmt == "gds":
        header, footer = g.gds_header(spec, flat), g.gds_footer()
        if max_refs is None:
            enc = partial(_gds_task, spec, flat)
        else:
            header, top_open, top_elements = g.split_top(header)
            if top_elements >= max_refs:
                raise InputError("--max-refs", max_refs, f"more than the {top_elements} frame elements of the top cell")
            enc = partial(_gds_task_hier, spec, flat, max_refs)
    else:
        header, footer = o.oas_header(spec), o.oas_footer()
        enc = partial(_oas_task, spec, compress)
    prepare_output(path, force)
    part, jpath = part_paths(path)

    t0 = time.perf_counter()
    start, offset = 0, len(header)
    counts = np.zeros(spec.levels, dtype=np.int64)
    leaves: list[int] = []  # leaf structures per task (max_refs)
    j = _load_journal(jpath) if resume else None
    fh = None
    try:
        if (j is not None and j.get("key") == key and part.is_file()
                and part.stat().st_size >= j["offset"] and 0 <= j["bands_done"] <= len(bands)
                and len(j.get("leaves", [])) == (j["bands_done"] if max_refs else 0)):
            start, offset = int(j["bands_done"]), int(j["offset"])
            counts += np.asarray(j["counts"], dtype=np.int64)
            leaves = [int(v) for v in j.get("leaves", [])]
            fh = DirectFile(part, offset, direct=direct)
        else:
            with contextlib.suppress(FileNotFoundError):
                jpath.unlink()
            fh = DirectFile(part, direct=direct)
            fh.write(header)
            fh.flush()
            _write_journal(jpath, {"key": key, "bands_done": 0, "offset": offset, "counts": counts.tolist(),
                                   "total_bands": len(bands), "leaves": []})
        bar = None
        if progress:
            from tqdm.auto import tqdm
            bar = tqdm(total=len(bands), initial=start, unit="band", desc=f"export {path.name}")
        st = {"done": start, "offset": offset, "last": time.perf_counter()}

        def written(nbytes: int, c: np.ndarray, meta: Any) -> None:  # runs in the writer thread
            st["offset"] += nbytes
            counts[:] += c
            st["done"] += 1
            if max_refs is not None:
                leaves.append(int(meta))
            now = time.perf_counter()
            if now - st["last"] > 0.5 or st["done"] == len(bands) or _stop_after is not None:
                fh.flush()
                _write_journal(jpath, {"key": key, "bands_done": st["done"], "offset": st["offset"],
                                       "counts": counts.tolist(), "total_bands": len(bands), "leaves": leaves})
                st["last"] = now
            if bar is not None:
                bar.update(1)
                bar.set_postfix(posts=f"{int(counts.sum()):,}", refresh=False)

        writer = _Writer(fh, written)
        try:
            todo = bands[start:] if _stop_after is None else bands[start:start + _stop_after]
            for pieces, c, meta in _ordered_map(enc, todo, workers, scheduler, inflight, threads):
                writer.put(pieces, c, meta)
        finally:
            writer.close()
            if bar is not None:
                bar.close()
        done, offset = st["done"], st["offset"]
        if done < len(bands):
            fh.close()
            fh = None
            raise KeyboardInterrupt("stopped after %d bands (test)" % done)
        if max_refs is not None:
            names = [g.leaf_name(t, i) for t, n in enumerate(leaves) for i in range(n)]
            footer = g.hierarchy_footer(spec, top_open, top_elements, names, max_refs)
        fh.write(footer)
        offset += len(footer)
        fh.sync()
        fh.close()
        fh = None
        os.replace(part, path)
        with contextlib.suppress(FileNotFoundError):
            jpath.unlink()
        with contextlib.suppress(OSError):
            dfd = os.open(path.parent, os.O_RDONLY)
            os.fsync(dfd)
            os.close(dfd)
    except OSError as e:
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()
        if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            raise ExportError(path, "a location with enough free space",
                              f"disk full (or file size limit) after {offset:,} bytes; the partial output {part.name} is kept for "
                              "resuming (rerun the same command after freeing space, or delete it)") from None
        raise ExportError(path, "a writable location", f"{e.strerror or e}") from None
    except BaseException:
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()
        raise
    dt = time.perf_counter() - t0
    extra = {}
    if max_refs is not None:
        extra = {"max_refs": max_refs, "leaf_structures": int(sum(leaves))}
    return ExportResult(path, fmt, flat, int(counts.sum()), counts.tolist(), offset, dt, len(bands), start, extra)


# ----------------------------------------------------------------------------------------------
# calibration (test) array
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TestArraySpec:
    """Each post type in its own ``block x block`` block at the lattice period; blocks in a row-major
    grid of ``ceil(sqrt(N))`` columns separated by ``gap_um``; lower-left block corner at
    ``(margin_um, margin_um)``; a text label under each block (``P003 wx=.. wy=..``) and one for the
    whole array."""

    spec: LayoutSpec
    block: int = 50
    gap_um: float = 100.0
    margin_um: float = 100.0

    __test__ = False  # not a pytest class

    @property
    def columns(self) -> int:
        return int(np.ceil(np.sqrt(self.spec.levels)))

    def block_origin_nm(self, k: int) -> tuple[int, int]:
        s = self.spec
        p = int(round(s.design.period_um * 1000))
        pitch = self.block * p + int(round(self.gap_um * 1000))
        r, c = divmod(k, self.columns)
        m = int(round(self.margin_um * 1000))
        return m + c * pitch + p // 2, m + r * pitch + p // 2


def export_test_array(ta: TestArraySpec, path: str | os.PathLike, fmt: str = "gds", *, flat: bool = False,
                      force: bool = False) -> ExportResult:
    """Write the calibration array (gdstk; GDSII AREFs or OASIS regular repetitions, or flat)."""
    import gdstk

    from metafovea.io import atomic_open

    fmt = check_choice("--format", fmt, FORMATS)
    if flat and fmt != "gds":
        raise InputError("--flat", True, "only with --format gds")
    path = Path(path)
    prepare_output(path, force)
    t0 = time.perf_counter()
    s = ta.spec
    lib = gdstk.Library(name="CALIBRATION", unit=1e-6, precision=1e-9)
    pl, pd = s.layers.posts
    tl, tt = s.layers.label
    top = gdstk.Cell(f"{s.top_name.rsplit('_', 1)[0]}_CAL")
    cells = []
    for name, (wx, wy) in zip(s.post_names, (s.post_sizes_nm / 1000.0).tolist()):
        c = gdstk.Cell(name)
        c.add(gdstk.rectangle((-wx / 2, -wy / 2), (wx / 2, wy / 2), layer=pl, datatype=pd))
        cells.append(c)
    p_um = s.design.period_um
    for k, c in enumerate(cells):
        x, y = ta.block_origin_nm(k)
        top.add(gdstk.Reference(c, (x / 1000.0, y / 1000.0), columns=ta.block, rows=ta.block,
                                spacing=(p_um, p_um)))
        wx, wy = s.post_sizes_nm[k].tolist()
        top.add(gdstk.Label(f"{s.post_names[k]} wx={wx}nm wy={wy}nm", (x / 1000.0, y / 1000.0 - p_um),
                            layer=tl, texttype=tt))
    top.add(gdstk.Label("calibration " + s.label_text(), (ta.margin_um / 2, ta.margin_um / 2), layer=tl,
                        texttype=tt))
    if flat:
        top.flatten()
        lib.add(top)
    else:
        lib.add(top, *cells)
    part, _ = part_paths(path)
    try:
        if fmt == "gds":
            lib.write_gds(str(part), timestamp=datetime_fixed())
        else:
            lib.write_oas(str(part))
        with open(part, "rb") as fh:
            data = fh.read()
        with atomic_open(path, "wb") as out:
            out.write(data)
    except OSError as e:
        raise ExportError(path, "a writable location with free space", e.strerror or str(e)) from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            part.unlink()
    n = ta.block * ta.block
    return ExportResult(path, fmt, flat, n * s.levels, [n] * s.levels, len(data), time.perf_counter() - t0, 0)


def datetime_fixed():
    from metafovea.layout.gds import FIXED_TIMESTAMP
    return FIXED_TIMESTAMP


__all__ = ["ExportError", "ExportResult", "FORMATS", "TestArraySpec", "export_layout", "export_test_array",
           "part_paths"]
