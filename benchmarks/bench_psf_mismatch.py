"""PSF mismatch: data made through one PSF, reconstructed with the file's nominal one, and with the PSF refined from
the data (:mod:`metafovea.reconstruct.psf_refine`).

    python benchmarks/bench_psf_mismatch.py [--quick] [--scenes siemens-star coins rooftop] [--methods wiener wavelet]
        [--cases none defocus-1/8-x1 ...] [--seed 5] [--frames 48]

Cases (the camera that made the data; the reconstruction is given the nominal camera's ``psf_x1``/``psf_x2``):

* ``none``: the nominal camera (the refinement's null case: it should keep the nominal PSFs);
* ``defocus-W-xI``: lens I's kernel on a plane moved by ``W`` waves peak-to-valley at 10 um
  (:class:`~metafovea.reconstruct.psf_refine.DisplacedFocusProvider`; the far haze and the geometry nominal);
* ``field``: both channels in 3 x 3 field patches (``field_patches=3``: the off-axis PSFs), reconstructed with the
  on-axis one, and with the file's patches (``psf_patches_x*``, :mod:`metafovea.reconstruct.field`); its "true PSF"
  column is the same scene and seed made shift-invariant (the on-axis PSF everywhere), reconstructed with its own
  PSF: what the field dependence costs;
* ``focal+5%-xI``: lens I's focal length times 1.05 (``LensDesign.with_(f_um=...)``), the sensor where it was.

Per case, scene, band (8-14 um and the 10 um filter) and channel: the PSNR against the scene with the true PSF, with
the nominal PSF, the loss (dB), and with the PSF refined from the data (the ``defocus`` family for ``none``, the
defocus and the field cases, the ``focal-length`` family for the focal cases and for ``none`` again), the member
chosen and its evidence (``2 ln B``, Vuong's ``Z``). The FPN is estimated from 16 shutter frames and its error counted,
as ``metafovea reconstruct --fpn calibration`` does; the true PSFs' illumination is used throughout (only the kernels
and pedestals differ). The refinement runs as ``deconvolve_measurement(refine_psf=...)`` does: the evidence, Vuong's
test and the foveal relation's check of both channels' Wiener estimates. The last lines summarise the loss and what
the refinement recovers per case, band and method.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
import warnings
from pathlib import Path

import numpy as np

from metafovea.config import load_system
from metafovea.imaging.kernels import resolve_provider
from metafovea.imaging.simulate import SimulationOptions, camera_for, simulate
from metafovea.reconstruct.deconvolve import deconvolve_measurement, separate_deconvolve
from metafovea.reconstruct.fpn import estimate_fpn
from metafovea.reconstruct.joint import ChannelPSFs
from metafovea.reconstruct.metrics import psnr
from metafovea.reconstruct.psf_refine import DisplacedFocusProvider, defocus_shift_um, psf_family, refine_psf

CASES = ("none", "defocus-1/8-x1", "defocus-1/4-x1", "defocus-1/8-x2", "defocus-1/4-x2", "field", "focal+5%-x1",
         "focal+5%-x2")
NAMES = {1: "foveal", 2: "perifoveal"}


def _load() -> str:
    return " ".join(open("/proc/loadavg").read().split()[:3])


def _simulate(system, scene: str, case: str, filt: bool, args: argparse.Namespace):
    """The data of ``case`` (a Measurement)."""
    kw = dict(rng=args.seed, frames=args.frames, calibration_frames=16, filter_enabled=filt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # defocus and the moved focal length are warned about, as they should be
        if case.startswith("defocus"):
            num, den = case.split("-")[1].split("/")
            waves = float(num) / float(den)
            ch = int(case[-1])
            cam = camera_for(system, SimulationOptions(filter_enabled=filt))
            base, _ = resolve_provider("auto", None, cam.post_sets)
            lens = cam.channels[ch - 1].lens
            prov = DisplacedFocusProvider(base, {NAMES[ch]: defocus_shift_um(lens.na, lens.wavelength_um, waves)},
                                          {c.name: t.metasurface_transmission for c, t in zip(cam.channels,
                                                                                               cam.trains)})
            return simulate(system, scene, psf=prov, **kw)
        if case == "field":
            return simulate(system, scene, field_patches=3, **kw)
        if case.startswith("focal"):
            name = NAMES[int(case[-1])]
            lens = getattr(system, name)
            return simulate(dataclasses.replace(system, **{name: lens.with_(f_um=lens.f_um * 1.05)}), scene, **kw)
        return simulate(system, scene, **kw)


def _scores(m, psfs: ChannelPSFs, method: str, fpn, fe: float, bound: bool = False) -> list[float]:
    """PSNR of both channels against the scene (``bound``: then the Wiener bound's, sectioned for patches)."""
    d = deconvolve_measurement(m, fpn=fpn, fpn_error_dn=fe, method=method, psfs=psfs, score_truth=bound)
    out = [psnr(d.scene[i], m.scene_truth[i]) for i in range(2)]
    return out + [d.info["scores"][f"wiener_bound_psnr_x{i}"] for i in (1, 2)] if bound else out


def _power_ratio(m, ref) -> list[float]:
    """Each channel's mean noise-free image over the reference's: the field patches' off-axis kernels keep less of
    the light than the on-axis one (the haze is the on-axis kernel's complement), which a reconstruction with the
    on-axis PSF reads as a change of level."""
    return [float(np.mean(getattr(m, f"truth_x{i}")) - m.dark_dn) / float(np.mean(getattr(ref, f"truth_x{i}"))
                                                                             - ref.dark_dn) for i in (1, 2)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a 128 x 128 crop, one scene, 24 frames")
    ap.add_argument("--scenes", nargs="+", default=None, help="default: siemens-star coins rooftop")
    ap.add_argument("--methods", nargs="+", default=["wiener", "wavelet"])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--frames", type=int, default=None, help="default 48 (24 with --quick)")
    args = ap.parse_args()
    args.frames = args.frames or (24 if args.quick else 48)
    scenes = args.scenes or (["siemens-star"] if args.quick else ["siemens-star", "coins", "rooftop"])
    system = load_system(Path(__file__).resolve().parents[1] / "designs" / "system.toml")
    if args.quick:
        system = dataclasses.replace(system, sensor=dataclasses.replace(system.sensor, crop=(128, 128)))
    print(f"nproc {os.cpu_count()}, load {_load()}, crop {system.sensor.crop}, {args.frames} frames, seed {args.seed}")
    print(f"{'case':<15} {'scene':<13} {'band':<7} {'ch':<3} {'method':<8} {'true':>6} {'nominal':>7} {'loss':>6} "
          f"{'refined':>7} {'gain':>6}  family: member (2 ln B, Z)")
    t_start = time.perf_counter()
    families: dict = {}
    summary: dict = {}
    field_loss: dict = {}
    for filt in (False, True):
        band = "10 um" if filt else "8-14 um"
        for scene in scenes:
            nominal_m = None
            for case in args.cases:
                kinds = (["defocus", "focal-length"] if case == "none" else
                         ["focal-length"] if case.startswith("focal") else ["defocus"])
                m = _simulate(system, scene, case, filt, args)
                if nominal_m is None or case == "none":
                    nominal_m = m if case == "none" else _simulate(system, scene, "none", filt, args)
                fpn, info = estimate_fpn(calibration=m.extras["calibration"])
                fe = float(info.get("error_rms_dn") or 0.0)
                file_psfs = ChannelPSFs.from_measurement(m)
                nom = ChannelPSFs.from_measurement(nominal_m)
                nominal = ChannelPSFs(nom.kernels, nom.pedestals, file_psfs.illumination, source="nominal")
                if case == "field":  # the reference: the same scene and seed through the on-axis PSF everywhere
                    nfpn, ninfo = estimate_fpn(calibration=nominal_m.extras["calibration"])
                    true = {me: _scores(nominal_m, ChannelPSFs.from_measurement(nominal_m), me, nfpn,
                                        float(ninfo.get("error_rms_dn") or 0.0)) for me in args.methods}
                else:
                    true = {me: _scores(m, file_psfs, me, fpn, fe) for me in args.methods}
                plain = {me: _scores(m, nominal, me, fpn, fe) for me in args.methods}
                # the field case through the file's own 3 x 3 patches (psf_patches_x*, field_psf='auto')
                patched = ({me: _scores(m, file_psfs, me, fpn, fe, bound=True) for me in args.methods}
                           if case == "field" else {})
                from metafovea.reconstruct.deconvolve import _frames_for  # the frames deconvolve_measurement uses

                frames = _frames_for(m, fpn)
                for kind in kinds:
                    fams = []
                    for ch in (1, 2):
                        key = (kind, filt, ch)
                        if key not in families:
                            families[key] = psf_family(system, channel=ch, kind=kind, filter_enabled=filt)
                        fams.append(families[key])
                    r = refine_psf(frames, m.alpha, nominal, fams, offset=m.dark_dn, fpn_error_dn=fe,
                                   foveal_scale=m.recorded_scale,  # the check deconvolve_measurement runs:
                                   estimate=lambda p, fr=frames, m=m, fe=fe: separate_deconvolve(
                                       fr, m.alpha, p, method="wiener", offset=m.dark_dn, fpn_error_dn=fe).scene)
                    for me in args.methods:
                        ref = _scores(m, r.psfs, me, fpn, fe) if r.refined else plain[me]
                        for i, c in enumerate(r.channels):
                            t, n, rf = true[me][i], plain[me][i], ref[i]
                            what = (f"{kind}: {c['chosen']:+g}{'' if c['refined'] else ' kept'} "
                                    f"(best {c['best']:+g}, {c['two_ln_b']:.0f}, {c['z']:.1f})")
                            if case == "field":
                                what += f"; light kept off axis: {_power_ratio(m, nominal_m)[i]:.3f} of on-axis"
                                if kind == kinds[0]:
                                    pt, pb = patched[me][i], patched[me][2 + i]
                                    what += (f"; with the file's patches {pt:.2f} (loss {t - pt:.2f}; the "
                                             f"sectioned Wiener bound {pb:.2f}, margin {pt - pb:+.2f})")
                                    field_loss.setdefault((band, me), []).append((t - pt, pt - n, pt - pb))
                            print(f"{case:<15} {scene:<13} {band:<7} x{i + 1:<2} {me:<8} {t:6.2f} {n:7.2f} "
                                  f"{t - n:6.2f} {rf:7.2f} {rf - n:+6.2f}  {what}", flush=True)
                            summary.setdefault((case, kind, band, me), []).append((t - n, rf - n, c["refined"]))
    print(f"load {_load()}, {time.perf_counter() - t_start:.0f} s")
    print("summary: case, family, band, method: mean loss (dB) with the nominal PSF, worst loss, mean gain of the "
          "refinement, channels refined")
    for (case, kind, band, me), v in summary.items():
        a = np.array([(x[0], x[1]) for x in v])
        print(f"  {case:<15} {kind:<12} {band:<7} {me:<8} loss {a[:, 0].mean():6.2f} (worst {a[:, 0].max():6.2f}), "
              f"refinement {a[:, 1].mean():+6.2f} (worst {a[:, 1].min():+6.2f}), refined {sum(x[2] for x in v)} of "
              f"{len(v)}")
    for (band, me), v in field_loss.items():
        a = np.array(v)
        print(f"  field, the file's 3 x 3 patches (field_psf='auto'), {band:<7} {me:<8} loss {a[:, 0].mean():6.2f} "
              f"(worst {a[:, 0].max():6.2f}), gain over the on-axis kernel {a[:, 1].mean():+6.2f} (worst "
              f"{a[:, 1].min():+6.2f}), margin to the sectioned Wiener bound {np.median(a[:, 2]):+6.2f} median "
              f"(worst {a[:, 2].min():+6.2f})")


if __name__ == "__main__":
    main()
