"""The optimiser's variables: how tuned parameters are selected and mapped.

`parameters(pair)` selects leaves of `(system, controller)` (the `eqx.tree_at`
convention). The optimisers work on unbounded variables u, one array per leaf: the
values themselves (`space` False), their logarithms (True: positive parameters,
relative steps), or, with bounds, value = exp(log lo + (log hi - log lo) sigmoid(u)),
inside the bounds whatever u.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np


def to_values(us, space) -> tuple:
    if space is False:
        return tuple(us)
    if space is True:
        return tuple(jnp.exp(u) for u in us)
    return tuple(
        jnp.exp(np.log(lo) + (np.log(hi) - np.log(lo)) * jax.nn.sigmoid(u))
        for u, (lo, hi) in zip(us, space, strict=True)
    )


def from_values(values, space, who: str) -> tuple:
    if space is False:
        return tuple(values)
    if space is True:
        return tuple(jnp.log(v) for v in values)
    out = []
    for v, (lo, hi) in zip(values, space, strict=True):
        p = (jnp.log(v) - np.log(lo)) / (np.log(hi) - np.log(lo))
        if not np.all((np.asarray(p) > 0) & (np.asarray(p) < 1)):
            raise ValueError(
                f"{who}: a starting value {v} lies outside its bounds ({lo}, {hi})."
            )
        out.append(jnp.log(p / (1 - p)))
    return tuple(out)


def as_space(log_space: bool, bounds, who: str):
    """`False`, `True` or a tuple of (low, high) per parameter."""
    if bounds is None:
        return bool(log_space)
    if not log_space:
        raise ValueError(f"{who}: `bounds` need `log_space=True`.")
    space = tuple((float(lo), float(hi)) for lo, hi in bounds)
    if any(not 0 < lo < hi for lo, hi in space):
        raise ValueError(f"{who}: `bounds` must be 0 < low < high, got {bounds}.")
    return space


def initial_values(pair, where, log_space: bool, who: str) -> tuple:
    values = tuple(jnp.asarray(v) for v in where(pair))
    if not values:
        raise ValueError(f"{who}: `parameters` selected no leaves.")
    for v in values:
        if not jnp.issubdtype(v.dtype, jnp.inexact):
            raise TypeError(
                f"{who}: every tuned parameter must be a floating-point array, got "
                f"dtype {v.dtype}."
            )
        if log_space and not np.all(np.asarray(v) > 0):
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
