"""metafovea: design, fabricate, simulate and reconstruct polarisation-multiplexed foveated meta-optics.

Data flows one way (see README, "Architecture"):
design files -> config -> rcwa -> library -> lens -> layout / optics -> imaging -> reconstruct -> report.

Units: micrometres for every length inside the package, radians for angles, kelvin for temperatures,
seconds for times. Time-harmonic convention exp(-i omega t). See :mod:`metafovea.units`.
"""

__version__ = "0.1.0"

from metafovea.errors import InputError  # noqa: F401  (re-exported for users)
