"""Sensors: each reading's noise, bias, quantisation, bandwidth and sample-and-hold as
set, differentiable; each machine's realistic set; the errors a controller meets when
it reads what no sensor gives. (The sensors in the closed loop: tests/test_observer.py,
which shares its runs.)"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr

DT = 1e-3
N = 20_000  # readings for the statistics below


def _read(sensor, signal, key=0):
    return jaxmr.Sensors({"s": sensor}).read({"s": signal}, jax.random.key(key), DT)[
        "s"
    ]


def test_noise_and_bias_have_the_set_statistics():
    sigma, bias = 0.3, 0.7
    r = np.asarray(_read(jaxmr.Sensor(noise=sigma, bias=bias), jnp.zeros(N)))
    # The sample mean's standard error is sigma/sqrt(N) = 0.002: 5 of them.
    assert abs(r.mean() - bias) < 5 * sigma / math.sqrt(N)
    # The sample std's relative standard error is 1/sqrt(2N) = 0.5 %: 6 of them.
    assert r.std() == pytest.approx(sigma, rel=0.03)
    # White: the lag-1 autocorrelation within 5/sqrt(N) of zero.
    e = r - r.mean()
    assert abs(np.mean(e[1:] * e[:-1]) / e.var()) < 5 / math.sqrt(N)
    # A second sensor of the same set draws independent noise.
    both = jaxmr.Sensors(
        {"a": jaxmr.Sensor(noise=1.0), "b": jaxmr.Sensor(noise=1.0)}
    ).read({"a": jnp.zeros(N), "b": jnp.zeros(N)}, jax.random.key(0), DT)
    assert abs(np.corrcoef(both["a"], both["b"])[0, 1]) < 5 / math.sqrt(N)


def test_quantisation_rounds_to_the_step():
    q = 0.01
    truth = jnp.linspace(-0.123, 0.456, 2000)
    r = np.asarray(_read(jaxmr.Sensor(quantum=q), truth))
    steps = r / q
    # Multiples of q up to the rounding of a float64 product (1e-9 of a step).
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    assert np.max(np.abs(r - np.asarray(truth))) <= q / 2 + 1e-12
    assert len(np.unique(np.round(steps))) == pytest.approx(0.579 / q, abs=2)


def test_bandwidth_is_a_first_order_lag_at_the_corner():
    fc = 20.0  # [Hz]; a sine at the corner: gain 1/sqrt(2), phase -45°
    t = np.arange(4000) * DT
    r = np.asarray(_read(jaxmr.Sensor(bandwidth=fc), jnp.sin(2 * np.pi * fc * t)))
    late = t > 0.1  # the start's transient decays as exp(-2 pi fc t): 3e-6 there
    basis = np.stack([np.sin(2 * np.pi * fc * t), np.cos(2 * np.pi * fc * t)], axis=1)
    (s, c), *_ = np.linalg.lstsq(basis[late], r[late], rcond=None)
    # The samples are taken as linear between samples, which attenuates a sine by
    # sinc²(f dt) = 0.9987 at 20 Hz and 1 kHz: 0.13 %, within the 0.3 % allowed.
    assert math.hypot(s, c) == pytest.approx(1 / math.sqrt(2), rel=3e-3)
    assert math.degrees(math.atan2(c, s)) == pytest.approx(-45.0, abs=0.2)


def test_a_slower_converter_holds_its_reading():
    truth = jnp.sin(0.05 * jnp.arange(400.0))
    r = np.asarray(_read(jaxmr.Sensor(rate=250.0), truth))  # every 4th sample
    blocks = r.reshape(-1, 4)
    np.testing.assert_array_equal(blocks, np.repeat(blocks[:, :1], 4, axis=1))
    np.testing.assert_array_equal(blocks[:, 0], np.asarray(truth)[::4])
    with pytest.raises(ValueError, match="divided by a whole number"):
        _read(jaxmr.Sensor(rate=300.0), truth)


def test_a_sensor_saturates_at_its_full_scale():
    truth = 3.0 * jnp.sin(0.01 * jnp.arange(1000.0))
    r = np.asarray(_read(jaxmr.Sensor(full_scale=1.0, quantum=1 / 2048), truth))
    inside = np.abs(np.asarray(truth)) < 1.0
    assert np.max(np.abs(r)) == 1.0
    assert np.max(np.abs(r[inside] - np.asarray(truth)[inside])) <= 1 / 4096 + 1e-12
    np.testing.assert_array_equal(r[~inside], np.sign(np.asarray(truth)[~inside]))
    # The car's wheel accelerometer reads at most its ±50 g.
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    wheel = jaxmr.realistic_sensors(car).sensors["wheel_acceleration"]
    assert float(wheel.full_scale) == pytest.approx(50 * 9.81, rel=1e-3)
    with pytest.raises(ValueError, match="full_scale"):
        jaxmr.Sensor(full_scale=0.0)


def test_an_ideal_sensor_reads_the_truth_exactly():
    truth = jnp.sin(0.01 * jnp.arange(500.0))
    np.testing.assert_array_equal(_read(jaxmr.Sensor(), truth), truth)


def test_gradients_flow_through_the_sampled_noise_and_the_quantiser():
    truth = jnp.linspace(-1.0, 1.0, 300)

    def total(noise, bias, scale):
        sensor = jaxmr.Sensor(noise=noise, bias=bias, quantum=0.05)
        return jnp.sum(_read(sensor, scale * truth))

    noise, bias = 0.2, 0.1
    g = jax.grad(total, argnums=(0, 1, 2))(noise, bias, 1.0)
    r = _read(jaxmr.Sensor(noise=noise, bias=bias), truth)  # the same draws, unrounded
    eps = (r - truth - bias) / noise
    # Reparameterised: d(sum r)/d(sigma) = sum eps; the quantiser passes the identity.
    assert float(g[0]) == pytest.approx(float(jnp.sum(eps)), rel=1e-9)
    assert float(g[1]) == pytest.approx(truth.size, rel=1e-12)
    assert float(g[2]) == pytest.approx(float(jnp.sum(truth)), abs=1e-9)


def test_invalid_sensors_are_refused():
    with pytest.raises(ValueError, match="noise"):
        jaxmr.Sensor(noise=-1.0)
    with pytest.raises(ValueError, match="bandwidth"):
        jaxmr.Sensor(bandwidth=0.0)
    with pytest.raises(ValueError, match="rate"):
        jaxmr.Sensor(rate=-5.0)
    with pytest.raises(TypeError, match="measurement name"):
        jaxmr.Sensors({"a": 1.0})
    with pytest.raises(KeyError, match="no signal"):
        jaxmr.Sensors({"a": jaxmr.Sensor()}).read(
            {"b": jnp.zeros(3)}, jax.random.key(0), DT
        )


def test_each_machine_has_its_realistic_sensors():
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    assert jaxmr.realistic_sensors(car).names == (
        "body_acceleration",
        "damper_displacement",
        "wheel_acceleration",
    )
    assert "damper_force" in jaxmr.realistic_sensors(car, load_cell=True).names
    sdof = jaxmr.hysteretic_benchmark_oscillator()
    assert jaxmr.realistic_sensors(sdof).names == (
        "body_acceleration",
        "damper_displacement",
    )
    # The car's numbers in its units: 12 bits over ±5 g for the body, ±100 mm for
    # the deflection. (The rig's set, the same parts in rad, is not built here:
    # `sas_rig()` takes seconds to find its equilibrium.)
    body = jaxmr.realistic_sensors(car).sensors["body_acceleration"]
    assert float(body.quantum) == pytest.approx(10 * 9.81 / 4096)
    deflection = jaxmr.realistic_sensors(car).sensors["damper_displacement"]
    assert float(deflection.quantum) == pytest.approx(0.2 / 4096)
    with pytest.raises(TypeError, match="build a jaxmr.Sensors"):
        jaxmr.realistic_sensors("a car")


# -- in the closed loop ---------------------------------------------------------------

T = 0.5  # [s]


@pytest.fixture(scope="module")
def car_and_road():
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    return car, jaxmr.iso8608_road("C", 20.0, T, jax.random.key(0))


def test_a_controller_reading_what_no_sensor_gives_is_told_what_to_do(car_and_road):
    car, road = car_and_road
    sensors = jaxmr.realistic_sensors(car)
    key = jax.random.key(0)
    skyhook = jaxmr.Skyhook(2000.0, 1.0)
    with pytest.raises(KeyError, match="'body_velocity' is not measured"):
        jaxmr.simulate_system(car, road, skyhook, T, sensors=sensors, key=key)
    # Velocities estimated, but the law inverts a damper it has no state of.
    estimated = jaxmr.ObserverBasedController(
        skyhook, estimator=jaxmr.VelocityEstimator()
    )
    with pytest.raises(TypeError, match="observer=jaxmr.DamperObserver"):
        jaxmr.simulate_system(car, road, estimated, T, sensors=sensors, key=key)
    # The estimator without its deflection sensor: told to add that sensor (it was
    # told to add the estimator it has).
    no_deflection = jaxmr.Sensors(
        {k: v for k, v in sensors.sensors.items() if k != "damper_displacement"}
    )
    on_off = jaxmr.ObserverBasedController(
        jaxmr.OnOffSkyhook(1.0), estimator=jaxmr.VelocityEstimator()
    )
    with pytest.raises(KeyError, match="Nothing in a controller estimates it"):
        jaxmr.simulate_system(car, road, on_off, T, sensors=no_deflection, key=key)
    # A bare law never reads the device's state through sensors.
    velocity = jaxmr.Sensors({"body_velocity": jaxmr.Sensor()})
    with pytest.raises(TypeError, match="whose state no sensor gives"):
        jaxmr.simulate_system(car, road, skyhook, T, sensors=velocity, key=key)
    with pytest.raises(TypeError, match="need `key="):
        jaxmr.simulate_system(car, road, 0.2, T, sensors=sensors)
    with pytest.raises(ValueError, match="`key` draws the sensors' noise"):
        jaxmr.simulate_system(car, road, 0.2, T, key=key)
    slow = jaxmr.ObserverBasedController(
        jaxmr.Skyhook(2000.0, 1.0), oracle=True, sampling=jaxmr.Sampling(dt=2e-3)
    )
    with pytest.raises(ValueError, match="give the controller the loop's"):
        jaxmr.simulate_system(car, road, slow, T, sampling=jaxmr.Sampling())
