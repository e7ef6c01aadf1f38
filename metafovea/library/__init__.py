"""Scatterer library stage: RCWA sweeps of post widths and the post sets chosen from them.

A :class:`PostSet` is what the later stages (lens, layout, optics) consume: the N posts actually used by one lens,
level ``k`` targeting the wrapped phase ``2 pi k / N`` for the lens' own polarisation ('x': the foveal lens, 'y':
the perifoveal lens; each passes the other polarisation).

Files, in the order a library is made and used::

    postset    PostSet (N posts, their transmissions for both polarisations, save / load), postset_table; the
               checked loading of the stage's .npz files
    sweep      Library (t, T, R per (wavelength, wx, wy)), LibraryOptions (stack, solver, run), width_grid,
               compute_library (one task per row through metafovea.parallel.run_tasks; cached under a hash of
               every input, library_key; resumable from finished rows)
    harmonics  choose_harmonics / HarmonicsChoice (the smallest RCWA truncation whose estimated zero-order phase
               error on probe posts is within a tolerance: ``metafovea library --tolerance-rad``), probe_posts
    select     select_posts (the paper's Fig. 7c: nominal grid search, or jointly over the -/0/+ edge-bias
               cases), usable_posts, bias_table (a set solved by RCWA under the edge bias)
    platform   PlatformSweep and platform_post_sets (a platform's library and both post sets: the path of
               ``metafovea library``, ``design`` and ``validate``), system_post_sets, rcwa_post_sets, POST_SOURCES
    oblique    ObliqueResponse, oblique_response (the chosen posts off axis, as t(theta) / t(0); cached)
    seed       the default system's library and oblique responses shipped in metafovea/data/ (read when the
               cache misses with the same key), seed_names, write_seed (``python -m metafovea.library.seed``)
    surrogate  Surrogate (a differentiable JAX B-spline of t_x, t_y over (wx, wy, lambda)), fit_surrogate (fitted to
               an RCWA sweep over a band; cached), error_report / SurrogateError (against fresh RCWA solves at
               held-out posts and wavelengths), rcwa_transmission (the reference)
    report     library_report / LibraryReport (numbers, the paper's Fig. 7b/7c and the files ``metafovea library``
               writes); imported as ``metafovea.library.report``
"""

from .harmonics import HarmonicsChoice, choose_harmonics, probe_posts
from .oblique import OBLIQUE_ANGLES_DEG, OBLIQUE_HARMONICS, ObliqueResponse, oblique_cache_name, oblique_response
from .platform import POST_SOURCES, PlatformSweep, platform_post_sets, rcwa_post_sets, system_post_sets
from .postset import PostSet, postset_table
from .select import BIAS_CASES, JOINT_MAX_ROUNDS, JOINT_POLISH, bias_table, select_posts, usable_posts
from .surrogate import (
           GOAL_AMPLITUDE_RMS_PCT,
           GOAL_PHASE_RMS_RAD,
           Surrogate,
           SurrogateError,
           error_report,
           fit_surrogate,
           held_out_points,
           rcwa_transmission,
           surrogate_from_library,
           surrogate_grid,
)
from .sweep import DEFAULT_HARMONICS, LIBRARY_ARRAYS, Library, LibraryOptions, compute_library, library_key, width_grid

__all__ = ["BIAS_CASES", "DEFAULT_HARMONICS", "GOAL_AMPLITUDE_RMS_PCT", "GOAL_PHASE_RMS_RAD", "HarmonicsChoice",
           "JOINT_MAX_ROUNDS", "JOINT_POLISH", "LIBRARY_ARRAYS", "Library", "LibraryOptions", "OBLIQUE_ANGLES_DEG",
           "OBLIQUE_HARMONICS", "ObliqueResponse", "POST_SOURCES", "PlatformSweep", "PostSet", "Surrogate",
           "SurrogateError", "bias_table", "choose_harmonics", "compute_library", "error_report", "fit_surrogate",
           "held_out_points", "library_key", "oblique_cache_name", "oblique_response", "platform_post_sets",
           "postset_table", "probe_posts", "rcwa_post_sets", "rcwa_transmission", "select_posts",
           "surrogate_from_library", "surrogate_grid", "system_post_sets", "usable_posts", "width_grid"]
