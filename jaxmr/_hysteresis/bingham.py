"""Bingham plastic: Coulomb friction in parallel with a dashpot (Stanway 1985)."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import Parameter, as_parameter
from .._custom_types import Array, Float, Scalar, State
from .._misc import Check
from .base import AbstractHysteresis


class Bingham(AbstractHysteresis):
    r"""Bingham model, $F = f_c(i)\,\mathrm{sgn}(v) + c_0(i)\,v + f_0$.

    Static (no internal state). The exact sign is discontinuous at $v = 0$: set
    `velocity_scale` $v_s > 0$ to use $\tanh(v / v_s)$ instead, which is what a gradient
    with respect to the input or a smooth closed loop needs. For a rotary brake read
    $v$ as angular velocity [rad/s] and $F$ as torque [N·m].

    **Arguments:**

    - `f_c`: yield (friction) force [N] or torque [N·m], ≥ 0; may be a current law.
    - `c0`: post-yield viscous coefficient [N·s/m] or [N·m·s/rad], ≥ 0; may be a law.
    - `f0`: force offset [N] or [N·m] (accumulator pressure, sensor bias).
    - `velocity_scale`: $v_s$ [m/s] or [rad/s]; 0 (default) for the exact sign, a
      form of the model that a fit leaves alone (give $v_s > 0$ to fit it).
    """

    f_c: Parameter = eqx.field(converter=as_parameter)
    c0: Parameter = eqx.field(converter=as_parameter)
    f0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    velocity_scale: Float[Array, ""] = eqx.field(converter=as_parameter, default=0.0)
    state_names: ClassVar[tuple[str, ...]] = ()
    # 0 is the exact sign, a form of the model: a fit leaves it there
    # (`jaxmr._parameter.fixed_by_class`).
    fit_modes: ClassVar[dict[str, float]] = {"velocity_scale": 0.0}

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        return state

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        smooth = self.velocity_scale > 0
        scale = jnp.where(smooth, self.velocity_scale, 1.0)
        direction = jnp.where(smooth, jnp.tanh(v / scale), jnp.sign(v))
        return self.f_c * direction + self.c0 * v + self.f0

    def yield_force(self) -> Scalar:
        return self.f_c

    def constraints(self):
        return [
            Check(self.f_c >= 0, "the yield force `f_c` must be >= 0", self.f_c),
            Check(self.c0 >= 0, "the viscous coefficient `c0` must be >= 0", self.c0),
            Check(
                self.velocity_scale >= 0,
                "`velocity_scale` must be >= 0 (0 for the exact sign)",
                self.velocity_scale,
            ),
        ]
