"""An open-loop current schedule: the ceiling a causal law is measured against."""

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import Array, Float
from .._misc import as_float_array, check_concrete
from .base import AbstractController


class CurrentSchedule(AbstractController):
    r"""A prescribed current at every sample, $i_k = I_\max\,\sigma(u_k)$ (logistic
    $\sigma$, so any real $u_k$ is a valid current and gradient descent on $u$ needs no
    bounds).

    Not a controller one could build — it knows the road in advance — but, optimised
    by gradients for one road (`tune` on `logits`), the best any current command could
    do on it: the bound a causal law's performance is measured against.

    **Arguments:**

    - `logits`: $u_k$, one per controller sample (samples beyond its end hold the last).
    - `i_max`: $I_\max$ [A].
    - `dt`: the sample time [s] the schedule is indexed by (static).
    """

    logits: Float[Array, " samples"] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    dt: float = eqx.field(static=True, default=1e-3)
    # Open loop: it reads only the clock, the default measurement of its export.
    reads_time: ClassVar[bool] = True

    def __check_init__(self):
        check_concrete(
            self.i_max > 0,
            "CurrentSchedule: `i_max` must be > 0 A (the top of the current range), "
            f"got {self.i_max}.",
            self.i_max,
        )
        if self.logits.ndim != 1 or self.logits.shape[0] == 0:
            raise ValueError(
                "CurrentSchedule: `logits` must be a 1-D array of at least one value "
                f"(one per controller sample), got shape {self.logits.shape}."
            )
        if not (
            isinstance(self.dt, (int, float)) and math.isfinite(self.dt) and self.dt > 0
        ):
            raise ValueError(f"CurrentSchedule: `dt` must be > 0 s, got {self.dt!r}.")

    @classmethod
    def constant(cls, current, samples: int, i_max, dt: float = 1e-3):
        """A schedule holding `current` [A] (strictly inside (0, i_max))."""
        p = jnp.asarray(current) / jnp.asarray(i_max)
        return cls(jnp.full((samples,), jnp.log(p / (1 - p))), i_max, dt)

    def __call__(self, measurement, state, plant):
        k = jnp.round(measurement["time"] / self.dt).astype(int)
        k = jnp.clip(k, 0, self.logits.shape[0] - 1)
        return self.i_max * jax.nn.sigmoid(self.logits[k]), state
