"""The acceleration-driven damper (Savaresi et al. 2005)."""

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Array, Float
from .._misc import as_float_array, check_concrete
from .base import AbstractController
from .smooth import angular_switch, check_range_and_temperature, clip_command, gate


class AccelerationDrivenDamper(AbstractController):
    r"""Acceleration-driven damper (ADD): full current when the damper force opposes
    the body's acceleration,
    $$i_k = I_\max\, H(\ddot z_{s,k-1}\, v_k)\quad(H(0) = 0),$$
    with the body acceleration [m/s²] of the *previous* sample (the present one
    depends on the force being decided: an algebraic loop) and the damper velocity $v$
    [m/s]. The previous acceleration is the controller's state (the first sample uses
    its own).

    Relaxed ($T > 0$): $i = I_\max\,\sigma(\hat s/T)$ with $\hat s = 2av/(a^2 + v^2)$,
    $a = \ddot z_s/(2\pi f_\mathrm{ref})$: the acceleration brought to m/s at a
    reference frequency (near the body mode, where $|\ddot z_s| \approx 2\pi f |\dot
    z_s|$). $f_\mathrm{ref}$ only shapes the relaxation; the hard law ignores it.

    **Arguments:**

    - `i_max`: the "on" current $I_\max$ [A].
    - `temperature`: $T \ge 0$, dimensionless; 0 (default) is the hard law.
    - `reference_frequency`: $f_\mathrm{ref} > 0$ [Hz], default 1 Hz (a car body).
    """

    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    reference_frequency: Float[Array, ""] = eqx.field(
        converter=as_float_array, default=1.0
    )

    def __check_init__(self):
        check_concrete(
            self.reference_frequency > 0,
            "AccelerationDrivenDamper: `reference_frequency` must be > 0 Hz, got "
            f"{self.reference_frequency}.",
            self.reference_frequency,
        )
        check_range_and_temperature(
            "AccelerationDrivenDamper", self.i_max, self.temperature
        )

    def init(self, measurement):
        return measurement["body_acceleration"]

    def __call__(self, measurement, state, plant):
        previous, v = state, measurement["damper_velocity"]
        scaled = previous / (2 * jnp.pi * self.reference_frequency)
        on = gate(
            previous * v, angular_switch(scaled, v), self.temperature, strict=True
        )
        command = clip_command(self.i_max * on, self.i_max)
        return command, measurement["body_acceleration"]
