"""Layout specification, file coordinates and the lens as a sequence of bands of lattice sites.

Conventions (all files written by :mod:`metafovea.layout`)
---------------------------------------------------------
* Database unit 1 nm (``UNITS`` 1e-3 user unit = 1 um, 1e-9 m). Inside the package lengths are um.
* Origin: the lower-left corner of the wafer's bounding square is ``(0, 0)``; the lens centre (the wafer's
  centre) is at ``(C, C)`` with ``C`` = :attr:`LayoutSpec.centre_nm`, so every coordinate in the file is >= 0
  (OASIS repetitions and DWL tools are happy with that). A patch keeps the full lens' coordinates.
* Site ``(ix, iy)`` (see :mod:`metafovea.lens`) has its post centred at
  ``C + snap((ix + o) p)``, ``C + snap((iy + o) p)`` (nm), ``snap`` rounding to the manufacturing grid.
* Post sizes: ``post_set.widths_um[k]`` (wx, wy) plus twice the platform's ``write_bias_um`` (process
  pre-bias), rounded to twice the grid, so that a post centred on a grid point has its edges on the grid.
* Layers (layer, datatype), see :mod:`metafovea.layout.frame`: posts (1, 0), aluminium aperture ring (2, 0),
  exposure-1 marks and vernier scales (3, 0), exposure-2 marks and vernier scales (4, 0), die frame (5, 0),
  printed label (6, 0), text label (10, 0), wafer outline (11, 0). One cell per post type named
  ``P000``..``P{N-1}`` holding one rectangle centred at the cell origin (a patch defines the types it uses),
  one top cell (``<NAME>_LENS``) holding the frame, the label and one reference per post.
* Bands: the lens is generated in bands of ``band_rows`` site rows across the window's columns; a band
  is a tile of :mod:`metafovea.lens` (``evaluate_tile``), evaluated on the half with x >= 0 and
  mirrored (the phase is even in x, so the mirror is exact).
* Tasks (export and expected counts): mirror-row bands. The phase is even in y too, so rows ``j >= 0``
  and ``-j - 2o`` have identical levels: a task evaluates one quadrant (x >= 0, y >= 0) of
  ``band_rows`` rows and emits the rows on both sides (each side's posts in row-major order, the
  ``+y`` side first). Tasks go outward from the centre row.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea.config import LensDesign, PlatformDesign, load_design
from metafovea.errors import InputError, check_choice, check_int, check_range
from metafovea.lens import EMPTY, added_phase, row_half_counts, site_index_range
from metafovea.library.postset import PostSet
from metafovea.units import NM_PER_UM, TWO_PI

DBU_UM = 1e-3  #: database unit in um (1 nm)
MAX_COORD_NM = 2**31 - 1  #: largest coordinate a 32-bit GDSII/OASIS reader holds (nm)


@dataclass(frozen=True)
class Layers:
    posts: tuple[int, int] = (1, 0)  #: exposure 1 (etched): the posts
    aperture: tuple[int, int] = (2, 0)  #: exposure 2 (lift-off): the aluminium aperture ring
    marks: tuple[int, int] = (3, 0)  #: exposure 1: alignment crosses, verniers' main scales
    marks2: tuple[int, int] = (4, 0)  #: exposure 2: marks matching the crosses, verniers' second scales
    die: tuple[int, int] = (5, 0)  #: exposure 1: the die frame (dicing outline)
    printed: tuple[int, int] = (6, 0)  #: exposure 1: the printed label (polygon text)
    label: tuple[int, int] = (10, 0)  #: non-printing text record with every parameter
    wafer: tuple[int, int] = (11, 0)  #: non-printing wafer outline

    def exposures(self) -> dict[str, list[tuple[int, int]]]:
        """Which layers each exposure writes, and the non-printing ones."""
        return {"exposure 1": [self.posts, self.marks, self.die, self.printed],
                "exposure 2": [self.aperture, self.marks2], "non-printing": [self.label, self.wafer]}


@dataclass(frozen=True)
class LayoutSpec:
    """Everything that fixes the content of an exported layout (hashable into a resume key).

    patch_um: optional ``(x, y, w)`` (um, relative to the lens centre): only sites with centre in
    ``[x - w/2, x + w/2) x [y - w/2, y + w/2)`` are written, at their positions in the full lens,
    without ring and marks.
    """

    design: LensDesign
    post_set: PostSet
    levels: int
    grid_nm: int = 5
    layers: Layers = field(default_factory=Layers)
    ring_gap_um: float | None = None  # clearance between the aperture and the ring (default: one period)
    ring_width_um: float = 1000.0
    mark_offset_um: float = 500.0  # from the ring's outer edge to the mark centre
    mark_size_um: float = 200.0  # cross arm length
    mark_width_um: float = 20.0
    patch_um: tuple[float, float, float] | None = None
    band_rows: int = 32
    mark_clearance_um: float = 5.0  # exposure-2 squares from the cross arms
    vernier_pitch_um: float = 8.0  # main scale pitch (bars half of it)
    vernier_step_um: float = 0.25  # second scale pitch - main pitch: the overlay resolution
    vernier_bars: int = 21  # bars per scale (odd): range +-(bars - 1) / 2 x step
    vernier_length_um: float = 40.0
    die_margin_um: float = 1000.0  # from the outermost frame element to the scribe lane
    scribe_width_um: float = 100.0
    label_height_um: float = 250.0  # printed label character height
    wafer_diameter_mm: float = 100.0
    wafer_flat_mm: float | None = None  # None: SEMI M1 for the diameter (none for 200/300 mm), 0: no flat
    wafer_edge_exclusion_mm: float = 3.0
    write_bias_um: float = 0.0  # process pre-bias per edge
    posts_resist_tone: str = "negative"
    ring_resist_tone: str = "positive"
    date: str = ""  # written in the labels (ISO date); not part of the resume key

    # -- derived -----------------------------------------------------------------------------
    @property
    def top_name(self) -> str:
        # GDSII/OASIS names are ASCII: any other character (also a non-ASCII letter) becomes '_'
        n = "".join(ch if (ch.isascii() and ch.isalnum()) else "_" for ch in self.design.name.upper())
        return f"{n}_LENS"

    @property
    def post_names(self) -> list[str]:
        return [f"P{k:03d}" for k in range(self.levels)]

    @property
    def ring_inner_um(self) -> float:
        gap = self.design.period_um if self.ring_gap_um is None else self.ring_gap_um
        return self.design.radius_um + gap

    @property
    def ring_outer_um(self) -> float:
        return self.ring_inner_um + self.ring_width_um

    @property
    def frame_half_um(self) -> float:
        """Half-size of the marks' bounding box, um, on the 1 um grid."""
        return float(math.ceil(self.ring_outer_um + self.mark_offset_um + self.mark_size_um / 2))

    @property
    def wafer_flat_distance_um(self) -> float:
        """Distance from the wafer centre to the primary flat (um); the radius when it has none."""
        from metafovea.layout.frame import SEMI_FLAT_MM

        R = self.wafer_diameter_mm * 500.0
        L = self.wafer_flat_mm
        if L is None:  # SEMI M1 for a standard diameter; none for 200/300 mm (notch) or a non-standard wafer
            L = SEMI_FLAT_MM.get(self.wafer_diameter_mm, 0.0)
        half = min(L * 500.0, R)
        return math.sqrt(max(R * R - half * half, 0.0))

    @property
    def centre_nm(self) -> int:
        """The lens (and wafer) centre in file coordinates: the wafer radius (or the frame's half-size if larger)."""
        return int(round(max(float(math.ceil(self.wafer_diameter_mm * 500.0)), self.frame_half_um) * NM_PER_UM))

    def snap(self, v_nm: ArrayLike) -> np.ndarray:
        g = self.grid_nm
        return (np.rint(np.asarray(v_nm, dtype=float) / g) * g).astype(np.int64)

    @property
    def post_sizes_nm(self) -> np.ndarray:
        """(N, 2) int64 post widths (wx, wy) in nm, on a 2 * grid raster (>= 2 * grid)."""
        g2 = 2 * self.grid_nm
        w = np.rint((self.post_set.widths_um + 2 * self.write_bias_um) * NM_PER_UM / g2).astype(np.int64) * g2
        return np.maximum(w, g2)

    def site_x_nm(self, ix: ArrayLike) -> np.ndarray:
        o = 0.0 if self.design.lattice == "integer" else 0.5
        return self.centre_nm + self.snap((np.asarray(ix, dtype=float) + o) * self.design.period_um * NM_PER_UM)

    site_y_nm = site_x_nm

    @property
    def period_nm(self) -> int | None:
        """Lattice period in nm when every site lies exactly on ``C + (i + o) P`` (else None)."""
        p = self.design.period_um * NM_PER_UM
        o = 0.0 if self.design.lattice == "integer" else 0.5
        P = int(round(p))
        if abs(p - P) < 1e-9 and P % self.grid_nm == 0 and (o * P) % self.grid_nm == 0:
            return P
        return None

    # -- window -----------------------------------------------------------------------------
    def window(self) -> tuple[int, int, int, int]:
        """Inclusive site index window ``(iy_lo, iy_hi, ix_lo, ix_hi)``."""
        lo, hi = site_index_range(self.design)
        if self.patch_um is None:
            return lo, hi, lo, hi
        x, y, w = self.patch_um
        p = self.design.period_um
        o = 0.0 if self.design.lattice == "integer" else 0.5
        ix_lo = max(lo, math.ceil((x - w / 2) / p - o))
        ix_hi = min(hi, math.ceil((x + w / 2) / p - o) - 1)
        iy_lo = max(lo, math.ceil((y - w / 2) / p - o))
        iy_hi = min(hi, math.ceil((y + w / 2) / p - o) - 1)
        return iy_lo, iy_hi, ix_lo, ix_hi

    def bands(self) -> list[tuple[int, int, int, int]]:
        """Bands ``(iy0, rows, ix0, cols)`` covering the window, in increasing y; empty rows trimmed."""
        iy_lo, iy_hi, ix_lo, ix_hi = self.window()
        if iy_lo > iy_hi or ix_lo > ix_hi:
            return []
        rows = np.arange(iy_lo, iy_hi + 1)
        lo, hi = row_half_counts(self.design, rows)
        lo = np.maximum(lo, ix_lo)
        hi = np.minimum(hi, ix_hi)
        nonempty = rows[lo <= hi]
        if nonempty.size == 0:
            return []
        out = []
        br = self.band_rows
        y0, y1 = int(nonempty[0]), int(nonempty[-1])
        for iy0 in range(y0, y1 + 1, br):
            n = min(br, y1 + 1 - iy0)
            sel = slice(iy0 - iy_lo, iy0 - iy_lo + n)
            ok = lo[sel] <= hi[sel]
            if not ok.any():
                continue
            c0 = int(lo[sel][ok].min())
            c1 = int(hi[sel][ok].max())
            out.append((iy0, n, c0, c1 - c0 + 1))
        return out

    def tasks(self) -> list[tuple[int, int, int, int, int]]:
        """Export units ``(t, j0, rows, ix0, cols)``: mirror-row bands. Row ``j >= 0`` and its mirror
        ``m(j) = -j - 2o`` (``-j`` on the integer lattice, ``-1 - j`` on the half lattice) hold the same
        levels, so one evaluation of rows ``j0 .. j0 + rows - 1`` (columns ``ix0 ..``) serves both; rows
        outside the window are skipped when encoding (see :func:`task_rows`)."""
        iy_lo, iy_hi, ix_lo, ix_hi = self.window()
        if iy_lo > iy_hi or ix_lo > ix_hi:
            return []
        two_o = 0 if self.design.lattice == "integer" else 1
        jmax = max(abs(iy_lo), abs(iy_hi)) + 1
        j = np.arange(0, jmax + 1)
        m = -j - two_o
        inwin = ((j >= iy_lo) & (j <= iy_hi)) | ((m >= iy_lo) & (m <= iy_hi))
        lo, hi = row_half_counts(self.design, j)
        lo = np.maximum(lo, ix_lo)
        hi = np.minimum(hi, ix_hi)
        ok = inwin & (lo <= hi)
        if not ok.any():
            return []
        sel = np.flatnonzero(ok)
        out = []
        br = self.band_rows
        y0, y1 = int(sel[0]), int(sel[-1])
        for j0 in range(y0, y1 + 1, br):
            n = min(br, y1 + 1 - j0)
            okb = ok[j0:j0 + n]
            if not okb.any():
                continue
            c0 = int(lo[j0:j0 + n][okb].min())
            c1 = int(hi[j0:j0 + n][okb].max())
            out.append((len(out), j0, n, c0, c1 - c0 + 1))
        return out

    def key(self) -> dict[str, Any]:
        """JSON-able description of everything that determines the file content (the date is kept apart:
        :func:`metafovea.layout.frame.content_hash` leaves it out, the export journal stores it)."""
        from dataclasses import asdict
        design = asdict(self.design)
        if not design["phase_poly_rad"]:
            del design["phase_poly_rad"]  # the plain hyperbola: the same key (and content hash) as before the field
        return {"design": design, "widths_um": self.post_set.widths_um.tolist(),
                "levels": self.levels, "grid_nm": self.grid_nm, "layers": asdict(self.layers),
                "ring": [self.ring_inner_um, self.ring_outer_um], "marks": [self.mark_offset_um,
                self.mark_size_um, self.mark_width_um, self.mark_clearance_um],
                "verniers": [self.vernier_pitch_um, self.vernier_step_um, self.vernier_bars, self.vernier_length_um],
                "die": [self.die_margin_um, self.scribe_width_um], "label_height_um": self.label_height_um,
                "wafer": [self.wafer_diameter_mm, self.wafer_flat_distance_um, self.wafer_edge_exclusion_mm],
                "write_bias_um": self.write_bias_um, "tone": [self.posts_resist_tone, self.ring_resist_tone],
                "posts": self.post_set.source, "patch_um": self.patch_um, "band_rows": self.band_rows,
                "date": self.date}

    def tone_text(self) -> str:
        """The resist tones, in words (the label and the README say the same)."""
        return (f"tone: posts {self.posts_resist_tone} (polygons = silicon kept"
                + ("" if self.posts_resist_tone == "negative" else "; invert layer 1 at conversion") + "), ring "
                + f"{self.ring_resist_tone} lift-off (polygons = aluminium kept"
                + ("" if self.ring_resist_tone == "positive" else "; invert layer 2 at conversion") + ")")

    def label_text(self) -> str:
        from metafovea.layout.frame import content_hash

        d = self.design
        name = "".join(ch if (ch.isascii() and ch.isprintable()) else "?" for ch in d.name)  # ASCII text records
        ex = "; ".join(f"{k}: " + ",".join(f"{a}/{b}" for a, b in v) for k, v in self.layers.exposures().items())
        s = (f"metafovea {name} f={d.f_mm:g}mm D={d.diameter_mm:g}mm lambda={d.wavelength_um:g}um "
             f"pol={d.polarization} p={d.period_um:g}um N={self.levels} lattice={d.lattice} "
             f"grid={self.grid_nm}nm dbu=1nm centre=({self.centre_nm},{self.centre_nm})nm "
             f"posts={self.post_set.source} write_bias={self.write_bias_um:g}um "
             f"wafer={self.wafer_diameter_mm:g}mm date={self.date or 'none'} hash={content_hash(self)}")
        if d.phase_poly_rad:
            s += " phase_poly_rad=(" + ",".join(f"{a:.9g}" for a in d.phase_poly_rad) + ")rad"
        if self.patch_um is not None:
            s += " patch=({:g},{:g},{:g})um".format(*self.patch_um)
        return s + f" | {self.tone_text()} | {ex}"

    def printed_text(self) -> str:
        """The printed label's line (polygon text on the wafer): lens, focal length and aperture, polarisation,
        levels, post set, date and content hash."""
        from metafovea.layout.frame import content_hash

        d = self.design
        name = "".join(ch if (ch.isascii() and ch.isalnum()) else "-" for ch in d.name.upper())
        return (f"{name} F{d.f_mm:g} D{d.diameter_mm:g} POL-{d.polarization.upper()} N{self.levels} "
                f"{self.post_set.source.upper()} {self.date or 'NODATE'} #{content_hash(self)}")

    def label_position_nm(self) -> tuple[int, int]:
        if self.patch_um is None:
            c = self.centre_nm - int(round(self.ring_outer_um * NM_PER_UM))
            return c, c
        x, y, w = self.patch_um
        # the patch's lower-left corner, kept inside the chip frame [0, 2 C] (a patch wider than the
        # lens would otherwise put the label at negative coordinates, outside everything written)
        c = self.centre_nm
        return (min(2 * c, max(0, c + int(round((x - w / 2) * NM_PER_UM)))),
                min(2 * c, max(0, c + int(round((y - w / 2) * NM_PER_UM)))))


def lens_platform(design: LensDesign, platform: PlatformDesign | None = None) -> PlatformDesign:
    """The platform a lens is made on: ``platform``, or the default silicon platform with the lens' period and post
    height (its RCWA library and fabrication rules)."""
    if platform is not None:
        return platform
    return replace(PlatformDesign(), period_um=design.period_um, post_height_um=design.post_height_um,
                   wavelength_um=design.wavelength_um)


def drc_summary(spec: LayoutSpec, platform: PlatformDesign | None = None) -> dict[str, Any]:
    """The written posts against the platform's fabrication rules: smallest side and gap, largest aspect ratio
    (cell sizes on the manufacturing grid), each rule's limit and whether it is met."""
    plat = lens_platform(spec.design, platform)
    w = spec.post_sizes_nm / NM_PER_UM
    side = float(w.min())
    gap = float(spec.design.period_um - w.max())
    ar = float(spec.design.post_height_um / side)
    gap_min = plat.min_feature_um if plat.min_gap_um is None else plat.min_gap_um
    return {"min_side_um": side, "min_gap_um": gap, "max_aspect_ratio": ar,
            "rules": {"min_feature_um": plat.min_feature_um, "min_gap_um": gap_min,
                      "max_aspect_ratio": plat.max_aspect_ratio},
            "ok": bool(side >= plat.min_feature_um - 1e-9 and gap >= gap_min - 1e-9
                       and ar <= plat.max_aspect_ratio + 1e-9),
            "grid_nm": spec.grid_nm}


def drc_line(d: dict[str, Any]) -> str:
    """One line of :func:`drc_summary` for the export and verify summaries."""
    r = d["rules"]
    return (f"DRC {'OK' if d['ok'] else 'VIOLATED'}: smallest side {d['min_side_um']:.3f} um "
            f"(>= {r['min_feature_um']:g}), smallest gap {d['min_gap_um']:.3f} um (>= {r['min_gap_um']:g}), "
            f"aspect ratio {d['max_aspect_ratio']:.1f} (<= {r['max_aspect_ratio']:g}), on a {d['grid_nm']} nm grid")


def make_spec(design: LensDesign, post_set: PostSet | str | None = "rcwa", levels: int | None = None, *,
              grid_nm: int = 5, patch_mm: tuple[float, float, float] | None = None,
              band_rows: int = 32, platform: PlatformDesign | None = None, **kw: Any) -> LayoutSpec:
    """Validated :class:`LayoutSpec` (``patch_mm`` = centre x, centre y, width in mm).

    ``post_set``: a :class:`PostSet`, ``'rcwa'`` (default, also for None: the platform's RCWA post set for the
    lens' polarisation and levels, library computed once and cached: the posts a fab should write) or
    ``'ideal'`` (the idealised ramp of :meth:`PostSet.ideal`, not a physical design; the label says so). Posts
    that break the platform's fabrication rules (:meth:`PlatformDesign.fabrication_violations`) are refused."""
    n = design.levels if levels is None else check_int("levels", levels, 2, 256)
    plat = lens_platform(design, platform)
    if post_set is None or isinstance(post_set, str):
        src = check_choice("posts", post_set or "rcwa", ("rcwa", "ideal"))
        if src == "ideal":
            post_set = PostSet.ideal(n, period_um=design.period_um, polarization=design.polarization,
                                     height_um=design.post_height_um, wavelength_um=design.wavelength_um)
        else:
            from metafovea.library import rcwa_post_sets

            post_set = rcwa_post_sets(plat, [replace(design, levels=n)])[(design.polarization, n)]
    if post_set.source != "ideal":
        bad = plat.fabrication_violations(post_set.widths_um, post_set.height_um)
        if bad:
            raise InputError("post_set", f"{post_set.source} post set",
                             f"posts that meet the platform's fabrication rules ({bad[0]}"
                             + (f"; {len(bad) - 1} more" if len(bad) > 1 else "") + ")")
    if post_set.levels != n:
        raise InputError("levels", n, f"the number of posts in the post set ({post_set.levels})")
    if abs(post_set.period_um - design.period_um) > 1e-9:
        raise InputError("post_set", post_set.period_um, f"a post set for period {design.period_um:g} um")
    grid_nm = check_int("grid_nm", grid_nm, 1, 1000)
    band_rows = check_int("band_rows", band_rows, 1, 1 << 16)
    patch = None
    if patch_mm is not None:
        if len(patch_mm) != 3:
            raise InputError("patch_mm", patch_mm, "X,Y,W in mm (patch centre and width)")
        x, y, w = (float(v) for v in patch_mm)
        if not all(math.isfinite(v) for v in (x, y, w)) or w <= 0:
            raise InputError("patch_mm", patch_mm, "finite X,Y and W > 0 (mm)")
        patch = (x * 1000.0, y * 1000.0, w * 1000.0)
    for name, lo_incl in (("ring_width_um", False), ("ring_gap_um", True), ("mark_offset_um", True),
                          ("mark_size_um", False), ("mark_width_um", False)):
        if kw.get(name) is not None:
            kw[name] = check_range(name, kw[name], 0.0, MAX_COORD_NM / NM_PER_UM, unit="um", lo_inclusive=lo_incl)
    for name in ("wafer_diameter_mm", "wafer_flat_mm", "wafer_edge_exclusion_mm", "write_bias_um", "posts_resist_tone",
                 "ring_resist_tone"):
        if kw.get(name) is None:
            kw[name] = getattr(plat, name)
    if kw.get("date") is None:
        from metafovea.layout.frame import layout_date
        kw["date"] = layout_date()
    spec = LayoutSpec(design, post_set, n, grid_nm=grid_nm, patch_um=patch, band_rows=band_rows, **kw)
    if 2 * spec.centre_nm > MAX_COORD_NM:
        raise InputError("ring_width_um" if "ring_width_um" in kw else "diameter_mm",
                         kw.get("ring_width_um", design.diameter_mm),
                         f"a layout frame (lens diameter + 2 x (ring gap + ring width + marks) = "
                         f"{2 * spec.frame_half_um / 1000:.6g} mm) of at most {MAX_COORD_NM / 1e6:.6g} mm: "
                         "GDSII/OASIS coordinates are 32-bit integers of 1 nm")
    if patch is None:
        from metafovea.layout.frame import frame_shapes
        frame_shapes(spec)  # the die must fit the wafer: an InputError naming wafer_diameter_mm if not
    if np.any(spec.post_sizes_nm >= spec.design.period_um * NM_PER_UM):
        raise InputError("grid_nm", grid_nm, "a grid on which the post widths stay below the period")
    if patch is not None and not spec.bands():
        x, y, w = patch
        R = design.radius_um
        # nearest point of the square to the lens centre: inside the aperture means it only misses the sites
        dx, dy = max(abs(x) - w / 2, 0.0), max(abs(y) - w / 2, 0.0)
        if math.hypot(dx, dy) < R:
            raise InputError("patch_mm", patch_mm, f"a square holding at least one of the lens' lattice sites "
                             f"(sites every {design.period_um:g} um, {design.lattice} lattice; this one holds none: "
                             "widen or move it)")
        raise InputError("patch_mm", patch_mm, f"a square that overlaps the lens aperture (radius "
                         f"{R / 1000:g} mm around 0,0)")
    return spec


def load_spec(design: str | os.PathLike | LensDesign, post_set: str | os.PathLike | PostSet | None = None,
              levels: int | None = None, *, posts: str = "rcwa", **kw: Any) -> LayoutSpec:
    """:func:`make_spec` from a lens design file and an optional PostSet ``.npz`` (as ``metafovea export`` and
    ``metafovea verify`` read them; objects are accepted too). The post set must be for the design's
    polarisation and, with ``levels``, hold that many posts; ``levels`` defaults to the post set's, else the
    design's. Without a post set, ``posts`` ('rcwa', default, or 'ideal') says which. ``kw``: :func:`make_spec`'s
    keywords."""
    d = design if isinstance(design, LensDesign) else load_design(design)
    if not isinstance(d, LensDesign):
        raise InputError("design", design, "a lens design file (with f_mm, diameter_mm, ...)")
    ps: Any = check_choice("posts", posts, ("rcwa", "ideal"))
    if post_set:
        if isinstance(post_set, PostSet):
            ps = post_set
        else:
            ps = PostSet.load(post_set, name="post_set")
        if levels is not None and levels != ps.levels:
            raise InputError("levels", levels, f"the number of posts in {post_set} ({ps.levels})")
        if ps.polarization != d.polarization:
            raise InputError("post_set", post_set, f"a post set for polarisation {d.polarization!r}")
    if levels is None and isinstance(ps, PostSet):
        levels = ps.levels
    return make_spec(d, ps, levels, **kw)


# ----------------------------------------------------------------------------------------------
# site levels per band
# ----------------------------------------------------------------------------------------------
def _levels_inplace(design: LensDesign, iy0: int, rows: int, ix0: int, cols: int, levels: int) -> np.ndarray:
    """Bit-identical to ``evaluate_tile(...).levels`` (same floating-point operations in the same order,
    see :func:`metafovea.lens.evaluate_tile`), computed in place with few temporaries."""
    n = levels
    o = 0.0 if design.lattice == "integer" else 0.5
    p = design.period_um
    x = (np.arange(ix0, ix0 + cols, dtype=float) + o) * p
    y = (np.arange(iy0, iy0 + rows, dtype=float) + o) * p
    a = np.hypot(x[None, :], y[:, None])  # r
    extra = added_phase(design, a) if design.phase_poly_rad else None  # the phase beyond the hyperbola
    np.square(a, out=a)  # r2
    b = a + design.f_um * design.f_um
    np.sqrt(b, out=b)
    b += design.f_um
    a *= design.phase_sign * (TWO_PI / design.wavelength_um)
    a /= b  # phi
    if extra is not None:
        a += extra
    np.mod(a, TWO_PI, out=a)
    a[a >= TWO_PI] = 0.0  # wrap_phase
    a *= n / TWO_PI
    a += 0.5
    np.floor(a, out=a)
    k = a.astype(np.int64)
    np.mod(k, n, out=k)
    lev = k.astype(np.int16)
    lo, hi = row_half_counts(design, np.arange(iy0, iy0 + rows))
    ix = np.arange(ix0, ix0 + cols)
    lev[(ix[None, :] < lo[:, None]) | (ix[None, :] > hi[:, None])] = EMPTY
    return lev


def band_levels(design: LensDesign, iy0: int, rows: int, ix0: int, cols: int, levels: int) -> np.ndarray:
    """Same as ``evaluate_tile(design, iy0, ix0, rows, cols, levels=levels).levels`` (int16), computed
    on the columns with x >= 0 and mirrored (site ``ix`` mirrors to ``-ix - 2o``)."""
    two_o = 0 if design.lattice == "integer" else 1
    ix = np.arange(ix0, ix0 + cols)
    j = np.where(2 * ix + two_o >= 0, ix, -ix - two_o)
    j0, j1 = int(j.min()), int(j.max())
    half = _levels_inplace(design, iy0, rows, j0, j1 - j0 + 1, levels)
    if j0 == ix0 and j1 == ix0 + cols - 1 and np.all(np.diff(j) == 1):
        return half
    return half[:, j - j0]


@dataclass
class Expected:
    """Expected content of a layout: posts per type and the posts' bounding box (nm)."""

    counts: np.ndarray
    posts_bbox_nm: tuple[int, int, int, int] | None

    @property
    def total(self) -> int:
        return int(self.counts.sum())


def post_count(spec: LayoutSpec) -> int:
    """Posts the layout of ``spec`` holds: the lattice sites inside the aperture and the window (exact, from the
    rows' site ranges: no level is computed)."""
    iy_lo, iy_hi, ix_lo, ix_hi = spec.window()
    if iy_lo > iy_hi or ix_lo > ix_hi:
        return 0
    lo, hi = row_half_counts(spec.design, np.arange(iy_lo, iy_hi + 1))
    return int(np.maximum(np.minimum(hi, ix_hi) - np.maximum(lo, ix_lo) + 1, 0).sum())


def task_post_counts(spec: LayoutSpec, task: tuple[int, int, int, int, int]) -> list[int]:
    """Posts of each row side of ``task`` (in :func:`task_rows`' order), from the rows' site ranges alone: what an
    encoder writes for it, known before its levels are computed."""
    _, j0, rows, _, _ = task
    _, _, ix_lo, ix_hi = spec.window()
    lo, hi = row_half_counts(spec.design, np.arange(j0, j0 + rows))
    n = np.maximum(np.minimum(hi, ix_hi) - np.maximum(lo, ix_lo) + 1, 0)
    return [int(n[mask].sum()) for _, mask, _ in task_rows(spec, task)]


def task_rows(spec: LayoutSpec, task: tuple[int, int, int, int, int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each row side (+1, then -1): ``(side, mask, ys)``, the task's local rows written on that side
    (bool per row) and their site y positions (nm, int64). Sides with no row are left out."""
    _, j0, rows, _, _ = task
    iy_lo, iy_hi, _, _ = spec.window()
    two_o = 0 if spec.design.lattice == "integer" else 1
    j = np.arange(j0, j0 + rows)
    out = []
    for side, iy, extra in ((1, j, True), (-1, -j - two_o, (-j - two_o) != j)):
        mask = (iy >= iy_lo) & (iy <= iy_hi) & extra
        if mask.any():
            out.append((side, mask, spec.site_y_nm(iy)))
    return out


def window_levels(spec: LayoutSpec, band: tuple[int, int, int, int]) -> tuple[np.ndarray, int]:
    """Levels of the band ``(iy0, rows, ix0, cols)`` (int16, EMPTY outside the aperture) on the columns inside the
    window (:meth:`LayoutSpec.window`: a patch clips them), and the first column index."""
    iy0, rows, ix0, cols = band
    lev = band_levels(spec.design, iy0, rows, ix0, cols, spec.levels)
    _, _, ix_lo, ix_hi = spec.window()
    if ix0 < ix_lo or ix0 + cols - 1 > ix_hi:
        a, b = max(ix0, ix_lo), min(ix0 + cols - 1, ix_hi)
        lev = np.ascontiguousarray(lev[:, a - ix0:b - ix0 + 1])
        ix0 = a
    return lev, ix0


def task_levels(spec: LayoutSpec, task: tuple[int, int, int, int, int]) -> tuple[np.ndarray, int]:
    """Levels of the task's rows ``j0 ..`` on the window's columns, and the first column index
    (:func:`window_levels` of the task's band)."""
    return window_levels(spec, task[1:])


def _task_summary(spec: LayoutSpec, task: tuple[int, int, int, int, int]) -> tuple[np.ndarray, list[int]]:
    lev, ix0 = task_levels(spec, task)
    sides = task_rows(spec, task)
    counts = np.zeros(spec.levels, dtype=np.int64)
    w = np.zeros(lev.shape[0], dtype=np.int64)
    for _, mask, _ in sides:
        w += mask
    for m in (1, 2):
        sub = lev[w == m]
        counts += m * np.bincount(sub[sub >= 0].astype(np.int64), minlength=spec.levels)
    r, c = np.nonzero((lev >= 0) & (w > 0)[:, None])
    if r.size == 0:
        return counts, [0, 0, -1, -1]
    k = lev[r, c]
    sz = spec.post_sizes_nm
    xs = spec.site_x_nm(np.arange(ix0, ix0 + lev.shape[1]))
    x0 = int((xs[c] - sz[k, 0] // 2).min())
    x1 = int((xs[c] + sz[k, 0] // 2).max())
    hh = sz[k, 1] // 2
    y0 = y1 = None
    for _, mask, ys in sides:
        sel = mask[r]
        if not sel.any():
            continue
        yy = ys[r[sel]]
        a, b = int((yy - hh[sel]).min()), int((yy + hh[sel]).max())
        y0 = a if y0 is None else min(y0, a)
        y1 = b if y1 is None else max(y1, b)
    return counts, [x0, y0, x1, y1]


#: posts counted per second and core (~16 M/s on the 2-core machine) times the ~1 s a worker process takes to start:
#: :func:`expected_content` gives a design one worker per this many posts at most (fewer would cost more to start)
POSTS_PER_WORKER = 16_000_000


def expected_content(spec: LayoutSpec, *, workers: int | None = None, scheduler: str | None = None,
                     progress: bool = False) -> Expected:
    """Count posts per type and the posts' bounding box from the design (band by band).

    ``workers``: local processes; None (the default of every ``--workers``): one per core, but no more than one per
    :data:`POSTS_PER_WORKER` posts (a small design is counted in this process)."""
    from functools import partial

    from metafovea.parallel import default_workers, run_tasks

    if workers is None and scheduler is None:
        workers = max(1, min(default_workers(), -(-post_count(spec) // POSTS_PER_WORKER)))
    bands = spec.tasks()
    counts = np.zeros(spec.levels, dtype=np.int64)
    bb = [None, None, None, None]
    for _, (c, b) in run_tasks(partial(_task_summary, spec), bands, workers=workers, scheduler=scheduler,
                               progress=progress, desc="expected"):
        counts += c
        if b[2] < b[0]:
            continue
        bb = [b[0] if bb[0] is None else min(bb[0], b[0]), b[1] if bb[1] is None else min(bb[1], b[1]),
              b[2] if bb[2] is None else max(bb[2], b[2]), b[3] if bb[3] is None else max(bb[3], b[3])]
    return Expected(counts, None if bb[0] is None else tuple(bb))  # type: ignore[arg-type]


# ----------------------------------------------------------------------------------------------
# frame geometry (ring, marks, label), in nm
# ----------------------------------------------------------------------------------------------
def used_levels(spec: LayoutSpec) -> list[int]:
    """The post types a layout references: all of them for the full lens, those the patch's sites use for a patch
    (a file defines only these cells, so no unused cell shows up as an extra top cell)."""
    if spec.patch_um is None:
        return list(range(spec.levels))
    return [int(k) for k in np.flatnonzero(expected_content(spec, workers=1).counts)]


def has_frame(spec: LayoutSpec) -> bool:
    return spec.patch_um is None


__all__ = ["DBU_UM", "EMPTY", "Expected", "Layers", "LayoutSpec", "MAX_COORD_NM", "band_levels", "expected_content",
           "has_frame", "load_spec", "make_spec", "post_count", "task_levels", "task_post_counts", "task_rows",
           "used_levels", "window_levels"]
