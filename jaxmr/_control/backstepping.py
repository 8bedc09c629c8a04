"""Backstepping control of the SAS rig's body angle (source doc 001 §7.1)."""

from typing import ClassVar

import equinox as eqx

from .._custom_types import Array, Float
from .._misc import as_float_array, check_concrete
from .base import AbstractController
from .smooth import check_range_and_temperature, clip_command, command_for_force


class Backstepping(AbstractController):
    r"""Backstepping regulation of the body coordinate $y_1$ to $y_\mathrm{ref}$.

    With $y_1$ = `body_position`, $y_2 = \dot y_1$ = `body_velocity` and
    $\dot y_2 = f + g\,T$ ($T$ the damper force or brake torque, $g$ a known
    constant), the errors $e_1 = y_1 - y_\mathrm{ref}$, $e_2 = y_2 + h_1 e_1$ obey
    $\dot e_1 = -h_1 e_1 + e_2$, $\dot e_2 = -e_1 - h_2 e_2$ under the desired torque
    $$T^* = \big(-f - (1 + h_1 h_2)(y_1 - y_\mathrm{ref}) - (h_1 + h_2)\,y_2\big)/g,$$
    where $f = \ddot y_1 - g\,T$ is computed from the measured `body_acceleration` and
    `damper_force`. The current is $i = \Pi(T^*)$ with the inverse damper model
    (`DamperPlant.current_for_force`), clipped to $[0, I_\max]$: for a Bouc–Wen brake
    with linear laws $T = (C_0 + C_1 i)\dot\theta + (\alpha_0 + \alpha_1 i) z$ this is
    exactly the source's $i = (T^* - C_0\dot\theta - \alpha_0 z)/(C_1\dot\theta +
    \alpha_1 z)$. Relaxed ($T > 0$) by a soft clip. (The "1" in $1 + h_1 h_2$ is
    1 s⁻², from $\dot e_2 = -e_1 - \ldots$.)

    $g$ is the system's: for a quarter car's body $g = -1/m_s$ (the body receives
    $-F$); for jaxmr's `SASRig`, whose brake acts with $-T_{MR}$ on the upper beam
    (its relative angle is body minus wheel arm, like the quarter car's), $g = -1/J_2$.
    The law itself is sign-agnostic: only $g$ carries the orientation.

    **Arguments:**

    - `h1`, `h2`: the error-dynamics gains $h_1, h_2 > 0$ [1/s].
    - `g`: $\partial \ddot y_1/\partial T \ne 0$ [rad/s² per N·m, or 1/kg].
    - `i_max`: the top of the current range $I_\max$ [A].
    - `y_ref`: the reference $y_\mathrm{ref}$ [rad or m], default 0.
    - `temperature`: $T \ge 0$; 0 (default) is the hard law.
    """

    # It reads positions: `ObserverBasedController`'s estimator estimates them.
    reads_positions: ClassVar[bool] = True

    h1: Float[Array, ""] = eqx.field(converter=as_float_array)
    h2: Float[Array, ""] = eqx.field(converter=as_float_array)
    g: Float[Array, ""] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    y_ref: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        check_concrete(
            (self.h1 > 0) & (self.h2 > 0),
            "Backstepping: the gains `h1`, `h2` must be > 0 1/s (the error dynamics "
            f"are stable only then), got h1={self.h1}, h2={self.h2}.",
            self.h1,
            self.h2,
        )
        check_concrete(
            self.g != 0,
            "Backstepping: `g` (∂body_acceleration/∂damper_force, e.g. -1/J for the "
            f"rig) must be nonzero, got {self.g}.",
            self.g,
        )
        check_range_and_temperature("Backstepping", self.i_max, self.temperature)

    def __call__(self, measurement, state, plant):
        y1, y2 = measurement["body_position"], measurement["body_velocity"]
        f = measurement["body_acceleration"] - self.g * measurement["damper_force"]
        error = y1 - self.y_ref
        target = (
            -f - (1 + self.h1 * self.h2) * error - (self.h1 + self.h2) * y2
        ) / self.g
        command = command_for_force(plant, target, self.i_max, self.temperature)
        return clip_command(command, self.i_max), state
