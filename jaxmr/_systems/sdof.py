"""Single-degree-of-freedom systems: a mass on a damper (SYSTEMS.md §4 and §5)."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Array, Float
from .._damper import Damper, as_damper
from .._misc import Check, as_float_array, check_concrete, is_concrete
from .base import AbstractSystem


class SingleDegreeOfFreedom(AbstractSystem):
    r"""A mass on a viscous damper, a spring and the device, driven by a force:
    $$m \ddot u + c \dot u + k u + F(u, \dot u) = f(t).$$

    The structural SDOF of source doc 004 ($F = a k u + (1 - a) k z$: a Bouc–Wen
    device holding the stiffness) and the hysteretic oscillator of the Bouc–Wen
    benchmark ($m = 2$ kg, $c = 10$ N·s/m, $k = 5\cdot 10^4$ N/m, with the spring and
    dashpot in the `BoucWen` model's `k0`, `c0` or here) are both this system; see
    `hysteretic_benchmark_oscillator`. The excitation signal is the force $f$ [N].
    "Wheel" measurements are the fixed ground (zero).

    States: `u` [m], `v` [m/s].

    **Arguments:**

    - `mass`: $m$ [kg].
    - `damper`: the device force $F(u, \dot u)$ (a `Damper` or hysteresis model).
    - `damping`: $c$ [N·s/m], default 0.
    - `stiffness`: $k$ [N/m], default 0.
    """

    mass: Float[Array, ""] = eqx.field(converter=as_float_array)
    damper: Damper = eqx.field(converter=as_damper)
    damping: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    stiffness: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    state_names: ClassVar[tuple[str, ...]] = ("u", "v")

    def __check_init__(self):
        if is_concrete(self.mass, self.damping, self.stiffness):
            for check in self.constraints():
                message = check.named("SingleDegreeOfFreedom").message()
                check_concrete(check.ok, message, self.mass)

    def constraints(self):
        return [
            Check(self.mass > 0, "`mass` must be > 0 kg", self.mass),
            Check(self.damping >= 0, "`damping` must be >= 0 N·s/m", self.damping),
            Check(self.stiffness >= 0, "`stiffness` must be >= 0 N/m", self.stiffness),
        ]

    def damper_motion(self, q, t, excitation):
        return q[0], q[1]

    def _acceleration(self, q, t, excitation, force):
        restoring = self.damping * q[1] + self.stiffness * q[0] + force
        return (excitation(t) - restoring) / self.mass

    def rates(self, q, t, excitation, force):
        return jnp.stack([q[1], self._acceleration(q, t, excitation, force)])

    def measure(self, q, t, excitation, force):
        zero = jnp.zeros_like(q[0])
        return {
            "body_position": q[0],
            "body_velocity": q[1],
            "body_acceleration": self._acceleration(q, t, excitation, force),
            "wheel_position": zero,
            "wheel_velocity": zero,
            "damper_displacement": q[0],
            "damper_velocity": q[1],
            "damper_force": force,
            "excitation": excitation(t),
        }

    def energy(self, q):
        return 0.5 * self.mass * q[1] ** 2 + 0.5 * self.stiffness * q[0] ** 2
