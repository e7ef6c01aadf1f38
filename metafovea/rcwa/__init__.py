"""In-house RCWA (Fourier modal method) for 2-D periodic stacks of rectangular-post layers.

See :mod:`metafovea.rcwa.solve` for the conventions (time dependence, reference planes, power
normalisation, entry side) and :mod:`metafovea.rcwa.basis` for the formulation.
"""

from metafovea.rcwa.geometry import Layer, Rectangle, Stack
from metafovea.rcwa.solve import FACTORIZATIONS, SIDES, Result, n_harmonics, solve

__all__ = ["Layer", "Rectangle", "Stack", "Result", "solve", "n_harmonics", "FACTORIZATIONS", "SIDES"]
