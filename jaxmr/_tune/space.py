"""The optimiser's variables: how tuned parameters are selected and mapped.

`parameters(pair)` selects leaves of `(system, controller)` (the `eqx.tree_at`
convention). The optimisers work on unbounded variables u, one array per leaf: the
values themselves (space False), their logarithms (True: positive parameters,
relative steps), or, with bounds (lo, hi), value = exp(log lo + (log hi - log lo)
sigmoid(u)), inside the bounds whatever u. A space is one of these for every leaf, or
a tuple of one per leaf (signed weights tuned with positive filter corners).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np


def per_leaf(space, count: int) -> tuple:
    """The space of each of `count` leaves: False, True or (lo, hi)."""
    return space if isinstance(space, tuple) else (space,) * count


def to_values(us, space) -> tuple:
    return tuple(
        _to_value(u, entry)
        for u, entry in zip(us, per_leaf(space, len(us)), strict=True)
    )


def _to_value(u, entry):
    if entry is False:
        return u
    if entry is True:
        return jnp.exp(u)
    lo, hi = entry
    return jnp.exp(np.log(lo) + (np.log(hi) - np.log(lo)) * jax.nn.sigmoid(u))


def from_values(values, space, who: str) -> tuple:
    return tuple(
        _from_value(v, entry, who)
        for v, entry in zip(values, per_leaf(space, len(values)), strict=True)
    )


def _from_value(v, entry, who: str):
    if entry is False:
        return v
    if entry is True:
        return jnp.log(v)
    lo, hi = entry
    p = (jnp.log(v) - np.log(lo)) / (np.log(hi) - np.log(lo))
    if not np.all((np.asarray(p) > 0) & (np.asarray(p) < 1)):
        raise ValueError(
            f"{who}: a starting value {v} lies outside its bounds ({lo}, {hi})."
        )
    return jnp.log(p / (1 - p))


def as_space(log_space, bounds, who: str):
    """`False` or `True` for every leaf, or a tuple of False, True or (low, high) per
    leaf: `log_space` a bool or one per parameter, `bounds` None or a (low, high) per
    parameter (None for an unbounded one)."""
    if isinstance(log_space, (list, tuple)):
        logs = tuple(log_space)
        if not logs or not all(isinstance(x, (bool, np.bool_)) for x in logs):
            raise TypeError(
                f"{who}: `log_space` must be a bool or one bool per parameter, got "
                f"{log_space!r}."
            )
        logs = tuple(bool(x) for x in logs)
    elif isinstance(log_space, (bool, np.bool_)):
        logs = bool(log_space)
    else:
        raise TypeError(
            f"{who}: `log_space` must be a bool or one bool per parameter, got "
            f"{log_space!r}."
        )
    if bounds is None:
        return logs
    bounds = tuple(bounds)
    if isinstance(logs, tuple) and len(logs) != len(bounds):
        raise ValueError(
            f"{who}: `log_space` and `bounds` must have one entry per parameter, got "
            f"{len(logs)} and {len(bounds)}."
        )
    logs = per_leaf(logs, len(bounds))
    space = []
    for log, bound in zip(logs, bounds, strict=True):
        if bound is None:
            space.append(log)
            continue
        if not log:
            raise ValueError(
                f"{who}: `bounds` need `log_space=True` (for that parameter)."
            )
        lo, hi = (float(b) for b in bound)
        if not 0 < lo < hi:
            raise ValueError(f"{who}: `bounds` must be 0 < low < high, got {bounds}.")
        space.append((lo, hi))
    return tuple(space)


def initial_values(pair, where, space, who: str) -> tuple:
    values = tuple(jnp.asarray(v) for v in where(pair))
    if not values:
        raise ValueError(f"{who}: `parameters` selected no leaves.")
    if isinstance(space, tuple) and len(space) != len(values):
        raise ValueError(
            f"{who}: `log_space` or `bounds` give {len(space)} entries, but "
            f"`parameters` selected {len(values)} arrays: give one per array."
        )
    for v, entry in zip(values, per_leaf(space, len(values)), strict=True):
        if not jnp.issubdtype(v.dtype, jnp.inexact):
            raise TypeError(
                f"{who}: every tuned parameter must be a floating-point array, got "
                f"dtype {v.dtype}."
            )
        if entry is not False and not np.all(np.asarray(v) > 0):
            raise ValueError(
                f"{who}: every tuned parameter must be positive (they are optimised "
                "in log space, as gains and damping coefficients are), got "
                f"{v}; pass `log_space=False` for signed parameters (weights)."
            )
    return values


@functools.lru_cache(maxsize=64)
def as_tuple_where(parameters):
    # Cached on the user's function, so repeated calls with it reuse the compiled loss
    # (the wrapper is a static argument of the jitted functions).
    def where(pair):
        leaves = parameters(pair)
        return tuple(leaves) if isinstance(leaves, (tuple, list)) else (leaves,)

    return where
