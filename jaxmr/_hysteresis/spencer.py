"""Spencer's phenomenological ("modified Bouc–Wen") MR damper model."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from .._current_law import Parameter, as_parameter
from .._custom_types import Scalar, State
from .._misc import Check
from .base import AbstractHysteresis
from .bouc_wen import bouc_wen_rate


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

    def dashpots(self, v: Scalar) -> tuple[Scalar, Scalar]:
        """$c_0$ and $c_1$ [N·s/m] at piston velocity `v` (constant here;
        `ShearThinningSpencer` lets them thin with velocity)."""
        del v
        return self.c0, self.c1

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        return spencer_rates(self, state, x, v)

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        return spencer_force(self, state, x, v)

    def state_bounds(self):
        return spencer_state_bounds(self)

    def yield_force(self) -> Scalar:
        # Near rest the dashpots share alpha z0 and c1 >> c0 passes nearly all of it.
        return self.alpha * spencer_state_bounds(self)[0]

    def constraints(self):
        return spencer_constraints(self)


# Shared by every Spencer-type model (`Spencer`, `ShearThinningSpencer`), which differ
# only in their `dashpots(v)`.
def _y_rate(model, z, y, x, v):
    c0, c1 = model.dashpots(v)
    return (model.alpha * z + c0 * v + model.k0 * (x - y)) / (c0 + c1)


# The rates see z clipped to this many z0. On a solution |z| <= z0 (simulate flags more
# than 1.01 z0), but an explicit adaptive solver's overlong trial step (at a stiff z:
# gamma |u| ~ 1e4 1/s) can drive its stages far beyond, where gamma |u| z |z|^(n-1)
# grows faster than z (|u| = |v - y_rate| grows with alpha |z|) and overflows to inf.
# The step is rejected, yet reverse mode still differentiates it: its zero cotangent
# meets the inf partials, 0 * inf = nan, in every gradient. At the clipped z the
# rejected step stays finite (and rejected), and nothing changes where |z| <= 1e3 z0.
_Z_CLIP = 1e3


def _clip_z(model, z):
    """z clipped to +-_Z_CLIP z0 (not clipped where z0 is no bound: beta + gamma <= 0,
    which the constraints refuse). The bound carries no gradient: it is a guard, not
    part of the model."""
    z0 = jax.lax.stop_gradient(spencer_state_bounds(model)[0])
    z_max = jnp.where(jnp.isfinite(z0) & (z0 > 0), _Z_CLIP * z0, jnp.inf)
    return jnp.clip(z, -z_max, z_max)


def spencer_rates(model, state: State, x: Scalar, v: Scalar) -> State:
    z, y = _clip_z(model, state[0]), state[1]
    y_rate = _y_rate(model, z, y, x, v)
    z_rate = bouc_wen_rate(z, v - y_rate, model.A, model.beta, model.gamma, model.n)
    return jnp.stack([z_rate, y_rate])


def spencer_force(model, state: State, x: Scalar, v: Scalar) -> Scalar:
    z, y = state[0], state[1]
    _, c1 = model.dashpots(v)
    return c1 * _y_rate(model, z, y, x, v) + model.k1 * (x - model.x0)


def spencer_state_bounds(model):
    # z0 is a bound only when beta + gamma > 0 (checked by the constraints).
    z0 = (model.A / (model.beta + model.gamma)) ** (1 / model.n)
    return jnp.stack([z0, jnp.full_like(z0, jnp.inf)])


def spencer_constraints(self):
    return [
        Check(self.n > 0, "the exponent `n` must be > 0", self.n),
        Check(self.A > 0, "`A` must be > 0", self.A),
        Check(self.gamma >= 0, "`gamma` must be >= 0", self.gamma),
        Check(
            self.beta + self.gamma > 0,
            "`beta + gamma` must be > 0",
            {"beta": self.beta, "gamma": self.gamma},
        ),
        Check(
            self.alpha >= 0,
            "`alpha` must be >= 0 (a negative value generates energy)",
            self.alpha,
        ),
        Check(self.c0 > 0, "`c0` must be > 0", self.c0),
        Check(self.c1 > 0, "`c1` must be > 0", self.c1),
    ]
