"""Frame times of a recording and the check of its timing: dropped frames, duplicated frames, non-uniform intervals.

The rules (:func:`check_timing`):

* **duplicated frames are removed** (the first copy kept): a frame whose timestamp equals the previous kept
  frame's, or whose pixels are bit-for-bit those of the previous kept frame. A frame grabber that repeats a buffer
  produces the second kind; a noisy 16-bit sensor never gives two identical frames of a real scene (the chance
  that 10^4 or more pixels with >= 1 DN of noise all repeat is nil). A mixed frame counted twice would weigh its
  mixing ratio twice in the separation; removed, the separation sees each exposure once. Their indices (in
  the file) are recorded.
* **dropped frames are detected, not filled**: an interval longer than 1.5 nominal intervals (the median one, or
  ``1 / frame_rate_hz`` when the user gave the rate) is a gap of ``round(dt / nominal) - 1`` frames. The kept
  frames carry their true times, which the reconstruction and the polariser model use, so nothing is
  interpolated. (With times made from ``frame_rate_hz`` a dropped frame cannot be seen: the report says so.)
* **non-uniform timing** is flagged when an interval (gaps aside) deviates from the nominal one by more than
  ``tolerance`` (1 %: a camera's own clock jitters by microseconds over 10-30 ms frames, 1e-4 relative; 1 % is a
  frame grabber or a software timestamp).
* timestamps that go **backwards** are an error (``times``): the file's order is then not the time order.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_range

#: an interval longer than this many nominal intervals is a gap of dropped frames
GAP_FACTOR = 1.5
#: relative deviation of an interval from the nominal one above which the timing is non-uniform
JITTER_TOLERANCE = 0.01
#: how :func:`frame_times` names times made from the nominal frame rate (``frame rate 30 Hz``)
FROM_RATE = "frame rate"


@dataclass(frozen=True)
class TimingReport:
    """What :func:`check_timing` found; ``meta()`` is what the Measurement records under ``meta['timing']``."""

    frames_in: int
    frames_out: int
    times_from: str
    nominal_dt_s: float | None
    dropped: list[dict[str, int]] = field(default_factory=list)  # {after_frame, missing}, kept-frame indices
    duplicates_removed: list[int] = field(default_factory=list)  # indices in the file
    duplicate_kinds: dict[str, int] = field(default_factory=dict)  # {same_time, same_pixels}
    max_deviation_rel: float = 0.0
    jitter_rel: float = 0.0
    uniform: bool = True
    drops_detectable: bool = True

    @property
    def n_dropped(self) -> int:
        return int(sum(d["missing"] for d in self.dropped))

    @property
    def frame_rate_hz(self) -> float | None:
        return None if not self.nominal_dt_s else 1.0 / self.nominal_dt_s

    def warnings(self) -> list[str]:
        """One line per finding, for the CLI."""
        out = []
        if self.duplicates_removed:
            kinds = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in self.duplicate_kinds.items() if v)
            out.append(f"{len(self.duplicates_removed)} duplicated frame(s) removed ({kinds}; file indices "
                       f"{_short(self.duplicates_removed)})")
        if self.dropped:
            out.append(f"{self.n_dropped} dropped frame(s) in {len(self.dropped)} gap(s) (after kept frames "
                       f"{_short([d['after_frame'] for d in self.dropped])}); the kept frames keep their times")
        if not self.uniform:
            out.append(f"non-uniform frame intervals: up to {100 * self.max_deviation_rel:.3g} % from the nominal "
                       f"{1e3 * (self.nominal_dt_s or 0):.4g} ms (jitter {100 * self.jitter_rel:.2g} % rms)")
        return out

    def meta(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(n_dropped=self.n_dropped, frame_rate_hz=self.frame_rate_hz, gap_factor=GAP_FACTOR,
                 tolerance_rel=JITTER_TOLERANCE, duplicates="removed (first copy kept)")
        return d


def _short(ix: list[int], n: int = 8) -> str:
    return ", ".join(str(i) for i in ix[:n]) + (" ..." if len(ix) > n else "")


def frame_times(times_s: np.ndarray | None, n: int, frame_rate_hz: float | None,
                times_from: str | None) -> tuple[np.ndarray, str]:
    """The file's times, else ``arange(n) / frame_rate_hz``; neither is an error naming ``frame_rate_hz``."""
    if times_s is not None:
        return np.asarray(times_s, dtype=np.float64), times_from or "file"
    if frame_rate_hz is None:
        raise InputError("frame_rate_hz", None, "the camera's frame rate in Hz: the recording has no timestamps "
                         "(or name them with times=...)")
    if not (np.isfinite(frame_rate_hz) and 0 < frame_rate_hz <= 1e6):
        raise InputError("frame_rate_hz", frame_rate_hz, "0 < frame rate <= 1e6 Hz")
    return np.arange(n) / float(frame_rate_hz), f"{FROM_RATE} {frame_rate_hz:g} Hz"


def check_timing(frames: np.ndarray, times_s: np.ndarray, *, times_from: str = "file",
                 frame_rate_hz: float | None = None,
                 tolerance: float = JITTER_TOLERANCE) -> tuple[np.ndarray, TimingReport]:
    """``(kept frame indices, report)``: duplicates removed, drops and non-uniform intervals found (module notes).

    ``frame_rate_hz``: the nominal rate when known (the user's ``frame_rate_hz`` next to the file's times); the
    median interval otherwise."""
    t = np.asarray(times_s, dtype=np.float64).reshape(-1)
    n = t.size
    nf = int(np.shape(frames)[0]) if np.ndim(frames) else 0
    if n != nf or n < 1:
        raise InputError("times", f"{n} timestamps", f"one per frame ({nf}), at least one")
    if not np.all(np.isfinite(t)):
        raise InputError("times", f"{int(np.sum(~np.isfinite(t)))} NaN/inf timestamp(s)", "finite times in seconds")
    if frame_rate_hz is not None:
        check_range("frame_rate_hz", frame_rate_hz, 0.0, 1e6, unit="Hz")
    dt = np.diff(t)
    if np.any(dt < 0):
        i = int(np.argmax(dt < 0))
        raise InputError("times", f"{t[i + 1]:.6g} s after {t[i]:.6g} s (frame {i + 1})",
                         "non-decreasing timestamps in the file's frame order")
    keep = [0]
    same_time = same_pixels = 0
    for i in range(1, n):
        j = keep[-1]
        if t[i] == t[j]:
            same_time += 1
        elif np.array_equal(frames[i], frames[j], equal_nan=True):
            same_pixels += 1
        else:
            keep.append(i)
    kept = np.asarray(keep)
    removed = sorted(set(range(n)) - set(keep))
    tk = t[kept]
    dk = np.diff(tk)
    from_rate = times_from.startswith(FROM_RATE)
    nominal = (1.0 / frame_rate_hz if frame_rate_hz else float(np.median(dk))) if dk.size else None
    dropped: list[dict[str, int]] = []
    dev = jit = 0.0
    if nominal and dk.size:
        gaps = dk > GAP_FACTOR * nominal
        dropped = [{"after_frame": int(i), "missing": max(1, int(round(dk[i] / nominal)) - 1)}
                   for i in np.flatnonzero(gaps)]
        reg = dk[~gaps]
        if reg.size:
            rel = np.abs(reg - nominal) / nominal
            dev, jit = float(rel.max()), float(np.std(reg) / nominal)
    rep = TimingReport(frames_in=n, frames_out=int(kept.size), times_from=times_from, nominal_dt_s=nominal,
                       dropped=dropped, duplicates_removed=removed,
                       duplicate_kinds={"same_time": same_time, "same_pixels": same_pixels},
                       max_deviation_rel=dev, jitter_rel=jit, uniform=dev <= tolerance,
                       drops_detectable=not from_rate)
    return kept, rep
