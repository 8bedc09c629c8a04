r"""Velocities a car measures no sensor for, estimated from its accelerometers and
its deflection sensor, as the controller of a real car estimates them."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Array, Bool, Float, Scalar
from .._misc import as_float_array, check_concrete


class EstimatorState(eqx.Module):
    """A `VelocityEstimator`'s memory between samples (every entry a scalar):
    `started` (False before the first sample); the low-passed accelerations
    `body_bias`, `wheel_bias` and the body's bias-free reading `body_previous` at
    the previous sample [m/s² or rad/s²]; the relative acceleration's reading
    `relative_previous` there and its bias estimate `relative_bias` [m/s² or
    rad/s²]; the body velocity `body_velocity`, the deflection `displacement` [m or
    rad] and its rate `damper_velocity` [m/s or rad/s] at the last sample; and
    `body_position` [m or rad], the body's estimated absolute position there, where
    the estimator estimates positions (`VelocityEstimator.init(...,
    positions=True)`), else `None`."""

    started: Bool[Array, ""]
    body_bias: Scalar
    wheel_bias: Scalar
    body_previous: Scalar
    relative_previous: Scalar
    relative_bias: Scalar
    body_velocity: Scalar
    displacement: Scalar
    damper_velocity: Scalar
    body_position: Scalar | None = None


def _cos_of_root_minus_one(u: Scalar) -> Scalar:
    r"""$\cos\sqrt u - 1 = -2\sin^2(\sqrt u/2)$ for $u \ge 0$ and
    $\cosh\sqrt{-u} - 1 = 2\sinh^2(\sqrt{-u}/2)$ for $u < 0$ (one entire function,
    $\sum_{n \ge 1} (-u)^n/(2n)!$), without the cancellation of $\cos - 1$ at small
    $u$ and with finite gradients at $u = 0$."""
    small = jnp.abs(u) < 1e-8
    safe = jnp.where(small, 1.0, jnp.abs(u))
    half = jnp.sqrt(safe) / 2
    big = jnp.where(u > 0, -2 * jnp.sin(half) ** 2, 2 * jnp.sinh(half) ** 2)
    return jnp.where(small, -u / 2 + u**2 / 24, big)


def _optional_array(value):
    return None if value is None else as_float_array(value)


class VelocityEstimator(eqx.Module):
    r"""The body velocity, the wheel velocity and the suspension's deflection rate,
    estimated from a body accelerometer, a wheel accelerometer and a deflection sensor.

    - **Deflection and its rate.** A third-order complementary filter: the
      deflection's own rate below the crossover $f_c$ (`crossover`), the integral of
      the relative acceleration $a_s - a_u$ above it, and the accelerometers'
      combined bias estimated on the way (it is observable through the deflection,
      so it leaves no offset in the rate). In discrete form an
      $\alpha$–$\beta$–$\gamma$ tracker: the deflection $\hat x$, its rate $\hat v$
      and the bias $\hat b$ predicted over a sample from the relative acceleration
      (linear between samples, less $\hat b$), then corrected by the deflection's
      innovation $e_k$: $\hat x \mathrel{+}= \alpha e_k$,
      $\hat v \mathrel{+}= (\beta/dt)\,e_k$, $\hat b \mathrel{+}= (\gamma/dt^2)\,e_k$,
      with $\alpha, \beta, \gamma$ placing the error's poles at those of
      $(s + \omega_c)(s^2 + 2\zeta\omega_c s + \omega_c^2)$, $\omega_c = 2\pi f_c$
      (`damping` $\zeta$), mapped to $z = e^{s\,dt}$ (`gains`). Readings that agree
      with each other (the deflection the integral of the accelerations, constant
      biases) give the true rate after the filter's transient.
    - **Body velocity.** The absolute velocity has no such reference: the body
      acceleration less its low-pass at $f_h$ (`high_pass`, the bias), integrated
      by a leaky integrator with the same corner, altogether
      $\hat{\dot z}_s = \frac{s}{(s + \omega_h)^2}\,a_s$, $\omega_h = 2\pi f_h$: an
      integrator above $f_h$ (its phase leads the true velocity by
      $2\arctan(f_h/f)$, 10° at the body mode of 1.1 Hz with the default 0.1 Hz)
      that holds no offset from a constant bias, and forgets the road's slow
      undulations (a quarter of the body velocity's RMS on an ISO C road at 20 m/s,
      where the Wk-weighted comfort weighs little).
    - **Wheel velocity** $\hat{\dot z}_u = \hat{\dot z}_s - \hat v$.
    - **Positions**, for the laws that read the full state $(z_s, \dot z_s, z_u,
      \dot z_u)$ (`ClippedOptimal`, `ContinuousClippedOptimal`,
      `LyapunovController`, `Backstepping`; `ObserverBasedController` asks for
      them where its law reads them): the body's absolute position is the estimated
      body velocity through a leaky integrator with the corner $f_p$
      (`position_high_pass`), $\hat z_s = \hat{\dot z}_s/(s + \omega_p)$,
      $\omega_p = 2\pi f_p$, altogether
      $\hat z_s = \frac{s^3}{(s + \omega_h)^2 (s + \omega_p)}\,z_s$: the
      position above both corners (its phase leads by $\arctan(f_p/f)$ more, 5° at
      1.1 Hz with the default 0.1 Hz), without the drift a pure integral of the
      velocity's slow errors would give (a change of accelerometer bias leaves no
      offset), and without the road's slow undulations. The wheel's is the body's
      less the filtered deflection, $\hat z_u = \hat z_s - \hat x$ (the deflection
      is $z_s - z_u$): the suspension's relative position is measured, only the
      common absolute part is estimated.

    The estimates start at rest. The biases start from the accelerometers' readings
    at rest where they are given (`body_bias`, `wheel_bias`: calibrated at
    standstill), else from the first readings, which holds only for a machine at
    rest when the controller starts: a first reading taken in motion (a free decay
    from a deflected state, a controller restarted while the car drives) is a
    false bias, which the estimates carry for about $1/(2\pi f_h)$ (1.6 s at the
    default corner; the SAS rig's free decay from rest at 0.28 rad read
    −19.7 rad/s² and its body velocity came out at up to 12 rad/s against a true
    2.4). A missing wheel accelerometer counts as
    zero acceleration: the fixed ground of a `SingleDegreeOfFreedom`, or, on a car,
    a deflection rate from the deflection sensor alone (a tracking differentiator).
    `ObserverBasedController` steps it at its sample time; every parameter is an
    array, to be tuned by gradients with the law.

    **Arguments:**

    - `crossover`: $f_c > 0$ [Hz], default 5 (between the body mode and the wheel
      hop of a car).
    - `damping`: $\zeta > 0$ [1], default 0.7.
    - `high_pass`: $f_h > 0$ [Hz], default 0.1.
    - `position_high_pass`: $f_p > 0$ [Hz], default 0.1.
    - `body_bias`, `wheel_bias`: the body and wheel accelerometers' readings at rest
      [m/s² or rad/s²] (their offset, gravity included where they read it), the
      start of the biases' estimates; default None: the first readings.
    """

    crossover: Float[Array, ""] = eqx.field(converter=as_float_array, default=5.0)
    damping: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.7)
    high_pass: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.1)
    position_high_pass: Float[Array, ""] = eqx.field(
        converter=as_float_array, default=0.1
    )
    body_bias: Float[Array, ""] | None = eqx.field(
        converter=_optional_array, default=None
    )
    wheel_bias: Float[Array, ""] | None = eqx.field(
        converter=_optional_array, default=None
    )

    def __check_init__(self):
        for name, unit in (
            ("crossover", "Hz"),
            ("damping", ""),
            ("high_pass", "Hz"),
            ("position_high_pass", "Hz"),
        ):
            value = getattr(self, name)
            check_concrete(
                (value > 0) & jnp.isfinite(value),
                f"VelocityEstimator: `{name}` must be a finite number > 0"
                f"{' ' + unit if unit else ''}, got {value}.",
                value,
            )
        for name in ("body_bias", "wheel_bias"):
            value = getattr(self, name)
            if value is not None:
                check_concrete(
                    jnp.isfinite(value),
                    f"VelocityEstimator: `{name}` must be a finite number [m/s² or "
                    f"rad/s²] or None, got {value}.",
                    value,
                )

    def start_biases(self, a_s, a_u, wheel: bool):
        """The biases' estimates at the first sample: the readings at rest where
        given, else the first readings `a_s`, `a_u` (a missing wheel accelerometer
        reads 0, `wheel` False); and the relative acceleration's bias, their
        difference."""
        body = a_s if self.body_bias is None else self.body_bias + 0.0 * a_s
        given = wheel and self.wheel_bias is not None
        wheel_start = self.wheel_bias + 0.0 * a_u if given else a_u
        return body, wheel_start, body - wheel_start

    def init(self, measurement, positions: bool = False) -> EstimatorState:
        """The state before the first sample (reset from the first readings there).
        `positions` (static): whether `step` also estimates the body and wheel
        positions (default False: the velocities alone, as a law that reads no
        position needs)."""
        zero = jnp.zeros_like(jnp.asarray(measurement["damper_displacement"]))
        return EstimatorState(
            jnp.asarray(False), *([zero] * 8), body_position=zero if positions else None
        )

    def gains(self, dt: float) -> tuple[Scalar, Scalar, Scalar]:
        r"""The tracker's $(\alpha, \beta, \gamma)$ [1] at sample time `dt` [s], for
        the poles $p_0 = e^{-\omega_c dt}$ and
        $p_\pm = e^{(-\zeta \pm \sqrt{\zeta^2 - 1})\,\omega_c\,dt}$: with
        $q_j = 1 - p_j$ and their elementary symmetric functions $e_2, e_3$,
        $\alpha = 1 - p_0 p_+ p_-$, $\beta = e_2 - \tfrac32 e_3$, $\gamma = -e_3$
        (the same as $\beta = (3 + 3 s_3 - s_1 - s_2)/2$,
        $\gamma = -(1 - s_1 + s_2 - s_3)$ in the poles' own symmetric functions)."""
        # In the poles' own symmetric functions beta and gamma are differences of
        # terms of order 1 that leave w^2 and w^3 (gamma some 3e-5 at 5 Hz and 1 ms),
        # so one ulp of an exp or a cos moved gamma by 1e-11 relative (eager against
        # compiled). The q_j are small and, for zeta <= 1, every product and sum
        # below has terms of one sign, each from expm1 or sin^2: a few ulps relative.
        w = 2 * jnp.pi * self.crossover * dt
        a = -self.damping * w  # the pair's real part, times dt
        minus_one = _cos_of_root_minus_one(w**2 * (1 - self.damping**2))
        expm1_a = jnp.expm1(a)
        q0 = -jnp.expm1(-w)
        # q+ + q- = 2 - 2 e^a cos(b) and q+ q- = |e^(a + ib) - 1|^2 = (e^a - 1)^2
        # + 2 e^a (1 - cos b), cos b - 1 = minus_one (cosh where overdamped).
        pair_sum = -2 * (expm1_a * (1 + minus_one) + minus_one)
        pair_product = expm1_a**2 - 2 * jnp.exp(a) * minus_one
        e2 = q0 * pair_sum + pair_product
        e3 = q0 * pair_product
        alpha = -jnp.expm1(-(1 + 2 * self.damping) * w)
        return alpha, e2 - 1.5 * e3, -e3

    def step(
        self, state: EstimatorState, measurement, dt: float
    ) -> tuple[dict[str, Scalar], EstimatorState]:
        """The estimates at this sample from the readings `measurement` (a dict with
        `body_acceleration`, `damper_displacement` and, where measured,
        `wheel_acceleration`), and the next state; `dt` [s] the sample time.

        **Returns:** `body_velocity`, `wheel_velocity`, `damper_velocity` [m/s or
        rad/s], the filtered `damper_displacement` [m or rad] and the bias-free
        (high-passed) `body_acceleration` (and `wheel_acceleration` where measured)
        [m/s² or rad/s²]; where `state` carries a position (`init(...,
        positions=True)`), also `body_position` and `wheel_position` [m or rad]; and
        the next `EstimatorState`."""
        a_s = jnp.asarray(measurement["body_acceleration"])
        x = jnp.asarray(measurement["damper_displacement"])
        wheel = "wheel_acceleration" in measurement
        a_u = jnp.asarray(measurement["wheel_acceleration"]) if wheel else 0.0 * a_s
        started = state.started

        leak = jnp.exp(-2 * jnp.pi * self.high_pass * dt)
        body_start, wheel_start, relative_start = self.start_biases(a_s, a_u, wheel)
        body_bias = jnp.where(
            started, leak * state.body_bias + (1 - leak) * a_s, body_start
        )
        wheel_bias = jnp.where(
            started, leak * state.wheel_bias + (1 - leak) * a_u, wheel_start
        )
        body = a_s - body_bias
        # Trapezoidal integration, the older term leaked over the sample.
        body_velocity = leak * state.body_velocity + 0.5 * dt * (
            leak * state.body_previous + body
        )

        relative = a_s - a_u
        before = state.relative_previous - state.relative_bias
        now = relative - state.relative_bias
        predicted_x = (
            state.displacement
            + dt * state.damper_velocity
            + dt**2 * (2 * before + now) / 6
        )
        predicted_v = state.damper_velocity + 0.5 * dt * (before + now)
        alpha, beta, gamma = self.gains(dt)
        innovation = x - predicted_x
        zero = jnp.zeros_like(x)
        new = EstimatorState(
            jnp.asarray(True),
            body_bias,
            wheel_bias,
            body,
            relative,
            jnp.where(
                started,
                state.relative_bias + (gamma / dt**2) * innovation,
                relative_start,
            ),
            jnp.where(started, body_velocity, zero),
            jnp.where(started, predicted_x + alpha * innovation, x),
            jnp.where(started, predicted_v + (beta / dt) * innovation, zero),
        )
        estimates = {
            "body_velocity": new.body_velocity,
            "wheel_velocity": new.body_velocity - new.damper_velocity,
            "damper_velocity": new.damper_velocity,
            "damper_displacement": new.displacement,
            "body_acceleration": body,
        }
        if wheel:
            estimates["wheel_acceleration"] = a_u - wheel_bias
        if state.body_position is not None:
            # The leaky integral of the body velocity, trapezoidal with the older
            # term leaked over the sample, as the velocity's own; apart from the
            # velocities', so that those stay what they are without positions.
            position_leak = jnp.exp(-2 * jnp.pi * self.position_high_pass * dt)
            body_position = position_leak * state.body_position + 0.5 * dt * (
                position_leak * state.body_velocity + new.body_velocity
            )
            body_position = jnp.where(started, body_position, zero)
            new = dataclasses.replace(new, body_position=body_position)
            estimates["body_position"] = body_position
            # The deflection is z_s - z_u.
            estimates["wheel_position"] = body_position - new.displacement
        return estimates, new
