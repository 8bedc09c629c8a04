"""The Lyapunov law (Leitmann 1994)."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Array, Float
from .._misc import as_float_array, check_concrete
from .base import AbstractController
from .riccati import solve_lyapunov
from .smooth import angular_switch, check_range_and_temperature, clip_command, gate
from .state_space import measured_state

# The damper velocity of the 4-state model, v = Cᵀx.
_DAMPER_VELOCITY = (0.0, 1.0, 0.0, -1.0)


class LyapunovController(AbstractController):
    r"""Lyapunov control: full current when the damper force makes
    $V = x^\top P x$ fall fastest,
    $$i = I_\max\, H(-(x^\top P B)\, v)\quad(H(0) = 0),$$
    with $A^\top P + P A = -Q$ for the linear model $\dot x = A x + B F$, the measured
    state $x = (z_s, \dot z_s, z_u, \dot z_u)$ [m, m/s], the damper force $F$ [N] and
    velocity $v$ [m/s]: $\dot V = -x^\top Q x + 2 x^\top P B\,F$ and a passive $F$ has
    the sign of $v$. Build it with `LyapunovController.design(A, B, Q, i_max)`.

    Relaxed ($T > 0$): $i = I_\max\,\sigma(\hat s/T)$, $\hat s = 2ab/(a^2 + b^2)$ with
    $a = -x^\top P B/\sqrt{B^\top P B}$ and $b = v/\sqrt{C^\top P^{-1} C}$,
    $C = (0, 1, 0, -1)$: both are bounded by $\sqrt{V}$ (Cauchy–Schwarz in the $P$
    metric), so $\hat s$ is dimensionless and unchanged by a rescaling of $Q$, as is
    the hard law.

    **Arguments:**

    - `P`: the Lyapunov matrix, (4, 4), symmetric positive definite.
    - `B`: the force input of the model, (4,) [1/kg] (`quarter_car_state_space`).
    - `i_max`: the "on" current $I_\max$ [A].
    - `temperature`: $T \ge 0$, dimensionless; 0 (default) is the hard law.
    """

    # It reads positions: `ObserverBasedController`'s estimator estimates them.
    reads_positions: ClassVar[bool] = True

    P: Float[Array, "4 4"] = eqx.field(converter=as_float_array)
    B: Float[Array, "4"] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        if self.P.shape[-2:] != (4, 4) or self.B.shape[-1:] != (4,):
            raise ValueError(
                "LyapunovController: `P` must be (4, 4) and `B` (4,) for the state "
                f"(zs, vs, zu, vu), got {self.P.shape} and {self.B.shape} (flatten a "
                "(4, 1) `B`)."
            )
        check_concrete(
            jnp.allclose(self.P, jnp.swapaxes(self.P, -1, -2))
            & jnp.all(jnp.linalg.eigvalsh(self.P) > 0),
            "LyapunovController: `P` must be symmetric positive definite: solve "
            "AᵀP + PA = -Q with a stable A and Q > 0 (`solve_lyapunov`).",
            self.P,
        )
        check_range_and_temperature("LyapunovController", self.i_max, self.temperature)

    @classmethod
    def design(cls, A, B, Q, i_max, temperature=0.0) -> "LyapunovController":
        """The law for $\\dot x = A x + B F$ and weight `Q` (4, 4): $P$ from
        `solve_lyapunov(A, Q)` (differentiable in `A` and `Q`). `A` must be stable: for
        the quarter car fold the damper's passive damping into it
        (`quarter_car_state_space(car, damping=c0)`)."""
        B = jnp.reshape(jnp.asarray(B), (-1,))
        return cls(solve_lyapunov(A, Q), B, i_max, temperature)

    def __call__(self, measurement, state, plant):
        x = measured_state(measurement)
        v = measurement["damper_velocity"]
        PB = self.P @ self.B
        a = -(x @ PB)
        C = jnp.asarray(_DAMPER_VELOCITY, dtype=self.P.dtype)
        a_hat = a / jnp.sqrt(self.B @ PB)
        b_hat = v / jnp.sqrt(C @ jnp.linalg.solve(self.P, C))
        on = gate(a * v, angular_switch(a_hat, b_hat), self.temperature, strict=True)
        return clip_command(self.i_max * on, self.i_max), state
