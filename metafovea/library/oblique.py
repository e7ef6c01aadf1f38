"""Oblique incidence: how the chosen posts' transmissions change off axis.

:func:`oblique_response` solves a post set's posts by RCWA at a few field angles (:data:`OBLIQUE_ANGLES_DEG`) in
both planes of incidence, light entering through the wafer, and returns the ratios ``t(theta) / t(0)`` with an
error estimate (truncation and interpolation) as an :class:`ObliqueResponse`, cached in the library cache.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import POLARIZATIONS, PlatformDesign
from metafovea.errors import InputError, check_choice, check_int
from metafovea.io import atomic_save_npz, cache_lock, input_hash, load_npz, seed_file
from metafovea.io import cache_dir as io_cache_dir

from .postset import PostSet

log = logging.getLogger(__name__)

#: field angles in air (deg) at which the posts are solved off axis; between them the ratio is interpolated in
#: angle^2 (the change is quadratic at small angles), beyond the last one it is extrapolated that way
OBLIQUE_ANGLES_DEG = (0.0, 6.0, 11.0, 16.0)
#: Fourier orders of the oblique solves: only the ratio t(theta) / t(0) at the same truncation is used, which
#: converges much faster than t itself (harmonics 5 is within 5e-4 of harmonics 8 for the paper's posts)
OBLIQUE_HARMONICS = 5
#: CPU seconds per post of :func:`oblique_response` at harmonics 5 and 4 angles (its 19 solves; measured on one core)
_OBLIQUE_POST_SECONDS = 1.5


@dataclass(frozen=True)
class ObliqueResponse:
    """How a post set's transmissions change off axis, as the ratio ``t(theta) / t(0)`` per level.

    ``ratio``: ``{'x' | 'y': (n_angles, 2, N) complex}`` for x/y-polarised light, plane of incidence xz (index
    0: the field along x) or yz (index 1); angles in air (``angles_deg``), the light entering through the wafer
    (refracted to ``asin(sin theta / n_Si)``). ``error``: the larger of max |ratio(M) - ratio(M - 1)| (truncation)
    and the interpolation's error at the midpoints of the upper segments (solved there).
    """

    angles_deg: np.ndarray
    ratio: dict[str, np.ndarray]
    error: float
    harmonics: int

    def factor(self, polarization: str, theta_deg: ArrayLike, azimuth_rad: ArrayLike = 0.0) -> np.ndarray:
        """``(..., N)`` ratio at field angle(s) ``theta_deg`` and azimuth(s) of the plane of incidence (from +x):
        interpolated in ``theta^2`` between the solved angles, the two planes blended as ``cos^2 / sin^2`` of
        the azimuth (exact in the planes, second order between them)."""
        r = self.ratio[check_choice("polarization", polarization, POLARIZATIONS)]
        th2 = np.square(np.asarray(theta_deg, dtype=float))[..., None]
        a2 = self.angles_deg ** 2
        out = []
        for plane in (0, 1):
            re = np.stack([np.interp(th2[..., 0], a2, r[:, plane, k].real) for k in range(r.shape[2])], -1)
            im = np.stack([np.interp(th2[..., 0], a2, r[:, plane, k].imag) for k in range(r.shape[2])], -1)
            # beyond the last angle: continue the last segment's slope in theta^2
            over = th2[..., 0] > a2[-1]
            if np.any(over):
                slope = (r[-1, plane] - r[-2, plane]) / (a2[-1] - a2[-2])
                ext = r[-1, plane] + (th2 - a2[-1]) * slope
                re = np.where(over[..., None], ext.real, re)
                im = np.where(over[..., None], ext.imag, im)
            out.append(re + 1j * im)
        c2 = np.cos(np.asarray(azimuth_rad, dtype=float))[..., None] ** 2
        return c2 * out[0] + (1 - c2) * out[1]

    def post_set_at(self, post_set: PostSet, theta_deg: float, azimuth_rad: float = 0.0) -> PostSet:
        """``post_set`` with its transmissions at that field (reflectances kept)."""
        fx = self.factor("x", theta_deg, azimuth_rad)
        fy = self.factor("y", theta_deg, azimuth_rad)
        return replace(post_set, t_x=post_set.t_x * fx, t_y=post_set.t_y * fy,
                       info={**post_set.info, "oblique_incidence_deg": float(theta_deg)})


def _oblique_ratios(widths_um: np.ndarray, platform: PlatformDesign, angles_deg: Sequence[float], wavelength_um: float,
                    harmonics: int) -> np.ndarray:
    """(n_angles, 2 planes, 2 pols, N) ratios t(theta) / t(0) of posts ``widths_um`` (N, 2)."""
    from tqdm.auto import tqdm

    from metafovea.rcwa.geometry import Layer, Rectangle, Stack
    from metafovea.rcwa.solve import solve

    n_sub = platform.n_substrate
    out = np.ones((len(angles_deg), 2, 2, widths_um.shape[0]), complex)
    for k, (wx, wy) in enumerate(tqdm(widths_um, desc=f"posts off axis (M={harmonics})", unit="post", leave=False,
                                      disable=None)):
        st = Stack(platform.period_um, platform.period_um,
                   (Layer(platform.post_height_um, platform.n_superstrate, (Rectangle(wx, wy, platform.n_post),)),),
                   n_sub, platform.n_superstrate)

        def jones(theta_air: float, phi: float, st: Stack = st) -> np.ndarray:
            th = math.degrees(math.asin(math.sin(math.radians(theta_air)) / n_sub))
            return solve(st, wavelength_um, harmonics=harmonics, theta_deg=th, phi_deg=phi, incidence="substrate",
                         check_energy=False).t00("substrate")

        j0 = jones(0.0, 0.0)  # (p, s) = (x, y) at normal incidence
        for i, th in enumerate(angles_deg):
            if th == 0.0:
                continue
            for plane, phi in ((0, 0.0), (1, 90.0)):
                j = jones(th, phi)
                # xz plane: x is p, y is s; yz plane: y is p, x is s
                tx, ty = (j[0, 0], j[1, 1]) if plane == 0 else (j[1, 1], j[0, 0])
                out[i, plane, 0, k] = tx / j0[0, 0]
                out[i, plane, 1, k] = ty / j0[1, 1]
    return out


def _oblique_key(post_set: PostSet, plat: PlatformDesign, angles: np.ndarray, m: int) -> dict[str, Any]:
    return {"kind": "oblique", "widths_um": np.round(post_set.widths_um, 9).tolist(), "angles_deg": angles.tolist(),
            "harmonics": m, "wavelength_um": post_set.wavelength_um, "period_um": plat.period_um,
            "height_um": plat.post_height_um, "n_post": plat.n_post, "n_substrate": plat.n_substrate,
            "n_superstrate": plat.n_superstrate}


def _checked(platform: PlatformDesign | None, angles_deg: Sequence[float], harmonics: int
             ) -> tuple[PlatformDesign, np.ndarray, int]:
    plat = platform or PlatformDesign()
    m = check_int("harmonics", harmonics, 3, 12)
    angles = np.asarray(sorted({0.0, *(float(a) for a in angles_deg)}), dtype=float)
    if angles.size < 2 or angles[-1] >= 60.0 or angles[0] < 0:
        raise InputError("angles_deg", list(angles_deg), "angles in [0, 60) deg, at least one above 0")
    return plat, angles, m


def oblique_cache_name(post_set: PostSet, platform: PlatformDesign | None = None, *,
                       angles_deg: Sequence[float] = OBLIQUE_ANGLES_DEG, harmonics: int = OBLIQUE_HARMONICS) -> str:
    """The cache file name of :func:`oblique_response` for these arguments, ``oblique_<key>.npz``: the key hashes
    every input that changes the numbers (the posts' widths, angles, harmonics, wavelength and the stack)."""
    plat, angles, m = _checked(platform, angles_deg, harmonics)
    return f"oblique_{input_hash(_oblique_key(post_set, plat, angles, m))}.npz"


def oblique_response(post_set: PostSet, platform: PlatformDesign | None = None, *,
                     angles_deg: Sequence[float] = OBLIQUE_ANGLES_DEG, harmonics: int = OBLIQUE_HARMONICS,
                     cache_dir: str | Path | None = None) -> ObliqueResponse:
    """The :class:`ObliqueResponse` of ``post_set``'s posts on ``platform`` (RCWA off axis at ``harmonics`` and one
    less for the error estimate; cached on disk in the library cache, or taken from the package's seed,
    :func:`metafovea.io.seed_file`, when that holds the same key)."""
    plat, angles, m = _checked(platform, angles_deg, harmonics)
    key = _oblique_key(post_set, plat, angles, m)
    path = Path(cache_dir) if cache_dir else io_cache_dir("library")
    path = path / f"oblique_{input_hash(key)}.npz"
    ratios, err = _cached_oblique(path)
    if ratios is None:
        ratios, err = _seed_oblique(path.name, key)
    lock = cache_lock(path) if ratios is None else contextlib.nullcontext()
    with lock:
        if ratios is None:
            ratios, err = _cached_oblique(path)  # another process may have written it meanwhile
        if ratios is None:
            log.warning("computing the posts' oblique-incidence response: %d posts at %d angles, harmonics %d, one "
                        "process: about %.0f s on an idle core (then cached in %s)", post_set.levels, angles.size, m,
                        _OBLIQUE_POST_SECONDS * post_set.levels * angles.size / 4 * ((2 * m + 1) / 11) ** 4.5,
                        path.parent)
            ratios, err = _solve_oblique(post_set, plat, angles, m, key, path)
    return ObliqueResponse(angles, {"x": ratios[:, :, 0, :], "y": ratios[:, :, 1, :]}, err, m)


def _cached_oblique(path: Path) -> tuple[np.ndarray | None, float | None]:
    if path.is_file():
        try:
            arrays, meta = load_npz(path)
            return arrays["ratios"], float(meta["error"])
        except Exception as e:  # noqa: BLE001 - a damaged cache entry is recomputed
            log.warning("ignoring unreadable oblique-incidence cache %s: %s", path, e)
    return None, None


def _seed_oblique(name: str, key: dict[str, Any]) -> tuple[np.ndarray | None, float | None]:
    """The response shipped with the package under the cache file name ``name`` when its key is ``key``."""
    path = seed_file(name)
    if path is None:
        return None, None
    try:
        _, meta = load_npz(path)
    except InputError as e:
        log.warning("ignoring the damaged oblique-incidence seed %s: %s", path, e)
        return None, None
    if input_hash(meta.get("key")) != input_hash(key):
        log.warning("ignoring the oblique-incidence seed %s: its key is not the inputs'", path)
        return None, None
    log.info("oblique-incidence response loaded from the package's seed %s", path)
    return _cached_oblique(path)


def _solve_oblique(post_set: PostSet, plat: PlatformDesign, angles: np.ndarray, m: int, key: dict[str, Any],
                   path: Path) -> tuple[np.ndarray, float]:
    """The ratios at ``m`` harmonics and their error estimate (truncation, interpolation), written to ``path``."""
    from metafovea.parallel import blas_threads

    mids = np.sqrt(0.5 * (angles[1:] ** 2 + angles[:-1] ** 2))[-2:]
    # one BLAS thread: the eigenproblems are small (242 unknowns at M = 5), and OpenBLAS' threads made the CPU time
    # per post 16x larger on a loaded 2-core machine (24 s against 1.5 s, measured here)
    with blas_threads(1):
        ratios = _oblique_ratios(post_set.widths_um, plat, angles, post_set.wavelength_um, m)
        lower = _oblique_ratios(post_set.widths_um, plat, angles, post_set.wavelength_um, m - 1)
        # interpolation: solve at the midpoints (in angle^2) of the upper segments and compare
        solved = _oblique_ratios(post_set.widths_um, plat, np.concatenate([[0.0], mids]), post_set.wavelength_um, m)
    err = float(np.max(np.abs(ratios - lower)))
    trial = ObliqueResponse(angles, {"x": ratios[:, :, 0, :], "y": ratios[:, :, 1, :]}, err, m)
    for i, th in enumerate(mids, start=1):
        for plane, az in ((0, 0.0), (1, 0.5 * math.pi)):
            for q, pol in enumerate(POLARIZATIONS):
                err = max(err, float(np.max(np.abs(trial.factor(pol, th, az) - solved[i, plane, q]))))
    try:
        atomic_save_npz(path, {"kind": "oblique-cache", "key": key, "error": err}, ratios=ratios)
    except OSError as e:
        log.warning("could not cache the oblique-incidence response in %s: %s", path, e)
    return ratios, err
