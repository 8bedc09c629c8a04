"""The two-degree-of-freedom quarter car (SYSTEMS.md §3)."""

from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Array, Float, Scalar, State
from .._damper import Damper, as_damper
from .._misc import Check, as_float_array, check_concrete, is_concrete
from .._signal import AbstractSignal
from .base import AbstractSystem

GRAVITY = 9.81  # m/s²


class QuarterCar(AbstractSystem):
    r"""Quarter car: body (sprung mass) on a spring and the damper, over a wheel
    (unsprung mass) on a tyre.

    Road-excited (`excitation="road"`, $z$ up, road height $z_r(t)$):
    $$m_s \ddot z_s = -k_s (z_s - z_u) - c_s (\dot z_s - \dot z_u) - F_d,$$
    $$m_u \ddot z_u = k_s (z_s - z_u) + c_s (\dot z_s - \dot z_u) + F_d
    - k_t (z_u - z_r) - c_t (\dot z_u - \dot z_r),$$
    with the damper force $F_d$ for $x = z_s - z_u$, $v = \dot z_s - \dot z_u$ (so a
    passive damper has $F_d v \ge 0$). Force-excited (`excitation="force"`, the variant
    of source doc 000): the ground is fixed ($z_r = 0$) and the signal is a force [N] on
    the wheel, added to its equation.

    Positions are deviations from static equilibrium, so gravity cancels; it returns
    only through the tyre's static load $(m_s + m_u) g$, the reference for the dynamic
    tyre load and for lift-off.

    States: `zs`, `vs`, `zu`, `vu` [m, m/s].

    **Arguments:**

    - `ms`, `mu`: body and wheel masses [kg].
    - `ks`: suspension spring [N/m]; `kt`: tyre stiffness [N/m].
    - `damper`: the controllable damper (a `Damper` or a hysteresis model).
    - `cs`: passive viscous damping in parallel with the damper [N·s/m], default 0.
    - `ct`: tyre damping [N·s/m], default 0.
    - `excitation`: `"road"` (default) or `"force"` (static).
    - `lift_off`: if True the tyre can only push (its total force is clipped at zero,
      the wheel leaves the road); default False, a linear tyre (static).
    """

    ms: Float[Array, ""] = eqx.field(converter=as_float_array)
    mu: Float[Array, ""] = eqx.field(converter=as_float_array)
    ks: Float[Array, ""] = eqx.field(converter=as_float_array)
    kt: Float[Array, ""] = eqx.field(converter=as_float_array)
    damper: Damper = eqx.field(converter=as_damper)
    cs: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    ct: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    excitation: str = eqx.field(static=True, default="road")
    lift_off: bool = eqx.field(static=True, default=False)
    state_names: ClassVar[tuple[str, ...]] = ("zs", "vs", "zu", "vu")

    def __check_init__(self):
        if self.excitation not in ("road", "force"):
            raise ValueError(
                'QuarterCar: `excitation` must be "road" (the signal is the road '
                f'height [m]) or "force" (a force [N] on the wheel), got '
                f"{self.excitation!r}."
            )
        if is_concrete(self.ms, self.mu, self.ks, self.kt, self.cs, self.ct):
            for check in self.constraints():
                check_concrete(check.ok, check.named("QuarterCar").message(), self.ms)

    def constraints(self):
        return [
            Check(self.ms > 0, "the body mass `ms` must be > 0 kg", self.ms),
            Check(self.mu > 0, "the wheel mass `mu` must be > 0 kg", self.mu),
            Check(self.ks > 0, "the spring `ks` must be > 0 N/m", self.ks),
            Check(self.kt > 0, "the tyre stiffness `kt` must be > 0 N/m", self.kt),
            Check(
                (self.cs >= 0) & (self.ct >= 0),
                "damping `cs` and `ct` must be >= 0 N·s/m (negative damping makes the "
                "car unstable)",
                {"cs": self.cs, "ct": self.ct},
            ),
        ]

    @property
    def static_load(self) -> Scalar:
        """$(m_s + m_u) g$ [N], the tyre's static load."""
        return (self.ms + self.mu) * GRAVITY

    def _road(self, t, excitation):
        if self.excitation == "force":
            zero = jnp.zeros_like(t)
            return zero, zero
        return excitation(t), excitation.derivative(t)

    def damper_motion(self, q, t, excitation):
        return q[0] - q[2], q[1] - q[3]

    def tyre_force(self, q: State, t: Scalar, excitation: AbstractSignal) -> Scalar:
        """Dynamic tyre force [N] on the wheel (upward positive; total = this +
        static load)."""
        zr, vr = self._road(t, excitation)
        force = -self.kt * (q[2] - zr) - self.ct * (q[3] - vr)
        if self.lift_off:
            force = jnp.maximum(force, -self.static_load)
        return force

    def _accelerations(self, q, t, excitation, force):
        zs, vs, zu, vu = q[0], q[1], q[2], q[3]
        suspension = self.ks * (zs - zu) + self.cs * (vs - vu) + force
        wheel = suspension + self.tyre_force(q, t, excitation)
        if self.excitation == "force":
            wheel = wheel + excitation(t)
        return -suspension / self.ms, wheel / self.mu

    def rates(self, q, t, excitation, force):
        a_s, a_u = self._accelerations(q, t, excitation, force)
        return jnp.stack([q[1], a_s, q[3], a_u])

    def measure(self, q, t, excitation, force):
        a_s, a_u = self._accelerations(q, t, excitation, force)
        x, v = self.damper_motion(q, t, excitation)
        return {
            "body_position": q[0],
            "body_velocity": q[1],
            "body_acceleration": a_s,
            "wheel_position": q[2],
            "wheel_velocity": q[3],
            "wheel_acceleration": a_u,
            "damper_displacement": x,
            "damper_velocity": v,
            "damper_force": force,
            "excitation": excitation(t),
            "road_velocity": self._road(t, excitation)[1],
            "tyre_force": self.tyre_force(q, t, excitation),
        }

    def energy(self, q):
        zs, vs, zu, vu = q[0], q[1], q[2], q[3]
        kinetic = 0.5 * self.ms * vs**2 + 0.5 * self.mu * vu**2
        # The tyre's potential is taken against a still road at zero height.
        potential = 0.5 * self.ks * (zs - zu) ** 2 + 0.5 * self.kt * zu**2
        return kinetic + potential

    def natural_frequencies(self) -> tuple[Scalar, Scalar]:
        """Undamped body and wheel-hop frequencies [Hz] of the linear car."""
        k = jnp.array([[self.ks, -self.ks], [-self.ks, self.ks + self.kt]])
        m = jnp.array([self.ms, self.mu])
        scaled = k / jnp.sqrt(m[:, None] * m[None, :])
        w2 = jnp.linalg.eigvalsh(scaled)
        f = jnp.sqrt(w2) / (2 * jnp.pi)
        return f[0], f[1]


def passenger_car(damper, **overrides) -> QuarterCar:
    """A passenger-car quarter (SYSTEMS.md §3's comparison set; the numbers of the
    control benchmark): ms = 350 kg, mu = 40 kg, ks = 20 kN/m, kt = 200 kN/m, no passive
    damping besides `damper` (body mode 1.1 Hz, wheel hop 11.8 Hz)."""
    values: dict[str, Any] = dict(ms=350.0, mu=40.0, ks=20e3, kt=200e3) | overrides
    return QuarterCar(damper=damper, **values)


def spencer_quarter_car(damper, **overrides) -> QuarterCar:
    """The published quarter-car set (source doc 004, from Spencer's work, as printed):
    ks = 80 000 N/m, kt = 500 000 N/m, mu = 320 kg, ms = 2 500 kg, cs = 320 N·s/m,
    ct = 15 050 N·s/m."""
    values: dict[str, Any] = dict(
        ms=2500.0, mu=320.0, ks=80e3, kt=500e3, cs=320.0, ct=15050.0
    )
    return QuarterCar(damper=damper, **(values | overrides))
