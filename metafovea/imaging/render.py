"""Rendering one channel's noise-free image of a scene: kernel convolution, field patches, far haze, pixel
integration and relative illumination (the model is in :mod:`~metafovea.imaging.kernels`).

The scene is sampled on the channel's own supersampled grid of field angles (plus the kernel's margin), in
in-band radiance; the image is the valid convolution with the channel's kernel(s), box-averaged to pixels, plus the
far haze convolved on a coarse grid and interpolated back, times ``cos^4`` relative illumination. Video scenes that
declare their changing boxes are rendered incrementally (:class:`ChannelRenderer`). A reduced model
(:mod:`~metafovea.imaging.plan`) may sample each coarse sample once instead of ``SUB x SUB`` times (``sub=1``) and
spread the glare as a uniform level (the optics' ``pedestal_weight`` times the crop's mean radiance); the image's
parts (:meth:`ChannelRenderer.components`) are what the planner's estimates recombine.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from metafovea.imaging.channel import relative_illumination_map
from metafovea.imaging.kernels import ChannelOptics, fftconvolve
from metafovea.imaging.scene import Scene, bilinear_grid
from metafovea.measurement import patch_weights
from metafovea.radiometry import BandRadiance


def _conv_valid(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The valid part of ``img * k`` (a 1 x 1 kernel is a scale)."""
    if k.shape == (1, 1):
        return img * k[0, 0]
    return fftconvolve(img, k, mode="valid")


class ChannelRenderer:
    """Renders one channel's noise-free image of a scene (see module docstring for the model).

    For video scenes that declare their static background and the boxes that change
    (:meth:`Scene.dynamic_regions`), the background is rendered once and each frame adds only the
    change inside those boxes (convolution is linear): the cost follows the moving objects' size.
    """

    SUB = 3  # supersampling of each coarse haze sample (small hot objects must not be missed)

    def __init__(self, scene: Scene, optics: ChannelOptics, radiance: BandRadiance,
                 relative_illumination: bool = True,
                 field_factor: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None, *, sub: int | None = None,
                 far_cache: dict | None = None, ri: np.ndarray | None = None):
        self.scene, self.optics, self.radiance = scene, optics, radiance
        self.far_cache = far_cache  # far components computed by other renderers of the same scene and camera
        if sub is not None:  # samples per coarse sample and axis of the far components (a reduced model: 1)
            self.SUB = int(sub)
        ch, ss = optics.channel, optics.ss
        H, W = ch.shape
        m = optics.margin
        self.ya = np.arctan(ch.positions_um(H, ss, m) / ch.focal_length_um)
        self.xa = np.arctan(ch.positions_um(W, ss, m) / ch.focal_length_um)
        # ``ri``: the relative illumination map of this channel and field factor, already computed (a plan's pilot)
        self.ri = None if not relative_illumination else ri if ri is not None else \
            relative_illumination_map(ch, field_factor)
        # far components, each on its own coarse grid: the chromatic haze, then the glare (ChannelOptics.far_parts)
        self.parts = []
        for weight, kernel, q in optics.far_parts():
            km = kernel.shape[0] // 2
            nh, nw = round(H * self.SUB / q), round(W * self.SUB / q)
            self.parts.append({
                "weight": weight, "kernel": kernel, "q": q,
                "yc": np.arctan(ch.positions_um(H, self.SUB, km * self.SUB, coarse=q) / ch.focal_length_um),
                "xc": np.arctan(ch.positions_um(W, self.SUB, km * self.SUB, coarse=q) / ch.focal_length_um),
                # output sample o of the valid convolution sits at ((o + 0.5) - n_fine / (2 SUB)) q pixels
                "ry": (np.arange(H) + 0.5 - H / 2.0) / q + nh / (2.0 * self.SUB) - 0.5,
                "rx": (np.arange(W) + 0.5 - W / 2.0) / q + nw / (2.0 * self.SUB) - 0.5})
        self.incremental = (not scene.static and optics.n_patches == 1
                            and scene.dynamic_regions(0.0) is not None)
        self._bg: dict[str, np.ndarray] | None = None

    # -- pieces ----------------------------------------------------------------------------------
    def _radiance(self, ya: np.ndarray, xa: np.ndarray, t: float | None) -> np.ndarray:
        ax, ay = np.broadcast_to(xa[None, :], (ya.size, xa.size)), np.broadcast_to(ya[:, None], (ya.size, xa.size))
        if t is None:
            temp, eps = self.scene.sample_background(ax, ay)
        else:
            temp, eps = self.scene.sample(ax, ay, t)
        return self.radiance.apparent(temp, eps, self.scene.reflected_k)

    def radiance_at(self, y_um: np.ndarray, x_um: np.ndarray, t: float = 0.0) -> np.ndarray:
        """The scene's in-band radiance at time ``t`` on the grid of focal-plane positions ``y_um`` x ``x_um`` (um, this
        channel's focal plane), ``(y_um.size, x_um.size)``."""
        f = self.optics.channel.focal_length_um
        return self._radiance(np.arctan(np.asarray(y_um) / f), np.arctan(np.asarray(x_um) / f), t)

    def _coarse_radiance(self, part: dict, r0: int, r1: int, c0: int, c1: int, t: float | None) -> np.ndarray:
        """Coarse samples [r0, r1) x [c0, c1) of a far component's grid, each the mean of SUB x SUB samples."""
        S = self.SUB
        L = self._radiance(part["yc"][r0 * S:r1 * S], part["xc"][c0 * S:c1 * S], t)
        return L.reshape(r1 - r0, S, c1 - c0, S).mean(axis=(1, 3))

    def kernel_image(self, L: np.ndarray) -> np.ndarray:
        """The kernel's image of fine samples ``L`` (the grid of :attr:`ya` x :attr:`xa`, margin included), box-averaged
        to the pixels, ``(H, W)``: the image's fine part, linear in ``L``."""
        ch, ss = self.optics.channel, self.optics.ss
        H, W = ch.shape
        fine = self._fine_image(L)
        return fine.reshape(H, ss, W, ss).mean(axis=(1, 3)) if ss > 1 else fine

    def _fine_image(self, L: np.ndarray) -> np.ndarray:
        o = self.optics
        if o.n_patches == 1:
            return _conv_valid(L, o.kernels[0])
        ch, ss, m = o.channel, o.ss, o.margin
        H, W = ch.shape
        n = o.n_patches
        rows = sorted({c[0] for c in o.patch_centres})
        cols = sorted({c[1] for c in o.patch_centres})
        wy = patch_weights(n, H * ss, [(r + 0.5) * ss - 0.5 for r in rows])
        wx = patch_weights(n, W * ss, [(c + 0.5) * ss - 0.5 for c in cols])
        img = np.zeros((H * ss, W * ss))
        for p, k in enumerate(o.kernels):
            i, j = divmod(p, n)
            km = k.shape[0] // 2
            sub = L[m - km: L.shape[0] - (m - km), m - km: L.shape[1] - (m - km)]
            img += wy[i][:, None] * wx[j][None, :] * _conv_valid(sub, k)
        return img

    def _crop_mean(self, L: np.ndarray) -> float:
        """Mean of the fine samples ``L`` over the crop (the margin left out): what a pedestal spreads."""
        m = self.optics.margin
        return float(L[m:L.shape[0] - m, m:L.shape[1] - m].mean())

    def to_pixels(self, part: dict, coarse: np.ndarray) -> np.ndarray:
        """A far component's coarse grid (the valid convolution's output, or any array of its shape) interpolated
        (linearly) to the pixels, ``(H, W)``: what the image gets from it, before its weight."""
        return bilinear_grid(coarse, part["ry"], part["rx"])

    def _finish(self, fine: np.ndarray, hz: list[np.ndarray], pedestal: float = 0.0) -> np.ndarray:
        ch, ss = self.optics.channel, self.optics.ss
        H, W = ch.shape
        img = fine.reshape(H, ss, W, ss).mean(axis=(1, 3)) if ss > 1 else fine.copy()
        return self._assemble(img, [part["weight"] * self.to_pixels(part, h) for part, h in zip(self.parts, hz)],
                              pedestal)

    def _assemble(self, img: np.ndarray, far: list[np.ndarray], pedestal: float) -> np.ndarray:
        """``(img + pedestal_weight * pedestal + sum(far)) * ri``, in place on ``img``."""
        if self.optics.pedestal_weight:
            img += self.optics.pedestal_weight * pedestal
        for f in far:
            img += f
        if self.ri is not None:
            img *= self.ri
        return img

    def render_static(self, t: float = 0.0, *, fine: np.ndarray | None = None, samples: np.ndarray | None = None,
                      far: list[np.ndarray] | None = None) -> np.ndarray:
        """:meth:`render`'s image at ``t`` from parts already computed with this renderer's optics and sampling (a
        plan's pilot): ``fine`` the kernel image on the pixels with ``samples`` the fine grid's samples it came from,
        ``far`` the far components' weighted images; the missing ones are computed."""
        if fine is None or samples is None:
            samples = self._radiance(self.ya, self.xa, t)
            fine = self.kernel_image(samples)
        far = self.far_images(t) if far is None else far
        return self._assemble(fine.copy(), far, self._crop_mean(samples) if self.optics.pedestal_weight else 0.0)

    def far_images(self, t: float = 0.0) -> list[np.ndarray]:
        """Each far component's weighted image on the pixels at time ``t`` (its coarse grid alone is sampled)."""
        return [part["weight"] * self.to_pixels(part, self._far_part(part, t)[1]) for part in self.parts]

    def components(self, t: float = 0.0) -> dict[str, object]:
        """The image at time ``t`` in its parts (a static evaluation, never incremental): ``fine`` the kernel's
        image box-averaged to pixels ``(H, W)``; ``far`` each far component's weighted image on the pixels (the
        chromatic haze first, then the glare bands: :meth:`~metafovea.imaging.kernels.ChannelOptics.far_parts`);
        ``pedestal`` the crop's mean radiance (what a pedestal weight multiplies); ``L`` the scene's samples on the
        fine grid (margin included); ``Lc`` each far component's coarse samples and ``hz`` their convolution with its
        (normalised) kernel; ``ri`` the relative illumination
        (None when off). ``(fine + sum(far) + pedestal_weight * pedestal) * ri`` is :meth:`render`'s image."""
        fine, hz, L, Lc = self._full(t)
        ch, ss = self.optics.channel, self.optics.ss
        H, W = ch.shape
        box = fine.reshape(H, ss, W, ss).mean(axis=(1, 3)) if ss > 1 else fine
        far = [part["weight"] * self.to_pixels(part, h) for part, h in zip(self.parts, hz)]
        return {"fine": box, "far": far, "pedestal": self._crop_mean(L), "L": L, "Lc": Lc, "hz": hz, "ri": self.ri}

    def _full(self, t: float | None) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, list[np.ndarray]]:
        L = self._radiance(self.ya, self.xa, t)
        fine = self._fine_image(L)
        hz, Lc = [], []
        for part in self.parts:
            lc, h = self._far_part(part, t)
            Lc.append(lc)
            hz.append(h)
        return fine, hz, L, Lc

    def _far_part(self, part: dict, t: float | None) -> tuple[np.ndarray, np.ndarray]:
        """A far component's coarse samples and their convolution with its normalised kernel (shared through
        :attr:`far_cache` by the renderers of a sweep of models of one scene and camera)."""
        S = self.SUB
        key = None
        if self.far_cache is not None:
            k = part["kernel"]
            key = (self.optics.channel.name, part["q"], S, t, k.shape, hash(k.tobytes()))
            if key in self.far_cache:
                return self.far_cache[key]
        lc = self._coarse_radiance(part, 0, part["yc"].size // S, 0, part["xc"].size // S, t)
        out = (lc, _conv_valid(lc, part["kernel"]))
        if key is not None:
            self.far_cache[key] = out
        return out

    @staticmethod
    def _range(axis: np.ndarray, lo: float, hi: float, group: int = 1) -> tuple[int, int]:
        """Index range [i0, i1) (in groups of ``group`` samples) covering angles [lo, hi], padded by 1."""
        i0 = int(np.searchsorted(axis, lo, side="left")) // group - 1
        i1 = -(-int(np.searchsorted(axis, hi, side="right")) // group) + 1
        n = axis.size // group
        return max(i0, 0), min(i1, n)

    @staticmethod
    def _add_full(out: np.ndarray, d: np.ndarray, k: np.ndarray, r0: int, c0: int, m: int) -> None:
        """Add the full convolution of ``d`` (placed at input index r0, c0 of a valid convolution with
        margin m) into ``out``."""
        f = fftconvolve(d, k, mode="full")
        y0, x0 = r0 - 2 * m, c0 - 2 * m
        ys, xs = max(0, -y0), max(0, -x0)
        ye = min(f.shape[0], out.shape[0] - y0)
        xe = min(f.shape[1], out.shape[1] - x0)
        if ye > ys and xe > xs:
            out[y0 + ys:y0 + ye, x0 + xs:x0 + xe] += f[ys:ye, xs:xe]

    def scene_image(self, t: float = 0.0) -> np.ndarray:
        """What a perfect lens would image at time ``t``: the scene's in-band radiance (W m^-2 sr^-1) averaged over
        each pixel's footprint (its ``s x s`` samples), without PSF, haze or relative illumination, ``(H, W)``
        float64: the truth a PSF-aware reconstruction is scored against."""
        H, W = self.optics.channel.shape
        ss, m = self.optics.ss, self.optics.margin
        ya = self.ya[m:self.ya.size - m]
        xa = self.xa[m:self.xa.size - m]
        L = self._radiance(ya, xa, t)
        return L.reshape(H, ss, W, ss).mean(axis=(1, 3)) if ss > 1 else L

    # -- public ---------------------------------------------------------------------------------------
    def render(self, t: float = 0.0) -> np.ndarray:
        """The image at time ``t``: in-band radiance (W m^-2 sr^-1) after PSF, haze, pixel integration and
        relative illumination, ``(H, W)`` float64."""
        if not self.incremental:
            fine, hz, L, _ = self._full(t)
            return self._finish(fine, hz, self._crop_mean(L) if self.optics.pedestal_weight else 0.0)
        if self._bg is None:
            fine, hz, L, Lc = self._full(None)
            self._bg = {"fine": fine, "hz": hz, "L": L, "Lc": Lc}
        bg = self._bg
        ped = self._crop_mean(bg["L"]) if self.optics.pedestal_weight else 0.0
        m_crop = self.optics.margin
        n_crop = (bg["L"].shape[0] - 2 * m_crop) * (bg["L"].shape[1] - 2 * m_crop)
        fine = bg["fine"].copy()
        hz = [h.copy() for h in bg["hz"]]
        k = self.optics.kernels[0]
        m = k.shape[0] // 2
        boxes = self.scene.dynamic_regions(t) or []
        fine_boxes = _merge_overlapping_boxes([self._range(self.ya, y0, y1) + self._range(self.xa, x0, x1)
                                               for (x0, y0, x1, y1) in boxes])
        for r0, r1, c0, c1 in fine_boxes:
            d = self._radiance(self.ya[r0:r1], self.xa[c0:c1], t) - bg["L"][r0:r1, c0:c1]
            self._add_full(fine, d, k, r0, c0, m)
            if self.optics.pedestal_weight:  # the change of the crop's mean radiance
                inside = d[max(m_crop - r0, 0):max(bg["L"].shape[0] - m_crop - r0, 0),
                           max(m_crop - c0, 0):max(bg["L"].shape[1] - m_crop - c0, 0)]
                ped += float(inside.sum()) / n_crop
        S = self.SUB
        for part, h, Lc in zip(self.parts, hz, bg["Lc"]):
            kf = part["kernel"]
            coarse_boxes = _merge_overlapping_boxes([self._range(part["yc"], y0, y1, S)
                                                     + self._range(part["xc"], x0, x1, S)
                                                     for (x0, y0, x1, y1) in boxes])
            for q0, q1, p0, p1 in coarse_boxes:
                dc = self._coarse_radiance(part, q0, q1, p0, p1, t) - Lc[q0:q1, p0:p1]
                self._add_full(h, dc, kf, q0, p0, kf.shape[0] // 2)
        return self._finish(fine, hz, ped)


def _merge_overlapping_boxes(boxes: list[tuple[int, int, int, int]]) -> list[tuple[int, int, int, int]]:
    """Index boxes (r0, r1, c0, c1), empty ones dropped and overlapping ones merged into their union,
    so that no sample is counted twice."""
    out = [b for b in boxes if b[1] > b[0] and b[3] > b[2]]
    merged = True
    while merged:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                a, b = out[i], out[j]
                if a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]:
                    out[i] = (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
                    del out[j]
                    merged = True
                    break
            if merged:
                break
    return out
