"""Spencer's phenomenological ("modified Bouc–Wen") MR damper model."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import AbstractCurrentLaw, as_parameter
from .._custom_types import Array, Float, Scalar, State
from .base import AbstractHysteresis
from .bouc_wen import bouc_wen_rate

Parameter = Float[Array, ""] | AbstractCurrentLaw


class Spencer(AbstractHysteresis):
    r"""Spencer et al. (1997) phenomenological model.

    $$F = c_1 \dot y + k_1 (x - x_0),\qquad
    \dot y = \frac{\alpha z + c_0 \dot x + k_0 (x - y)}{c_0 + c_1},$$
    $$\dot z = A (\dot x - \dot y) - \gamma |\dot x - \dot y|\, z |z|^{n-1}
    - \beta (\dot x - \dot y) |z|^n.$$

    $\alpha$, $c_0$, $c_1$ are usually linear in the filtered voltage $u$; put the
    voltage filter $\dot u = -\eta (u - v_\mathrm{cmd})$ in the `Damper`
    (`FirstOrderLag(eta)`). States: $z$ [m] and the internal displacement $y$ [m],
    which starts at $x$ (the device at rest).

    **Arguments:**

    - `alpha`: [N/m]; `c0`, `c1`: [N·s/m]; `k0`, `k1`: [N/m]; `x0`: [m];
      `gamma`, `beta`: [1/m^n]; `A`: [1]; `n`: [1]. Any may be a current law.
    """

    alpha: Parameter = eqx.field(converter=as_parameter)
    c0: Parameter = eqx.field(converter=as_parameter)
    k0: Parameter = eqx.field(converter=as_parameter)
    c1: Parameter = eqx.field(converter=as_parameter)
    k1: Parameter = eqx.field(converter=as_parameter)
    x0: Parameter = eqx.field(converter=as_parameter)
    gamma: Parameter = eqx.field(converter=as_parameter)
    beta: Parameter = eqx.field(converter=as_parameter)
    A: Parameter = eqx.field(converter=as_parameter)
    n: Parameter = eqx.field(converter=as_parameter)
    state_names: ClassVar[tuple[str, ...]] = ("z", "y")

    def initial_state(self, x: Scalar, v: Scalar) -> State:
        del v
        return jnp.stack([jnp.zeros_like(x), x])

    def _y_rate(self, z, y, x, v):
        return (self.alpha * z + self.c0 * v + self.k0 * (x - y)) / (self.c0 + self.c1)

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        z, y = state[0], state[1]
        y_rate = self._y_rate(z, y, x, v)
        z_rate = bouc_wen_rate(z, v - y_rate, self.A, self.beta, self.gamma, self.n)
        return jnp.stack([z_rate, y_rate])

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        z, y = state[0], state[1]
        return self.c1 * self._y_rate(z, y, x, v) + self.k1 * (x - self.x0)

    def state_bounds(self):
        z0 = (self.A / (self.beta + self.gamma)) ** (1 / self.n)
        return jnp.stack([z0, jnp.full_like(z0, jnp.inf)])

    def constraints(self):
        return [
            (self.n > 0, f"the exponent `n` must be > 0, got {self.n}."),
            (self.A > 0, f"`A` must be > 0, got {self.A}."),
            (self.gamma >= 0, f"`gamma` must be >= 0, got {self.gamma}."),
            (
                self.beta + self.gamma > 0,
                f"`beta + gamma` must be > 0, got beta={self.beta}, gamma={self.gamma}.",
            ),
            (self.c0 > 0, f"`c0` must be > 0, got {self.c0}."),
            (self.c1 > 0, f"`c1` must be > 0, got {self.c1}."),
        ]
