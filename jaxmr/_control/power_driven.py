"""The power-driven damper (Morselli & Zanasi 2008)."""

import equinox as eqx

from .._custom_types import Array, Float
from .._misc import as_float_array, check_concrete
from .base import AbstractController
from .smooth import check_range_and_temperature, clip_command, command_for_force


class PowerDrivenDamper(AbstractController):
    r"""Power-driven damper (PDD): the damper cancels the suspension spring's force on
    the body whenever it can,
    $$F^* = -k_s\,(z_s - z_u),\qquad i = \Pi(F^*),$$
    with the damper displacement $z_s - z_u$ [m] and the inverse damper model $\Pi$
    (`DamperPlant.current_for_force`, the semi-active projection on the device's
    band: where $F^* v < 0$ it gives the least force). Relaxed ($T > 0$) by a soft clip.

    **Arguments:**

    - `ks`: the stiffness to cancel $k_s > 0$ [N/m] (the suspension spring).
    - `i_max`: the top of the current range $I_\max$ [A].
    - `temperature`: $T \ge 0$; 0 (default) is the hard law.
    """

    ks: Float[Array, ""] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_concrete(
            self.ks > 0,
            f"PowerDrivenDamper: `ks` must be > 0 N/m, got {self.ks}.",
            self.ks,
        )
        check_range_and_temperature("PowerDrivenDamper", self.i_max, self.temperature)

    def __call__(self, measurement, state, plant):
        target = -self.ks * measurement["damper_displacement"]
        command = command_for_force(plant, target, self.i_max, self.temperature)
        return clip_command(command, self.i_max), state
