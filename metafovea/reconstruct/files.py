"""Writing a :class:`~metafovea.reconstruct.PipelineResult`: the Reconstruction ``.npz`` and, next to it, the last
output's foveal and perifoveal images (``<stem>_x1.png``, ``<stem>_x2.png``, one PNG pixel per image pixel) and a
side-by-side figure with colour bars (``<stem>.png``). Every path is checked before anything is computed
(:func:`prepare_outputs`), so a run that would overwrite a file without ``force`` writes nothing."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from metafovea.errors import InputError
from metafovea.io import atomic_write_bytes, prepare_output
from metafovea.reconstruct.result import PipelineResult
from metafovea.report import array_png, fig_to_png

if TYPE_CHECKING:
    from metafovea.reconstruct.deconvolve import Deconvolution


def load_pattern(path: str | os.PathLike, name: str = "fpn") -> np.ndarray:
    """A fixed pattern from a user's file.

    Parameters
    ----------
    path : str or PathLike
        ``.npy``, ``.npz`` (its ``fpn`` array, or its only array) or a one-page ``.tif``.
    name : str
        The parameter an :class:`InputError` names for anything else.

    Returns
    -------
    ndarray, shape (H, W)
        float64, finite.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(name, str(p), "none, prior, calibration, or an existing pattern file (.npy, .npz, .tif)")
    try:
        suf = p.suffix.lower()
        if suf == ".npy":
            a = np.load(p, allow_pickle=False)
        elif suf == ".npz":
            with np.load(p, allow_pickle=False) as z:
                keys = [k for k in z.files if k != "__meta__"]
                key = "fpn" if "fpn" in keys else (keys[0] if len(keys) == 1 else None)
                if key is None:
                    raise InputError(name, str(p), "an .npz file with an 'fpn' array (or a single array)")
                a = z[key]
        elif suf in (".tif", ".tiff"):
            import tifffile

            a = tifffile.imread(p)
        else:
            raise InputError(name, str(p), "a pattern file ending in .npy, .npz, .tif or .tiff")
    except InputError:
        raise
    except (OSError, ValueError, KeyError) as e:
        raise InputError(name, str(p), "a readable pattern file (.npy, .npz, .tif)", detail=str(e)[:200]) from None
    a = np.asarray(a)
    if a.ndim != 2 or not np.issubdtype(a.dtype, np.number) or not np.all(np.isfinite(a)):
        raise InputError(name, f"{p} (array of shape {a.shape}, dtype {a.dtype})", "a finite (H, W) pattern")
    return a.astype(np.float64)


def figure_paths(out: str | os.PathLike) -> list[Path]:
    """The PNG files written next to the reconstruction ``out``.

    Parameters
    ----------
    out : str or PathLike

    Returns
    -------
    list of Path
        ``<stem>_x1.png``, ``<stem>_x2.png`` (one PNG pixel per image pixel) and ``<stem>.png`` (side by side).
    """
    stem = Path(out).with_suffix("")
    return [Path(f"{stem}_x1.png"), Path(f"{stem}_x2.png"), Path(f"{stem}.png")]


def prepare_outputs(measurement: str | os.PathLike, out: str | os.PathLike | None = None, *, figures: bool = True,
                    force: bool = False) -> tuple[Path, list[Path]]:
    """The output paths of a reconstruction of the file ``measurement``, all checked before anything is computed.

    Parameters
    ----------
    measurement : str or PathLike
    out : str or PathLike, optional
        Default ``<measurement>_rec.npz``; it must end in ``.npz`` and must not be the measurement itself.
    figures : bool
        Also the figures (:func:`figure_paths`).
    force : bool
        Allow overwriting; otherwise neither the output nor a figure may exist.

    Returns
    -------
    path : Path
    figures : list of Path
    """
    src = Path(measurement)
    path = Path(out) if out else src.with_name(src.stem + "_rec.npz")
    if path.suffix.lower() != ".npz":
        raise InputError("out", str(path), "a file name ending in .npz")
    if path.resolve() == src.resolve() or (path.exists() and src.exists() and os.path.samefile(path, src)):
        raise InputError("out", str(path), "a path other than the measurement itself (it would be overwritten)")
    path = prepare_output(path, force)
    pngs = figure_paths(path) if figures else []
    for name in pngs:
        prepare_output(name, force)
    return path, pngs


def write_outputs(result: PipelineResult, out: str | os.PathLike, figures: list[Path] | None = None, *,
                  title: str = "", units: str = "DN") -> list[str]:
    """Save a pipeline result and the figures of its last output.

    Parameters
    ----------
    result : PipelineResult
    out : str or PathLike
        The reconstruction's ``.npz``.
    figures : list of Path, optional
        :func:`figure_paths` (from :func:`prepare_outputs`); None or empty: no figures.
    title : str
        The side-by-side figure's title (default: the method).
    units : str
        The images' unit, the recording's (``meta['units']``: DN, or an imported camera's counts).

    Returns
    -------
    list of str
        The files written.
    """
    rec = result.reconstruction
    rec.save(out)
    files = [str(out)]
    if figures:
        from metafovea.plotting import iron_colormap

        x1, x2 = result.x1s[-1], result.x2s[-1]
        iron = iron_colormap()
        pngs = (array_png(x1, iron), array_png(x2, iron), pair_figure(x1, x2, title or rec.method, units))
        for name, data in zip(figures, pngs):
            atomic_write_bytes(name, data)
            files.append(str(name))
    return files


def pair_figure(x1: np.ndarray, x2: np.ndarray, title: str, units: str = "DN") -> bytes:
    """The foveal and perifoveal images side by side in the iron palette, colour bars in ``units``.

    Parameters
    ----------
    x1, x2 : ndarray, shape (H, W)
    title : str
    units : str
        The images' unit (the frames'; the simulator's are DN).

    Returns
    -------
    bytes
        PNG.
    """
    from matplotlib.figure import Figure

    from metafovea.plotting import image

    fig = Figure(figsize=(9, 4.2), layout="constrained")
    axs = fig.subplots(1, 2)
    for ax, img, name in ((axs[0], x1, "foveal x1"), (axs[1], x2, "perifoveal x2")):
        image(ax, img, label=f"signal ({units})", title=name)
        ax.set_axis_off()
    fig.suptitle(title)
    return fig_to_png(fig)


def scene_paths(out: str | os.PathLike, figures: bool = True, force: bool = False) -> list[Path]:
    """The PSF-aware outputs next to the reconstruction ``out``, checked like :func:`prepare_outputs`.

    Parameters
    ----------
    out : str or PathLike
    figures : bool
    force : bool

    Returns
    -------
    list of Path
        ``<stem>_scene.npz`` and, with ``figures``, ``<stem>_scene.png``.
    """
    stem = Path(out).with_suffix("")
    paths = [Path(f"{stem}_scene.npz")] + ([Path(f"{stem}_scene.png")] if figures else [])
    return [prepare_output(p, force) for p in paths]


def write_scene(d: Deconvolution, paths: list[Path], title: str = "") -> list[str]:
    """Save a PSF-aware reconstruction and its figure.

    Parameters
    ----------
    d : Deconvolution
    paths : list of Path
        :func:`scene_paths`: the ``.npz`` (``scene_x1``, ``scene_x2`` DN, ``temperature_x1_k``,
        ``temperature_x2_k``, ``info`` as metadata) and optionally the figure (:func:`scene_figure`).
    title : str

    Returns
    -------
    list of str
        The files written.
    """
    from metafovea.io import atomic_save_npz

    arrays = {"scene_x1": d.scene[0].astype(np.float32), "scene_x2": d.scene[1].astype(np.float32)}
    if d.temperature_k is not None:
        arrays.update(temperature_x1_k=d.temperature_k[0].astype(np.float32),
                      temperature_x2_k=d.temperature_k[1].astype(np.float32))
    atomic_save_npz(paths[0], {"kind": "scene", **d.info}, compress=False, **arrays)
    files = [str(paths[0])]
    if len(paths) > 1:
        atomic_write_bytes(paths[1], scene_figure(d, title))
        files.append(str(paths[1]))
    return files


def scene_figure(d: Deconvolution, title: str = "") -> bytes:
    """Both channels' scene estimates side by side with colour bars.

    Parameters
    ----------
    d : Deconvolution
        Shown in brightness temperature (K, iron palette), or in DN without a radiometric calibration.
    title : str

    Returns
    -------
    bytes
        PNG.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from metafovea.plotting import iron_colormap

    imgs = d.temperature_k if d.temperature_k is not None else d.scene
    unit = "K" if d.temperature_k is not None else "DN"
    fig, axs = plt.subplots(1, 2, figsize=(9, 4.2), constrained_layout=True)
    for ax, img, name in ((axs[0], imgs[0], "foveal scene"), (axs[1], imgs[1], "perifoveal scene")):
        lo, hi = np.nanpercentile(img, [0.5, 99.5])
        im = ax.imshow(img, cmap=iron_colormap(), vmin=lo, vmax=hi)
        ax.set_title(name)
        ax.set_axis_off()
        fig.colorbar(im, ax=ax, shrink=0.8, label=f"brightness temperature ({unit})" if unit == "K" else unit)
    fig.suptitle(title or f"PSF-aware reconstruction ({d.info.get('method')})")
    png = fig_to_png(fig)
    plt.close(fig)
    return png
