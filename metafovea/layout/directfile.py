"""A sequential file writer for multi-gigabyte layouts: ``O_DIRECT`` through two aligned staging buffers, one being
filled while a background thread writes the other, so the disk never waits for a copy.

Why: on the 2-core benchmark machine the kernel's buffered write path (page-cache copies) cost more CPU than
encoding the posts, and with one staging buffer the disk idled while the next one was filled. See
``benchmarks/bench_export_disk.py`` for the export against an ``O_DIRECT`` write of the same bytes.
"""

from __future__ import annotations

import contextlib
import errno
import os
import threading
from pathlib import Path
from typing import Any


class DirectFile:
    """Sequential writer with ``O_DIRECT`` through aligned staging buffers; falls back to plain writes where
    ``O_DIRECT`` is refused (tmpfs, some network file systems) or ``direct=False``.

    Two buffers of ``staging`` bytes: :meth:`write` copies into one; when it is full a background thread writes
    it (``pwrite`` releases the GIL) while the next one fills. An error of the background write is raised by the
    next :meth:`write`, :meth:`flush` or :meth:`sync`.

    ``flush()`` makes every byte written so far part of the file (the pending buffer is written, the last partial
    block goes through a buffered descriptor and is rewritten, aligned, by a later direct write), so a journal
    written after ``flush()`` is consistent. ``offset`` (resume): truncate the file there and continue."""

    BLOCK = 4096

    def __init__(self, path: Path, offset: int | None = None, *, direct: bool = True, staging: int = 32 << 20):
        import mmap

        self.path = path
        new = offset is None
        self.bfd = os.open(path, os.O_RDWR | os.O_CREAT | (os.O_TRUNC if new else 0), 0o666)
        self.dfd = -1
        self.pos = 0 if new else int(offset)
        self.bufs: list = []
        self._io: threading.Thread | None = None
        self._exc: BaseException | None = None
        self._job: tuple[int, int, int] | None = None  # (buffer index, file offset, bytes) being written
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
                self.cur = 0
                self.mv = self.mvs[0]
                self.base = self.pos - self.pos % self.BLOCK
                self.fill = self.pos - self.base
                if self.fill:
                    self.mv[:self.fill] = os.pread(self.bfd, self.fill, self.base)
                self._io = threading.Thread(target=self._run, daemon=True, name="directfile-io")
                self._io.start()
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
                while self._job is None and not self._stop:
                    self._cv.wait()
                if self._job is None:
                    return
                i, off, n = self._job
            try:
                self._pwrite_all(self.dfd, self.mvs[i][:n], off)
            except BaseException as e:  # noqa: BLE001 - raised in the caller's thread
                self._exc = e
            with self._cv:
                self._job = None
                self._cv.notify_all()

    def _wait(self) -> None:
        """Until the background write (if any) is done; its error raised here."""
        with self._cv:
            while self._job is not None:
                self._cv.wait()
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

    def _hand_off(self) -> None:
        """The full current buffer to the background thread; continue in the other one."""
        self._wait()
        with self._cv:
            self._job = (self.cur, self.base, self.cap)
            self._cv.notify_all()
        self.base += self.cap
        self.fill = 0
        self.cur ^= 1
        self.mv = self.mvs[self.cur]

    # -- public ----------------------------------------------------------------------------------
    def write(self, data: Any) -> int:
        m = memoryview(data).cast("B")
        n = len(m)
        if self.dfd < 0:
            self._pwrite_all(self.bfd, m, self.pos)
            self.pos += n
            return n
        if self._exc is not None:
            self._wait()
        while len(m):
            k = min(len(m), self.cap - self.fill)
            self.mv[self.fill:self.fill + k] = m[:k]
            self.fill += k
            m = m[k:]
            if self.fill == self.cap:  # cap is a multiple of BLOCK: all aligned
                self._hand_off()
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
        if self._io is not None:
            with self._cv:
                self._stop = True
                self._cv.notify_all()
            self._io.join()
            self._io = None
        for fd in (self.dfd, self.bfd):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.dfd = self.bfd = -1
        for mv in getattr(self, "mvs", []):
            with contextlib.suppress(BufferError):
                mv.release()
        for b in self.bufs:
            with contextlib.suppress(BufferError):
                b.close()
        self.bufs = []


__all__ = ["DirectFile"]
