"""A ramp signal: constant rate, e.g. a brake rotor's angle at constant speed."""

import equinox as eqx
import jax.numpy as jnp

from ._custom_types import Array, Float
from ._misc import as_float_array
from ._signal import AbstractSignal


class Ramp(AbstractSignal):
    r"""$s(t) = s_0 + r\,t$: constant rate $r$, e.g. the rotor angle [rad] of a brake
    turning at constant speed $r$ [rad/s] (60 rpm is $2\pi$ rad/s).

    **Arguments:**

    - `rate`: $r$, in the signal's unit per second.
    - `offset`: $s_0$, the value at $t = 0$, in the signal's unit (default 0).
    """

    rate: Float[Array, ""] = eqx.field(converter=as_float_array)
    offset: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __call__(self, t):
        return self.offset + self.rate * t

    def derivative(self, t):
        return self.rate + 0.0 * t

    def bounds(self):
        # Unbounded over all time unless the rate is zero.
        inf = jnp.where(self.rate == 0, 0.0, jnp.inf)
        return self.offset - inf, self.offset + inf
