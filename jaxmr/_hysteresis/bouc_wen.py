"""Bouc–Wen hysteresis with current-dependent coefficients, and its normalised form."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import Parameter, as_parameter, is_law
from .._custom_types import Array, Scalar, State
from .._misc import Check, abs_pow
from .base import AbstractHysteresis


def bouc_wen_rate(z, v, A, beta, gamma, n):
    r"""$\dot z = A v - \gamma |v| z |z|^{n-1} - \beta v |z|^n$ (Spencer's convention)."""
    # One power for both terms (z|z|^(n-1) = sgn(z)|z|^n): the power dominates the cost.
    power = abs_pow(z, n)
    return A * v - (gamma * jnp.abs(v) * jnp.sign(z) + beta * v) * power


class BoucWen(AbstractHysteresis):
    r"""Bouc–Wen model with current-dependent coefficients.

    $$F = \alpha(i)\,z + c_0(i)\,v + k_0\,(x - x_0) + f_0,\qquad
    \dot z = A v - \gamma |v|\, z |z|^{n-1} - \beta\, v |z|^n.$$

    The rotary brake of the SAS study is $T = \alpha(i) z + C(i)\dot\theta$ with $A$
    written $\delta$ (leave `k0 = 0`); Spencer's "simple Bouc–Wen" damper uses `k0`,
    `x0`. jaxmr writes every Bouc–Wen-family model in this convention ($\gamma$ on the
    $|v|$ term, $\beta$ on the $v$ term, as Spencer 1997 and the SAS study do).

    $\beta + \gamma \le 0$ is allowed (z then grows without bound while loading, as in
    the Noël–Schoukens benchmark oscillator, $\beta\delta < -\beta\gamma$).
    With $\gamma \ge 0$, $\beta + \gamma > 0$, $A > 0$ and $|z(0)| \le z_0$ the state
    stays in $|z| \le z_0 = (A / (\beta + \gamma))^{1/n}$. After a reversal $z$ leaves
    saturation at the rate $A - (\beta - \gamma) z_0^n = 2\gamma A / (\beta + \gamma)$ per
    unit of $x$: with $\gamma \ll \beta$ (the SAS brake) it lingers near $z_0$, then
    flips within a fraction of a degree, so the loop is nearly rectangular (friction-like)
    and the solution is sensitive where $z$ crosses zero.

    The set $(\alpha, A, \beta, \gamma)$ is redundant: $z \to z/s$ maps it to
    $(\alpha s, A/s, \beta s^{n-1}, \gamma s^{n-1})$ with the same force. Fix one of them
    when identifying, or use `NormalizedBoucWen`.

    **Arguments:**

    - `alpha`: hysteretic stiffness $\alpha$ [N/m] or [N·m per unit z]; may be a law.
    - `c0`: viscous coefficient [N·s/m] or [N·m·s/rad]; may be a law.
    - `A`: $A$ (the SAS study's $\delta$), [1] when $z$ has the unit of $x$; > 0.
    - `beta`: $\beta$ [1/m^n] (or [1/rad^n]).
    - `gamma`: $\gamma$ [1/m^n] (or [1/rad^n]); ≥ 0.
    - `n`: exponent $n$ [1], > 0; the SAS brake uses 0.9.
    - `k0`: stiffness [N/m] (accumulator), default 0.
    - `x0`: spring's initial displacement [m], default 0.
    - `f0`: force offset [N], default 0.
    """

    alpha: Parameter = eqx.field(converter=as_parameter)
    c0: Parameter = eqx.field(converter=as_parameter)
    A: Parameter = eqx.field(converter=as_parameter)
    beta: Parameter = eqx.field(converter=as_parameter)
    gamma: Parameter = eqx.field(converter=as_parameter)
    n: Parameter = eqx.field(converter=as_parameter)
    k0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    x0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    f0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    state_names: ClassVar[tuple[str, ...]] = ("z",)

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        z = state[0]
        return bouc_wen_rate(z, v, self.A, self.beta, self.gamma, self.n)[None]

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        z = state[0]
        return self.alpha * z + self.c0 * v + self.k0 * (x - self.x0) + self.f0

    def yield_force(self) -> Scalar:
        # alpha z0, or alpha (z in units of its growth) when z is unbounded.
        z0 = self.state_bounds()[0]
        return jnp.abs(self.alpha) * jnp.where(jnp.isfinite(z0), z0, 1.0)

    def state_bounds(self) -> Array:
        # beta + gamma <= 0 is allowed (the Noel-Schoukens benchmark oscillator has it:
        # z keeps growing while loading, which small strokes tolerate); then no bound.
        bounded = self.beta + self.gamma > 0
        safe = jnp.where(bounded, self.beta + self.gamma, 1.0)
        z0 = (self.A / safe) ** (1 / self.n)
        return jnp.where(bounded, z0, jnp.inf)[None]

    def z_bound(self) -> Array:
        """$z_0 = (A/(\\beta+\\gamma))^{1/n}$, the bound on $|z|$ (resolved parameters)."""
        return (self.A / (self.beta + self.gamma)) ** (1 / self.n)

    def constraints(self):
        return [
            Check(self.n > 0, "the exponent `n` must be > 0", self.n),
            Check(self.A > 0, "`A` must be > 0 (it sets the initial slope)", self.A),
            Check(
                self.gamma >= 0,
                "`gamma` must be >= 0 (a negative value generates energy)",
                self.gamma,
            ),
            Check(
                self.alpha >= 0,
                "`alpha` must be >= 0 (a negative value generates energy)",
                self.alpha,
            ),
            Check(
                self.c0 >= 0,
                "`c0` must be >= 0 (a negative dashpot generates energy)",
                self.c0,
            ),
        ]

    def normalized(self) -> "NormalizedBoucWen":
        """The same model in Ikhouane & Rodellar's normalised form (exactly the same
        force). `A`, `beta`, `gamma`, `n` must be plain numbers; `alpha` and `c0` too
        (resolve laws first with `.at(current)`)."""
        if any(is_law(p) for p in (self.alpha, self.A, self.beta, self.gamma, self.n)):
            raise TypeError(
                "BoucWen.normalized: resolve current laws first, e.g. "
                "`model.at(current).normalized()`."
            )
        z0 = self.z_bound()
        return NormalizedBoucWen(
            kappa_x=self.k0,
            kappa_w=self.alpha * z0,
            c0=self.c0,
            rho=self.A / z0,
            sigma=self.gamma / (self.beta + self.gamma),
            n=self.n,
            x0=self.x0,
            f0=self.f0,
        )


class NormalizedBoucWen(AbstractHysteresis):
    r"""Bouc–Wen in the normalised form of Ikhouane & Rodellar, free of the redundancy.

    $$F = \kappa_x (x - x_0) + \kappa_w w + c_0 v + f_0,\qquad
    \dot w = \rho\,(v - \sigma |v| |w|^{n-1} w + (\sigma - 1) v |w|^n),\quad |w| \le 1.$$

    Derivation from `BoucWen` (jaxmr's convention, $\gamma$ on the $|v|$ term): put
    $z = z_0 w$ with $z_0 = (A/(\beta+\gamma))^{1/n}$; then
    $\dot w = (A/z_0)\,[v - \tfrac{\gamma}{\beta+\gamma}|v| w|w|^{n-1}
    - \tfrac{\beta}{\beta+\gamma} v |w|^n]$, so $\rho = A/z_0$,
    $\sigma = \gamma/(\beta+\gamma)$, $\kappa_w = \alpha z_0$, $\kappa_x = k_0$.
    (Ikhouane's papers put $\beta$ on the $|v|$ term, hence their $\sigma = \beta/(\beta+\gamma)$.)
    Their "physical" class is $\rho > 0$, $\sigma \ge 1/2$, $n \ge 1$; the SAS brake has
    $\sigma \approx 0.001$ and $n = 0.9$, outside it ($w$ lingers at $\pm 1$ after a
    reversal, then flips quickly). For any $\sigma \ge 0$, $|w| \le 1$.

    **Arguments:**

    - `kappa_x`: elastic stiffness [N/m]; may be a law.
    - `kappa_w`: hysteretic force amplitude [N] (force at $|w| = 1$); may be a law.
    - `c0`: viscous coefficient [N·s/m]; may be a law.
    - `rho`: $\rho$ [1/m], > 0: the inverse of the displacement over which $w$ saturates.
    - `sigma`: $\sigma$ [1], shape (≥ 0).
    - `n`: exponent [1], > 0.
    - `x0`, `f0`: offsets [m], [N].
    """

    kappa_x: Parameter = eqx.field(converter=as_parameter)
    kappa_w: Parameter = eqx.field(converter=as_parameter)
    c0: Parameter = eqx.field(converter=as_parameter)
    rho: Parameter = eqx.field(converter=as_parameter)
    sigma: Parameter = eqx.field(converter=as_parameter)
    n: Parameter = eqx.field(converter=as_parameter)
    x0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    f0: Parameter = eqx.field(converter=as_parameter, default=0.0)
    state_names: ClassVar[tuple[str, ...]] = ("w",)

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        w = state[0]
        power = abs_pow(w, self.n)
        rate = self.rho * (
            v - (self.sigma * jnp.abs(v) * jnp.sign(w) + (1 - self.sigma) * v) * power
        )
        return rate[None]

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        w = state[0]
        return self.kappa_x * (x - self.x0) + self.kappa_w * w + self.c0 * v + self.f0

    def yield_force(self) -> Scalar:
        return self.kappa_w  # |w| <= 1

    def state_bounds(self) -> Array:
        return jnp.ones((1,), dtype=jnp.result_type(self.rho))

    def constraints(self):
        return [
            Check(self.n > 0, "the exponent `n` must be > 0", self.n),
            Check(self.rho > 0, "`rho` must be > 0", self.rho),
            Check(self.sigma >= 0, "`sigma` must be >= 0", self.sigma),
            Check(
                self.c0 >= 0,
                "`c0` must be >= 0 (a negative dashpot generates energy)",
                self.c0,
            ),
            Check(
                self.kappa_w >= 0,
                "`kappa_w` must be >= 0 (a negative value generates energy)",
                self.kappa_w,
            ),
        ]

    def to_bouc_wen(self, A=1.0) -> BoucWen:
        """The equivalent `BoucWen` with the redundant scale fixed by `A` (default 1)."""
        z0 = A / self.rho
        scale = z0**self.n
        return BoucWen(
            alpha=self.kappa_w / z0,
            c0=self.c0,
            A=A,
            beta=(1 - self.sigma) * A / scale,
            gamma=self.sigma * A / scale,
            n=self.n,
            k0=self.kappa_x,
            x0=self.x0,
            f0=self.f0,
        )
