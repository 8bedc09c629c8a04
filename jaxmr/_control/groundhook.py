"""Groundhook laws (Valášek et al. 1997): a damper from the wheel to the ground."""

import equinox as eqx

from .._custom_types import Array, Float
from .._misc import as_float_array, check_concrete
from .base import AbstractController
from .smooth import (
    angular_switch,
    check_range_and_temperature,
    clip_command,
    command_for_force,
    gate,
)


class OnOffGroundhook(AbstractController):
    r"""On/off groundhook: full current when the damper can push the wheel toward rest,
    $$i = I_\max\, H(-\dot z_u\, v),$$
    with the wheel velocity $\dot z_u$ and the damper velocity $v$ [m/s] ($H(0) = 1$).
    The damper force acts on the wheel as $+F$, so $F^* = -c\,\dot z_u$ is admissible
    ($F^* v \ge 0$) exactly when $-\dot z_u v \ge 0$.

    Relaxed ($T > 0$): $i = I_\max\,\sigma(\hat s/T)$,
    $\hat s = -2\dot z_u v/(\dot z_u^2 + v^2) \in [-1, 1]$.

    **Arguments:**

    - `i_max`: the "on" current $I_\max$ [A].
    - `temperature`: $T \ge 0$, dimensionless; 0 (default) is the hard law.
    """

    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_range_and_temperature("OnOffGroundhook", self.i_max, self.temperature)

    def __call__(self, measurement, state, plant):
        wheel, v = -measurement["wheel_velocity"], measurement["damper_velocity"]
        on = gate(wheel * v, angular_switch(wheel, v), self.temperature)
        return clip_command(self.i_max * on, self.i_max), state


class Groundhook(AbstractController):
    r"""Continuous groundhook: $F^* = -c_\mathrm{gnd}\,\dot z_u$, $i = \Pi(F^*)$ with
    the inverse damper model $\Pi$ (`DamperPlant.current_for_force`, the semi-active
    projection on the device's band); relaxed ($T > 0$) by a soft clip.

    **Arguments:**

    - `c_gnd`: the ground damping $c_\mathrm{gnd} \ge 0$ [N·s/m].
    - `i_max`: the top of the current range $I_\max$ [A].
    - `temperature`: $T \ge 0$; 0 (default) is the hard law.
    """

    c_gnd: Float[Array, ""] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_concrete(
            self.c_gnd >= 0,
            f"Groundhook: `c_gnd` must be >= 0 N·s/m, got {self.c_gnd}.",
            self.c_gnd,
        )
        check_range_and_temperature("Groundhook", self.i_max, self.temperature)

    def __call__(self, measurement, state, plant):
        target = -self.c_gnd * measurement["wheel_velocity"]
        command = command_for_force(plant, target, self.i_max, self.temperature)
        return clip_command(command, self.i_max), state
