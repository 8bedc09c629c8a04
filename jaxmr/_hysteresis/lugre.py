"""LuGre friction model with a Stribeck curve."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import Parameter, as_parameter
from .._custom_types import Scalar, State
from .._misc import Check
from .base import AbstractHysteresis


class LuGre(AbstractHysteresis):
    r"""LuGre model (Canudas de Wit et al. 1995), standard form.

    $$F = \sigma_0 y + \sigma_1 \dot y + \sigma_2 v,\qquad
    \dot y = v - \sigma_0 \frac{|v|}{g(v)} y,\qquad
    g(v) = F_c + (F_s - F_c)\,e^{-(v/v_s)^2}.$$

    At constant velocity $y \to g(v)\,\mathrm{sgn}(v)/\sigma_0$ and
    $F \to g(v)\,\mathrm{sgn}(v) + \sigma_2 v$, the Stribeck curve. (The review paper
    prints the Stribeck term with the state in place of $v$; this is the standard form.)

    **Arguments:**

    - `sigma0`: bristle stiffness $\sigma_0$ [N/m], > 0.
    - `sigma1`: bristle damping $\sigma_1$ [N·s/m], ≥ 0.
    - `sigma2`: viscous coefficient $\sigma_2$ [N·s/m]; may be a law.
    - `F_c`: Coulomb force [N], > 0; may be a law.
    - `F_s`: static (break-away) force [N], > 0; may be a law.
    - `v_s`: Stribeck velocity [m/s], > 0.
    """

    sigma0: Parameter = eqx.field(converter=as_parameter)
    sigma1: Parameter = eqx.field(converter=as_parameter)
    sigma2: Parameter = eqx.field(converter=as_parameter)
    F_c: Parameter = eqx.field(converter=as_parameter)
    F_s: Parameter = eqx.field(converter=as_parameter)
    v_s: Parameter = eqx.field(converter=as_parameter)
    state_names: ClassVar[tuple[str, ...]] = ("y",)

    def stribeck(self, v: Scalar) -> Scalar:
        """$g(v)$ [N], the steady-state friction magnitude at velocity $v$."""
        return self.F_c + (self.F_s - self.F_c) * jnp.exp(-((v / self.v_s) ** 2))

    def _rate(self, y, v):
        return v - self.sigma0 * jnp.abs(v) * y / self.stribeck(v)

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        return self._rate(state[0], v)[None]

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        y = state[0]
        return self.sigma0 * y + self.sigma1 * self._rate(y, v) + self.sigma2 * v

    def yield_force(self) -> Scalar:
        return jnp.maximum(self.F_c, self.F_s)

    def state_bounds(self):
        # y → g(v)/σ0 at steady sliding and g ≤ max(F_c, F_s).
        return (jnp.maximum(self.F_c, self.F_s) / self.sigma0)[None]

    def constraints(self):
        return [
            Check(self.sigma0 > 0, "`sigma0` must be > 0", self.sigma0),
            Check(self.sigma1 >= 0, "`sigma1` must be >= 0", self.sigma1),
            Check(
                self.sigma2 >= 0,
                "`sigma2` must be >= 0 (a negative viscous term generates energy)",
                self.sigma2,
            ),
            Check(self.F_c > 0, "`F_c` must be > 0", self.F_c),
            Check(self.F_s > 0, "`F_s` must be > 0", self.F_s),
            Check(self.v_s > 0, "`v_s` must be > 0", self.v_s),
        ]
