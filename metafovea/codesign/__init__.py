"""Broadband co-design of the two metalenses for the band (issue 33).

``limits``    the achromatic bandwidth limit and the diffractive focal shift of a lens (stated in every report)
``bound``     the line bound: the most any phase profile can give a lens' band-integrated MTF
``optimize``  a bounded, resumable optimiser (optax's Adam, box projection, checkpoints)
``run``       the co-design of a system's lenses (:func:`codesign`) on the differentiable channel model
``report``    what a run writes (design files, production check, JSON, HTML) and :func:`run_codesign`
"""

from .bound import MTFBound, band_mtf_bound
from .limits import BandwidthLimit, bandwidth_limit
from .optimize import Bounds, OptimizeOptions, OptimizeResult, minimize
from .report import production_check, run_codesign, write_codesign
from .run import CODESIGN_OBJECTIVES, CodesignOptions, CodesignResult, LensResult, codesign, spectral_sampling

__all__ = ["CODESIGN_OBJECTIVES", "BandwidthLimit", "Bounds", "CodesignOptions", "CodesignResult", "LensResult",
           "MTFBound", "OptimizeOptions", "OptimizeResult", "band_mtf_bound", "bandwidth_limit", "codesign",
           "minimize", "production_check", "run_codesign", "spectral_sampling", "write_codesign"]
