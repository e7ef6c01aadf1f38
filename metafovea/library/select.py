"""Birefringent post selection (the paper's Fig. 7c): one lens' N posts from a :class:`~.sweep.Library`.

:func:`select_posts` chooses, for the lens that focuses one polarisation, the posts whose focusing phase steps by
``2 pi / N`` while the other polarisation's phase stays constant and both transmit well: for the nominal widths
(a grid search over the two free phase offsets) or, with ``bias_weight`` > 0, jointly over the platform's -/0/+
edge-bias cases (:class:`_JointCost`). :func:`usable_posts` is the set it may choose from; :func:`bias_table`
solves a chosen set under the edge bias by RCWA.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from metafovea.config import POLARIZATIONS, PlatformDesign
from metafovea.errors import InputError, check_choice, check_int, check_range

from .postset import PostSet
from .sweep import DEFAULT_HARMONICS, Library, _stack


def _wrap(a: np.ndarray) -> np.ndarray:
    """Wrap to (-pi, pi]."""
    return np.angle(np.exp(1j * a))


def _wavelength_index(lib: Library, wavelength_um: float | None) -> int:
    """Index of ``wavelength_um`` in the library (None: its only wavelength, else the design wavelength its meta
    states; a library of several wavelengths that states none is an :class:`InputError` on ``wavelength_um``)."""
    if wavelength_um is None and lib.wavelengths_um.size == 1:
        return 0
    if wavelength_um is None:
        wavelength_um = lib.meta.get("design_wavelength_um")
        if wavelength_um is None:
            raise InputError("wavelength_um", None, f"one of the library wavelengths {lib.wavelengths_um.tolist()} "
                             "(the library has several and states no design wavelength)")
    return lib.index_of_wavelength(float(wavelength_um))


def usable_posts(lib: Library, wavelength_um: float | None = None, *, max_error: float | None = 0.05) -> np.ndarray:
    """(n_wx, n_wy) bool: posts :func:`select_posts` may use at ``wavelength_um`` (finite t for both
    polarisations and, with ``max_error``, a convergence estimate of at most ``max_error``)."""
    il = _wavelength_index(lib, wavelength_um)
    ok = np.isfinite(lib.t_x[il]) & np.isfinite(lib.t_y[il])
    if max_error is not None:
        ok &= ~(np.fmax(lib.err_x[il], lib.err_y[il]) > max_error)
    return ok


def _fabricable(lib: Library, platform: PlatformDesign, WX: np.ndarray, WY: np.ndarray) -> np.ndarray:
    """(n_wx, n_wy) bool: posts that meet the platform's fabrication rules."""
    h = float(_stack(lib, "height_um"))
    fab = np.array([not platform.fabrication_violations([[a, b]], h) for a, b in zip(WX.ravel(), WY.ravel())])
    return fab.reshape(WX.shape)


#: the edge-bias cases of the tolerant selection and of :func:`bias_table`: name and sign of the per-side bias
BIAS_CASES = (("-", -1.0), ("0", 0.0), ("+", 1.0))
#: most coordinate-descent rounds of the joint search; a start whose round does not lower the cost stops (on the
#: paper's 31 x 31 library, 8 levels, the last of ~900 starts stops after 13-18 rounds)
JOINT_MAX_ROUNDS = 50
#: ends of the coordinate descent that the swap search of the joint search starts from (the best ones)
JOINT_POLISH = 8
#: the largest ``bias_weight``: the bias cases against the nominal one weighted 1; at 1e6 the nominal case has no say
#: left in double precision sums of phase errors, and 1e308 overflowed (the nominal selection came back, claimed joint)
MAX_BIAS_WEIGHT = 1e6


def _candidates(lib: Library, wavelength_um: float | None, max_error: float | None, platform: PlatformDesign | None,
                N: int, WX: np.ndarray, WY: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(n_wx, n_wy) bool masks of the usable (converged) posts and of those :func:`select_posts` may choose (usable
    and, with ``platform``, within its fabrication rules), and how many the rules excluded; fewer than ``N``
    candidates is an :class:`InputError`."""
    usable = usable_posts(lib, wavelength_um, max_error=max_error)
    ok = usable.copy()
    n_rules = 0
    if platform is not None:
        fab = _fabricable(lib, platform, WX, WY)  # posts that break a fabrication rule are never chosen
        n_rules = int(np.count_nonzero(ok & ~fab))
        ok &= fab
    if np.count_nonzero(ok) < N:
        raise InputError("library", int(np.count_nonzero(ok)), f"at least levels = {N} usable (converged) posts"
                         + (" that meet the platform's fabrication rules" if platform is not None else ""))
    return usable, ok, n_rules


def _wrap_fast(a: np.ndarray) -> np.ndarray:
    """Wrap to [-pi, pi) in real arithmetic, for squared costs (5x faster than :func:`_wrap`, which the nominal
    search keeps: its numbers must not move by a rounding)."""
    return np.mod(a + np.pi, 2 * np.pi) - np.pi


def _best_offsets(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``a`` (M, N) the phi that minimises ``sum_k wrap(a_k - phi)^2``, and that minimum, exactly:
    between the antipodes of the points the sum is a quadratic in phi and at an antipode it has a peak, so its
    minimum is the plain mean of one of the N unwrappings of the sorted angles (each starting at one of them)."""
    s = np.sort(np.mod(np.asarray(a, dtype=float), 2 * np.pi), axis=-1)
    n = s.shape[-1]
    # unwrapping j of a row starts at its j-th angle: the angles before it go up by 2 pi
    means = (s[:, None, :] + 2 * np.pi * (np.arange(n)[None, :] < np.arange(n)[:, None])).mean(-1)  # (M, N)
    cost = np.sum(_wrap_fast(s[:, None, :] - means[:, :, None]) ** 2, -1)
    j = np.argmin(cost, -1)
    rows = np.arange(s.shape[0])
    return _wrap(means[rows, j]), cost[rows, j]


def _biased_t(lib: Library, tf_all: np.ndarray, tp_all: np.ndarray, usable: np.ndarray, WX: np.ndarray,
              WY: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """(3, n_wx, n_wy) focusing and pass-through t of every library post in the cases of :data:`BIAS_CASES`
    (widths -2 delta, 0, +2 delta), the library interpolated bilinearly: exact where 2 delta is a multiple of the
    grid step (the biased posts are grid points, as for the paper's 50 nm on a 0.1 um grid). NaN where a biased
    post leaves the grid or needs a post that is not usable (not converged)."""
    out_f, out_p = [], []
    for _, sgn in BIAS_CASES:
        if sgn == 0:
            out_f.append(tf_all)
            out_p.append(tp_all)
            continue
        wx, wy = np.round(WX + sgn * 2 * delta, 9), np.round(WY + sgn * 2 * delta, 9)
        # every corner with weight must be usable (NaN outside the grid compares False)
        inside = _interp_t(lib, usable.astype(float), wx, wy).real > 1 - 1e-9
        for t_all, out in ((tf_all, out_f), (tp_all, out_p)):
            out.append(np.where(inside, _interp_t(lib, np.where(usable, t_all, 0), wx, wy), np.nan))
    return np.stack(out_f), np.stack(out_p)


def _offset_grid_search(af: np.ndarray, ap: np.ndarray, loss: np.ndarray, targets: np.ndarray, offs: np.ndarray,
                        pw: float) -> tuple[np.ndarray, np.ndarray]:
    """The nominal search: for each focusing offset ``offs[i]`` the best pass-through offset on the same grid, its
    total cost ``vals[i]`` and each level's post ``choices[i]`` (argmin of the per-level cost)."""
    cp = pw * _wrap(ap[None, :] - offs[:, None]) ** 2 + loss[None, :]  # pass-through cost for every psi: (n_off, C)
    vals = np.empty(offs.size)
    choices = np.empty((offs.size, targets.size), dtype=int)
    for i0, phi0 in enumerate(offs):
        cf = _wrap(af[None, :] - phi0 - targets[:, None]) ** 2          # (N, C)
        tot = cf[None, :, :] + cp[:, None, :]                            # (n_off psi, N, C)
        idx = np.argmin(tot, axis=-1)                                    # (n_off, N)
        val = np.take_along_axis(tot, idx[..., None], -1)[..., 0].sum(-1)
        j = int(np.argmin(val))
        vals[i0], choices[i0] = val[j], idx[j]
    return vals, choices


@dataclass(frozen=True)
class _JointCost:
    """The joint cost of :func:`select_posts` over the bias cases: candidates' phases ``af``, ``ap`` and
    transmission losses ``loss`` (each (3, C), cases in :data:`BIAS_CASES` order), case weights ``wts``."""

    af: np.ndarray
    ap: np.ndarray
    loss: np.ndarray
    targets: np.ndarray
    pw: float
    wts: tuple[float, float, float]

    def best_posts(self, offsets: np.ndarray, chunk: int = 64) -> np.ndarray:
        """(M, N) each level's cheapest candidate for each row of case offsets ``(phi_b, psi_b)`` (M, 3, 2); a
        candidate's cost at level k is the sum over cases of
        ``w_b [wrap(arg t_f - phi_b - 2 pi k/N)^2 + pw wrap(arg t_p - psi_b)^2 + loss]``."""
        out = np.empty((offsets.shape[0], self.targets.size), dtype=int)
        for i in range(0, offsets.shape[0], chunk):
            off = offsets[i:i + chunk]
            cost = np.zeros((off.shape[0], self.targets.size, self.af.shape[1]))
            for b, w in enumerate(self.wts):
                cost += w * _wrap_fast(self.af[b] - off[:, b, 0, None, None] - self.targets[:, None]) ** 2
                cost += w * (self.pw * _wrap_fast(self.ap[b] - off[:, b, 1, None]) ** 2 + self.loss[b])[:, None, :]
            out[i:i + chunk] = np.argmin(cost, -1)
        return out

    def of(self, choices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cost (M,) of each row of ``choices`` (M, N candidate indices) with each case's best offsets (exact),
        and those offsets (M, 3, 2)."""
        cost = np.zeros(choices.shape[0])
        offsets = np.zeros((choices.shape[0], len(self.wts), 2))
        for b, w in enumerate(self.wts):
            offsets[:, b, 0], f = _best_offsets(self.af[b][choices] - self.targets[None, :])
            offsets[:, b, 1], p = _best_offsets(self.ap[b][choices])
            cost += w * (f + self.pw * p + self.loss[b][choices].sum(-1))
        return cost, offsets

    def descend(self, choices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coordinate descent from each row of ``choices`` (M, N candidate indices): the cases' offsets for the
        chosen posts (exact), then each level's post for those offsets (exact), while the cost falls (so it ends);
        the ends (M, N) and their costs (M,)."""
        choices = np.array(choices, dtype=int)
        cost, off = self.of(choices)
        active = np.arange(choices.shape[0])
        for _ in range(JOINT_MAX_ROUNDS):
            if active.size == 0:
                break
            new = self.best_posts(off[active])
            new_cost, new_off = self.of(new)
            down = new_cost < cost[active]
            moved = active[down]
            choices[moved], cost[moved], off[moved] = new[down], new_cost[down], new_off[down]
            active = moved
        return choices, cost

    def swap(self, choice: np.ndarray, cost: float) -> tuple[np.ndarray, float]:
        """Local search from ``choice``: the best change of one level's post (every level, every candidate, the
        offsets re-optimised), then coordinate descent, while the cost falls; the end and its cost."""
        n, n_c = choice.size, self.af.shape[1]
        for _ in range(JOINT_MAX_ROUNDS):
            trial = np.repeat(choice[None, :], n * n_c, 0)
            trial[np.arange(n * n_c), np.repeat(np.arange(n), n_c)] = np.tile(np.arange(n_c), n)
            costs = self.of(trial)[0]
            i = int(np.argmin(costs))
            if not costs[i] < cost - 1e-12:
                break
            ends, end_cost = self.descend(trial[i:i + 1])
            choice, cost = ends[0], float(end_cost[0])
        return choice, float(cost)

    def search(self, starts: np.ndarray, n_polish: int = JOINT_POLISH) -> dict[str, Any]:
        """The lowest cost found: coordinate descent from every start (rows of ``starts``, N candidate indices each;
        repeated rows once) and from each candidate as the anchor of level 0 (its own phases in every case as the
        offsets: the optimum's offsets lie within the residuals of each of its posts), then the swap search
        from the ``n_polish`` best ends. The first start wins a tie."""
        anchors = self.best_posts(np.stack([self.af, self.ap], -1).transpose(1, 0, 2))
        rows = np.concatenate([np.asarray(starts, dtype=int).reshape(-1, self.targets.size), anchors])
        rows = rows[np.sort(np.unique(rows, axis=0, return_index=True)[1])]
        ends, cost = self.descend(rows)
        first = np.sort(np.unique(ends, axis=0, return_index=True)[1])  # each distinct end at its first start
        best = first[np.argsort(cost[first], kind="stable")[:n_polish]]
        polished = [self.swap(ends[i], float(cost[i])) for i in best]
        k = min(range(len(polished)), key=lambda j: polished[j][1])
        return {"cost": polished[k][1], "choice": polished[k][0], "starts": int(rows.shape[0]), "ends": int(first.size),
                "polished": int(best.size)}


def _case_figures(tf: np.ndarray, tp: np.ndarray, targets: np.ndarray) -> dict[str, Any]:
    """Figures of merit of N posts in one bias case: focusing phase error after removing the shift common to all
    levels (a lens does not see it; ``shift_rad``), expected focusing efficiency, pass-through phase about its
    mean (per level and its spread) and mean transmissions."""
    shift = np.angle(np.sum(np.exp(1j * (np.angle(tf) - targets))))
    err = _wrap(np.angle(tf) - shift - targets)
    pp = _wrap(np.angle(tp) - np.angle(np.mean(tp)))
    return {"rms_phase_error_rad": float(np.sqrt(np.mean(err ** 2))),
            "max_abs_phase_error_rad": float(np.max(np.abs(err))),
            "expected_focusing_efficiency": float(abs(np.mean(tf * np.exp(-1j * targets))) ** 2
                                                  * np.sinc(1.0 / targets.size) ** 2),
            "pass_phase_spread_rad": float(np.max(pp) - np.min(pp)),
            "mean_T_focus": float(np.mean(np.abs(tf) ** 2)), "mean_T_pass": float(np.mean(np.abs(tp) ** 2)),
            "shift_rad": float(shift), "phase_error_rad": err.tolist(), "pass_phase_rad": pp.tolist()}


def _tolerance_info(tf3: np.ndarray, tp3: np.ndarray, targets: np.ndarray, delta: float, bias_weight: float,
                    n_excluded: int, search: dict[str, Any] | None) -> dict[str, Any]:
    """``info['tolerance']`` of a selection: the chosen posts' figures in each bias case (tf3, tp3: (3, N)) as the
    library's interpolation sees them (None for a case whose biased posts leave the library), the worst case, and
    the joint search's cost (and that of the nominal choice), its starts, distinct descent ends and polished ends."""
    cases: dict[str, Any] = {}
    for b, (name, _) in enumerate(BIAS_CASES):
        ok = bool(np.all(np.isfinite(tf3[b])) and np.all(np.isfinite(tp3[b])))
        cases[name] = ({k: v for k, v in _case_figures(tf3[b], tp3[b], targets).items() if k != "shift_rad"}
                       if ok else None)
    done = [c for c in cases.values() if c is not None]
    out = {"delta_um": delta, "bias_weight": bias_weight,
           "case_weights": {"-": bias_weight, "0": 1.0, "+": bias_weight},
           "source": "library, bilinear (exact where 2 delta is a multiple of the grid step)", "cases": cases,
           "worst_expected_focusing_efficiency": min(c["expected_focusing_efficiency"] for c in done),
           "worst_rms_phase_error_rad": max(c["rms_phase_error_rad"] for c in done),
           "worst_max_abs_phase_error_rad": max(c["max_abs_phase_error_rad"] for c in done),
           "worst_pass_phase_spread_rad": max(c["pass_phase_spread_rad"] for c in done),
           "posts_excluded": n_excluded}
    if search is not None:
        out.update(joint_cost=search["cost"], nominal_choice_joint_cost=search["start_cost"], starts=search["starts"],
                   descent_ends=search["ends"], polished=search["polished"])
    return out


def select_posts(lib: Library, polarization: str, levels: int = 8, *, wavelength_um: float | None = None,
                 pass_weight: float = 1.0, transmission_weight: float = 0.5, max_error: float | None = 0.05,
                 n_offsets: int = 72, platform: PlatformDesign | None = None,
                 bias_weight: float = 0.0) -> PostSet:
    """Choose ``levels`` posts for the lens that focuses ``polarization``.

    Level k must give the focusing polarisation the phase ``phi0 + 2 pi k / N`` (phi0 free), while the
    pass-through polarisation keeps a phase ``psi`` (free) as constant as possible and both
    transmissions are high. For every (phi0, psi) on an ``n_offsets`` x ``n_offsets`` grid each level
    takes the post minimising

        wrap(arg t_f - phi0 - 2 pi k/N)^2 + pass_weight * wrap(arg t_p - psi)^2
        + transmission_weight * ((1 - |t_f|^2) + (1 - |t_p|^2))

    and the (phi0, psi) with the smallest total wins. Posts whose convergence estimate exceeds
    ``max_error`` are not used. The stored t are rotated by the offsets (``t_f e^{-i phi0}``,
    ``t_p e^{-i psi}``), so level k has arg t_focus ~ 2 pi k / N; the offsets and figures of merit are
    in ``info``: per-level phase errors (rad), pass-through phase spread (max - min, rad, and rms),
    zero-order efficiencies, and the expected focusing efficiency
    ``|mean_k t_f,k e^{-i 2 pi k/N}|^2 sinc^2(1/N)`` (equal-area levels; the sinc is the N-level
    quantisation loss) and pass-through coherent transmission ``|mean_k t_p,k|^2``.

    With ``platform``, posts that break its fabrication rules are not used, and ``info['tolerance']`` gives the
    chosen posts in the three cases of its edge bias delta = ``edge_bias_um`` per side (widths -2 delta, 0,
    +2 delta; :data:`BIAS_CASES`) as the library sees them (:func:`bias_table` solves them by RCWA).

    ``bias_weight`` = w > 0 (with such a platform) chooses jointly over the three cases: the cost is the sum over
    the cases of the cost above, each case with its own t (the biased posts) and its own free offsets
    (phi0_b, psi_b) (a shift common to all levels does no harm), the nominal case weighted 1, each biased one w.
    Posts whose biased widths leave the library are not used (``info['tolerance']['posts_excluded']``). It is
    minimised by coordinate descent (each case's offsets for the chosen posts, exactly; then each level's post for
    those offsets, exactly; while the cost falls) from the grid search's best psi of each phi0 and from every post
    as the anchor of level 0, then a one-post swap search from the best ends (on small libraries: the exhaustive
    optimum). The trade-off on the paper's library (RCWA at the biased widths, BENCHMARKS.md): w >= 0.5 raises the
    worst biased focusing efficiency from 0.623 to 0.639 and lowers the worst biased rms phase error from 0.32 to
    0.23 rad for 0.020 of nominal efficiency (0.699 -> 0.679); w = 0.11-0.25: 0.641 and 0.25 rad for 0.013; below
    0.11 the nominal choice. w = 0 (the default) is the nominal grid search alone.
    """
    pol = check_choice("polarization", polarization, POLARIZATIONS)
    N = check_int("levels", levels, 2, 64)
    pw = check_range("pass_weight", pass_weight, 0.0, None, lo_inclusive=True)
    tw = check_range("transmission_weight", transmission_weight, 0.0, None, lo_inclusive=True)
    n_off = check_int("n_offsets", n_offsets, 4, 720)
    bias_weight = check_range("bias_weight", bias_weight, 0.0, MAX_BIAS_WEIGHT, lo_inclusive=True)
    il = _wavelength_index(lib, wavelength_um)
    tf_all = (lib.t_x if pol == "x" else lib.t_y)[il]
    tp_all = (lib.t_y if pol == "x" else lib.t_x)[il]
    WX, WY = np.meshgrid(lib.wx_um, lib.wy_um, indexing="ij")
    usable, ok, n_rules = _candidates(lib, wavelength_um, max_error, platform, N, WX, WY)
    delta = 0.0 if platform is None else platform.edge_bias_um
    tf3 = tp3 = None
    n_bias = 0
    if delta > 0:
        tf3, tp3 = _biased_t(lib, tf_all, tp_all, usable, WX, WY, delta)
        if bias_weight > 0:  # the joint search needs every case of every candidate
            inside = np.all(np.isfinite(tf3) & np.isfinite(tp3), axis=0)
            n_bias = int(np.count_nonzero(ok & ~inside))
            ok &= inside
            if np.count_nonzero(ok) < N:
                raise InputError("edge_bias_um", delta,
                                 f"a bias that leaves at least levels = {N} posts inside the library")
    tf, tp = tf_all[ok], tp_all[ok]
    wxc, wyc = WX[ok], WY[ok]
    specular = _specular(lib, il, ok)
    af, ap = np.angle(tf), np.angle(tp)
    loss = tw * ((1 - np.abs(tf) ** 2) + (1 - np.abs(tp) ** 2))
    targets = 2 * np.pi * np.arange(N) / N
    offs = 2 * np.pi * np.arange(n_off) / n_off
    vals, choices = _offset_grid_search(af, ap, loss, targets, offs, pw)
    choice = choices[int(np.argmin(vals))]
    search = None
    if tf3 is not None and bias_weight > 0:
        tfc, tpc = tf3[:, ok], tp3[:, ok]
        joint = _JointCost(np.angle(tfc), np.angle(tpc), tw * ((1 - np.abs(tfc) ** 2) + (1 - np.abs(tpc) ** 2)),
                           targets, pw, (bias_weight, 1.0, bias_weight))
        search = {**joint.search(choices[np.argsort(vals, kind="stable")]),
                  "start_cost": float(joint.of(choice[None])[0][0])}
        choice = search["choice"]
    tfs, tps, figures = _rotated_figures(tf[choice], tp[choice], targets)
    widths = np.stack([wxc[choice], wyc[choice]], 1)
    t_x, t_y = (tfs, tps) if pol == "x" else (tps, tfs)
    info = {
        "method": ("grid search over (phi0, psi); per-level argmin of phase + pass + transmission cost"
                   if search is None
                   else "joint search over the -delta/0/+delta edge-bias cases (each with free offsets; biased cases "
                        "weighted bias_weight): coordinate descent from the grid search's best psi of each phi0 and "
                        "from every post as the anchor of level 0, then a one-post swap search from the best ends"),
        "wavelength_um": float(lib.wavelengths_um[il]), "levels": N, **figures,
        "weights": {"pass": pw, "transmission": tw}, "max_error": max_error,
        "bias_weight": bias_weight,
        "tolerance": None if tf3 is None else _tolerance_info(
            tf3[:, ok][:, choice], tp3[:, ok][:, choice], targets, delta, bias_weight, n_bias, search),
        "fabrication_rules": None if platform is None else {
            "min_feature_um": platform.min_feature_um,
            "min_gap_um": platform.min_feature_um if platform.min_gap_um is None else platform.min_gap_um,
            "max_aspect_ratio": platform.max_aspect_ratio, "posts_excluded": n_rules},
        "library_key": lib.meta.get("key"), "harmonics": lib.meta.get("harmonics"),
        "incidence": lib.meta.get("incidence"),
    }
    return PostSet(pol, float(_stack(lib, "period_um")), float(_stack(lib, "height_um")),
                   float(lib.wavelengths_um[il]), widths, t_x, t_y, source="rcwa", info=info,
                   R_x=None if specular["x"] is None else specular["x"][choice],
                   R_y=None if specular["y"] is None else specular["y"][choice])


def _rotated_figures(tf: np.ndarray, tp: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """The chosen posts' t (N,) rotated by their offsets (circular means: arg t_f ~ 2 pi k / N, arg t_p ~ 0) and
    the figures of merit :func:`select_posts` puts in ``info``."""
    phi0 = float(np.angle(np.sum(np.exp(1j * (np.angle(tf) - targets)))))
    psi = float(np.angle(np.sum(np.exp(1j * np.angle(tp)))))
    tfs = tf * np.exp(-1j * phi0)
    tps = tp * np.exp(-1j * psi)
    ph_err = _wrap(np.angle(tfs) - targets)
    pass_ph = _wrap(np.angle(tps))
    return tfs, tps, {
        "phase_offset_focus_rad": phi0 % (2 * np.pi), "phase_offset_pass_rad": psi % (2 * np.pi),
        "phase_error_rad": ph_err.tolist(), "max_abs_phase_error_rad": float(np.max(np.abs(ph_err))),
        "rms_phase_error_rad": float(np.sqrt(np.mean(ph_err ** 2))),
        "pass_phase_rad": pass_ph.tolist(),
        "pass_phase_spread_rad": float(np.max(pass_ph) - np.min(pass_ph)),
        "pass_phase_rms_rad": float(np.sqrt(np.mean(pass_ph ** 2))),
        "T_focus": (np.abs(tfs) ** 2).tolist(), "T_pass": (np.abs(tps) ** 2).tolist(),
        "mean_T_focus": float(np.mean(np.abs(tfs) ** 2)), "mean_T_pass": float(np.mean(np.abs(tps) ** 2)),
        "expected_focusing_efficiency": float(abs(np.mean(tfs * np.exp(-1j * targets))) ** 2
                                              * np.sinc(1.0 / targets.size) ** 2),
        "pass_coherent_transmission": float(abs(np.mean(tps)) ** 2)}


def _specular(lib: Library, il: int, ok: np.ndarray) -> dict[str, np.ndarray | None]:
    """Per polarisation the candidates' specular reflection back into the entry side, None for a library without
    reflections (hand-made: :meth:`PostSet.reflectance` bounds it). Entering through the wafer, 'other' is the
    reflected higher orders (only the zero order exists in air), so R_00 = R - other; entering from air, R is
    specular."""
    specular: dict[str, np.ndarray | None] = {}
    for q in POLARIZATIONS:
        if f"R_{q}" not in lib.arrays or f"other_{q}" not in lib.arrays:
            specular[q] = None
            continue
        R_all, oth_all = lib.arrays[f"R_{q}"][il], lib.arrays[f"other_{q}"][il]
        spec = R_all if lib.meta.get("incidence") == "superstrate" else R_all - oth_all
        specular[q] = np.clip(np.nan_to_num(spec[ok]), 0.0, 1.0)
    return specular


def _interp_t(lib: Library, t: np.ndarray, wx: np.ndarray, wy: np.ndarray) -> np.ndarray:
    """Complex ``t`` on the library's (wx, wy) grid at other widths (bilinear in the real and imaginary parts);
    NaN outside the grid."""
    from scipy.interpolate import RegularGridInterpolator

    pts = np.stack([np.ravel(wx), np.ravel(wy)], -1)
    grid = (lib.wx_um, lib.wy_um)
    re = RegularGridInterpolator(grid, np.real(t), bounds_error=False, fill_value=np.nan)(pts)
    im = RegularGridInterpolator(grid, np.imag(t), bounds_error=False, fill_value=np.nan)(pts)
    return (re + 1j * im).reshape(np.shape(wx))


def _solve_like(lib: Library, wx: np.ndarray, wy: np.ndarray, wavelength_um: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_x, t_y) of posts (wx, wy), solved by RCWA with the library's stack and settings (its cache meta)."""
    from metafovea.rcwa.posts import post_response

    m = lib.meta

    def idx(name: str) -> complex:
        v = _stack(lib, name)
        return complex(v[0], v[1]) if isinstance(v, (list, tuple)) else complex(v)

    kw = {}
    for name in ("n_post", "n_surround", "n_substrate", "n_superstrate"):
        v = idx(name)
        kw[name] = v.real if v.imag == 0 else v
    r = post_response(np.asarray(wx), np.asarray(wy), wavelength_um, period_um=float(_stack(lib, "period_um")),
                      height_um=float(_stack(lib, "height_um")), harmonics=int(m.get("harmonics", DEFAULT_HARMONICS)),
                      factorization=m.get("factorization", "li"), incidence=m.get("incidence", "substrate"), **kw)
    return r.t_x, r.t_y


def bias_table(lib: Library, widths_um: np.ndarray, polarization: str, delta_um: float, il: int = 0) -> dict[str, Any]:
    """How posts ``widths_um`` (N, 2) respond to a uniform edge bias of -delta, 0, +delta per side (widths -2 delta,
    0, +2 delta), each post solved by RCWA with the library's settings: per level the focusing and pass-through
    phase error after removing the common shift (which a lens does not see), and per bias the expected focusing
    efficiency and the pass-through phase spread."""
    N = widths_um.shape[0]
    wl = float(lib.wavelengths_um[il])
    targets = 2 * np.pi * np.arange(N) / N
    w_all = np.concatenate([widths_um + sgn * 2 * delta_um for _, sgn in BIAS_CASES])
    tx, ty = _solve_like(lib, w_all[:, 0], w_all[:, 1], wl)
    tf_all, tp_all = (tx, ty) if polarization == "x" else (ty, tx)
    rows, summary = [], {}
    ph0 = float(np.angle(np.sum(np.exp(1j * (np.angle(tf_all[N:2 * N]) - targets)))))  # the offset select_posts removes
    for j, (name, _) in enumerate(BIAS_CASES):
        f = _case_figures(tf_all[j * N:(j + 1) * N], tp_all[j * N:(j + 1) * N], targets)
        summary[name] = {k: f[k] for k in ("rms_phase_error_rad", "max_abs_phase_error_rad")}
        summary[name].update(common_shift_rad=float(_wrap(np.array(f["shift_rad"] - ph0))),
                             expected_focusing_efficiency=f["expected_focusing_efficiency"],
                             pass_phase_spread_rad=f["pass_phase_spread_rad"])
        rows.append({"bias": name, "phase_error_rad": f["phase_error_rad"], "pass_phase_rad": f["pass_phase_rad"]})
    return {"delta_um": delta_um, "per_bias": summary, "levels": rows, "method": "RCWA at the biased widths"}
