"""Spencer's model with shear-thinning dashpots (MODELS.md §0)."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import Parameter, as_parameter
from .._custom_types import Scalar, State
from .._misc import Check
from .base import AbstractHysteresis
from .spencer import (
    spencer_constraints,
    spencer_force,
    spencer_rates,
    spencer_state_bounds,
)


class ShearThinningSpencer(AbstractHysteresis):
    r"""Spencer et al. (1997) phenomenological model whose dashpots thin with velocity.

    $$F = c_1(\dot x)\,\dot y + k_1 (x - x_0),\qquad
    \dot y = \frac{\alpha z + c_0(\dot x)\,\dot x + k_0 (x - y)}
    {c_0(\dot x) + c_1(\dot x)},$$
    $$\dot z = A (\dot x - \dot y) - \gamma |\dot x - \dot y|\, z |z|^{n-1}
    - \beta (\dot x - \dot y) |z|^n,\qquad
    c_k(\dot x) = \frac{c_k}{1 + e_k |\dot x|}.$$

    MR fluid's post-yield viscosity falls with shear rate (Herschel–Bulkley
    behaviour), so a constant dashpot over-predicts the force at velocities beyond the
    fitted range and under-predicts it below. The coefficients $e_0$, $e_1$ [s/m] bend
    the force–velocity curve: $c_k$ is the viscous coefficient at rest and $1/e_k$ the
    velocity at which it has halved. The shear rate is taken from the piston velocity
    $\dot x$ (not $\dot x - \dot y$, which would make $\dot y$ implicit); in the
    post-yield regime, where thinning matters, $c_1 \gg c_0$ and $\dot x - \dot y
    \approx \dot x$. With $e_0 = e_1 = 0$ it is `Spencer` exactly.

    On the UTFSM sine tests (30 files, 0–1 A, 0.1–5 Hz) a joint fit with $e_0$ free
    cut the median NRMSE of the refitted Spencer model from 0.094 to 0.085; $e_1$
    added nothing there, so leave it at 0 unless the data ask for it.

    States: $z$ [m] and the internal displacement $y$ [m], which starts at $x$.

    **Arguments:**

    - `alpha`: [N/m]; `c0`, `c1`: [N·s/m] (at zero velocity); `k0`, `k1`: [N/m];
      `x0`: [m]; `gamma`, `beta`: [1/m^n]; `A`: [1]; `n`: [1]. Any may be a current law.
    - `e0`, `e1`: thinning coefficients of `c0` and `c1` [s/m], ≥ 0 (default 0); may
      be current laws.
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
    e0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    e1: Parameter = eqx.field(converter=as_parameter, default=0.0)
    state_names: ClassVar[tuple[str, ...]] = ("z", "y")

    def initial_state(self, x: Scalar, v: Scalar) -> State:
        del v
        return jnp.stack([jnp.zeros_like(x), x])

    def dashpots(self, v: Scalar) -> tuple[Scalar, Scalar]:
        """$c_0(\\dot x)$ and $c_1(\\dot x)$ [N·s/m], resolved parameters."""
        speed = jnp.abs(v)
        return self.c0 / (1 + self.e0 * speed), self.c1 / (1 + self.e1 * speed)

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
        return spencer_constraints(self) + [
            Check(
                self.e0 >= 0, "`e0` must be >= 0 (thinning, not thickening)", self.e0
            ),
            Check(
                self.e1 >= 0, "`e1` must be >= 0 (thinning, not thickening)", self.e1
            ),
        ]
