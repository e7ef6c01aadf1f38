"""Broadband co-design of the two metalenses with the reconstruction (issue 33).

``limits``    the achromatic bandwidth limit and the diffractive focal shift of a lens (stated in every report)
``optimize``  a bounded, resumable optimiser (optax's Adam, box projection, checkpoints)
"""

from .limits import BandwidthLimit, bandwidth_limit
from .optimize import Bounds, OptimizeOptions, OptimizeResult, minimize

__all__ = ["BandwidthLimit", "Bounds", "OptimizeOptions", "OptimizeResult", "bandwidth_limit", "minimize"]
