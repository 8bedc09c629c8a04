"""Clipped-optimal control (Dyke et al. 1996) around a linear primary controller."""

from typing import ClassVar

import equinox as eqx

from .._custom_types import Array, Float
from .._misc import as_float_array
from .base import AbstractController
from .riccati import lqr
from .smooth import (
    angular_switch,
    check_range_and_temperature,
    clip_command,
    command_for_force,
    gate,
)
from .state_space import measured_state


def _check_gain(name, gain):
    if gain.shape[-1:] != (4,):
        raise ValueError(
            f"{name}: `gain` must have shape (4,) for the state (zs, vs, zu, vu) "
            f"[N/m, N·s/m, N/m, N·s/m], got {gain.shape} (take `K[0]` of `lqr`)."
        )


class ClippedOptimal(AbstractController):
    r"""Clipped-optimal control: the damper is switched on while its force $f$ [N]
    lags the primary controller's $f_c = -K x$ in the same direction,
    $$i = I_\max\, H((f_c - f)\, f)\quad(H(0) = 1),$$
    with the measured damper force $f$ and the measured state
    $x = (z_s, \dot z_s, z_u, \dot z_u)$ [m, m/s] (on a car's sensors, estimated:
    run it in an `ObserverBasedController` with a `VelocityEstimator`, which then
    estimates the positions too). $K$ is typically an LQR gain:
    `ClippedOptimal.design(A, B, Q, R, i_max)` (differentiable in the weights).

    Relaxed ($T > 0$): $i = I_\max\,\sigma(\hat s/T)$,
    $\hat s = 2(f_c - f)f/((f_c - f)^2 + f^2) \in [-1, 1]$ (both factors in N).

    **Arguments:**

    - `gain`: $K$, (4,) [N/m, N·s/m, N/m, N·s/m].
    - `i_max`: the "on" current (or voltage, Dyke's $V_\max$) $I_\max$ [A].
    - `temperature`: $T \ge 0$, dimensionless; 0 (default) is the hard law.
    """

    # It reads positions: `ObserverBasedController`'s estimator estimates them.
    reads_positions: ClassVar[bool] = True

    gain: Float[Array, "4"] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        _check_gain("ClippedOptimal", self.gain)
        check_range_and_temperature("ClippedOptimal", self.i_max, self.temperature)

    @classmethod
    def design(cls, A, B, Q, R, i_max, N=None, temperature=0.0):
        """The law around the LQR gain of `lqr(A, B, Q, R, N)` for $\\dot x = A x + B F$
        (`quarter_car_state_space`)."""
        K, _ = lqr(A, B, Q, R, N)
        return cls(K[0], i_max, temperature)

    def __call__(self, measurement, state, plant):
        target = -(self.gain @ measured_state(measurement))
        force = measurement["damper_force"]
        lag = target - force
        on = gate(lag * force, angular_switch(lag, force), self.temperature)
        return clip_command(self.i_max * on, self.i_max), state


class ContinuousClippedOptimal(AbstractController):
    r"""Continuous clipped-optimal control: the primary controller's force
    $f_c = -K x$ realised as nearly as the damper allows,
    $$i = \Pi(f_c),$$
    with the inverse damper model $\Pi$ (`DamperPlant.current_for_force`, the
    semi-active projection on the device's band) and the measured state
    $x = (z_s, \dot z_s, z_u, \dot z_u)$ [m, m/s] (estimated on a car's sensors, as
    for `ClippedOptimal`). Relaxed ($T > 0$) by a soft clip.

    **Arguments:**

    - `gain`: $K$, (4,) [N/m, N·s/m, N/m, N·s/m].
    - `i_max`: the top of the current range $I_\max$ [A].
    - `temperature`: $T \ge 0$; 0 (default) is the hard law.
    """

    # It reads positions: `ObserverBasedController`'s estimator estimates them.
    reads_positions: ClassVar[bool] = True

    gain: Float[Array, "4"] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)

    def __check_init__(self):
        _check_gain("ContinuousClippedOptimal", self.gain)
        check_range_and_temperature(
            "ContinuousClippedOptimal", self.i_max, self.temperature
        )

    @classmethod
    def design(cls, A, B, Q, R, i_max, N=None, temperature=0.0):
        """The law around the LQR gain of `lqr(A, B, Q, R, N)`."""
        K, _ = lqr(A, B, Q, R, N)
        return cls(K[0], i_max, temperature)

    def __call__(self, measurement, state, plant):
        target = -(self.gain @ measured_state(measurement))
        command = command_for_force(plant, target, self.i_max, self.temperature)
        return clip_command(command, self.i_max), state
