"""Double deep image prior (DIP) in JAX, as in the paper.

Two skip-U-Nets ``g1``, ``g2`` map fixed random inputs ``z1``, ``z2`` to the foveal and perifoveal images; they and
the mixing ratios (``alpha_t = sigmoid(w_t)``, initialised from frame means as in the paper or from the classical
solver's estimate, or held fixed when given) are fitted with Adam [1]_ to

    L = mean_t ||y_t - alpha_t g1 - (1 - alpha_t) g2||^2 + tv_weight (TV g1 + TV g2)
        + exclusion_weight exclusion(g1, g2) [+ foveal_weight ||D g1 - gain C g2 - offset||^2]          (1)

(the paper's ``tv_weight = exclusion_weight = 0.01``; the defaults here: a TV weight from the data's noise and
gradient scale and no exclusion term for a random start, :func:`dip`). ``foveal_weight`` (default 0, not in the
paper) adds the foveal constraint, which fixes the alpha gauge as in :mod:`~metafovea.reconstruct.alternating`.

Network (``channels``, ``depth``, ``skip_channels``, ``input_channels``): per level a stride-2 3 x 3 conv and a
3 x 3 conv (LeakyReLU 0.2), a 1 x 1 skip branch, bilinear upsampling, concatenation, 3 x 3 + 1 x 1 convs and a
sigmoid output [2]_; ``norm`` normalises each conv's output per channel over the image (the original DIP's batch
norm with a batch of one), which is what lets a random start converge. Frames are rescaled to [0.05, 0.95] for
the sigmoid and the result is mapped back.

Random start's TV weight (MAP rule, :data:`AUTO_TV`): with ``sigma_x`` the images' noise after the per-pixel fit
and ``b`` the mean |difference| of the TV-denoised least-squares images (a Laplace gradient prior of scale ``b``),
the ROF weight [3]_

    lambda = AUTO_TV sigma_x^2 / b,    tv_weight = 2 lambda mean(diag N) / T                             (2)

(``N`` the per-pixel normal matrix; ``tv_weight`` in the loss's per-pixel means and the frames' normalised units).

Warm start (``init='classical'``/``'lsq'``/``(x1, x2)``): ``x_k = x_init_k + range_k (g_k(z_k) - mean)`` with the
output layers zeroed, so the DIP starts from the classical estimate and cannot move its level (the alpha gauge,
which the loss (1) does not fix).

Each jitted step is compiled once per frame shape and switch set and reused; it runs on JAX's default device (a GPU
when JAX has one). JAX is imported only when :func:`dip` is called.

Measured figures: BENCHMARKS.md, section "Reconstruction" ("Double deep image prior: warm start" and "... random
start").

References
----------
.. [1] D. P. Kingma and J. Ba, "Adam: a method for stochastic optimization", ICLR (2015), arXiv:1412.6980.
.. [2] D. Ulyanov, A. Vedaldi and V. Lempitsky, "Deep image prior", CVPR (2018) 9446.
.. [3] L. I. Rudin, S. Osher and E. Fatemi, "Nonlinear total variation based noise removal algorithms",
   Physica D 60, 259 (1992).
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from metafovea import stopping
from metafovea.errors import InputError, as_float, as_rng, check_choice, check_int
from metafovea.io import use_jax_cache
from metafovea.reconstruct._common import Timings, as_alpha, as_frames, image_dtype, with_overrides
from metafovea.reconstruct.alternating import alternating, frame_mean_alpha
from metafovea.reconstruct.denoise import denoise
from metafovea.reconstruct.lsq import lsq_known_alpha
from metafovea.reconstruct.operators import FovealOperator
from metafovea.reconstruct.polarizer import PolarizerModel
from metafovea.reconstruct.result import Reconstruction

if TYPE_CHECKING:
    import jax

log = logging.getLogger(__name__)


def _init_params(rng: np.random.Generator, cin: int, ch: int, depth: int, skip: int) -> dict[str, Any]:
    def conv(k: int, ci: int, co: int) -> dict[str, np.ndarray]:
        std = np.sqrt(2.0 / (k * k * ci))
        return {"w": (rng.normal(0, std, (co, ci, k, k))).astype(np.float32), "b": np.zeros(co, np.float32),
                "g": np.ones(co, np.float32)}

    p: dict[str, Any] = {"down": [], "skip": [], "up": []}
    c = cin
    for _ in range(depth):
        p["down"].append([conv(3, c, ch), conv(3, ch, ch)])
        p["skip"].append(conv(1, c, skip))
        c = ch
    for _ in range(depth):
        cin_up = ch + skip
        p["up"].append([conv(3, cin_up, ch), conv(1, ch, ch)])
    p["out"] = conv(1, ch, 1)
    return p


#: traces of the jitted functions (incremented while JAX traces them, i.e. once per compilation); a call's
#: ``info['traces']`` is how many it caused (0 when a call with the same shape and switches ran before)
_TRACES = [0]


def _build(depth: int, norm: bool = False):
    """``net(p, z) -> (H, W)``; ``norm``: each conv's output normalised per channel over the image (the
    original DIP's batch norm with a batch of one), then scaled by ``g`` and shifted by ``b``."""
    import jax
    import jax.numpy as jnp

    def conv(x, c, stride=1, normed=norm):
        k = c["w"].shape[-1]
        y = jax.lax.conv_general_dilated(x, c["w"], (stride, stride), [(k // 2, k // 2)] * 2,
                                         dimension_numbers=("NCHW", "OIHW", "NCHW"))
        if normed:
            mu = y.mean(axis=(2, 3), keepdims=True)
            y = (y - mu) * jax.lax.rsqrt(((y - mu) ** 2).mean(axis=(2, 3), keepdims=True) + 1e-5)
            y = y * c["g"][None, :, None, None]
        return y + c["b"][None, :, None, None]

    def act(x):
        return jax.nn.leaky_relu(x, 0.2)

    def net(p, z):
        skips = []
        x = z
        for lev in range(depth):
            skips.append(act(conv(x, p["skip"][lev])))
            x = act(conv(x, p["down"][lev][0], stride=2))
            x = act(conv(x, p["down"][lev][1]))
        for lev in reversed(range(depth)):
            s = skips[lev]
            x = jax.image.resize(x, (x.shape[0], x.shape[1]) + s.shape[2:], "bilinear")
            x = jnp.concatenate([x, s], axis=1)
            x = act(conv(x, p["up"][lev][0]))
            x = act(conv(x, p["up"][lev][1]))
        return conv(x, p["out"], normed=False)[0, 0]

    return net


def _head(residual: bool):
    """Network output -> image in the frames' normalised units: ``A + B u`` with ``u`` the image in its
    own normalised units (``sigmoid(raw)``, or ``base + raw`` for the residual parameterisation)."""
    import jax

    def head(raw, base, ab):
        # residual: zero-mean correction, the level (the alpha gauge) stays the warm start's
        u = base + (raw - raw.mean()) if residual else jax.nn.sigmoid(raw)
        return ab[0] + ab[1] * u

    return head


def _images_fn(depth: int, learn_alpha: bool, residual: bool, norm: bool):
    """``images(p, data) -> (g1, g2, alpha)`` in the frames' normalised units (traced inside the jitted step)."""
    import jax

    net, head = _build(depth, norm), _head(residual)

    def images(p, data):
        g1 = head(net(p["g1"], data["z1"]), data["b1"], data["ab"][0:2])
        g2 = head(net(p["g2"], data["z2"]), data["b2"], data["ab"][2:4])
        return g1, g2, (jax.nn.sigmoid(p["alpha"]) if learn_alpha else data["a"])

    return images


@functools.lru_cache(maxsize=32)
def _make_render(depth: int, learn_alpha: bool, residual: bool, norm: bool):
    """Jitted :func:`_images_fn` (checkpoints and the final images), compiled once per shape and switches."""
    import jax

    images = _images_fn(depth, learn_alpha, residual, norm)

    def render(p, data):
        _TRACES[0] += 1
        return images(p, data)

    return jax.jit(render)


@functools.lru_cache(maxsize=32)
def _make_step(depth: int, learn_alpha: bool, foveal: bool, residual: bool = False, norm: bool = False):
    """Jitted Adam step ``(state, t, lr, alpha_lr, beta, data) -> (state, loss)`` for one network depth and
    switches; ``state = (p, m, v, ema1, ema2)``, ``ema_k`` the running mean (decay ``beta``) of image ``k``.
    Cached here and by ``jax.jit`` per input shape: one compilation per (shape, switches)."""
    import jax.numpy as jnp

    images = _images_fn(depth, learn_alpha, residual, norm)

    def mean_abs_tv(x):
        """Anisotropic TV per pixel: the mean |vertical| plus the mean |horizontal| difference."""
        return jnp.mean(jnp.abs(jnp.diff(x, axis=0))) + jnp.mean(jnp.abs(jnp.diff(x, axis=1)))

    def excl(x1, x2):
        val = 0.0
        for _ in range(2):
            for ax in (0, 1):
                g1 = jnp.diff(x1, axis=ax)
                g2 = jnp.diff(x2, axis=ax)
                lam = jnp.sqrt(jnp.mean(jnp.abs(g2)) / (jnp.mean(jnp.abs(g1)) + 1e-8) + 1e-8)
                val = val + jnp.sqrt(jnp.mean((jnp.tanh(lam * jnp.abs(g1)) * jnp.tanh(jnp.abs(g2))) ** 2) + 1e-12)
            h2, w2 = x1.shape[0] // 2 * 2, x1.shape[1] // 2 * 2
            if h2 < 4 or w2 < 4:
                break
            x1 = x1[:h2, :w2].reshape(h2 // 2, 2, w2 // 2, 2).mean(axis=(1, 3))
            x2 = x2[:h2, :w2].reshape(h2 // 2, 2, w2 // 2, 2).mean(axis=(1, 3))
        return val

    def loss_fn(p, data):
        tvw, exw, fw, gain_n, bias_n = (data["c"][i] for i in range(5))
        g1, g2, a = images(p, data)
        model = a[:, None, None] * g1[None] + (1 - a)[:, None, None] * g2[None]
        loss = jnp.mean((data["y"] - model) ** 2) + tvw * (mean_abs_tv(g1) + mean_abs_tv(g2)) + exw * excl(g1, g2)
        if foveal:
            Dm = data["D"]
            r = Dm[0] @ g1 @ Dm[1].T - gain_n * (Dm[2] @ g2 @ Dm[3].T) - bias_n
            loss = loss + fw * jnp.mean(r ** 2)
        return loss, (g1, g2)

    return _adam(loss_fn)


def _adam(loss_fn):
    """Jitted Adam step for ``loss_fn(p, data) -> (loss, (img1, img2))`` with running means of the images."""
    import jax
    import jax.numpy as jnp

    b1, b2, eps = 0.9, 0.999, 1e-8

    def step(state, t, lr, alpha_lr, beta, data):
        _TRACES[0] += 1
        p, m, v, e1, e2 = state
        (loss, (i1, i2)), g = jax.value_and_grad(loss_fn, has_aux=True)(p, data)
        m = jax.tree_util.tree_map(lambda mi, gi: b1 * mi + (1 - b1) * gi, m, g)
        v = jax.tree_util.tree_map(lambda vi, gi: b2 * vi + (1 - b2) * gi * gi, v, g)
        mh = 1 - b1 ** t
        vh = 1 - b2 ** t
        lrs = {k: (alpha_lr if k == "alpha" else lr) for k in p}
        p = {k: jax.tree_util.tree_map(lambda pi, mi, vi, lk=lrs[k]: pi - lk * (mi / mh) / (jnp.sqrt(vi / vh) + eps),
                                       p[k], m[k], v[k]) for k in p}
        e1, e2 = beta * e1 + (1 - beta) * i1, beta * e2 + (1 - beta) * i2
        return (p, m, v, e1, e2), loss

    return jax.jit(step)


@functools.lru_cache(maxsize=16)
def _make_fit_step(depth: int, norm: bool = False):
    """Jitted Adam step of the supervised warm start: ``mean (u_k - target_k)^2`` in each image's units."""
    import jax
    import jax.numpy as jnp

    net = _build(depth, norm)

    def loss_fn(p, data):
        u1 = jax.nn.sigmoid(net(p["g1"], data["z1"]))
        u2 = jax.nn.sigmoid(net(p["g2"], data["z2"]))
        return jnp.mean((u1 - data["t1"]) ** 2) + jnp.mean((u2 - data["t2"]) ** 2), (u1, u2)

    return _adam(loss_fn)


INITS = ("random", "lsq", "classical")
#: TV and exclusion weights: the paper's, and the default after a warm start (measured on the simulated
#: 290 x 290 paper measurement: the paper's 0.01 smooths the warm start's perifoveal structure away,
#: -4 dB on x2 after 60 steps; 0.001 keeps both images within 0.05 dB of the warm start). The paper's 0.01 times the
#: scenes' mean |gradient| (~0.05 per pixel) is ~10x the data term's noise floor (~8e-5 at a noise of 1 % of the
#: range): an estimate, not measured with the normalised network
PAPER_WEIGHT = 0.01
RANDOM_WEIGHT = 0.0
WARM_WEIGHT = 0.001
#: the random start's TV weight unless given: ``AUTO_TV sigma_x^2 / b``, eq. (2) (:func:`_auto_tv_weight`; the MAP
#: weight of a Laplace gradient prior is 1 x). Measured (BENCHMARKS.md, bench_dip.py, 64 x 64, 2 scenes x sigma
#: 0.01 / 0.05, unknown alpha): 0.5 came within 1 dB of alternating's TV prior in all four cases, 1.0 fell 1.1-1.2 dB
#: below it at sigma 0.05 on one scene, and no TV 1.2-3.2 dB below at sigma 0.05
AUTO_TV = 0.5
#: Adam learning rates: random start, and warm start (0.01 made the residual of a 32-channel network
#: diverge after ~30 steps on that measurement; 0.002 is stable for 8 and 32 channels over 200 steps)
PAPER_LR = 0.01
WARM_LR = 0.002
WARMS = ("residual", "fit")
SCHEDULES = ("cosine", "constant")
ALPHA_INITS = ("means", "classical")
#: why the steps stopped (``info['stopped']``)
STOP_REASONS = ("steps", "converged", "time")


def _initial_images(Y: np.ndarray, init: str | tuple[ArrayLike, ArrayLike], alpha: np.ndarray | None,
                    a_init: np.ndarray | None, scale: float, gain: float, offset: float,
                    polarizer: PolarizerModel | None = None
                    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """``(x1, x2, alpha)`` of the warm start (``None`` for ``init='random'``)."""
    T, H, W = Y.shape
    if not isinstance(init, str):
        try:
            x1, x2 = (np.asarray(v, dtype=np.float64) for v in init)
        except (TypeError, ValueError):
            raise InputError("init", type(init).__name__,
                             f"one of {INITS} or a pair (x1, x2) of (H, W) images") from None
        if x1.shape != (H, W) or x2.shape != (H, W):
            raise InputError("init", f"images {x1.shape}, {x2.shape}", f"a pair of ({H}, {W}) images")
        if not (np.all(np.isfinite(x1)) and np.all(np.isfinite(x2))):
            raise InputError("init", "images with NaN/inf", "finite initial images")
        return x1, x2, None
    init = check_choice("init", init, INITS)
    if init == "random":
        return None, None, None
    if init == "classical":
        if alpha is None and a_init is None:
            r = alternating(Y, scale=scale, foveal_gain=gain, foveal_offset=offset, strict=False, polarizer=polarizer)
            return np.asarray(r.x1, np.float64), np.asarray(r.x2, np.float64), np.asarray(r.alpha, np.float64)
        if Y.shape[0] < 3:
            raise InputError("init", init, "'lsq' for fewer than 3 frames")
    a = alpha if alpha is not None else a_init
    if a is None:
        raise InputError("init", init, "'lsq' needs alpha or alpha_init as an array (or use init='classical')")
    ls = lsq_known_alpha(Y, a, regularize="difference")
    x1, x2 = np.asarray(ls.x1, np.float64), np.asarray(ls.x2, np.float64)
    if init == "classical":  # alpha known: the classical estimate is the LSQ images with the TV prior
        x1, x2 = np.asarray(denoise(x1, "tv"), np.float64), np.asarray(denoise(x2, "tv"), np.float64)
    return x1, x2, None


def _range(x: np.ndarray) -> tuple[float, float]:
    """Robust range (0.1 / 99.9 percentiles, widened by 10 %) of one initial image."""
    lo, hi = (float(v) for v in np.percentile(x, [0.1, 99.9]))
    span = hi - lo
    if not span > 0:
        span = max(abs(lo), 1.0) * 1e-3
    return lo - 0.05 * span, span * 1.1


@dataclass(frozen=True)
class DipOptions:
    """The knobs of :func:`dip` (each is also a keyword argument of it).

    Attributes
    ----------
    channels, depth, skip_channels, input_channels : int
        The skip-U-Net (per network).
    norm : bool or None
        Per-channel normalisation of each conv (the original DIP's batch norm with a batch of one; None: on for a
        random start, off for a warm start).
    input_scale : float
        The fixed random inputs are ``input_scale U(0, 1)`` (the paper's 0.1).
    steps : int
        The step budget (the most Adam steps of the loss).
    tol, patience : float, int
        Stop earlier when the best loss improved by less than ``tol`` (relative) over the last ``patience`` steps
        (``tol=0``: never).
    max_seconds : float or None
        Stop when the steps took this long (None: no time limit).
    lr, alpha_lr : float or None
        Learning rates (None: see :func:`dip`).
    schedule : {'cosine', 'constant'}
        ``'cosine'``: decay to 0 over ``steps`` after ``warmup`` linear warm-up steps.
    warmup : int
    average : float
        Decay of the running mean of the images returned (0: the last step's images).
    tv_weight, exclusion_weight : float or None
        Loss weights of eq. (1) (None: see :func:`dip`).
    foveal_weight : float
        Weight of the foveal term ``||D x1 - foveal_gain C x2 - foveal_offset||^2`` (0: off).
    scale, foveal_gain, foveal_offset : float
        The foveal constraint (also used by the classical estimates).
    alpha_init : {'means', 'classical'} or array_like, shape (T,)
        Unknown alpha's start: the frame means (the paper), :func:`alternating`'s estimate, or values.
    polarizer : PolarizerModel or None
        The classical solver's polariser model, for the alpha it supplies (``alpha_init='classical'``,
        ``init='classical'``); None: its foveal gauge alone.
    init : {'random', 'lsq', 'classical'} or tuple of 2 ndarray
        The start: random weights (the paper), least squares, :func:`alternating`, or an ``(x1, x2)`` pair.
    warm : {'residual', 'fit'}
        How a warm start enters: the residual parameterisation, or ``warm_steps`` supervised steps first.
    warm_steps : int
    checkpoints : sequence of int
        Step counts recorded in ``info['checkpoints']`` (0: the start, after the warm-start fit).
    rng : int or numpy.random.Generator
        Seed of the weights and inputs (same seed, same result on one machine).
    log_every : int
        Log the loss every so many steps (0: never).
    progress : bool or callable
        True: step, loss and ETA on stderr (a bar on a terminal, a log line every 10 s otherwise); a callable:
        called with a dict ``step, steps, loss, seconds, eta_s`` every ``progress_every`` steps and at the end.
    progress_every : int
    """

    channels: int = 16
    depth: int = 3
    skip_channels: int = 16
    input_channels: int = 32
    norm: bool | None = None
    input_scale: float = 0.1
    steps: int = 2000
    tol: float = 1e-3
    patience: int = 100
    max_seconds: float | None = None
    lr: float | None = None
    alpha_lr: float | None = None
    schedule: str = "cosine"
    warmup: int = 0
    average: float = 0.0
    tv_weight: float | None = None
    exclusion_weight: float | None = None
    foveal_weight: float = 0.0
    scale: float = 6.0
    foveal_gain: float = 1.0
    foveal_offset: float = 0.0
    alpha_init: str | ArrayLike = "means"
    polarizer: PolarizerModel | None = None
    init: str | tuple[ArrayLike, ArrayLike] = "random"
    warm: str = "residual"
    warm_steps: int = 40
    checkpoints: Sequence[int] = ()
    rng: np.random.Generator | int | None = None
    log_every: int = 0
    progress: bool | Callable[[dict[str, Any]], None] = False
    progress_every: int = 10


#: the memory bound: channels x H x W (and skip_channels, input_channels x H x W) at most this: 32 channels at
#: 1024 x 1024. XLA's buffers of the jitted step (``memory_analysis()`` of the compiled step, depth 3, both
#: networks, activations, gradients and Adam's moments) were 170-220 bytes per channel-pixel (64^2 and 128^2,
#: 16 and 32 channels, skip 16, input 32), so ~6-7 GB at the bound
MAX_CHANNEL_PIXELS = 2 ** 25


def _checked(opt: DipOptions, H: int, W: int) -> tuple[DipOptions, list[int]]:
    """The integer and choice options checked; the sorted checkpoint steps."""
    channels = check_int("channels", opt.channels, 1, 4096)
    depth = check_int("depth", opt.depth, 1, 8)
    if min(H, W) < 2 ** depth:
        raise InputError("frames", f"{H} x {W} pixels", f"at least {2 ** depth} x {2 ** depth} pixels for a "
                         f"depth-{depth} network (or a smaller depth: 2**depth <= min(H, W) = {min(H, W)})")
    cap = MAX_CHANNEL_PIXELS // (H * W)
    if cap < 1:
        raise InputError("frames", f"{H} x {W} pixels", f"H x W <= {MAX_CHANNEL_PIXELS} pixels for the DIP "
                         "(memory bound; crop or bin the frames)")
    if channels * H * W > MAX_CHANNEL_PIXELS:
        raise InputError("channels", channels, f"1 <= channels <= {cap} at {H} x {W} pixels (memory bound: "
                         f"channels x H x W <= {MAX_CHANNEL_PIXELS})")
    for name in ("skip_channels", "input_channels"):
        n = check_int(name, getattr(opt, name), 1, 4096)
        if n * H * W > MAX_CHANNEL_PIXELS:
            raise InputError(name, n, f"1 <= {name} <= {cap} at {H} x {W} pixels (memory bound)")
    steps = check_int("steps", opt.steps, 1, 10_000_000)
    check_int("patience", opt.patience, 1, 10_000_000)
    check_int("warmup", opt.warmup, 0, 10_000_000)
    check_int("progress_every", opt.progress_every, 1, 10_000_000)
    if not 0 <= as_float("tol", opt.tol) < 1:
        raise InputError("tol", opt.tol, "0 <= tol < 1 (relative loss improvement over patience steps; 0: never)")
    if opt.max_seconds is not None and not as_float("max_seconds", opt.max_seconds) > 0:
        raise InputError("max_seconds", opt.max_seconds, "a positive time budget in seconds, or None")
    if not 0 <= as_float("average", opt.average) < 1:
        raise InputError("average", opt.average, "0 <= average < 1 (decay of the images' running mean)")
    if not as_float("input_scale", opt.input_scale) > 0:
        raise InputError("input_scale", opt.input_scale, "a positive scale of the random inputs")
    if not (isinstance(opt.progress, bool) or callable(opt.progress)):
        raise InputError("progress", opt.progress, "True, False or a callable taking a dict")
    schedule = check_choice("schedule", opt.schedule, SCHEDULES)
    warm = check_choice("warm", opt.warm, WARMS)
    warm_steps = check_int("warm_steps", opt.warm_steps, 0, 10_000_000)
    try:
        cps = sorted({int(c) for c in np.atleast_1d(np.asarray(opt.checkpoints, dtype=float))
                      if np.isfinite(c) and float(c).is_integer() and 0 <= c <= steps})
        if len(cps) != np.size(opt.checkpoints):
            raise ValueError
    except (TypeError, ValueError):
        raise InputError("checkpoints", opt.checkpoints, f"step counts between 0 and steps = {steps}") from None
    return replace(opt, channels=channels, depth=depth, steps=steps, warm=warm, warm_steps=warm_steps,
                   schedule=schedule), cps


@dataclass(frozen=True)
class _Units:
    """The frames' normalised units ``yn = 0.05 + 0.9 (y - lo) / span`` and, per image, its own units ``u_k``
    (``x_k`` normalised = ``ab[2k] + ab[2k+1] u_k``; ``base_k``: the warm start in those units)."""

    lo: float
    span: float
    base1: np.ndarray
    base2: np.ndarray
    ab: list[float]

    def to_frames(self, g: np.ndarray) -> np.ndarray:
        return (g - 0.05) / 0.9 * self.span + self.lo


def _units(Y: np.ndarray, xi1: np.ndarray | None, xi2: np.ndarray | None, known: np.ndarray | None,
           residual: bool) -> _Units:
    """Normalisation of the frames and of each image (see :func:`dip`); ``known``: the given (or initial) alpha of
    a random start, whose LSQ images widen the range."""
    H, W = Y.shape[1:]
    lo, hi = float(Y.min()), float(Y.max())
    if xi1 is not None:
        lo = min(lo, float(np.min(xi1)), float(np.min(xi2)))
        hi = max(hi, float(np.max(xi1)), float(np.max(xi2)))
    elif known is not None:
        ls = lsq_known_alpha(Y, known, regularize="difference")
        lo = min(lo, float(np.min(ls.x1)), float(np.min(ls.x2)))
        hi = max(hi, float(np.max(ls.x1)), float(np.max(ls.x2)))
    span = hi - lo if hi > lo else 1.0
    if xi1 is None:
        return _Units(lo, span, np.zeros((H, W)), np.zeros((H, W)), [0.0, 1.0, 0.0, 1.0])
    # image k in its own units u_k (lo_k + span_k u_k in DN; global normalised: A_k + B_k u_k)
    (lo1, s1), (lo2, s2) = _range(xi1), _range(xi2)
    if not residual:
        # sigmoid range [0.05, 0.95] over the initial image's range
        lo1, s1, lo2, s2 = lo1 - s1 * 0.05 / 0.9, s1 / 0.9, lo2 - s2 * 0.05 / 0.9, s2 / 0.9
    # residual: u_k = (x - x_init_k) / span_k + base_k, base_k = normalised x_init_k
    base1, base2 = (xi1 - lo1) / s1, (xi2 - lo2) / s2
    ab = [0.05 + 0.9 * (lo1 - lo) / span, 0.9 * s1 / span, 0.05 + 0.9 * (lo2 - lo) / span, 0.9 * s2 / span]
    return _Units(lo, span, base1, base2, ab)


def _auto_tv_weight(Y: np.ndarray, a: np.ndarray, span: float) -> tuple[float, dict[str, float]]:
    """The random start's TV weight from the data (normalised units), a MAP rule: the images' noise after the
    per-pixel fit with ``a`` (``sigma_x^2 = sigma^2 mean diag N^-1``, ``sigma`` from the fit's residuals) and the
    scale ``b`` of a Laplace prior on their gradients (mean |difference| per direction of the TV-denoised
    least-squares images) give the ROF weight ``lambda = AUTO_TV * sigma_x^2 / b``, mapped onto the loss's
    per-pixel means (``tv_weight = 2 lambda mean diag N / T``). 0 with fewer than 3 frames (no residual)."""
    T = Y.shape[0]
    A = np.stack([a, 1.0 - a], axis=1)
    N = A.T @ A
    if T < 3 or np.linalg.cond(N) > 1e8:
        return 0.0, {}
    y = Y.reshape(T, -1).astype(np.float64)
    x = np.linalg.solve(N, A.T @ y)
    sigma2 = float(np.mean((y - A @ x) ** 2) * T / (T - 2))
    sx2 = sigma2 * float(np.mean(np.diag(np.linalg.inv(N))))
    grads = []
    for img in x.reshape(2, *Y.shape[1:]):
        d = denoise(img, "tv")
        grads.append(0.5 * (np.mean(np.abs(np.diff(d, axis=0))) + np.mean(np.abs(np.diff(d, axis=1)))))
    b = max(float(np.mean(grads)), 1e-12 * span)
    lam = AUTO_TV * sx2 / b
    tvw = 2.0 * lam * float(np.mean(np.diag(N))) / T * 0.9 / span
    return tvw, {"sigma": float(np.sqrt(sigma2)), "image_noise": float(np.sqrt(sx2)), "gradient_scale": b,
                 "rof_lambda": lam}


def _weights(opt: DipOptions, warm_start: bool, op: FovealOperator | None, u: _Units,
             tv_default: float | None = None) -> dict[str, float]:
    """Loss weights, learning rates and the foveal constraint in the frames' normalised units (``tv_default``:
    the TV weight when ``opt.tv_weight`` is None; the module's default otherwise)."""
    lr = as_float("lr", (WARM_LR if warm_start else PAPER_LR) if opt.lr is None else opt.lr)
    if lr <= 0:
        raise InputError("lr", lr, "a positive learning rate")
    # alternating's alpha (alpha_init='classical', or init='classical' with unknown alpha) is held: the DIP loss
    # does not fix the gauge, and learning it took the alpha error from 0.002 to 0.015 (x2 -6 dB; at lr / 10 after
    # a warm start: 0.007, x1 -1.9 dB) over 1,500 steps on a 64 x 64 scene
    held = (isinstance(opt.alpha_init, str) and opt.alpha_init == "classical") or (
        isinstance(opt.init, str) and opt.init == "classical")
    a_def = 0.0 if held else (lr / 10 if warm_start else lr)
    alpha_lr = as_float("alpha_lr", a_def if opt.alpha_lr is None else opt.alpha_lr)
    if alpha_lr < 0:
        raise InputError("alpha_lr", alpha_lr, "a learning rate >= 0 (0 holds alpha at its initial value)")
    # the constraint in normalised units yn = A y + B: D x1n = gain C x2n + (1 - gain) B + A bias
    A_n, B_n = 0.9 / u.span, 0.05 - 0.9 * u.lo / u.span
    w_def = WARM_WEIGHT if warm_start else RANDOM_WEIGHT
    tv_def = w_def if tv_default is None else tv_default
    w = {"tv": as_float("tv_weight", tv_def if opt.tv_weight is None else opt.tv_weight),
         "exclusion": as_float("exclusion_weight", w_def if opt.exclusion_weight is None else opt.exclusion_weight),
         "foveal": as_float("foveal_weight", opt.foveal_weight),
         "gain_n": 1.0 if op is None else float(op.gain),
         "bias_n": 0.0 if op is None else float((1 - op.gain) * B_n + A_n * op.bias), "lr": lr, "alpha_lr": alpha_lr}
    if min(w["tv"], w["exclusion"], w["foveal"]) < 0:
        raise InputError("tv_weight/exclusion_weight/foveal_weight", (w["tv"], w["exclusion"], w["foveal"]),
                         "weights >= 0")
    return w


def _alpha_and_weights(Y: np.ndarray, Yn: np.ndarray, alpha: np.ndarray | None, a_init: np.ndarray | None,
                       opt: DipOptions, warm_start: bool, op: FovealOperator | None, u: _Units) -> tuple:
    """``(a0, learn_alpha, weights, tv_auto, tv_rule)``: the starting alpha, whether it is learned, the loss weights
    (:func:`_weights`) and the random start's data-driven TV weight with what it found (None, {} otherwise)."""
    learn_alpha = alpha is None
    a0 = (frame_mean_alpha(Yn) if a_init is None else a_init) if learn_alpha else alpha
    tv_auto, tv_rule = (None, {})
    if not warm_start and opt.tv_weight is None:
        tv_auto, tv_rule = _auto_tv_weight(Y, np.asarray(a0, np.float64), u.span)
    w = _weights(opt, warm_start, op, u, tv_auto)
    if learn_alpha and w["alpha_lr"] == 0.0:
        # held (alternating's alpha): the exact values as data, not the sigmoid of a logit clipped to [0.02, 0.98],
        # which cost least squares 14 dB on the perifoveal image of frames at alpha 0.01 (the ablation study)
        learn_alpha = False
    return a0, learn_alpha, w, tv_auto, tv_rule


def _networks(gen: np.random.Generator, opt: DipOptions, shape: tuple[int, int], residual: bool,
              a0: np.ndarray | None) -> tuple[dict[str, Any], Any, Any]:
    """The two networks' weights (output layers zeroed for the residual warm start; the logit of ``a0`` when alpha
    is learned) and their fixed random inputs ``input_scale * U(0, 1)``, drawn from ``gen`` in that order, on
    JAX's default device (a GPU when there is one)."""
    import jax
    import jax.numpy as jnp

    params = {"g1": _init_params(gen, opt.input_channels, opt.channels, opt.depth, opt.skip_channels),
              "g2": _init_params(gen, opt.input_channels, opt.channels, opt.depth, opt.skip_channels)}
    if residual:
        for g in ("g1", "g2"):
            params[g]["out"]["w"][:] = 0.0
    if a0 is not None:
        a_c = np.clip(a0, 1e-3, 1 - 1e-3)  # a finite logit
        params["alpha"] = np.log(a_c / (1 - a_c)).astype(np.float32)
    params = jax.tree_util.tree_map(jnp.asarray, params)
    sc = float(opt.input_scale)
    z1 = jnp.asarray((sc * gen.uniform(0, 1, (1, opt.input_channels, *shape))).astype(np.float32))
    z2 = jnp.asarray((sc * gen.uniform(0, 1, (1, opt.input_channels, *shape))).astype(np.float32))
    return params, z1, z2


def _zeros_state(params: dict[str, Any], shape: tuple[int, int]) -> tuple:
    """Adam's moments (zeros like ``params``) and the images' running means (zeros)."""
    import jax
    import jax.numpy as jnp

    z = jax.tree_util.tree_map(jnp.zeros_like, params)
    return (params, z, jax.tree_util.tree_map(jnp.zeros_like, params), jnp.zeros(shape, jnp.float32),
            jnp.zeros(shape, jnp.float32))


def _warm_fit(params: dict[str, Any], z1: jax.Array, z2: jax.Array, u: _Units, opt: DipOptions, lr: float,
              hist: list[float]) -> dict[str, Any]:
    """The supervised warm start (``warm='fit'``): ``warm_steps`` Adam steps fitting each network to its image."""
    import jax.numpy as jnp

    fstep = _make_fit_step(opt.depth, bool(opt.norm))
    fdata = {"z1": z1, "z2": z2, "t1": jnp.asarray(u.base1.astype(np.float32)),
             "t2": jnp.asarray(u.base2.astype(np.float32))}
    state = _zeros_state({"g1": params["g1"], "g2": params["g2"]}, u.base1.shape)
    for k in range(1, opt.warm_steps + 1):
        state, fl = fstep(state, float(k), lr, 0.0, 0.0, fdata)
        if k % max(1, opt.warm_steps // 50) == 0 or k == opt.warm_steps:
            hist.append(float(fl))
    return {**params, **state[0]}


def _lr_at(k: int, opt: DipOptions, lr: float) -> float:
    """Learning-rate factor of step ``k`` (1-based): linear warm-up, then constant or cosine decay to 0 at
    ``steps``."""
    if opt.warmup and k <= opt.warmup:
        return k / opt.warmup
    if opt.schedule == "constant":
        return 1.0
    x = (k - opt.warmup) / max(opt.steps - opt.warmup, 1)
    return 0.5 * (1.0 + float(np.cos(np.pi * min(x, 1.0))))


class _Progress:
    """Step, loss and ETA: on stderr (``progress=True``: a bar on a terminal, log lines otherwise), a callable's
    dict, or nothing."""

    def __init__(self, opt: DipOptions):
        self.fn = opt.progress if callable(opt.progress) else None
        self.every, self.steps = opt.progress_every, opt.steps
        self.bar = None
        if opt.progress is True:  # a bar on a terminal, log lines otherwise
            from metafovea.parallel import progress_bar

            self.bar = progress_bar(opt.steps, "dip", "step")
        self.done = 0

    def __call__(self, k: int, loss: float, seconds: float, last: bool = False) -> None:
        if not (last or k % self.every == 0):
            return
        eta = seconds / max(k, 1) * (self.steps - k)
        if self.bar is not None:
            self.bar.update(k - self.done)
            self.bar.set_postfix(loss=f"{loss:.4g}", refresh=False)
        self.done = k
        if self.fn is not None:
            self.fn({"step": k, "steps": self.steps, "loss": loss, "seconds": seconds, "eta_s": 0.0 if last else eta})

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _optimise(step: Callable[..., tuple[tuple, jax.Array]], params: dict[str, Any], data: dict[str, Any],
              opt: DipOptions, w: dict, cps: list[int],
              images: Callable[[dict[str, Any]], tuple[np.ndarray, np.ndarray, np.ndarray]],
              tm: Timings) -> tuple[tuple, list[float], list[dict[str, Any]], dict]:
    """The Adam loop of the DIP loss: ``(state, loss history, checkpoints, stop info)``; the first step (which
    compiles when this shape and these switches are new) is timed as ``compile``, the others as ``steps``.

    Stops after ``steps`` steps, when the best loss improved by less than ``tol`` (relative) over the last
    ``patience`` steps, or after ``max_seconds``; stopped by the time cap it returns the state of the lowest loss
    seen (the learning rate has not decayed yet, so the last step need not be the best), ``kept_step`` its
    steps."""
    recorded: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    beta = float(opt.average)

    def record(k: int, st: tuple) -> None:
        if k in cps:
            x1_, x2_, a_ = images(st[0])
            recorded.append({"step": k, "x1": x1_, "x2": x2_, "alpha": a_, "seconds": time.perf_counter() - t_start})

    state = _zeros_state(params, data["y"].shape[1:])
    hist: list[float] = []
    best: list[float] = []
    record(0, state)
    bar = _Progress(opt)
    stop, k = "steps", 0
    lowest = (float("inf"), 0, state)  # (loss, steps done, state) of the lowest loss: the loss of step k is that of
    t0 = time.perf_counter()  # the state before it (JAX arrays are immutable: keeping it costs no copy)
    try:
        for k in range(1, opt.steps + 1):
            f = _lr_at(k, opt, 1.0)
            before = state
            with tm.measure("compile" if k == 1 else "steps"):
                state, loss = step(state, float(k), w["lr"] * f, w["alpha_lr"] * f, beta, data)
                loss = float(loss)
            if loss < lowest[0]:
                lowest = (loss, k - 1, before)
            best.append(min(loss, best[-1]) if best else loss)
            if k == 1 or k % max(1, opt.steps // 200) == 0 or k == opt.steps:
                hist.append(loss)
            el = time.perf_counter() - t0
            if opt.log_every and k % opt.log_every == 0:
                log.info("dip step %d/%d loss %.4g (%.3f s/step)", k, opt.steps, loss, el / k)
            record(k, state)
            bar(k, loss, el)
            stopping.check()  # a stop signal that a callback of XLA's dropped (metafovea.stopping)
            if opt.tol and k > opt.patience and best[k - 1 - opt.patience] - best[-1] <= opt.tol * abs(
                    best[k - 1 - opt.patience]):
                stop = "converged"
            elif opt.max_seconds is not None and el >= opt.max_seconds and k < opt.steps:
                stop = "time"
            if stop != "steps":
                break
        bar(k, loss, time.perf_counter() - t0, last=True)
    finally:
        bar.close()
    if hist[-1] != loss:
        hist.append(loss)
    info = {"steps_run": k, "stopped": stop, "best_loss": best[-1], "final_loss": loss, "kept_step": k}
    if stop == "time":
        state, info["kept_step"] = lowest[2], lowest[1]
    return state, hist, recorded, info


def _start_alpha(Y: np.ndarray, opt: DipOptions,
                 alpha: ArrayLike | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(alpha held fixed, initial alpha of a learned one)`` from ``alpha`` and ``alpha_init``."""
    T = Y.shape[0]
    if alpha is not None:
        return as_alpha(alpha, T), None
    ai = opt.alpha_init
    if isinstance(ai, str):
        ai = check_choice("alpha_init", ai, ALPHA_INITS)
        if ai == "means" or opt.init == "classical":  # the classical warm start supplies its own alpha
            return None, None
        r = alternating(Y, scale=opt.scale, foveal_gain=opt.foveal_gain, foveal_offset=opt.foveal_offset,
                        strict=False, polarizer=opt.polarizer)
        # alpha = cos^2 lies in [0, 1]; an estimate without an absolute gauge can stray past it by its error
        return None, np.clip(np.asarray(r.alpha, np.float64), 0.0, 1.0)
    return None, as_alpha(ai, T, name="alpha_init")


def dip(frames: ArrayLike, alpha: ArrayLike | None = None, options: DipOptions | None = None,
        **overrides: Any) -> Reconstruction:
    """Fit the double DIP, eq. (1), to the frames.

    Parameters
    ----------
    frames : array_like, shape (T, H, W)
        Finite; ``T >= 2``.
    alpha : array_like, shape (T,), optional
        Mixing ratios, held fixed; None: learned from ``alpha_init``.
    options : DipOptions, optional
    **overrides
        Fields of ``options`` (``dip(Y, steps=20, rng=0)``).

    Returns
    -------
    Reconstruction
        ``info``: ``steps_run`` and ``stopped`` (one of :data:`STOP_REASONS`), ``loss_history``, the weights and
        learning rates used (``tv_weight_rule``: what eq. (2) found), ``checkpoints``, ``seconds_per_step``,
        ``first_step_seconds`` (with the step's compilation where ``traces`` > 0), ``traces`` (compilations this
        call caused), ``device``; ``initial`` (the warm start's images).

    Notes
    -----
    ``alpha_init='means'`` labels the brighter frames as more foveal: wrong when the foveal channel is the darker
    one (the paper's F/2 against F/1), where it converges to the swapped solution. The loss does not fix alpha's
    gauge, so a learned alpha drifts along it: alternating's alpha (``alpha_init='classical'`` or
    ``init='classical'``) is held fixed unless ``alpha_lr`` is given.

    A warm start gives each image its own normalisation (its initial estimate's robust range), so a low-contrast
    foveal image is not squashed by the frames' range. ``warm='residual'``: ``x_k = x_init_k + range_k g_k(z_k)``
    with ``g_k``'s output layer zeroed, so step 0 returns the initial estimate exactly; ``'fit'``: ``warm_steps``
    supervised steps fitting ``g_k`` (sigmoid output) to ``x_init_k``, then the loss. With known alpha the
    normalisation range includes the LSQ images (the true images extend beyond the frames' range).

    Step budget: at most ``steps`` steps, fewer when the loss converged (``tol``, ``patience``) or ``max_seconds``
    ran out (``info['stopped']``); a run stopped by the time cap returns the images of its lowest loss, after
    ``info['kept_step']`` steps.

    Defaults: ``tv_weight`` from eq. (2) for a random start, ``exclusion_weight`` 0 for it; both
    :data:`WARM_WEIGHT` after a warm start; ``lr`` :data:`PAPER_LR` for a random start, :data:`WARM_LR` for a warm
    start, cosine-decayed over ``steps``; ``alpha_lr`` 0 (held) for alternating's alpha, else ``lr`` for a random
    start and ``lr / 10`` for a warm start. The foveal term works in the frames' units (mapped to the network's
    normalised range internally). Memory bound: ``channels x H x W <= MAX_CHANNEL_PIXELS`` (an
    :class:`InputError` otherwise).
    """
    use_jax_cache()
    import jax.numpy as jnp

    opt = with_overrides(DipOptions, options, overrides)
    tm = Timings()
    traces0 = _TRACES[0]
    Y = as_frames(frames, min_frames=2)
    if not np.all(np.isfinite(Y)):
        raise InputError("frames", "frames with NaN/inf", "finite frames for the DIP (mask/fill them first)")
    T, H, W = Y.shape
    opt, cps = _checked(opt, H, W)
    gen = as_rng(opt.rng)
    dt = image_dtype(Y)
    with tm.measure("init"):
        alpha, a_init = _start_alpha(Y, opt, alpha)
        xi1, xi2, a_cl = _initial_images(Y, opt.init, alpha, a_init, float(opt.scale), float(opt.foveal_gain),
                                         float(opt.foveal_offset), opt.polarizer)
    warm_start = xi1 is not None
    residual = warm_start and opt.warm == "residual"
    opt = replace(opt, norm=(not warm_start) if opt.norm is None else bool(opt.norm))
    if a_cl is not None:
        a_init = a_cl
    u = _units(Y, xi1, xi2, alpha if alpha is not None else a_init, residual)
    op = FovealOperator((H, W), opt.scale, gain=opt.foveal_gain, bias=opt.foveal_offset) if opt.foveal_weight else None
    # frames in [0.05, 0.95] so that both images fit the sigmoid's range with some margin
    Yn = (0.05 + 0.9 * (Y.astype(np.float64) - u.lo) / u.span).astype(np.float32)
    with tm.measure("init"):
        a0, learn_alpha, w, tv_auto, tv_rule = _alpha_and_weights(Y, Yn, alpha, a_init, opt, warm_start, op, u)
    params, z1, z2 = _networks(gen, opt, (H, W), residual, a0 if learn_alpha else None)
    # everything that varies between calls is an argument of the jitted step, so a second call with
    # the same shapes and switches (another window of a video, a test's rerun) reuses the compilation
    data = {"y": jnp.asarray(Yn), "z1": z1, "z2": z2, "a": jnp.asarray(a0.astype(np.float32)),
            "b1": jnp.asarray(u.base1.astype(np.float32)), "b2": jnp.asarray(u.base2.astype(np.float32)),
            "ab": jnp.asarray(np.array(u.ab, np.float32)),
            "D": [jnp.asarray(m_.astype(np.float32)) for m_ in (op.Dy, op.Dx, op.Cy, op.Cx)] if op else [],
            "c": jnp.asarray(np.array([w["tv"], w["exclusion"], w["foveal"], w["gain_n"], w["bias_n"]], np.float32))}
    render = _make_render(opt.depth, learn_alpha, residual, bool(opt.norm))

    def images(p: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        g1, g2, a = (np.asarray(v, dtype=np.float64) for v in render(p, data))
        return u.to_frames(g1).astype(dt), u.to_frames(g2).astype(dt), a

    fit_hist: list[float] = []
    if warm_start and opt.warm == "fit" and opt.warm_steps:
        with tm.measure("warm_fit"):
            params = _warm_fit(params, z1, z2, u, opt, w["lr"], fit_hist)
    step = _make_step(opt.depth, learn_alpha, op is not None, residual, bool(opt.norm))
    state, hist, recorded, stop = _optimise(step, params, data, opt, w, cps, images, tm)
    x1, x2, a = images(state[0])
    if opt.average and stop["kept_step"]:  # the running means, bias-corrected
        c = 1.0 - opt.average ** stop["kept_step"]
        x1, x2 = (u.to_frames(np.asarray(e, np.float64) / c).astype(dt) for e in state[3:5])
    info = {"steps": opt.steps, "max_seconds": opt.max_seconds, **stop, "channels": opt.channels, "depth": opt.depth,
            "loss_history": hist,
            "alpha_learned": learn_alpha, "tv_weight": w["tv"], "exclusion_weight": w["exclusion"],
            "tv_weight_rule": ({"rule": f"MAP: {AUTO_TV:g} sigma_x^2 / b (random start)", **tv_rule}
                               if tv_auto is not None else ("given" if opt.tv_weight is not None else "default")),
            "foveal_weight": w["foveal"], "foveal_gain": w["gain_n"], "foveal_offset": None if op is None else op.bias,
            "init": opt.init if isinstance(opt.init, str) else "images", "warm": opt.warm if warm_start else None,
            "warm_fit_history": fit_hist, "lr": w["lr"], "alpha_lr": w["alpha_lr"], "schedule": opt.schedule,
            "norm": opt.norm,
            "checkpoints": recorded, "initial_alpha": np.asarray(a0, np.float64),
            "seconds_per_step": tm.get("steps", 0.0) / max(stop["steps_run"] - 1, 1),
            "first_step_seconds": tm.get("compile", 0.0),  # the jitted step's compilation when the shape was new
            "traces": _TRACES[0] - traces0, "device": str(data["y"].devices().pop())}
    if warm_start:
        info["initial"] = (xi1.astype(dt), xi2.astype(dt))
    return Reconstruction(x1=x1, x2=x2, alpha=np.asarray(a, dtype=np.float64), fpn=None, method="dip",
                          timings=dict(tm), info=info)
