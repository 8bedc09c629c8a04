"""The hybrid skyhook–groundhook law (Goncalves & Ahmadian 2003)."""

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


class Hybrid(AbstractController):
    r"""Hybrid skyhook–groundhook control: a blend of the admissible sky and ground
    forces,
    $$F^* = G\,[\alpha\,\sigma_\mathrm{sky} + (1 - \alpha)\,\sigma_\mathrm{gnd}],\quad
    \sigma_\mathrm{sky} = \dot z_s\,H(\dot z_s v),\quad
    \sigma_\mathrm{gnd} = -\dot z_u\,H(-\dot z_u v),$$
    then $i = \Pi(F^*)$ with the inverse damper model $\Pi$
    (`DamperPlant.current_for_force`). $\alpha = 1$ is on/off-gated skyhook, $\alpha =
    0$ groundhook.

    Relaxed ($T > 0$): each $H$ becomes $\sigma(\hat s/T)$ with the angular switching
    functions of `OnOffSkyhook` and `OnOffGroundhook`, and the band clip a soft clip.

    **Arguments:**

    - `gain`: $G \ge 0$ [N·s/m].
    - `alpha`: the blend $\alpha \in [0, 1]$ (dimensionless).
    - `i_max`: the top of the current range $I_\max$ [A].
    - `temperature`: $T \ge 0$; 0 (default) is the hard law.
    """

    gain: Float[Array, ""] = eqx.field(converter=as_float_array)
    alpha: Float[Array, ""] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_concrete(
            self.gain >= 0,
            f"Hybrid: `gain` must be >= 0 N·s/m, got {self.gain}.",
            self.gain,
        )
        check_concrete(
            (self.alpha >= 0) & (self.alpha <= 1),
            f"Hybrid: `alpha` must lie in [0, 1] (1: skyhook, 0: groundhook), got "
            f"{self.alpha}.",
            self.alpha,
        )
        check_range_and_temperature("Hybrid", self.i_max, self.temperature)

    def __call__(self, measurement, state, plant):
        v = measurement["damper_velocity"]
        body, wheel = measurement["body_velocity"], -measurement["wheel_velocity"]
        sky = body * gate(body * v, angular_switch(body, v), self.temperature)
        ground = wheel * gate(wheel * v, angular_switch(wheel, v), self.temperature)
        target = self.gain * (self.alpha * sky + (1 - self.alpha) * ground)
        command = command_for_force(plant, target, self.i_max, self.temperature)
        return clip_command(command, self.i_max), state
