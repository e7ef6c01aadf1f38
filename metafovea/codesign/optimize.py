"""A bounded, resumable first-order optimiser over named parameter arrays: optax's Adam on scaled variables,
projected onto box bounds after each step, with a checkpoint file that a stopped run resumes from.

The problem is given as a JAX-differentiable loss of a dict of arrays (``loss(params) -> (value, aux)``, ``aux`` a
dict of scalars recorded in the history) with, per array, a box ``(lo, hi)`` and a scale (the size of a change that
matters: the step lengths are in these units, so arrays of very different magnitudes move together). The best
iterate (lowest loss) is returned, not the last; the history holds every step's loss and aux values.

Checkpoint (``.npz``, written atomically every ``checkpoint_every`` steps, on a stop (Ctrl-C) and at the end): the
step, the parameters, the optimiser state's leaves, the best parameters, the history and a ``problem_key`` (a
hash of what defines the problem, given by the caller): a checkpoint of another problem is refused rather than
resumed. A resumed run continues exactly where the stopped one was (same optimiser state), so ``steps`` counts
the total, not the remainder.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from metafovea.errors import InputError, check_int, check_positive
from metafovea.io import atomic_save_npz, load_npz, use_jax_cache
from metafovea.parallel import progress_bar

#: the checkpoint file's format (raise when the layout changes: an old file is then refused, not misread)
CHECKPOINT_VERSION = 1


@dataclass(frozen=True)
class OptimizeOptions:
    """``steps``: total Adam steps (a resumed run counts the steps already made); ``learning_rate``: the step in
    scaled units (a parameter's scale is the change that matters); ``checkpoint_every``: steps between
    checkpoints; ``progress``: show progress (a line per few seconds, or a bar on a terminal)."""

    steps: int = 200
    learning_rate: float = 0.05
    checkpoint_every: int = 10
    progress: bool = True

    def __post_init__(self) -> None:
        check_int("steps", self.steps, 1, 1_000_000)
        check_positive("learning_rate", self.learning_rate)
        check_int("checkpoint_every", self.checkpoint_every, 1, 1_000_000)


@dataclass(frozen=True)
class Bounds:
    """Per parameter array: lower and upper bounds (broadcast to its shape) and its scale (> 0)."""

    lo: np.ndarray
    hi: np.ndarray
    scale: np.ndarray

    def __post_init__(self) -> None:
        if np.any(np.asarray(self.lo) > np.asarray(self.hi)):
            raise InputError("bounds", "lo > hi", "lower bounds <= upper bounds")
        if np.any(np.asarray(self.scale) <= 0) or not np.all(np.isfinite(self.scale)):
            raise InputError("scale", "<= 0", "finite scales > 0")


@dataclass
class OptimizeResult:
    """The best parameters, their loss and aux values, the history (per step: ``loss`` and every aux key), the
    steps made in total and whether the run was resumed from a checkpoint (at which step)."""

    params: dict[str, np.ndarray]
    loss: float
    aux: dict[str, float]
    history: dict[str, np.ndarray]
    steps: int
    resumed_from: int | None = None
    info: dict[str, Any] = field(default_factory=dict)


def _checkpoint_arrays(step, params, best, best_loss, opt_leaves, history, key) -> tuple[dict, dict]:
    arrays = {f"p_{k}": np.asarray(v) for k, v in params.items()}
    arrays.update({f"b_{k}": np.asarray(v) for k, v in best.items()})
    arrays.update({f"s_{i}": np.asarray(v) for i, v in enumerate(opt_leaves)})
    arrays.update({f"h_{k}": np.asarray(v, dtype=np.float64) for k, v in history.items()})
    meta = {"checkpoint_version": CHECKPOINT_VERSION, "step": int(step), "best_loss": float(best_loss),
            "problem_key": key, "n_state": len(opt_leaves), "names": sorted(params), "history": sorted(history)}
    return arrays, meta


def read_checkpoint(path: str | Path, problem_key: str) -> dict[str, Any] | None:
    """The checkpoint at ``path`` as a dict (step, params, best, best_loss, state leaves, history), None if there is
    no file; an :class:`InputError` when it belongs to another problem or format."""
    p = Path(path)
    if not p.is_file():
        return None
    arrays, meta = load_npz(p, name="checkpoint")
    if meta.get("checkpoint_version") != CHECKPOINT_VERSION or meta.get("problem_key") != problem_key:
        raise InputError("checkpoint", str(p), "a checkpoint of this same problem (options, system and band); "
                         "start afresh with another output folder or force=True")
    names = meta["names"]
    return {"step": int(meta["step"]), "best_loss": float(meta["best_loss"]),
            "params": {k: arrays[f"p_{k}"] for k in names}, "best": {k: arrays[f"b_{k}"] for k in names},
            "state": [arrays[f"s_{i}"] for i in range(int(meta["n_state"]))],
            "history": {k: list(arrays[f"h_{k}"]) for k in meta["history"]}}


def minimize(loss: Callable[[dict[str, Any]], tuple[Any, dict[str, Any]]], x0: dict[str, np.ndarray],
             bounds: dict[str, Bounds], options: OptimizeOptions = OptimizeOptions(), *,
             checkpoint: str | Path | None = None, problem_key: str = "", desc: str = "optimise",
             on_step: Callable[[int, float, dict[str, float]], None] | None = None) -> OptimizeResult:
    """Minimise ``loss`` over the arrays of ``x0`` within ``bounds`` (see the module docstring).

    Parameters
    ----------
    loss : callable
        ``loss(params) -> (value, aux)``: JAX-differentiable in ``params`` (a dict of arrays like ``x0``); ``aux`` a
        dict of scalars (recorded per step).
    x0 : dict of name -> ndarray
        The start (clipped into the bounds).
    bounds : dict of name -> Bounds
        Box and scale of every array of ``x0``.
    options : OptimizeOptions
    checkpoint : path or None
        The checkpoint file: resumed from when it exists and holds this ``problem_key``; written every
        ``options.checkpoint_every`` steps, when stopped (KeyboardInterrupt, re-raised after writing) and at the end.
    problem_key : str
        Identifies the problem (a hash of its definition): a checkpoint with another key is refused.
    desc : str
        The progress line's label.
    on_step : callable or None
        Called after every step with (step, loss, aux).

    Returns
    -------
    OptimizeResult
        The best iterate (the lowest loss seen, the start included).
    """
    use_jax_cache()
    import jax

    if set(x0) != set(bounds):
        raise InputError("bounds", sorted(bounds), f"one Bounds per parameter array: {sorted(x0)}")
    with jax.enable_x64(True):  # scoped: float64 throughout the optimisation, nothing global changed
        return _minimize(loss, x0, bounds, options, checkpoint, problem_key, desc, on_step)


def _minimize(loss, x0, bounds, options, checkpoint, problem_key, desc, on_step) -> OptimizeResult:
    import jax
    import jax.numpy as jnp
    import optax

    if set(x0) != set(bounds):
        raise InputError("bounds", sorted(bounds), f"one Bounds per parameter array: {sorted(x0)}")
    names = sorted(x0)
    scale = {k: jnp.asarray(np.broadcast_to(bounds[k].scale, np.shape(x0[k])), dtype=jnp.float64) for k in names}
    lo = {k: np.broadcast_to(bounds[k].lo, np.shape(x0[k])) / np.asarray(scale[k]) for k in names}
    hi = {k: np.broadcast_to(bounds[k].hi, np.shape(x0[k])) / np.asarray(scale[k]) for k in names}

    def to_x(u):
        return {k: u[k] * scale[k] for k in names}

    def scaled_loss(u):
        return loss(to_x(u))

    value_and_grad = jax.jit(jax.value_and_grad(scaled_loss, has_aux=True))
    opt = optax.adam(options.learning_rate)
    u = {k: jnp.clip(jnp.asarray(x0[k], dtype=jnp.float64) / scale[k], lo[k], hi[k]) for k in names}
    state = opt.init(u)
    step, resumed = 0, None
    history: dict[str, list[float]] = {"loss": []}
    best_u, best_loss, best_aux = u, math.inf, {}
    ck = read_checkpoint(checkpoint, problem_key) if checkpoint is not None else None
    if ck is not None:
        u = {k: jnp.asarray(ck["params"][k], dtype=jnp.float64) / scale[k] for k in names}
        leaves, treedef = jax.tree_util.tree_flatten(opt.init(u))
        if len(leaves) != len(ck["state"]):
            raise InputError("checkpoint", str(checkpoint), "a checkpoint of this optimiser (its state differs)")
        state = jax.tree_util.tree_unflatten(treedef, [jnp.asarray(s) for s in ck["state"]])
        step = resumed = ck["step"]
        history = ck["history"]
        best_u = {k: jnp.asarray(ck["best"][k], dtype=jnp.float64) / scale[k] for k in names}
        best_loss = ck["best_loss"]

    def save() -> None:
        if checkpoint is None:
            return
        arrays, meta = _checkpoint_arrays(step, {k: np.asarray(v) for k, v in to_x(u).items()},
                                          {k: np.asarray(v) for k, v in to_x(best_u).items()}, best_loss,
                                          [np.asarray(x) for x in jax.tree_util.tree_leaves(state)], history,
                                          problem_key)
        atomic_save_npz(checkpoint, meta, **arrays)

    bar = progress_bar(options.steps, desc, "step", enabled=options.progress, initial=step)
    try:
        with bar:
            while step < options.steps:
                (val, aux), g = value_and_grad(u)
                val = float(val)
                aux = {k: float(v) for k, v in aux.items()}
                if not math.isfinite(val) or not all(bool(jnp.all(jnp.isfinite(g[k]))) for k in names):
                    raise FloatingPointError(f"{desc}: the loss or its gradient is not finite at step {step}")
                history["loss"].append(val)
                for k, v in aux.items():
                    history.setdefault(k, []).append(v)
                if val < best_loss:
                    best_u, best_loss, best_aux = u, val, aux
                updates, state = opt.update(g, state, u)
                u = optax.apply_updates(u, updates)
                u = {k: jnp.clip(u[k], lo[k], hi[k]) for k in names}
                step += 1
                bar.update(1)
                bar.set_postfix_str(f"loss {val:.5g}")
                if on_step is not None:
                    on_step(step, val, aux)
                if step % options.checkpoint_every == 0:
                    save()
            (val, aux), _ = value_and_grad(u)  # the last iterate's loss (the loop scored the one before it)
            if float(val) < best_loss:
                best_u, best_loss, best_aux = u, float(val), {k: float(v) for k, v in aux.items()}
    except KeyboardInterrupt:
        save()
        raise
    save()
    if not best_aux:
        _, aux = scaled_loss(best_u)
        best_aux = {k: float(v) for k, v in aux.items()}
    return OptimizeResult({k: np.asarray(v) for k, v in to_x(best_u).items()}, float(best_loss), best_aux,
                          {k: np.asarray(v, dtype=np.float64) for k, v in history.items()}, step, resumed)
