"""Streamed, resumable, atomic export of a lens layout (GDSII or OASIS) and of a calibration array.

The file is written to ``.<name>.part`` next to the final path, task after task (a task is a mirror-row band, see
:meth:`LayoutSpec.tasks`; tasks are encoded serially, in local threads or processes, at most a few in flight, and
written in order by a writer thread through :class:`DirectFile`, ``O_DIRECT`` where possible). GDSII without a
hierarchy is encoded in place: each task's size is known beforehand
(:func:`~metafovea.layout.tiling.task_post_counts`), so its offset in the file is too, and its encoder fills a
page-aligned buffer from a bounded pool at that offset within a disk block; the disk writes the buffer as it is
(:meth:`DirectFile.write_placed`), so encoding and writing overlap with no copy between them. On a Dask cluster the
workers write tile files that this process stitches in band order (:mod:`metafovea.layout.tilefiles`). A small
journal ``.<name>.part.json`` (updated at most every 0.5 s) records the tasks finished and the byte offset (and, for
hierarchical GDSII, the leaf structures per task); a rerun with the same parameters truncates the part file to that
offset and continues. When all tasks are written the footer is added (hierarchical GDSII: the intermediate
structures and the top cell), the file is fsynced and renamed to the final name; nothing ever appears under the
final name half-written.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import json
import logging
import os
import queue
import shutil
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import partial
from itertools import islice
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from metafovea.errors import InputError, check_choice, check_int, human_bytes
from metafovea.io import file_stem, input_hash, prepare_output
from metafovea.layout import gds, oasis
from metafovea.layout.directfile import DirectFile
from metafovea.layout.mesh import MESH_FORMATS, export_mesh
from metafovea.layout.tilefiles import TileDir, default_tiles_dir
from metafovea.layout.tiling import Expected, LayoutSpec, drc_summary, post_count, task_post_counts
from metafovea.parallel import default_workers

FORMATS = ("gds", "oas")  #: layout formats (:func:`export_layout`)
#: every format :func:`export_file` writes, and the file-name suffixes each accepts
SUFFIXES = {"gds": (".gds", ".gdsii"), "oas": (".oas", ".oasis"), "stl": (".stl",), "glb": (".glb",)}
DEFAULT_DIR = Path("gds_export")  #: where :func:`export_file` writes without ``out``
JOURNAL_VERSION = 2
#: a layout file estimated this large or larger is announced before the write starts (:func:`size_notice`)
SIZE_NOTICE_BYTES = 1 << 30

log = logging.getLogger(__name__)


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


def _with_posts(res: dict[str, Any], spec: LayoutSpec) -> dict[str, Any]:
    """The result with the post set written: its source and widths (the JSON names an idealised set as such)."""
    ps = spec.post_set
    res["post_set"] = {"source": ps.source, "widths_um": ps.widths_um.tolist(),
                       "note": "idealised width ramp, not a physical design" if ps.source == "ideal" else None}
    res["drc"] = drc_summary(spec)
    return res


class ExportError(InputError):
    """Writing failed (disk full, not writable); nothing under the final name."""

    def __init__(self, path: Path, reason: str, detail: str | None = None):
        super().__init__("path", str(path), reason, detail=detail)


def _ordered_map(fn: Callable, items: list, workers: int | None, scheduler: None = None,
                 inflight: int | None = None, threads: bool = True) -> Iterator[Any]:
    """``fn`` over ``items`` in order, at most ``inflight`` tasks pending (bounded memory), locally.

    Local workers are threads by default (the encoders spend their time in numpy and zlib, which
    release the GIL, and results need no pickling); ``threads=False`` uses processes. (A Dask cluster does not
    come here: its workers write tiles, :func:`_export_tiled`; ``scheduler`` is kept for old callers and must be
    None.)"""
    if scheduler:
        raise ValueError("_ordered_map runs locally: a cluster export goes through _export_tiled")
    if workers in (None, 1):
        for it in items:
            yield fn(it)
        return
    import concurrent.futures as cf

    from metafovea.parallel import get_executor

    nw = workers or 2
    ex = cf.ThreadPoolExecutor(max_workers=nw) if threads else get_executor(workers)
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


class _Placed(NamedTuple):
    """A task encoded in place: its ``n`` bytes at ``pre`` in the page-aligned ``buf`` (see
    :meth:`DirectFile.write_placed`); ``done()`` gives ``buf`` back to its pool."""

    buf: Any
    pre: int
    n: int
    done: Callable[[], None]


class _Buffers:
    """A pool of page-aligned buffers (anonymous mmaps: their pages are faulted in by their first encoder, then
    reused) that encoders fill in place and the disk gives back; taking one waits for one to be free, which bounds
    the memory (``count * size`` bytes)."""

    def __init__(self, count: int, size: int):
        import mmap

        self.free: queue.Queue = queue.Queue()
        for _ in range(count):
            self.free.put(mmap.mmap(-1, size))

    def get(self) -> Any:
        return self.free.get()


def _placed_tasks(todo: list, sizes: list[int], offset: int, pool: _Buffers) -> Iterator[tuple]:
    """``(task, pre, n, buffer)`` for each task, in order: its bytes ``n`` start ``pre`` bytes into a block of the
    file (the tasks before it end at ``offset + sum(sizes)``), in a buffer from ``pool`` (taken here, in task order,
    so that a task never waits for a buffer a later task holds)."""
    for t, n in zip(todo, sizes):
        yield t, offset % DirectFile.BLOCK, n, pool.get()
        offset += n


def _gds_task_into(spec: LayoutSpec, flat: bool, pool: _Buffers, item: tuple):
    task, pre, n, buf = item
    counts = gds.encode_task_into(spec, flat, task, np.frombuffer(buf, dtype=np.uint8, count=n, offset=pre))
    return _Placed(buf, pre, n, partial(pool.free.put, buf)), counts, None


def _encoded(spec: LayoutSpec, fmt: str, o: ExportOptions, enc: Callable, todo: list,
             offset: int) -> Iterator[tuple[Any, np.ndarray, Any]]:
    """``(pieces, counts, meta)`` of each task of ``todo``, in order, the first written at ``offset``. GDSII without
    a hierarchy, encoded in threads, goes in place into page-aligned buffers (``pieces``: one :class:`_Placed`, which
    the disk writes without a copy); anything else into new arrays (``pieces``: a list, copied into the writer's
    staging buffers)."""
    workers = o.workers or default_workers()
    window = o.inflight or workers + 1
    if fmt != "gds" or o.max_refs is not None or o.dwl or not o.threads or not todo:
        yield from _ordered_map(enc, todo, workers, None, window, o.threads)
        return
    sizes = [sum(task_post_counts(spec, t)) * (gds.BOUNDARY_BYTES if o.flat else gds.SREF_BYTES) for t in todo]
    pool = _Buffers(window + 4, max(sizes) + DirectFile.BLOCK)  # > window + 1: see _placed_tasks
    yield from _ordered_map(partial(_gds_task_into, spec, o.flat, pool), _placed_tasks(todo, sizes, offset, pool),
                            workers, None, window, True)


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
            pieces, c, meta = item
            if self.exc is not None:
                if isinstance(pieces, _Placed):
                    pieces.done()  # its buffer back to the pool: an encoder may be waiting for it
                continue
            try:
                if isinstance(pieces, _Placed):
                    nbytes = self.fh.write_placed(pieces.buf, pieces.pre, pieces.n, pieces.done)
                else:
                    nbytes = 0
                    for data in pieces:
                        self.fh.write(data)
                        nbytes += memoryview(data).nbytes
                self.on_written(nbytes, c, meta)
            except BaseException as e:  # noqa: BLE001 - re-raised in the caller
                self.exc = e

    def put(self, pieces: Any, c: np.ndarray, meta: Any = None) -> None:
        if self.exc is not None:
            if isinstance(pieces, _Placed):
                pieces.done()
            raise self.exc
        self.q.put((pieces, c, meta))

    def close(self) -> None:
        self.q.put(None)
        self.join()
        if self.exc is not None:
            exc, self.exc = self.exc, None
            raise exc


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


class _Journal:
    """The resume journal next to the part file: tasks written, byte offset, counts so far and (hierarchical
    GDSII) the leaf structures per task, under the key of everything that fixes the file's content."""

    def __init__(self, path: Path, key: str, total: int, date: str = ""):
        self.path, self.key, self.total, self.date = path, key, total, date

    def write(self, done: int, offset: int, counts: np.ndarray, leaves: list[int]) -> None:
        _write_journal(self.path, {"key": self.key, "bands_done": done, "offset": offset, "counts": counts.tolist(),
                                   "total_bands": self.total, "leaves": leaves, "date": self.date})

    def resumable(self, j: dict[str, Any] | None, part: Path, hier: bool) -> bool:
        """Whether journal ``j`` (from :func:`_load_journal`) describes a consistent partial export of this key."""
        return (j is not None and j.get("key") == self.key and part.is_file()
                and part.stat().st_size >= j["offset"] and 0 <= j["bands_done"] <= self.total
                and len(j.get("leaves", [])) == (j["bands_done"] if hier else 0))


class _Checkpoint:
    """Called by the writer thread after each task is written: adds its counts, and journals the progress at
    most every 0.5 s (after the last task, and after every task with ``every_task``)."""

    def __init__(self, fh: DirectFile, journal: _Journal, counts: np.ndarray, leaves: list[int], done: int,
                 offset: int, *, hier: bool, every_task: bool, bar: Any = None):
        self.fh, self.journal, self.counts, self.leaves = fh, journal, counts, leaves
        self.done, self.offset, self.hier, self.every_task, self.bar = done, offset, hier, every_task, bar
        self.last = time.perf_counter()

    def __call__(self, nbytes: int, c: np.ndarray, meta: Any) -> None:
        self.offset += nbytes
        self.counts[:] += c
        self.done += 1
        if self.hier:
            self.leaves.append(int(meta))
        now = time.perf_counter()
        if now - self.last > 0.5 or self.done == self.journal.total or self.every_task:
            self.fh.flush()
            self.journal.write(self.done, self.offset, self.counts, self.leaves)
            self.last = now
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(posts=f"{int(self.counts.sum()):,}", refresh=False)


def _gds_task(spec: LayoutSpec, flat: bool, task):
    pieces, counts = gds.encode_task_records(spec, flat, task)
    return pieces, counts, None


def _gds_task_hier(spec: LayoutSpec, flat: bool, leaf_max: int | None, task):
    return gds.encode_task_hier(spec, flat, leaf_max, task)


def _oas_task(spec: LayoutSpec, compress: int, task):
    pieces, counts = oasis.encode_task_oas(spec, compress, task)
    return pieces, counts, None


#: Heidelberg DWL 66: at most this many structure definitions, and references per structure
DWL_LIMIT = 8192


def _encoder(spec: LayoutSpec, fmt: str, flat: bool, compress: int, max_refs: int | None, dwl: bool = False):
    """``(header, footer, top_open, frame_elements, encode)``: the bytes before and after the posts, the top
    structure's opening records and its frame elements (hierarchical GDSII, whose footer is built at the end),
    and the task encoder (picklable, for processes). ``max_refs``: leaves of at most that many posts; ``dwl``:
    one leaf per task side (posts as boundaries), references per structure and definitions within
    :data:`DWL_LIMIT`."""
    top_open, frame_el = b"", []
    if fmt == "gds":
        header, footer = gds.gds_header(spec, flat), gds.gds_footer()
        if max_refs is None and not dwl:
            return header, footer, top_open, frame_el, partial(_gds_task, spec, flat)
        header, top_open, frame_el = gds.split_top(header)
        if dwl:
            leaves = 2 * len(spec.tasks()) + 1
            if leaves > DWL_LIMIT - 64:
                raise InputError("band_rows", spec.band_rows, f"more rows per task: {leaves:,} leaf structures "
                                 f"exceed the DWL 66 limit of {DWL_LIMIT} definitions")
            return header, footer, top_open, frame_el, partial(_gds_task_hier, spec, flat, None)
        return header, footer, top_open, frame_el, partial(_gds_task_hier, spec, flat, max_refs)
    return oasis.oas_header(spec), oasis.oas_footer(), top_open, frame_el, partial(_oas_task, spec, compress)


def _publish(part: Path, path: Path, jpath: Path) -> None:
    """The complete part file (synced and closed) under its final name; the journal removed, the directory
    synced."""
    os.replace(part, path)
    with contextlib.suppress(FileNotFoundError):
        jpath.unlink()
    with contextlib.suppress(OSError):
        dfd = os.open(path.parent, os.O_RDONLY)
        os.fsync(dfd)
        os.close(dfd)


@dataclass(frozen=True)
class ExportOptions:
    """How :func:`export_layout` (and :func:`export_file`) write a layout; validated on construction, each error
    naming its field.

    Attributes
    ----------
    flat : bool
        GDSII only: one rectangle per post instead of one reference.
    max_refs : int, optional
        GDSII only: a hierarchical file with at most that many elements per structure (posts in leaf structures, a
        tree of intermediate structures, the top cell holding the frame and its children), e.g. 8192 for the
        Heidelberg DWL 66 if it counts every element; 16 to 2**30.
    dwl : bool
        GDSII only, without ``max_refs``: the Heidelberg DWL 66 mode: posts as boundaries in one leaf structure per
        task side, the frame in one structure, a tree of references above them: at most :data:`DWL_LIMIT` structure
        definitions and references per structure (shapes per structure are not limited: no layout of a large lens
        meets both limits counting every shape).
    compress : int
        OASIS deflate level of the per-task CBLOCKs, 0 (none) to 9.
    force, resume : bool
        Overwrite an existing file; continue a partial export of the same parameters (its journal) instead of
        starting over.
    workers : int, optional
        Local encoder threads (processes with ``threads=False``) while the writer thread writes; None:
        :func:`metafovea.parallel.default_workers` (one per core, the default of every ``--workers``). The
        output bytes do not depend on it.
    threads : bool
        Encoders in threads (default: numpy and zlib release the GIL, results need no pickling) or processes.
    inflight : int, optional
        Encoded tasks waiting for the writer at most (memory: each holds one task's bytes); default ``workers + 1``.
    direct : bool
        Write with ``O_DIRECT`` where the file system allows it (:class:`~metafovea.layout.directfile.DirectFile`).
    scheduler : str, optional
        A Dask scheduler address, or ``local:N``: the workers write the encoded bands as tile files into
        ``tiles_dir`` and this process stitches them in band order (:mod:`metafovea.layout.tilefiles`): the same
        bytes, resumable from the tiles written.
    tiles_dir : path, optional
        With ``scheduler``: where the workers write their tiles, on a file system the client and every worker share
        (default ``.<name>.tiles`` next to the output).
    progress : bool
        A progress bar over the tasks.
    stop_after : int, optional
        For tests of resumption: stop, as if interrupted (``KeyboardInterrupt``), after that many tasks, with the
        journal written after each.
    """

    flat: bool = False
    max_refs: int | None = None
    dwl: bool = False
    compress: int = 1
    force: bool = False
    resume: bool = True
    workers: int | None = None
    threads: bool = True
    inflight: int | None = None
    direct: bool = True
    scheduler: str | None = None
    tiles_dir: str | os.PathLike | None = None
    progress: bool = False
    stop_after: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.compress, bool) or not isinstance(self.compress, int) or not 0 <= self.compress <= 9:
            raise InputError("compress", self.compress, "an integer 0..9")
        for name in ("workers", "inflight"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
                raise InputError(name, v, "an integer >= 1")
        if self.max_refs is not None:
            object.__setattr__(self, "max_refs", check_int("max_refs", self.max_refs, 16, 1 << 30))
        if self.dwl and self.max_refs is not None:
            raise InputError("dwl", True, "only without max_refs=...")
        if self.stop_after is not None:
            object.__setattr__(self, "stop_after", check_int("stop_after", self.stop_after, 0))
        if self.tiles_dir is not None and not self.scheduler:
            raise InputError("tiles_dir", str(self.tiles_dir), "only with scheduler=... (local exports write one file)")

    def checked_for(self, fmt: str) -> tuple[str, ExportOptions]:
        """``(fmt, options)`` checked together (``flat``, ``max_refs`` and ``dwl`` are GDSII's; ``dwl`` is flat)."""
        fmt = check_choice("fmt", fmt, FORMATS)
        if self.flat and fmt != "gds":
            raise InputError("flat", True, "only with fmt='gds' (OASIS is always hierarchical)")
        if self.max_refs is not None and fmt != "gds":
            raise InputError("max_refs", self.max_refs, "only with fmt='gds' (OASIS has no such limit)")
        if self.dwl and fmt != "gds":
            raise InputError("dwl", True, "only with fmt='gds' and without max_refs=...")
        return fmt, replace(self, flat=True) if self.dwl else self


def estimated_bytes(spec: LayoutSpec, fmt: str = "gds", options: ExportOptions | None = None) -> int | None:
    """The size of the file :func:`export_layout` writes, without writing it: GDSII's record per post (an SREF,
    :data:`~metafovea.layout.gds.SREF_BYTES`; flat or ``dwl``: a BOUNDARY, ``BOUNDARY_BYTES``) times the posts
    (:func:`~metafovea.layout.tiling.post_count`); the header, the frame and a hierarchy's structures (a few kB to
    MB) are left out. None for OASIS, whose compressed size is known only once written."""
    fmt, o = (options or ExportOptions()).checked_for(fmt)
    if fmt != "gds":
        return None
    return post_count(spec) * (gds.BOUNDARY_BYTES if o.flat else gds.SREF_BYTES)


def free_bytes(path: str | os.PathLike) -> int:
    """Free space (bytes) on the file system ``path`` goes to (its nearest existing folder's)."""
    d = Path(path).absolute().parent
    while not d.exists() and d != d.parent:
        d = d.parent
    return shutil.disk_usage(d).free


def size_notice(spec: LayoutSpec, path: str | os.PathLike, fmt: str = "gds",
                options: ExportOptions | None = None) -> str | None:
    """One line announcing a write of :data:`SIZE_NOTICE_BYTES` or more (``writing about 7.2 GiB to x.gds; 73 GiB
    free there``), None for a smaller file or an OASIS one (:func:`estimated_bytes`)."""
    n = estimated_bytes(spec, fmt, options)
    if n is None or n < SIZE_NOTICE_BYTES:
        return None
    return f"writing about {human_bytes(n)} to {path}; {human_bytes(free_bytes(path))} free there"


def _check_space(path: Path, need: int | None) -> None:
    """Refuse a write of ``need`` more bytes (None: unknown) where less is free; log a large one."""
    if need is None:
        return
    free = free_bytes(path)
    if need > free:
        raise ExportError(path, "a location with enough free space",
                          f"about {human_bytes(need)} to write, {human_bytes(free)} free there")
    if need >= SIZE_NOTICE_BYTES:
        log.info("writing about %s to %s; %s free there", human_bytes(need), path, human_bytes(free))


def export_layout(spec: LayoutSpec, path: str | os.PathLike, fmt: str = "gds",
                  options: ExportOptions | None = None) -> ExportResult:
    """Write the lens (or patch) layout of ``spec`` to ``path`` as GDSII (``'gds'``) or OASIS (``'oas'``).

    Parameters
    ----------
    spec : LayoutSpec
        The layout: design, post set, frame, patch.
    path : str or PathLike
        The file written (atomically: under its name only once complete; see the module docstring).
    fmt : {'gds', 'oas'}
        GDSII or OASIS.
    options : ExportOptions, optional
        How to write it (hierarchy, compression, encoder threads, ``O_DIRECT``, a Dask cluster, resuming).

    Returns
    -------
    ExportResult
        What was written: posts per type, bytes, seconds, tasks (``bands``) and those resumed.
    """
    fmt, o = (options or ExportOptions()).checked_for(fmt)
    path = Path(path)
    skey = spec.key()
    skey.pop("date", None)  # the labels' date: a resumed export keeps the date its part file was started with
    key = input_hash({"v": JOURNAL_VERSION, "spec": skey, "fmt": fmt, "flat": o.flat, "compress": o.compress,
                      "max_refs": o.max_refs, "dwl": o.dwl})
    prepare_output(path, o.force, name="path")
    need = estimated_bytes(spec, fmt, o)
    if o.scheduler:
        _check_space(path, need)
        return _export_tiled(spec, path, fmt, key, o)
    return _export_local(spec, path, fmt, key, o, need)


def _export_local(spec: LayoutSpec, path: Path, fmt: str, key: str, o: ExportOptions,
                  need: int | None) -> ExportResult:
    """:func:`export_layout` in this process: encoder threads (or processes), a writer thread, the journal;
    ``need``: the bytes it will write (:func:`estimated_bytes`), less what a resumed part file holds."""
    bands = spec.tasks()
    part, jpath = part_paths(path)
    j = _load_journal(jpath) if o.resume else None
    if j is not None and j.get("key") == key and isinstance(j.get("date"), str) and j["date"] != spec.date:
        spec = replace(spec, date=j["date"])
    header, footer, top_open, frame_el, enc = _encoder(spec, fmt, o.flat, o.compress, o.max_refs, o.dwl)
    journal = _Journal(jpath, key, len(bands), spec.date)

    t0 = time.perf_counter()
    start, offset = 0, len(header)
    counts = np.zeros(spec.levels, dtype=np.int64)
    leaves: list[int] = []  # leaf structures per task (max_refs)
    hier = o.max_refs is not None or o.dwl
    fh = None
    try:
        resumed = journal.resumable(j, part, hier)
        _check_space(path, None if need is None else need - (int(j["offset"]) - len(header) if resumed else 0))
        if resumed:
            start, offset = int(j["bands_done"]), int(j["offset"])
            counts += np.asarray(j["counts"], dtype=np.int64)
            leaves = [int(v) for v in j.get("leaves", [])]
            fh = DirectFile(part, offset, direct=o.direct)
        else:
            with contextlib.suppress(FileNotFoundError):
                jpath.unlink()
            fh = DirectFile(part, direct=o.direct)
            fh.write(header)
            fh.flush()
            journal.write(0, offset, counts, [])
        bar = None
        if o.progress:
            from tqdm.auto import tqdm
            bar = tqdm(total=len(bands), initial=start, unit="band", desc=f"export {path.name}")
        ck = _Checkpoint(fh, journal, counts, leaves, start, offset, hier=hier, every_task=o.stop_after is not None,
                         bar=bar)
        writer = _Writer(fh, ck)
        try:
            todo = bands[start:] if o.stop_after is None else bands[start:start + o.stop_after]
            for pieces, c, meta in _encoded(spec, fmt, o, enc, todo, offset):
                writer.put(pieces, c, meta)
        finally:
            writer.close()
            if bar is not None:
                bar.close()
        offset = ck.offset
        if ck.done < len(bands):
            fh.close()
            fh = None
            raise KeyboardInterrupt(f"stopped after {ck.done} bands (test)")
        if hier:
            names = [gds.leaf_name(t, i) for t, n in enumerate(leaves) for i in range(n)]
            footer = (gds.hierarchy_footer(spec, top_open, frame_el, names, DWL_LIMIT, frame_max=len(frame_el))
                      if o.dwl else gds.hierarchy_footer(spec, top_open, frame_el, names, o.max_refs))
        fh.write(footer)
        offset += len(footer)
        fh.sync()
        fh.close()
        fh = None
        _publish(part, path, jpath)
    except OSError as e:
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()
        raise _write_error(path, part, offset, e) from None
    except BaseException:
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()
        raise
    return ExportResult(path, fmt, o.flat, int(counts.sum()), counts.tolist(), offset, time.perf_counter() - t0,
                        len(bands), start, _extra(spec, hier, o.dwl, o.max_refs, leaves))


def _write_error(path: Path, part: Path, offset: int, e: OSError) -> ExportError:
    """The :class:`ExportError` of a failed write: a full disk (the partial output kept for resuming) or another."""
    if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        try:  # what reached the disk (``offset`` is only brought up to date at the end of the bands)
            written = part.stat().st_size
        except OSError:
            written = offset
        return ExportError(path, "a location with enough free space",
                           f"disk full (or file size limit) after {written:,} bytes; the partial output {part.name} "
                           "is kept for resuming (rerun the same command after freeing space, or delete it)")
    return ExportError(path, "a writable location", f"{e.strerror or e}")


def _extra(spec: LayoutSpec, hier: bool, dwl: bool, max_refs: int | None, leaves: list[int]) -> dict[str, Any]:
    extra: dict[str, Any] = {}
    if hier:
        extra = {"max_refs": DWL_LIMIT if dwl else max_refs, "leaf_structures": int(sum(leaves)), "dwl": dwl}
    from metafovea.layout.frame import content_hash
    extra.update(date=spec.date, content_hash=content_hash(spec), printed_label=spec.printed_text(),
                 tone=spec.tone_text())
    return extra


def _export_tiled(spec: LayoutSpec, path: Path, fmt: str, key: str, o: ExportOptions) -> ExportResult:
    """:func:`export_layout` on a Dask cluster: tiles written by the workers, stitched here in band order."""
    from metafovea.parallel import get_executor

    with get_executor(scheduler=o.scheduler) as ex:  # a bad scheduler is refused before anything is made
        return _tiled(spec, path, fmt, key, o, ex)


def _tiled(spec: LayoutSpec, path: Path, fmt: str, key: str, o: ExportOptions, executor: Any) -> ExportResult:
    """:func:`_export_tiled` on the open cluster ``executor``."""
    bands = spec.tasks()
    hier = o.max_refs is not None or o.dwl
    td = TileDir(Path(o.tiles_dir) if o.tiles_dir is not None else default_tiles_dir(path), key, len(bands))
    t0 = time.perf_counter()
    date, done = td.open(o.resume, spec.date)
    if date != spec.date:  # a resumed export keeps the date its tiles were started with
        spec = replace(spec, date=date)
    header, footer, top_open, frame_el, enc = _encoder(spec, fmt, o.flat, o.compress, o.max_refs, o.dwl)
    todo = [(i, b) for i, b in enumerate(bands) if i not in done]
    if o.stop_after is not None:
        todo = todo[:o.stop_after]
    try:
        td.run(enc, todo, executor, o.progress, f"export {path.name}")
    except OSError as e:  # raised by a worker writing its tile
        raise InputError("tiles_dir", str(td.d), "a writable directory with free space, shared by the client and "
                         "every worker", detail=f"a worker could not write its tile: {e.strerror or e}") from None
    if len(done) + len(todo) < len(bands):
        raise KeyboardInterrupt(f"stopped after {len(todo)} bands (test)")
    part, jpath = part_paths(path)
    fh = None
    try:
        fh = DirectFile(part, direct=o.direct)
        fh.write(header)
        counts, metas = td.stitch(fh.write)
        leaves = [int(m) for m in metas] if hier else []
        if hier:
            names = [gds.leaf_name(t, i) for t, n in enumerate(leaves) for i in range(n)]
            footer = (gds.hierarchy_footer(spec, top_open, frame_el, names, DWL_LIMIT, frame_max=len(frame_el))
                      if o.dwl else gds.hierarchy_footer(spec, top_open, frame_el, names, o.max_refs))
        fh.write(footer)
        fh.sync()
        fh.close()
        fh = None
        _publish(part, path, jpath)
    except OSError as e:
        raise ExportError(path, "a writable location with free space", f"{e.strerror or e}") from None
    finally:
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()
    td.clean(remove_dir=o.tiles_dir is None)
    if counts.size == 0:
        counts = np.zeros(spec.levels, dtype=np.int64)
    return ExportResult(path, fmt, o.flat, int(counts.sum()), counts.tolist(), path.stat().st_size,
                        time.perf_counter() - t0, len(bands), len(done),
                        {**_extra(spec, hier, o.dwl, o.max_refs, leaves), "tiles_dir": str(td.d)})


# ----------------------------------------------------------------------------------------------
# calibration (test) array
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TestArraySpec:
    """Each post type in its own ``block x block`` block at the lattice period; blocks in a row-major
    grid of ``ceil(sqrt(N))`` columns separated by ``gap_um``; lower-left block corner at
    ``(margin_um, margin_um)``; a text label under each block (``P003 wx=.. wy=..``) and one for the
    whole array. ``block``: 1 to 4096 posts per side."""

    spec: LayoutSpec
    block: int = 50
    gap_um: float = 100.0
    margin_um: float = 100.0

    __test__ = False  # not a pytest class

    def __post_init__(self) -> None:
        object.__setattr__(self, "block", check_int("block", self.block, 1, 4096))

    @property
    def columns(self) -> int:
        return int(np.ceil(np.sqrt(self.spec.levels)))

    @property
    def top_name(self) -> str:
        """``<NAME>_CAL``: the top cell of the calibration array."""
        return f"{self.spec.top_name.rsplit('_', 1)[0]}_CAL"

    def block_origin_nm(self, k: int) -> tuple[int, int]:
        s = self.spec
        p = int(round(s.design.period_um * 1000))
        pitch = self.block * p + int(round(self.gap_um * 1000))
        r, c = divmod(k, self.columns)
        m = int(round(self.margin_um * 1000))
        return m + c * pitch + p // 2, m + r * pitch + p // 2

    def expected(self) -> Expected:
        """``block**2`` posts of each type and the bounding box of all blocks' posts (nm)."""
        s = self.spec
        counts = np.full(s.levels, self.block * self.block, dtype=np.int64)
        p = int(round(s.design.period_um * 1000))
        boxes = []
        for k in range(s.levels):
            x, y = self.block_origin_nm(k)
            w, h = (int(v) for v in s.post_sizes_nm[k])
            span = (self.block - 1) * p
            boxes.append((x - w // 2, y - h // 2, x + span + w // 2, y + span + h // 2))
        bb = (min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes), max(b[3] for b in boxes))
        return Expected(counts, bb)


def export_test_array(ta: TestArraySpec, path: str | os.PathLike, fmt: str = "gds", *, flat: bool = False,
                      force: bool = False) -> ExportResult:
    """Write the calibration array (gdstk; GDSII AREFs or OASIS regular repetitions, or flat)."""
    import gdstk

    from metafovea.io import atomic_open

    fmt = check_choice("fmt", fmt, FORMATS)
    if flat and fmt != "gds":
        raise InputError("flat", True, "only with fmt='gds'")
    path = Path(path)
    prepare_output(path, force, name="path")
    t0 = time.perf_counter()
    s = ta.spec
    lib = gdstk.Library(name="CALIBRATION", unit=1e-6, precision=1e-9)
    pl, pd = s.layers.posts
    tl, tt = s.layers.label
    top = gdstk.Cell(ta.top_name)
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
            lib.write_gds(str(part), timestamp=gds.FIXED_TIMESTAMP)
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


# ----------------------------------------------------------------------------------------------
# one file, as `metafovea export` writes it
# ----------------------------------------------------------------------------------------------
def output_path(spec: LayoutSpec, fmt: str, out: str | os.PathLike | None = None, *, test_array: bool = False,
                flat: bool = False, max_refs: int | None = None, dwl: bool = False) -> Path:
    """Where :func:`export_file` writes: ``out`` with ``.<fmt>`` added when it ends in none of the known
    suffixes (:data:`SUFFIXES`), or ``gds_export/<name>[_cal][_patch][_flat][_h<max_refs>].<fmt>`` (``name``:
    the lens name with anything but letters, digits, ``-_.`` replaced by ``_``, so that it names no other
    folder). A suffix of another format is an :class:`InputError` (tools trust the suffix)."""
    name = file_stem(spec.design.name) + ("_cal" if test_array else "") + ("_patch" if spec.patch_um else "") + \
        ("_flat" if flat and not dwl else "") + (f"_h{max_refs}" if max_refs else "") + ("_dwl" if dwl else "")
    path = Path(out) if out else DEFAULT_DIR / name
    known = tuple(x for v in SUFFIXES.values() for x in v)
    if path.suffix.lower() not in known:
        return path.with_name(path.name + "." + fmt)
    if path.suffix.lower() not in SUFFIXES[fmt]:
        # a .oas name with GDSII inside (or the reverse) would mislead every tool that trusts the suffix
        raise InputError("out", str(path), f"a file name ending in {' or '.join(SUFFIXES[fmt])} for fmt={fmt!r} "
                         "(or no suffix: it is added)")
    return path


def export_file(spec: LayoutSpec, out: str | os.PathLike | None = None, fmt: str = "gds",
                options: ExportOptions | None = None, *, test_array: TestArraySpec | None = None,
                substrate_thickness_um: float | None = None) -> dict[str, Any]:
    """Write one file as ``metafovea export`` does: the lens (or patch) layout (:func:`export_layout`), the
    calibration array ``test_array`` (:func:`export_test_array`) or a patch mesh
    (:func:`~metafovea.layout.mesh.export_mesh`), chosen by ``fmt`` (one of :data:`SUFFIXES`, any case), at
    :func:`output_path`. ``options``: :class:`ExportOptions` (the calibration array and the mesh use ``flat`` and
    ``force``; a lens layout all of them). Returns the writer's result as a dict (layouts:
    :meth:`ExportResult.as_dict`)."""
    o = options or ExportOptions()
    fmt_given, fmt = fmt, str(fmt).lower()
    if fmt not in SUFFIXES:
        raise InputError("fmt", fmt_given, "one of 'gds', 'oas', 'stl', 'glb'")
    if o.dwl and (fmt != "gds" or test_array is not None):
        raise InputError("dwl", True, "only with fmt='gds' for a lens (not test_array=..., not max_refs=...)")
    path = output_path(spec, fmt, out, test_array=test_array is not None, flat=o.flat, max_refs=o.max_refs,
                       dwl=o.dwl)
    if o.max_refs is not None and (fmt != "gds" or test_array is not None):
        raise InputError("max_refs", o.max_refs, "only with fmt='gds' for a lens (not test_array=...)")
    if fmt in MESH_FORMATS:
        if o.flat or test_array is not None:
            raise InputError("fmt", fmt, "gds or oas with flat=True or test_array=...")
        return export_mesh(spec, path, fmt, force=o.force, substrate_thickness_um=substrate_thickness_um)
    if test_array is not None:
        return _with_posts(export_test_array(test_array, path, fmt, flat=o.flat, force=o.force).as_dict(), spec)
    return _with_posts(export_layout(spec, path, fmt, o).as_dict(), spec)


__all__ = ["DEFAULT_DIR", "ExportError", "ExportOptions", "ExportResult", "FORMATS", "SIZE_NOTICE_BYTES", "SUFFIXES",
           "TestArraySpec", "estimated_bytes", "export_file", "export_layout", "export_test_array",
           "free_bytes", "output_path", "part_paths", "size_notice"]
