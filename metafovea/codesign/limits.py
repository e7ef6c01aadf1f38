"""What no flat lens of this platform can do over a band: the achromatic bandwidth limit and the diffractive focal
shift, for a lens at hand (stated in every co-design report next to what the co-design reached).

Achromatic limit (F. Presutti and F. Monticone, "Focusing on bandwidth: achromatic metalens limits", Optica 7,
624 (2020)): a lens focuses a band without chromatic shift only if its structure supplies the group-delay
difference between the central and the marginal ray. Posts of height ``h`` and index ``n`` supply at most the
extra optical path ``(n - 1) h``; the marginal ray of a lens of focal length ``f`` and diameter ``D`` travels
``f (sqrt(1 + (D / 2f)^2) - 1)`` farther than the central one. The achromatic fractional bandwidth is then at most
about their ratio (the limit's constant kappa taken as 1):

    delta_omega / omega_0  <~  (n - 1) h / (f (sqrt(1 + (D / 2f)^2) - 1))

Diffractive focal shift: a wrapped (diffractive) lens focuses ``lambda`` at ``f lambda_0 / lambda``; the depth of
focus is ``+- 2 lambda_0 N^2`` (N the f-number), so the band spans ``(f lambda_0 / lambda_min - f lambda_0 /
lambda_max) / (4 lambda_0 N^2)`` depths of focus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from metafovea.config import LensDesign, PlatformDesign
from metafovea.errors import check_positive
from metafovea.radiometry import check_band


@dataclass(frozen=True)
class BandwidthLimit:
    """The limit figures of one lens over one band (lengths um; fractions of the centre frequency)."""

    lens: str
    band_um: tuple[float, float]
    post_path_um: float  #: (n_post - 1) h: the largest extra optical path the posts supply
    marginal_delay_um: float  #: f (sqrt(1 + (D / 2f)^2) - 1): what an achromat must supply
    shortfall: float  #: marginal_delay_um / post_path_um (how many times too short the posts are)
    achromatic_fraction: float  #: post_path_um / marginal_delay_um: the achromatic fractional bandwidth
    band_fraction: float  #: the band's fractional bandwidth in frequency, (1/lo - 1/hi) / (1/lambda_0)
    focal_shift_um: float  #: f lambda_0 / lambda_lo - f lambda_0 / lambda_hi
    depth_of_focus_um: float  #: 4 lambda_0 N^2 (the full depth, +- 2 lambda_0 N^2)
    post_height_for_achromat_um: float  #: marginal_delay_um / (n_post - 1)

    @property
    def depths_of_focus(self) -> float:
        return self.focal_shift_um / self.depth_of_focus_um

    def lines(self) -> list[str]:
        """The limit in words (for reports and the command's output)."""
        return [
            f"{self.lens}: posts supply at most (n - 1) h = {self.post_path_um:.1f} um of extra path; the marginal "
            f"ray needs {self.marginal_delay_um / 1000:.2f} mm ({self.shortfall:.0f}x short): an achromatic band of "
            f"~{100 * self.achromatic_fraction:.2f} % of the centre frequency, against "
            f"{100 * self.band_fraction:.0f} % for {self.band_um[0]:g}-{self.band_um[1]:g} um (an achromat would "
            f"need posts {self.post_height_for_achromat_um / 1000:.1f} mm tall)",
            f"{self.lens}: the diffractive focus moves {self.focal_shift_um / 1000:.1f} mm across the band, "
            f"{self.depths_of_focus:.0f} depths of focus ({self.depth_of_focus_um:.0f} um each)",
        ]


def bandwidth_limit(lens: LensDesign, platform: PlatformDesign, band_um: tuple[float, float]) -> BandwidthLimit:
    """The achromatic bandwidth limit and the diffractive focal shift of ``lens`` on ``platform`` over ``band_um``.

    Parameters
    ----------
    lens : LensDesign
    platform : PlatformDesign
        Its posts' index ``n_post`` and height ``post_height_um``.
    band_um : (lo, hi), um

    Returns
    -------
    BandwidthLimit
    """
    lo, hi = check_band(band_um)
    f, d, lam0 = lens.f_um, lens.diameter_um, lens.wavelength_um
    n, h = platform.n_post, lens.post_height_um
    check_positive("n_post - 1", n - 1.0)
    post = (n - 1.0) * h
    marginal = f * (math.sqrt(1.0 + (d / (2.0 * f)) ** 2) - 1.0)
    fnum = f / d
    return BandwidthLimit(lens=lens.name, band_um=(lo, hi), post_path_um=post, marginal_delay_um=marginal,
                          shortfall=marginal / post, achromatic_fraction=post / marginal,
                          band_fraction=(1.0 / lo - 1.0 / hi) * lam0, focal_shift_um=f * lam0 / lo - f * lam0 / hi,
                          depth_of_focus_um=4.0 * lam0 * fnum**2, post_height_for_achromat_um=marginal / (n - 1.0))
