"""metafovea: design, fabricate, simulate and reconstruct polarisation-multiplexed foveated meta-optics.

Data flows one way (see README, "Architecture"):
design files -> config -> rcwa -> library -> lens -> layout / optics -> imaging -> reconstruct -> report.

Units: micrometres for every length inside the package, radians for angles, kelvin for temperatures,
seconds for times. Time-harmonic convention exp(-i omega t). See :mod:`metafovea.units`.

The main functions and types are available from the package itself (README, "Quick start in Python")::

    import metafovea as mf
    system = mf.SystemDesign.paper()                   # or mf.load_system("designs/system.toml")
    print(mf.format_summary(mf.summarize(system.foveal)))
    posts, library = mf.platform_post_sets(system.platform)
    p = mf.psf(system.foveal, post_set=posts["x"])
    m = mf.simulate(system, "bars", frames=12, posts=posts)
    rec = mf.reconstruct_measurement(m).reconstruction

================================  ==========================================================================
stage                             names
================================  ==========================================================================
design files (config)             load_system, load_lens, load_platform, load_design, SystemDesign,
                                  LensDesign, PlatformDesign, SensorDesign
design summary (lens)             summarize, LensSummary, format_summary, design_lenses
scatterer library (library)       platform_post_sets, system_post_sets, compute_library, select_posts,
                                  PostSet, Library, LibraryOptions
optics                            psf, sensor_psf, encircled_energy_on_axis, PSF
imaging                           simulate, SimulationOptions, make_scene, list_scenes, Scene, iron_colormap
measurement                       Measurement, FovealConstraint
reconstruct                       reconstruct_measurement, deconvolve_measurement, Reconstruction,
                                  PipelineResult, Deconvolution, ChannelPSFs
validate                          validate_system, ValidateOptions
errors                            InputError
================================  ==========================================================================

The names are loaded on first use (PEP 562 module ``__getattr__``): ``import metafovea`` itself imports only the
error type, never scipy, jax or matplotlib (a test keeps it so), and the command line starts as fast as before.
The subpackages (``metafovea.optics``, ``metafovea.reconstruct``, ...) hold everything else.
"""

from __future__ import annotations

import importlib
from typing import Any

from metafovea.errors import InputError

__version__ = "0.1.0"

#: public name -> the module that defines it (imported on first attribute access)
_LAZY: dict[str, str] = {
    **dict.fromkeys(("load_system", "load_lens", "load_platform", "load_design", "SystemDesign", "LensDesign",
                     "PlatformDesign", "SensorDesign"), "metafovea.config"),
    **dict.fromkeys(("summarize", "LensSummary"), "metafovea.lens"),
    **dict.fromkeys(("format_summary", "design_lenses"), "metafovea.design_report"),
    **dict.fromkeys(("platform_post_sets", "system_post_sets", "compute_library", "select_posts", "PostSet",
                     "Library", "LibraryOptions"), "metafovea.library"),
    **dict.fromkeys(("psf", "sensor_psf", "encircled_energy_on_axis", "PSF"), "metafovea.optics"),
    **dict.fromkeys(("simulate", "SimulationOptions", "make_scene", "list_scenes", "Scene"), "metafovea.imaging"),
    "iron_colormap": "metafovea.plotting",
    **dict.fromkeys(("Measurement", "FovealConstraint"), "metafovea.measurement"),
    **dict.fromkeys(("reconstruct_measurement", "deconvolve_measurement", "Reconstruction", "PipelineResult",
                     "Deconvolution", "ChannelPSFs"), "metafovea.reconstruct"),
    **dict.fromkeys(("validate_system", "ValidateOptions"), "metafovea.validate"),
}

__all__ = ["InputError", "__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    """Import the module defining ``name`` on first access and keep the name (PEP 562)."""
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'metafovea' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
