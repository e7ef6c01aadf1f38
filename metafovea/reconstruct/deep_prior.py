"""Double deep image prior (DIP) in JAX, as in the paper.

Two skip-U-Nets ``g1``, ``g2`` map fixed random inputs to the foveal and perifoveal images; they and
the mixing ratios (``alpha_t = sigmoid(z_t)``, initialised from frame means as in the paper, or held
fixed when given) are fitted with Adam to

    mean_t ||y_t - alpha_t g1 - (1 - alpha_t) g2||^2 + tv_weight (TV g1 + TV g2)
        + exclusion_weight * exclusion(g1, g2) [+ foveal_weight ||D g1 - C g2||^2]

with the paper's ``tv_weight = exclusion_weight = 0.01``. ``foveal_weight`` (default 0, not in the
paper) adds the foveal constraint, which fixes the alpha gauge the same way as in
:mod:`~metafovea.reconstruct.alternating`.

Network (configurable ``channels``, ``depth``, ``skip_channels``): per level a stride-2 3x3 conv and a
3x3 conv (LeakyReLU 0.2), a 1x1 skip branch, bilinear upsampling, concatenation, 3x3 + 1x1 convs, and a
sigmoid output; batch norm of the original DIP is left out (single image, full batch). Frames are
rescaled to [0, 1] for the sigmoid and the result is mapped back.

Cost on the 2-core reference machine (anchors): 128 channels at 256^2 ~14-18 s per step, 32 channels
~2.3 s per step; thousands of steps are needed, so this is an offline method. JAX is imported only
when :func:`dip` is called.
"""

from __future__ import annotations

import functools
import logging
import time
from typing import Any

import numpy as np

from metafovea.errors import InputError, as_float, check_int
from metafovea.reconstruct._common import Timings, as_alpha, as_frames, as_rng, image_dtype
from metafovea.reconstruct.result import Reconstruction

log = logging.getLogger(__name__)


def _init_params(rng: np.random.Generator, cin: int, ch: int, depth: int, skip: int) -> dict[str, Any]:
    def conv(k: int, ci: int, co: int) -> dict[str, np.ndarray]:
        std = np.sqrt(2.0 / (k * k * ci))
        return {"w": (rng.normal(0, std, (co, ci, k, k))).astype(np.float32), "b": np.zeros(co, np.float32)}

    p: dict[str, Any] = {"down": [], "skip": [], "up": []}
    c = cin
    for _ in range(depth):
        p["down"].append([conv(3, c, ch), conv(3, ch, ch)])
        p["skip"].append(conv(1, c, skip))
        c = ch
    for lev in range(depth):
        cin_up = ch + skip
        p["up"].append([conv(3, cin_up, ch), conv(1, ch, ch)])
    p["out"] = conv(1, ch, 1)
    return p


def _build(depth: int):
    import jax
    import jax.numpy as jnp

    def conv(x, c, stride=1):
        k = c["w"].shape[-1]
        y = jax.lax.conv_general_dilated(x, c["w"], (stride, stride), [(k // 2, k // 2)] * 2,
                                         dimension_numbers=("NCHW", "OIHW", "NCHW"))
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
        return jax.nn.sigmoid(conv(x, p["out"]))[0, 0]

    return net


@functools.lru_cache(maxsize=16)
def _make_step(depth: int, learn_alpha: bool, foveal: bool):
    """Jitted Adam step ``(p, m, v, t, data) -> (p, m, v, loss)`` for one network depth and switches."""
    import jax
    import jax.numpy as jnp

    net = _build(depth)

    def tv(x):
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
        g1 = net(p["g1"], data["z1"])
        g2 = net(p["g2"], data["z2"])
        a = jax.nn.sigmoid(p["alpha"]) if learn_alpha else data["a"]
        model = a[:, None, None] * g1[None] + (1 - a)[:, None, None] * g2[None]
        loss = jnp.mean((data["y"] - model) ** 2) + tvw * (tv(g1) + tv(g2)) + exw * excl(g1, g2)
        if foveal:
            Dm = data["D"]
            r = Dm[0] @ g1 @ Dm[1].T - gain_n * (Dm[2] @ g2 @ Dm[3].T) - bias_n
            loss = loss + fw * jnp.mean(r ** 2)
        return loss

    b1, b2, eps = 0.9, 0.999, 1e-8

    @jax.jit
    def step(p, m, v, t, data):
        lr = data["c"][5]
        loss, g = jax.value_and_grad(loss_fn)(p, data)
        m = jax.tree_util.tree_map(lambda mi, gi: b1 * mi + (1 - b1) * gi, m, g)
        v = jax.tree_util.tree_map(lambda vi, gi: b2 * vi + (1 - b2) * gi * gi, v, g)
        mh = 1 - b1 ** t
        vh = 1 - b2 ** t
        p = jax.tree_util.tree_map(lambda pi, mi, vi: pi - lr * (mi / mh) / (jnp.sqrt(vi / vh) + eps), p, m, v)
        return p, m, v, loss

    return step


def dip(frames: Any, alpha: Any = None, *, channels: int = 32, depth: int = 3, skip_channels: int = 4,
        input_channels: int = 8, steps: int = 2000, lr: float = 0.01, tv_weight: float = 0.01,
        exclusion_weight: float = 0.01, foveal_weight: float = 0.0, scale: float = 6.0,
        foveal_gain: float = 1.0, foveal_offset: float = 0.0, alpha_init: Any = "means",
        rng: Any = None, log_every: int = 0) -> Reconstruction:
    """Fit the double DIP to ``frames (T, H, W)``; ``alpha`` given = held fixed, else learned.

    ``alpha_init`` (unknown alpha): ``'means'`` initialises alpha from the frame means as in the paper
    (which labels the brighter frames as more foveal: wrong when the foveal channel is the darker one, as
    with the paper's F/2 vs F/1 lenses, where it converges to the swapped solution), or ``(T,)`` values,
    e.g. the classical solver's estimate (``alternating(...).alpha``), which the DIP then refines.

    The foveal term (``foveal_weight > 0``) uses ``D x1 = foveal_gain C x2 + foveal_offset`` in the
    frames' units (mapped to the network's normalised range internally). With known ``alpha`` the
    normalisation range includes the LSQ images (the true images extend beyond the frames' range).

    ``rng`` seeds the network weights and inputs (same seed, same result on one machine).
    """
    import jax
    import jax.numpy as jnp

    from metafovea.reconstruct.alternating import frame_mean_alpha
    from metafovea.reconstruct.operators import FovealOperator

    tm = Timings()
    Y = as_frames(frames, min_frames=2)
    if not np.all(np.isfinite(Y)):
        raise InputError("frames", "frames with NaN/inf", "finite frames for the DIP (mask/fill them first)")
    T, H, W = Y.shape
    channels = check_int("channels", channels, 1, 4096)
    depth = check_int("depth", depth, 1, 8)
    if min(H, W) < 2 ** depth:
        raise InputError("depth", depth, f"2**depth <= min(H, W) = {min(H, W)}")
    steps = check_int("steps", steps, 1, 10_000_000)
    lr = as_float("lr", lr)
    gen = as_rng(rng)
    dt = image_dtype(Y)
    lo, hi = float(Y.min()), float(Y.max())
    a_init = None
    if alpha is None and not (isinstance(alpha_init, str) and alpha_init == "means"):
        if isinstance(alpha_init, str):
            raise InputError("alpha_init", alpha_init, "'means' or an array of T mixing ratios")
        a_init = as_alpha(alpha_init, T, name="alpha_init")
    if alpha is not None or a_init is not None:
        from metafovea.reconstruct.lsq import lsq_known_alpha

        try:
            ls = lsq_known_alpha(Y, alpha if alpha is not None else a_init, regularize="difference")
            lo = min(lo, float(np.min(ls.x1)), float(np.min(ls.x2)))
            hi = max(hi, float(np.max(ls.x1)), float(np.max(ls.x2)))
        except InputError:
            pass  # as_alpha below reports bad alpha
    span = hi - lo if hi > lo else 1.0
    # frames in [0.05, 0.95] so that both images fit the sigmoid's range with some margin
    Yn = (0.05 + 0.9 * (Y.astype(np.float64) - lo) / span).astype(np.float32)
    learn_alpha = alpha is None
    if learn_alpha:
        a0 = frame_mean_alpha(Yn) if a_init is None else a_init
    else:
        a0 = as_alpha(alpha, T)
    z_alpha = np.log(np.clip(a0, 0.02, 0.98) / (1 - np.clip(a0, 0.02, 0.98))).astype(np.float32)
    params = {"g1": _init_params(gen, input_channels, channels, depth, skip_channels),
              "g2": _init_params(gen, input_channels, channels, depth, skip_channels)}
    if learn_alpha:
        params["alpha"] = z_alpha
    params = jax.tree_util.tree_map(jnp.asarray, params)
    z1 = jnp.asarray(gen.uniform(0, 0.1, (1, input_channels, H, W)).astype(np.float32))
    z2 = jnp.asarray(gen.uniform(0, 0.1, (1, input_channels, H, W)).astype(np.float32))
    net = _build(depth)
    op = FovealOperator((H, W), scale, gain=foveal_gain, bias=foveal_offset) if foveal_weight else None
    # the constraint in normalised units yn = A y + B: D x1n = gain C x2n + (1 - gain) B + A bias
    A_n, B_n = 0.9 / span, 0.05 - 0.9 * lo / span
    bias_n = 0.0 if op is None else float((1 - op.gain) * B_n + A_n * op.bias)
    gain_n = 1.0 if op is None else float(op.gain)
    tvw, exw, fw = (float(v) for v in (tv_weight, exclusion_weight, foveal_weight))
    # everything that varies between calls is an argument of the jitted step, so a second call with
    # the same shapes and switches (another window of a video, a test's rerun) reuses the compilation
    data = {"y": jnp.asarray(Yn), "z1": z1, "z2": z2, "a": jnp.asarray(a0.astype(np.float32)),
            "D": [jnp.asarray(m_.astype(np.float32)) for m_ in (op.Dy, op.Dx, op.Cy, op.Cx)] if op else [],
            "c": jnp.asarray(np.array([tvw, exw, fw, gain_n, bias_n, lr], np.float32))}
    step = _make_step(depth, learn_alpha, op is not None)
    m = jax.tree_util.tree_map(jnp.zeros_like, params)
    v = jax.tree_util.tree_map(jnp.zeros_like, params)
    hist: list[float] = []
    with tm.measure("compile"):
        params, m, v, loss = step(params, m, v, 1.0, data)
        hist.append(float(loss))
    t0 = time.perf_counter()
    with tm.measure("steps"):
        for k in range(2, steps + 1):
            params, m, v, loss = step(params, m, v, float(k), data)
            if k % max(1, steps // 200) == 0 or k == steps:
                hist.append(float(loss))
            if log_every and k % log_every == 0:
                log.info("dip step %d/%d loss %.4g (%.2f s/step)", k, steps, float(loss),
                         (time.perf_counter() - t0) / (k - 1))
    g1 = np.asarray(net(params["g1"], z1), dtype=np.float64)
    g2 = np.asarray(net(params["g2"], z2), dtype=np.float64)
    a = np.asarray(jax.nn.sigmoid(params["alpha"])) if learn_alpha else a0
    x1 = ((g1 - 0.05) / 0.9 * span + lo).astype(dt)
    x2 = ((g2 - 0.05) / 0.9 * span + lo).astype(dt)
    info = {"steps": steps, "channels": channels, "depth": depth, "loss_history": hist, "alpha_learned": learn_alpha,
            "tv_weight": tvw, "exclusion_weight": exw, "foveal_weight": fw,
            "foveal_gain": gain_n, "foveal_offset": None if op is None else op.bias,
            "seconds_per_step": tm["steps"] / max(steps - 1, 1)}
    return Reconstruction(x1=x1, x2=x2, alpha=np.asarray(a, dtype=np.float64), fpn=None, method="dip",
                          timings=dict(tm), info=info)
