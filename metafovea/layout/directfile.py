"""A sequential file writer for multi-gigabyte layouts: ``O_DIRECT`` from aligned buffers, written by background
threads while the caller fills the next ones, so the disk never waits for the encoders, nor they for it.

Two ways in: :meth:`DirectFile.write` copies bytes into two aligned staging buffers (headers, footers, pieces of
any size); :meth:`DirectFile.write_placed` takes a page-aligned buffer that an encoder filled at the file's current
block offset and writes it as it is (no copy of the bulk: the previous partial block is put in front of it).

Why: on the 2-core benchmark machine the kernel's buffered write path (page-cache copies) cost more CPU than
encoding the posts, and copying every encoded byte into a staging buffer made the export take the sum of the
encoding and the disk time rather than the larger. See ``benchmarks/bench_export_disk.py``.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


class DirectFile:
    """Sequential writer with ``O_DIRECT`` from aligned buffers; falls back to plain writes where ``O_DIRECT`` is
    refused (tmpfs, some network file systems) or ``direct=False``.

    ``io_threads`` background threads write queued blocks (``pwrite`` releases the GIL; with two, the disk is busy
    with one write while the other thread, its write done, waits for the GIL), at most ``depth`` waiting. :meth:`write`
    copies into one of two staging buffers of ``staging`` bytes and queues it when full; :meth:`write_placed` queues
    a caller's aligned buffer. An error of the background write is raised by the next :meth:`write`,
    :meth:`write_placed`, :meth:`flush` or :meth:`sync`.

    ``flush()`` makes every byte written so far part of the file (the queue is written, the last partial block
    goes through a buffered descriptor and is rewritten, aligned, by a later direct write), so a journal written
    after ``flush()`` is consistent. ``offset`` (resume): truncate the file there and continue."""

    BLOCK = 4096

    def __init__(self, path: Path, offset: int | None = None, *, direct: bool = True, staging: int = 32 << 20,
                 depth: int = 2, io_threads: int = 2):
        import mmap

        self.path = path
        new = offset is None
        self.bfd = os.open(path, os.O_RDWR | os.O_CREAT | (os.O_TRUNC if new else 0), 0o666)
        self.dfd = -1
        self.pos = 0 if new else int(offset)
        self.bufs: list = []
        self._io: list[threading.Thread] = []
        self._exc: BaseException | None = None
        self._jobs: collections.deque = collections.deque()  # (memoryview, file offset, done callback or None)
        self._busy = 0  # jobs being written
        self._depth = max(1, depth)
        self._cv = threading.Condition()
        self._stop = False
        try:
            if not new:
                os.ftruncate(self.bfd, self.pos)
            if direct and hasattr(os, "O_DIRECT"):
                try:
                    self.dfd = os.open(path, os.O_WRONLY | os.O_DIRECT)
                except OSError:
                    self.dfd = -1
            if self.dfd >= 0:
                if staging % self.BLOCK:
                    raise ValueError("staging must be a multiple of the block size")
                self.cap = staging
                self.bufs = [mmap.mmap(-1, staging) for _ in range(2)]
                self.mvs = [memoryview(b) for b in self.bufs]
                self.arrs = [np.frombuffer(b, dtype=np.uint8) for b in self.bufs]
                self.queued = [False, False]  # staging buffer i is waiting in (or being written from) the queue
                self.cur = 0
                self.mv = self.mvs[0]
                self.base = self.pos - self.pos % self.BLOCK
                self.fill = self.pos - self.base
                if self.fill:
                    self.mv[:self.fill] = os.pread(self.bfd, self.fill, self.base)
                self._io = [threading.Thread(target=self._run, daemon=True, name=f"directfile-io-{i}")
                            for i in range(max(1, io_threads))]
                for t in self._io:
                    t.start()
        except BaseException:
            self.close()
            raise

    @property
    def direct(self) -> bool:
        return self.dfd >= 0

    # -- background writer -----------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._jobs and not self._stop:
                    self._cv.wait()
                if not self._jobs:
                    return
                mv, off, done = self._jobs.popleft()
                self._busy += 1
                drop = self._stop or self._exc is not None  # closing, or failed before: nothing more written
            try:
                if not drop:
                    self._pwrite_all(self.dfd, mv, off)
            except BaseException as e:  # noqa: BLE001 - raised in the caller's thread
                self._exc = e
            finally:
                if done is not None:
                    done()
                with self._cv:
                    self._busy -= 1
                    self._cv.notify_all()

    def _submit(self, mv: memoryview, off: int, done: Callable[[], None] | None) -> None:
        """Queue ``mv`` (aligned) for writing at ``off``; waits while ``depth`` jobs are queued."""
        with self._cv:
            while len(self._jobs) >= self._depth and self._exc is None:
                self._cv.wait()
            self._raise()
            self._jobs.append((mv, off, done))
            self._cv.notify_all()

    def _wait(self, until: Callable[[], bool] | None = None) -> None:
        """Until the queue is written (or ``until()``); a background error raised here."""
        with self._cv:
            while not (until() if until else not self._jobs and not self._busy) and self._exc is None:
                self._cv.wait()
            self._raise()

    def _raise(self) -> None:
        if self._exc is not None:
            exc, self._exc = self._exc, None
            raise exc

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

    def _queue_staging(self, n: int) -> None:
        """The current staging buffer's first ``n`` bytes (aligned) to the queue; continue in the other buffer, the
        current one's bytes after ``n`` (a partial block) moved to its start."""
        i = self.cur
        self.queued[i] = True
        self._submit(self.mvs[i][:n], self.base, lambda: self.queued.__setitem__(i, False))
        j = i ^ 1
        self._wait(lambda: not self.queued[j])
        tail = self.fill - n
        if tail:
            self.arrs[j][:tail] = self.arrs[i][n:self.fill]
        self.cur, self.mv = j, self.mvs[j]
        self.base += n
        self.fill = tail

    # -- public ----------------------------------------------------------------------------------
    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Append ``data`` (any bytes-like object), copied into the staging buffers."""
        m = np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8)
        n = m.size
        if self.dfd < 0:
            self._pwrite_all(self.bfd, memoryview(m), self.pos)
            self.pos += n
            return n
        self._raise()
        while m.size:
            k = min(m.size, self.cap - self.fill)
            self.arrs[self.cur][self.fill:self.fill + k] = m[:k]  # numpy copies without the GIL
            self.fill += k
            m = m[k:]
            if self.fill == self.cap:  # cap is a multiple of BLOCK: all aligned
                self._queue_staging(self.cap)
        self.pos += n
        return n

    def write_placed(self, buf: Any, pre: int, n: int, done: Callable[[], None] | None = None) -> int:
        """Append the ``n`` bytes ``buf[pre:pre + n]``, written from ``buf`` itself: ``buf`` is page-aligned and
        ``pre`` is the file's current offset within its block (``pos % BLOCK``), so that ``buf[:pre]`` can take the
        partial block written so far. ``done()`` is called once ``buf`` is no longer needed (written, or the bytes
        copied); until then the caller must not touch it."""
        mv = memoryview(buf).cast("B")
        if self.dfd < 0:
            try:
                self._pwrite_all(self.bfd, mv[pre:pre + n], self.pos)
            finally:
                if done is not None:
                    done()
            self.pos += n
            return n
        if pre != self.pos % self.BLOCK or len(mv) < pre + n:
            raise ValueError(f"a placed buffer must start {self.pos % self.BLOCK} bytes into its block and hold "
                             f"{pre + n} bytes (it starts {pre} bytes in and holds {len(mv)})")
        self._raise()
        if self.fill > pre:  # the staging buffer's whole blocks go first
            self._queue_staging(self.fill - pre)
        mv[:pre] = self.mv[:pre]  # the partial block, ahead of the new bytes
        end = pre + n
        e = end - end % self.BLOCK
        tail = end - e
        self.mv[:tail] = mv[e:end]
        if e:
            self._submit(mv[:e], self.pos - pre, done)
        elif done is not None:
            done()
        self.base = self.pos - pre + e
        self.fill = tail
        self.pos += n
        return n

    def flush(self) -> None:
        if self.dfd < 0:
            return
        self._wait()
        if not self.fill:
            return
        a = self.fill - self.fill % self.BLOCK
        if a:
            self._pwrite_all(self.dfd, self.mv[:a], self.base)
        tail = self.fill - a
        if tail:
            self._pwrite_all(self.bfd, self.mv[a:self.fill], self.base + a)
            self.mv[:tail] = self.mv[a:self.fill]
        self.base += a
        self.fill = tail

    def sync(self) -> None:
        self.flush()
        if self.dfd >= 0:
            os.fsync(self.dfd)
        os.fsync(self.bfd)

    def close(self) -> None:
        """Stop the background threads (jobs still queued are dropped, their ``done`` called); close the file."""
        if self._io:
            with self._cv:
                self._stop = True
                self._cv.notify_all()
            for t in self._io:
                t.join()
            self._io = []
        for fd in (self.dfd, self.bfd):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.dfd = self.bfd = -1
        self.arrs = []
        for mv in getattr(self, "mvs", []):
            with contextlib.suppress(BufferError):
                mv.release()
        for b in self.bufs:
            with contextlib.suppress(BufferError):
                b.close()
        self.bufs = []


__all__ = ["DirectFile"]
