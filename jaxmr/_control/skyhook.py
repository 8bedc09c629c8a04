"""Skyhook laws (Karnopp, Crosby & Harwood 1974): a damper to the inertial sky."""

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


class OnOffSkyhook(AbstractController):
    r"""On/off skyhook: full current when the damper can push the body toward rest,
    $$i = I_\max\, H(\dot z_s\, v),$$
    with the body velocity $\dot z_s$ and the damper velocity $v$ [m/s] ($H(0) = 1$).

    Relaxed ($T > 0$): $i = I_\max\,\sigma(\hat s / T)$ with
    $\hat s = 2\dot z_s v / (\dot z_s^2 + v^2) \in [-1, 1]$ (both factors in m/s).

    **Arguments:**

    - `i_max`: the "on" current $I_\max$ [A] (or voltage [V]).
    - `temperature`: $T \ge 0$, dimensionless; 0 (default) is the hard law.
    """

    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_range_and_temperature("OnOffSkyhook", self.i_max, self.temperature)

    def __call__(self, measurement, state, plant):
        body, v = measurement["body_velocity"], measurement["damper_velocity"]
        on = gate(body * v, angular_switch(body, v), self.temperature)
        return clip_command(self.i_max * on, self.i_max), state


class Skyhook(AbstractController):
    r"""Continuous skyhook: the damper force closest to a sky damper $c_\mathrm{sky}$,
    $$F^* = c_\mathrm{sky}\,\dot z_s,\qquad i = \Pi(F^*),$$
    where $\Pi$ is the inverse damper model `DamperPlant.current_for_force`: the current
    in $[0, I_\max]$ whose force is nearest $F^*$ in the damper's present state (the
    semi-active projection $\Pi_v$ on the real device's force band).

    Relaxed ($T > 0$): the clip to the band becomes a soft clip of the band fraction
    (`jaxmr` control relaxations; $T$ dimensionless).

    **Arguments:**

    - `c_sky`: the sky damping $c_\mathrm{sky} \ge 0$ [N·s/m].
    - `i_max`: the top of the current range $I_\max$ [A].
    - `temperature`: $T \ge 0$; 0 (default) is the hard law.
    """

    c_sky: Float[Array, ""] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_concrete(
            self.c_sky >= 0,
            f"Skyhook: `c_sky` must be >= 0 N·s/m, got {self.c_sky}.",
            self.c_sky,
        )
        check_range_and_temperature("Skyhook", self.i_max, self.temperature)

    def __call__(self, measurement, state, plant):
        target = self.c_sky * measurement["body_velocity"]
        command = command_for_force(plant, target, self.i_max, self.temperature)
        return clip_command(command, self.i_max), state
