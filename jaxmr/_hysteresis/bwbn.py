"""Bouc–Wen–Baber–Noori with pinching and degradation, modified for force lag."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import Parameter, as_parameter
from .._custom_types import Scalar, State
from .._misc import Check
from .base import AbstractHysteresis
from .bouc_wen import bouc_wen_rate


class BoucWenBaberNoori(AbstractHysteresis):
    r"""Modified Bouc–Wen–Baber–Noori model: pinching, degradation, dashpot and offset.

    $$F = \alpha k u + (1-\alpha) k z + c \dot u + f_0,\qquad
    \dot z = h(z)\,\frac{A(\varepsilon) \dot u - \nu(\varepsilon)\,[\gamma |\dot u|
    z|z|^{n-1} + \beta \dot u |z|^n]}{\eta(\varepsilon)},\qquad
    \dot\varepsilon = z \dot u,$$
    $$h(z) = 1 - \zeta_1 \exp\!\big(-(z\,\mathrm{sgn}(\dot u) - q z_u)^2/\zeta_2^2\big),
    \quad z_u = \Big(\frac{A}{\nu(\beta+\gamma)}\Big)^{1/n},$$
    $$\zeta_1 = \zeta_s (1 - e^{-p\varepsilon}),\ \zeta_2 = (\psi + \delta_\psi
    \varepsilon)(\lambda + \zeta_1),\ \nu = 1 + \delta_\nu \varepsilon,\ \eta = 1 +
    \delta_\eta \varepsilon,\ A = A_0 - \delta_A \varepsilon.$$

    Conventions: jaxmr's Bouc–Wen convention ($\gamma$ on the $|\dot u|$ term; Baber
    and Noori name them the other way round), so that with $\zeta_s = 0$ and
    $\delta_\nu = \delta_\eta = \delta_A = 0$ this is exactly `BoucWen(alpha=(1-α)k,
    c0=c, A=A0, beta, gamma, n, k0=αk, f0=f0)`. $z_u$ is the ultimate $z$; the source
    writes it for $A = 1$. The dashpot $c$ and offset $f_0$ are the source's
    modification for the "force-lag" loop, whose pinched shape plain Bouc–Wen cannot
    follow. States: $z$ [m], $\varepsilon$ [m²] (the integral of $z\,du$).

    **Arguments:**

    - `k`: stiffness $k$ [N/m]; `alpha`: post/pre-yield ratio [1]; `c` [N·s/m];
      `f0` [N]; `A0` [1]; `beta`, `gamma` [1/m^n]; `n` [1] — any may be a law.
    - Degradation: `delta_nu`, `delta_eta`, `delta_A` [1/m²] (default 0: none).
    - Pinching: `zeta_s` [1] (default 0: none), `p` [1/m²], `q` [1], `psi` [m],
      `delta_psi` [1/m], `lam` [1].
    """

    k: Parameter = eqx.field(converter=as_parameter)
    alpha: Parameter = eqx.field(converter=as_parameter)
    c: Parameter = eqx.field(converter=as_parameter)
    A0: Parameter = eqx.field(converter=as_parameter)
    beta: Parameter = eqx.field(converter=as_parameter)
    gamma: Parameter = eqx.field(converter=as_parameter)
    n: Parameter = eqx.field(converter=as_parameter)
    f0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    delta_nu: Parameter = eqx.field(converter=as_parameter, default=0.0)
    delta_eta: Parameter = eqx.field(converter=as_parameter, default=0.0)
    delta_A: Parameter = eqx.field(converter=as_parameter, default=0.0)
    zeta_s: Parameter = eqx.field(converter=as_parameter, default=0.0)
    p: Parameter = eqx.field(converter=as_parameter, default=1.0)
    q: Parameter = eqx.field(converter=as_parameter, default=0.1)
    psi: Parameter = eqx.field(converter=as_parameter, default=0.2)
    delta_psi: Parameter = eqx.field(converter=as_parameter, default=0.0)
    lam: Parameter = eqx.field(converter=as_parameter, default=0.5)
    state_names: ClassVar[tuple[str, ...]] = ("z", "energy")

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        z, energy = state[0], state[1]
        nu = 1 + self.delta_nu * energy
        eta = 1 + self.delta_eta * energy
        # Degradation ends at A = 0 (no restoring capacity left): a negative A would
        # generate energy, and z_u = (A/...)^(1/n) of it is NaN.
        A = jnp.maximum(self.A0 - self.delta_A * energy, 0.0)
        zeta1 = self.zeta_s * (1 - jnp.exp(-self.p * energy))
        zeta2 = (self.psi + self.delta_psi * energy) * (self.lam + zeta1)
        # z_u only shapes the pinching: without pinching (zeta1 = 0) or once A = 0 it
        # is not evaluated at all, so neither its value nor its gradient (d/dn of
        # 0^(1/n) is infinite) can turn into NaN.
        pinched = (zeta1 != 0) & (A > 0)
        safe_A = jnp.where(pinched, A, 1.0)
        safe_sum = jnp.where(pinched, nu * (self.beta + self.gamma), 1.0)
        z_u = jnp.where(pinched, (safe_A / safe_sum) ** (1 / self.n), 0.0)
        h = jnp.where(
            pinched,
            1 - zeta1 * jnp.exp(-(((z * jnp.sign(v) - self.q * z_u) / zeta2) ** 2)),
            1.0,
        )
        # `bouc_wen_rate` with A/nu, scaled by nu, is A v - nu (γ|v|z|z|^(n-1) + β v|z|^n).
        z_rate = (
            h * nu * bouc_wen_rate(z, v, A / nu, self.beta, self.gamma, self.n) / eta
        )
        return jnp.stack([z_rate, z * v])

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        z = state[0]
        return (
            self.alpha * self.k * x
            + (1 - self.alpha) * self.k * z
            + self.c * v
            + self.f0
        )

    def yield_force(self) -> Scalar:
        # (1 - alpha) k z_u of the undegraded model.
        z_u = (self.A0 / (self.beta + self.gamma)) ** (1 / self.n)
        return (1 - self.alpha) * self.k * z_u

    def constraints(self):
        return [
            Check(self.n > 0, "the exponent `n` must be > 0", self.n),
            Check(self.A0 > 0, "`A0` must be > 0", self.A0),
            Check(self.gamma >= 0, "`gamma` must be >= 0", self.gamma),
            Check(
                self.beta + self.gamma > 0,
                "`beta + gamma` must be > 0",
                {"beta": self.beta, "gamma": self.gamma},
            ),
            Check(self.k >= 0, "`k` must be >= 0", self.k),
            Check(
                (self.alpha >= 0) & (self.alpha <= 1),
                "`alpha` (post/pre-yield ratio) must be in [0, 1]",
                self.alpha,
            ),
            Check(
                self.c >= 0,
                "`c` must be >= 0 (a negative dashpot generates energy)",
                self.c,
            ),
            Check(self.psi > 0, "`psi` must be > 0 (pinching width)", self.psi),
            Check(self.lam > 0, "`lam` must be > 0", self.lam),
            Check(
                (self.zeta_s >= 0) & (self.zeta_s < 1),
                "`zeta_s` must be in [0, 1) (1 pinches the loop shut)",
                self.zeta_s,
            ),
        ]
