"""Units and conventions shared by every module.

Units
-----
* Lengths: **micrometres** everywhere inside the package (wavelength, period, post widths, pixel pitch,
  focal length, diameter, GDS coordinates are converted to nm only when written). User-facing lens-scale
  input is in millimetres and says so in its name (``f_mm``, ``d_mm``, ``--f``/``--d`` at the CLI).
* Angles: radians inside the package, degrees at the CLI and in names ending in ``_deg``.
* Temperatures: kelvin. Times: seconds. Spatial frequencies in reports: cycles/mm.

Time-harmonic convention
------------------------
Fields are ``Re[E exp(-i omega t)]``. A plane wave travelling towards +z is ``exp(+i k z)``; phase
*accumulates positively* with propagation distance. A lossy medium has ``Im(n) > 0``.

Lens phase sign
---------------
A thin element multiplies the incident field by ``t(x, y) = |t| exp(i phi(x, y))``. A wave converging
to a focus at distance f behind the lens is ``exp(-i k sqrt(r^2 + f^2))`` up to a constant, so the
focusing hyperbolic profile is

    phi(r) = -(2 pi / lambda0) (sqrt(r^2 + f^2) - f)   (``PHASE_SIGN = -1``)

phi = 0 at the centre and decreases outward. A linear phase ``phi = +k sin(theta) x`` tilts the beam
towards +x (the spot moves to +x). Wrapped phases are reported in [0, 2 pi).

Array layout
------------
Spatial axes last, ``(..., H, W)``, row index = y (increasing downward in images, upward in physical
coordinates only where a function says so). Leading axes are documented per function.
"""

from __future__ import annotations

import math

UM_PER_MM = 1000.0
NM_PER_UM = 1000.0
TWO_PI = 2.0 * math.pi

#: Sign of the focusing phase profile under the exp(-i omega t) convention (see module docstring).
PHASE_SIGN = -1
