"""Dahl friction model with current-dependent stiffnesses."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import Parameter, as_parameter
from .._custom_types import Scalar, State
from .._misc import Check
from .base import AbstractHysteresis


class Dahl(AbstractHysteresis):
    r"""Dahl model, $F = k_x(i)\,v + k_w(i)\,z$, $\dot z = \rho\,(v - |v|\,z)$.

    $z$ is dimensionless and stays in $[-1, 1]$; it approaches $\mathrm{sgn}(v)$ over a
    displacement of order $1/\rho$, so at steady sliding $F \to k_w\,\mathrm{sgn}(v) +
    k_x v$ (a smoothed Bingham law).

    **Arguments:**

    - `k_x`: viscous coefficient [N·s/m] or [N·m·s/rad]; may be a law.
    - `k_w`: friction force amplitude [N] or [N·m]; may be a law.
    - `rho`: $\rho$ [1/m] or [1/rad], > 0.
    """

    k_x: Parameter = eqx.field(converter=as_parameter)
    k_w: Parameter = eqx.field(converter=as_parameter)
    rho: Parameter = eqx.field(converter=as_parameter)
    state_names: ClassVar[tuple[str, ...]] = ("z",)

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        z = state[0]
        return (self.rho * (v - jnp.abs(v) * z))[None]

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        return self.k_x * v + self.k_w * state[0]

    def yield_force(self) -> Scalar:
        return self.k_w  # |z| <= 1

    def state_bounds(self):
        return jnp.ones((1,), dtype=jnp.result_type(self.rho))

    def constraints(self):
        return [
            Check(self.rho > 0, "`rho` must be > 0", self.rho),
            Check(
                self.k_x >= 0,
                "`k_x` must be >= 0 (a negative dashpot generates energy)",
                self.k_x,
            ),
            Check(
                self.k_w >= 0,
                "`k_w` must be >= 0 (a negative friction force generates energy)",
                self.k_w,
            ),
        ]
