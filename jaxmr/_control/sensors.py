r"""Sensors: what a controller reads of a machine, with the noise, bias, bandwidth,
quantisation and sample-and-hold of real transducers and converters.

A `Sensor` models one measurement's chain, in this order: the transducer's first-order
bandwidth acting on the true signal, its bias, white noise on each conversion, the
converter's quantisation, and the converter's sample-and-hold at its own rate. A
`Sensors` set maps measurement names (`jaxmr.constants.MEASUREMENT_NAMES` and the
system's own) to sensors; `simulate_system(..., sensors=..., key=...)` hands the
controller these readings instead of the true measurements, and
`realistic_sensors(system)` is the set such a machine really has.

Noise is drawn from an explicit key, all of a run's at once (`Sensors.noise`), as
standard normals scaled by each sensor's `noise`: the reparameterisation, so gradients
flow through the sampled noise to the noise level and on to whatever the readings feed.
"""

import math
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import Array, Float, Int, PyTree, Scalar
from .._misc import as_float_array, check_concrete
from .._systems.quarter_car import GRAVITY, QuarterCar
from .._systems.sas_rig import SASRig
from .._systems.sdof import SingleDegreeOfFreedom


class Sensor(eqx.Module):
    r"""One measurement's transducer and converter.

    The reading $r_k$ at controller sample $k$ of a true signal $u(t)$:
    $$\tau\dot y = u - y,\quad \tau = \frac{1}{2\pi f_c},\qquad
    r_k = Q\big(y(t_k) + b + \sigma\,\varepsilon_k\big),\qquad
    \varepsilon_k \sim \mathcal N(0, 1),$$
    with $Q(r) = q\,\mathrm{round}(r/q)$ of the value clipped to the converter's full
    scale $\pm R$, held between conversions when the converter converts every $m$-th
    controller sample ($r_k = r_{k-1}$ otherwise).

    The lag is discretised at the controller's samples, exactly for a true signal that
    is linear between samples (the ramp-invariant form): content well below the
    Nyquist frequency $1/(2\,dt)$ is filtered as the continuous lag would, content
    above it is not aliased (jaxmr's machines have little there). Quantisation passes
    gradients through as the identity (a straight-through estimator): its true
    derivative is zero almost everywhere, which would cut every path from the
    measurements back to the tuned parameters, while its effect on the value is a
    small noise.

    Every argument is in the measurement's own unit (m, m/s², N, rad, ...), except
    the bandwidth and rate. `Sensor()` is an ideal sensor: it reads the true value.

    **Arguments:**

    - `noise`: $\sigma \ge 0$, the standard deviation of the white noise on each
      conversion [the measurement's unit]; default 0.
    - `bias`: $b$, a constant offset [the measurement's unit]; default 0.
    - `bandwidth`: $f_c > 0$, the transducer's first-order corner [Hz]; default
      `inf` (no lag).
    - `quantum`: $q \ge 0$, the converter's step [the measurement's unit], e.g. the
      range over $2^{\mathrm{bits}}$; default 0 (no quantisation).
    - `rate`: the converter's sample rate [Hz] (static), the controller's rate divided
      by a whole number; default `None`, the controller's rate. A faster converter
      is read at the controller's samples: give `None`.
    - `full_scale`: $R > 0$, the largest reading [the measurement's unit]: a reading
      beyond $\pm R$ reads $\pm R$ (the transducer or converter saturates, e.g. a
      ±50 g accelerometer on a pothole); default `inf`. Its gradient is 0 where it
      saturates, as the reading's is.
    """

    noise: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    bias: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    bandwidth: Float[Array, ""] = eqx.field(converter=as_float_array, default=math.inf)
    quantum: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    rate: float | None = eqx.field(static=True, default=None)
    full_scale: Float[Array, ""] = eqx.field(converter=as_float_array, default=math.inf)

    def __check_init__(self):
        check_concrete(
            self.full_scale > 0,
            f"Sensor: `full_scale` must be > 0 (inf: no saturation), got "
            f"{self.full_scale}.",
            self.full_scale,
        )
        check_concrete(
            self.noise >= 0,
            f"Sensor: `noise` must be a standard deviation >= 0, got {self.noise}.",
            self.noise,
        )
        check_concrete(
            jnp.isfinite(self.bias),
            f"Sensor: `bias` must be finite, got {self.bias}.",
            self.bias,
        )
        check_concrete(
            self.bandwidth > 0,
            f"Sensor: `bandwidth` must be > 0 Hz (inf: no lag), got {self.bandwidth}.",
            self.bandwidth,
        )
        check_concrete(
            (self.quantum >= 0) & jnp.isfinite(self.quantum),
            f"Sensor: `quantum` must be a finite step >= 0 (0: no quantisation), got "
            f"{self.quantum}.",
            self.quantum,
        )
        if self.rate is not None and (
            isinstance(self.rate, bool)
            or not isinstance(self.rate, (int, float))
            or not (math.isfinite(self.rate) and self.rate > 0)
        ):
            raise ValueError(
                f"Sensor: `rate` must be None (the controller's rate) or a positive "
                f"number of Hz, got {self.rate!r}."
            )

    def holds(self, dt: float) -> int:
        """The controller samples of period `dt` [s] per conversion (1: every
        sample). Raises unless the converter's period is a whole number of them."""
        if self.rate is None:
            return 1
        ratio = 1.0 / (self.rate * dt)
        every = round(ratio)
        if every < 1 or abs(ratio - every) > 1e-6 * ratio:
            raise ValueError(
                f"Sensor: the converter's rate {self.rate:g} Hz must be the "
                f"controller's rate 1/dt = {1 / dt:g} Hz divided by a whole number "
                "(the controller reads the latest conversion); give `rate=None` for "
                "a converter at, or faster than, the controller's rate."
            )
        return every

    def lag(self, dt: float) -> tuple[Scalar, Scalar, Scalar]:
        r"""The coefficients $(a, b_0, b_1)$ of the lag over one sample `dt` [s],
        $y_k = a\,y_{k-1} + b_0\,u_{k-1} + b_1\,u_k$ (ramp-invariant: exact when $u$ is
        linear between samples): $a = e^{-w}$, $b_1 = 1 - (1 - a)/w$,
        $b_0 = 1 - a - b_1$ with $w = 2\pi f_c\,dt$; $(0, 0, 1)$ for $f_c = \infty$."""
        w = 2 * jnp.pi * self.bandwidth * dt
        finite = jnp.isfinite(w)
        safe = jnp.where(finite, w, 1.0)
        a = jnp.exp(-safe)
        b1 = 1 + jnp.expm1(-safe) / safe  # 1 - (1 - a)/w, accurate for small w
        b0 = 1 - a - b1
        zero = jnp.zeros_like(w)
        return (
            jnp.where(finite, a, zero),
            jnp.where(finite, b0, zero),
            jnp.where(finite, b1, zero + 1),
        )

    def quantise(self, value: Scalar) -> Scalar:
        """`value` rounded to the converter's step (straight-through: the gradient is
        the identity's, see the class docstring)."""
        positive = self.quantum > 0
        q = jnp.where(positive, self.quantum, 1.0)
        rounded = jnp.where(positive, q * jnp.round(value / q), value)
        return value + jax.lax.stop_gradient(rounded - value)


class SensorState(eqx.Module):
    """One sensor's memory between samples: `filtered` (the lag's output $y_{k-1}$),
    `truth` (the true value $u_{k-1}$) and `reading` (the value held by the converter),
    each in the measurement's unit."""

    filtered: Scalar
    truth: Scalar
    reading: Scalar


# What a `VelocityEstimator` must read (the wheel accelerometer is optional).
ESTIMATOR_READS = ("body_acceleration", "damper_displacement")


class _Readings(dict):
    """The readings a controller gets: a dict whose missing names say what is measured
    and what to do instead of a bare KeyError."""

    def __missing__(self, name):
        measured = sorted(k for k in self if k != "time")
        if name in ESTIMATOR_READS:
            # Asked for by an estimator, whose own inputs no estimate replaces.
            raise KeyError(
                f"{name!r} is not measured: the sensors read {measured}. Nothing in "
                "a controller estimates it: a jaxmr.VelocityEstimator reads a body "
                "accelerometer (`body_acceleration`) and a deflection sensor "
                "(`damper_displacement`), a jaxmr.DamperObserver the deflection. Add "
                "the missing sensor to the `Sensors`."
            )
        raise KeyError(
            f"{name!r} is not measured: the sensors read {measured}. A quantity no "
            "sensor gives is estimated inside the controller: wrap the law in "
            "jaxmr.ObserverBasedController(law, estimator=jaxmr.VelocityEstimator(), "
            "...) for the velocities, and the absolute positions of a law that reads "
            "them (its class's `reads_positions`), or add a sensor for it to the "
            "`Sensors`."
        )


def readings(values: Mapping[str, Scalar]) -> dict:
    """`values` as the dict a controller reads (a missing name raises a `KeyError`
    that says what is measured)."""
    return _Readings(values)


class Sensors(eqx.Module):
    """The sensors of a machine: one `Sensor` per measurement the controller reads.

    `simulate_system(system, road, controller, T, sensors=Sensors({...}),
    key=jax.random.key(0))` hands the controller these readings (and the time) instead
    of the true measurements. `realistic_sensors(system)` gives a machine's usual set.

    **Arguments:**

    - `sensors`: a dict from measurement name (`jaxmr.constants.MEASUREMENT_NAMES` or
      the system's own, e.g. `"wheel_acceleration"`) to its `Sensor`.
    """

    sensors: dict[str, Sensor]

    def __init__(self, sensors: Mapping):
        if not isinstance(sensors, Mapping) or not sensors:
            raise TypeError(
                "Sensors: give a non-empty dict from measurement name to jaxmr.Sensor, "
                f"got {sensors!r}."
            )
        for name, sensor in sensors.items():
            if not isinstance(name, str) or not isinstance(sensor, Sensor):
                raise TypeError(
                    "Sensors: every entry must be a measurement name (str) and a "
                    f"jaxmr.Sensor, got {name!r}: {type(sensor).__name__}."
                )
            if name == "time":
                raise ValueError(
                    "Sensors: 'time' is the controller's own clock, not a measurement."
                )
        self.sensors = dict(sensors)

    @property
    def names(self) -> tuple[str, ...]:
        """The measurements read, in the order noise is drawn for them (sorted)."""
        return tuple(sorted(self.sensors))

    def holds(self, dt: float) -> dict[str, int]:
        """Controller samples of period `dt` [s] per conversion, by name."""
        return {name: self.sensors[name].holds(dt) for name in self.names}

    def init(self, truth: Mapping[str, Scalar]) -> dict[str, SensorState]:
        """The sensors' state before the first sample: every lag settled at the first
        true value (the machine at rest when it is switched on)."""
        state = {}
        for name in self.names:
            if name not in truth:
                raise KeyError(
                    f"Sensors: the system measures no {name!r}; it measures "
                    f"{sorted(k for k in truth if k != 'time')}."
                )
            u = jnp.asarray(truth[name])
            state[name] = SensorState(u, u, u)
        return state

    def noise(self, key: jax.Array, samples: int, dtype=None) -> Float[Array, "s n"]:
        """The standard normal draws of a run of `samples` controller samples from
        `key`: `jax.random.normal(key, (samples, len(names)))`, row $k$ for sample
        $k$, a column per sensor in the order of `names` (drawn at once, outside the
        simulation's loop, where a generator per sample cost seconds of compilation)."""
        dtype = jnp.result_type(float) if dtype is None else dtype
        return jax.random.normal(key, (samples, len(self.names)), dtype)

    def step(
        self,
        state: dict[str, SensorState],
        truth: Mapping[str, Scalar],
        eps: Float[Array, " n"],
        k: Int[Array, ""],
        dt: float,
    ) -> tuple[dict[str, Scalar], dict[str, SensorState]]:
        """The readings at controller sample `k` (an integer) from the true values
        `truth` there, and the sensors' next state; `eps` the sample's standard
        normal draws (a row of `noise`), `dt` [s] the sample time."""
        names = self.names
        dtype = jnp.result_type(*(jnp.asarray(truth[n]) for n in names))
        out, new = {}, {}
        for i, name in enumerate(names):
            sensor, old = self.sensors[name], state[name]
            u = jnp.asarray(truth[name], dtype)
            a, b0, b1 = sensor.lag(dt)
            y = a * old.filtered + b0 * old.truth + b1 * u
            drawn = sensor.noise * eps[i].astype(dtype)
            measured = jnp.clip(
                y + sensor.bias + drawn, -sensor.full_scale, sensor.full_scale
            )
            converted = sensor.quantise(measured)
            every = sensor.holds(dt)
            if every == 1:
                reading = converted
            else:
                reading = jnp.where(k % every == 0, converted, old.reading)
            out[name] = reading
            new[name] = SensorState(y, u, reading)
        return out, new

    def read(
        self, signals: Mapping[str, Float[Array, " samples"]], key: jax.Array, dt: float
    ) -> dict[str, Float[Array, " samples"]]:
        """The readings of sampled true signals: `signals[name]` at the controller's
        samples $t_k = k\\,dt$ (`dt` [s]), one array per sensor's name, read from
        sample 0 with the noise of `key` as `simulate_system` reads them (same key,
        same readings)."""
        if not isinstance(dt, (int, float)) or isinstance(dt, bool) or not dt > 0:
            raise ValueError(
                f"Sensors.read: `dt` must be a positive number, got {dt!r}."
            )
        missing = [name for name in self.names if name not in signals]
        if missing:
            raise KeyError(
                f"Sensors.read: no signal for the sensors {missing}; the signals are "
                f"{sorted(signals)}."
            )
        return _read(self, {n: signals[n] for n in self.names}, key, float(dt))


@eqx.filter_jit
def _read(sensors: Sensors, signals: dict, key, dt: float) -> PyTree:
    state = sensors.init({name: signals[name][0] for name in sensors.names})
    samples = jnp.shape(signals[sensors.names[0]])[0]
    dtype = jnp.result_type(*(signals[name] for name in sensors.names))
    eps = sensors.noise(key, samples, dtype)

    def one(state, inputs):
        k, eps = inputs
        truth = {name: signals[name][k] for name in sensors.names}
        out, state = sensors.step(state, truth, eps, k, dt)
        return state, out

    _, out = jax.lax.scan(one, state, (jnp.arange(samples), eps))
    return out


# -- the sensors machines have -------------------------------------------------------
#
# Typical automotive and laboratory parts (an assumption of jaxmr, of the order of
# their datasheets, not a measured set): 12-bit converters over each sensor's range;
# MEMS accelerometers with white noise of 0.05 m/s² (body, ±5 g) and 0.3 m/s² (wheel,
# ±50 g) per reading at 1 kHz and residual biases of about 10 mg and 50 mg after a
# static calibration; a ride-height (deflection) sensor of ±100 mm with 0.1 mm noise
# and 1 mm offset; a load cell of ±5 kN with 5 N noise and 10 N offset; every
# transducer behind a 200 Hz (deflection: 100 Hz) first-order anti-alias filter.


def _accelerometers(scale, wheel: bool) -> dict[str, Sensor]:
    # `scale`: m/s² per unit of the machine's acceleration (1, or the rig's lever arm).
    body = Sensor(
        noise=0.05 / scale,
        bias=0.1 / scale,
        bandwidth=200.0,
        quantum=2 * 5 * GRAVITY / 4096 / scale,
        full_scale=5 * GRAVITY / scale,
    )
    out = {"body_acceleration": body}
    if wheel:
        out["wheel_acceleration"] = Sensor(
            noise=0.3 / scale,
            bias=0.5 / scale,
            bandwidth=200.0,
            quantum=2 * 50 * GRAVITY / 4096 / scale,
            full_scale=50 * GRAVITY / scale,
        )
    return out


def realistic_sensors(system, *, load_cell: bool = False) -> Sensors:
    """The sensors such a machine really has (typical parts: see the list below; an
    assumption of jaxmr, of the order of datasheets, not a measured set).

    - `QuarterCar`: a body accelerometer (`body_acceleration`, ±5 g, 12 bits, noise
      0.05 m/s², bias 0.1 m/s², 200 Hz), a wheel accelerometer (`wheel_acceleration`,
      ±50 g, 12 bits, 0.3 m/s², 0.5 m/s², 200 Hz) and a ride-height sensor for the
      suspension deflection (`damper_displacement`, ±100 mm, 12 bits, noise 0.1 mm,
      offset 1 mm, 100 Hz).
    - `SingleDegreeOfFreedom`: the body accelerometer and the displacement sensor (the
      "wheel" is the ground).
    - `SASRig`: accelerometers on both beams at the wheel's radius $R$ (the car's,
      their m/s² divided by $R$ into rad/s²) and a 4096-count encoder on the brake's
      relative angle (`damper_displacement`, no noise or offset).

    **Arguments:**

    - `system`: a `QuarterCar`, `SingleDegreeOfFreedom` or `SASRig`.
    - `load_cell`: add a force sensor on the damper (`damper_force`, as on a test
      rig): ±5 kN, 12 bits, noise 5 N, offset 10 N, 200 Hz; on the rig a torque
      sensor of ±5 N·m, 12 bits, noise 0.005 N·m, offset 0.01 N·m. Default False.

    Every reading saturates at its sensor's range (`Sensor.full_scale`: ±5 g, ±50 g,
    ±100 mm, ±5 kN; the rig's encoder does not).

    **Returns:** a `Sensors`. Adjust one with `Sensors({**s.sensors, name: Sensor(...)})`.
    """
    if isinstance(system, QuarterCar):
        sensors = _accelerometers(1.0, wheel=True)
        sensors["damper_displacement"] = _deflection()
        force = _load_cell(5e3)
    elif isinstance(system, SingleDegreeOfFreedom):
        sensors = _accelerometers(1.0, wheel=False)
        sensors["damper_displacement"] = _deflection()
        force = _load_cell(5e3)
    elif isinstance(system, SASRig):
        sensors = _accelerometers(system.R, wheel=True)
        sensors["damper_displacement"] = Sensor(quantum=2 * math.pi / 4096)
        force = Sensor(
            noise=0.005,
            bias=0.01,
            bandwidth=200.0,
            quantum=10.0 / 4096,
            full_scale=5.0,
        )
    else:
        raise TypeError(
            "realistic_sensors knows the QuarterCar, SingleDegreeOfFreedom and SASRig; "
            f"for a {type(system).__name__}, build a jaxmr.Sensors({{name: "
            "jaxmr.Sensor(...)}) of what it measures."
        )
    if load_cell:
        sensors["damper_force"] = force
    return Sensors(sensors)


def _deflection() -> Sensor:
    return Sensor(
        noise=1e-4, bias=1e-3, bandwidth=100.0, quantum=0.2 / 4096, full_scale=0.1
    )


def _load_cell(full_scale: float) -> Sensor:
    return Sensor(
        noise=5.0,
        bias=10.0,
        bandwidth=200.0,
        quantum=2 * full_scale / 4096,
        full_scale=full_scale,
    )
