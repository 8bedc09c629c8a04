"""Road and cam excitations: shapes, derivatives, validation, and ISO 8608 spectra.

Derivatives are checked against central finite differences with step h: the error is
O(h²·z''') ≈ 1e-9 of the scale here, so a relative tolerance of 1e-6 leaves room;
against `jax.grad` (same formula differentiated) the tolerance is rounding, 1e-10.

Random-road spectra are Welch estimates, so they scatter: with K averaged segments each
PSD value has a relative standard deviation of about 1/sqrt(K), and an octave's mean
over M bins about 1/sqrt(K·M) (neighbouring Hann bins are correlated, so a bit more).
Here K = 4 roads × 11 segments = 44 and M ≥ 5 bins, so an octave's ratio scatters by
≲ 7 %: each octave must be within 20 % of ISO 8608, and the mean over the five octaves
within 10 %. A factor-of-two gain error (the often-printed 2π n0 sqrt(Gd V) for white
noise) gives a ratio of 2 and fails both by far.
"""

import equinox as eqx
import jax
import numpy as np
import pytest

from jaxmr._road import (
    Cam,
    HaversineBump,
    Pothole,
    RandomRoad,
    SmoothStep,
    _white_noise_gain,
    iso8608_psd,
    iso8608_road,
    road_psd,
)

H = 1e-6  # finite-difference step [s]
N_POINTS = 64  # every evaluation is padded to this many times: one compilation per type


@eqx.filter_jit
def _evaluate(signal, ts):
    value = jax.vmap(signal)
    derivative = jax.vmap(signal.derivative)(ts)
    fd = (value(ts + H) - value(ts - H)) / (2 * H)
    return value(ts), derivative, fd, jax.vmap(jax.grad(signal))(ts)


def _values(signal, ts):
    ts = np.asarray(ts, dtype=float)
    assert ts.size <= N_POINTS
    padded = np.concatenate([ts, np.zeros(N_POINTS - ts.size)])
    return [np.asarray(x)[: ts.size] for x in _evaluate(signal, padded)]


def _check_derivative(signal, ts, scale):
    _, d, fd, grad = _values(signal, ts)
    np.testing.assert_allclose(d, fd, atol=1e-6 * scale)
    np.testing.assert_allclose(d, grad, atol=1e-10 * scale)


def test_haversine_bump_shape_and_derivative():
    h, length, speed, start = 0.05, 2.0, 10.0, 0.3
    bump = HaversineBump(h, length, speed, start)
    s = np.array([-1.0, 0.0, 0.25, 0.5, 0.75, 1.0, 1.5]) * length
    z, dz, *_ = _values(bump, start + s / speed)
    expected = np.where(
        (s >= 0) & (s <= length), h / 2 * (1 - np.cos(2 * np.pi * s / length)), 0.0
    )
    np.testing.assert_allclose(np.asarray(z), expected, atol=1e-15)
    # C¹: zero slope at both ends, peak slope pi h V / L at the quarter points.
    np.testing.assert_allclose(np.asarray(dz)[[1, 5]], 0.0, atol=1e-15)
    np.testing.assert_allclose(float(dz[2]), np.pi * h * speed / length, rtol=1e-12)
    ts = np.linspace(0.0, 0.8, 37)  # across the bump, avoiding its two end points
    _check_derivative(bump, ts, scale=np.pi * h * speed / length)
    lo, hi = bump.bounds()
    assert float(lo) == 0.0 and float(hi) == h


def test_pothole_default_is_negative_haversine_and_flat_bottom():
    depth, length, speed = 0.04, 0.6, 5.0
    ts = np.linspace(-0.05, 0.17, 45)
    hole, *_ = _values(Pothole(depth, length, speed), ts)
    bump, *_ = _values(HaversineBump(-depth, length, speed), ts)
    np.testing.assert_allclose(np.asarray(hole), np.asarray(bump), atol=1e-15)
    steep = Pothole(depth, length, speed, start=0.0, edge=0.2)
    z, *_ = _values(steep, np.array([0.2, 0.5, 0.8]) * length / speed)
    np.testing.assert_allclose(np.asarray(z), -depth, rtol=1e-14)  # the flat bottom
    _check_derivative(
        steep, np.linspace(0.003, 0.117, 31), scale=np.pi * depth * speed / 0.24
    )
    lo, hi = steep.bounds()
    assert float(lo) == -depth and float(hi) == 0.0


def test_smooth_step_and_cam():
    step = SmoothStep(0.1, 0.2, start=1.0)
    z, dz, *_ = _values(step, np.array([0.0, 1.0, 1.1, 1.2, 5.0]))
    np.testing.assert_allclose(np.asarray(z), [0.0, 0.0, 0.05, 0.1, 0.1], atol=1e-15)
    np.testing.assert_allclose(float(dz[2]), np.pi * 0.1 / (2 * 0.2), rtol=1e-12)
    _check_derivative(step, np.linspace(0.95, 1.25, 29), scale=1.0)

    cam = Cam(0.005, 1.5, phase=0.3)
    ts = np.linspace(0.0, 2.0, 23)
    z, *_ = _values(cam, ts)
    np.testing.assert_allclose(
        np.asarray(z), 0.005 * np.sin(2 * np.pi * 1.5 * ts + 0.3), rtol=1e-14
    )
    _check_derivative(cam, ts, scale=0.005 * 2 * np.pi * 1.5)
    assert [float(b) for b in cam.bounds()] == [-0.005, 0.005]


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda: HaversineBump(0.05, 0.0, 10.0), "length"),
        (lambda: HaversineBump(0.05, 1.0, -3.0), "speed"),
        (lambda: Pothole(-0.05, 1.0, 3.0), "depth"),
        (lambda: Pothole(0.05, 1.0, 3.0, edge=0.7), "edge"),
        (lambda: SmoothStep(0.05, 0.0), "rise_time"),
        (lambda: Cam(0.005, 0.0), "frequency"),
        (lambda: RandomRoad(np.zeros(5), -1e-3), "dt"),
        (lambda: RandomRoad(np.zeros((2, 5)), 1e-3), "1-D"),
        (lambda: iso8608_road("Z", 20.0, 1.0, jax.random.key(0)), "road_class"),
        (lambda: iso8608_road("C", 0.0, 1.0, jax.random.key(0)), "speed"),
        (lambda: iso8608_road("C", 20.0, 1.0, jax.random.key(0), dt=0.01), "dt <="),
        (
            lambda: iso8608_road("C", 20.0, 1.0, jax.random.key(0), method="pink"),
            "method",
        ),
        (
            lambda: iso8608_road(
                "C", 20.0, 1.0, jax.random.key(0), method="white_noise", waviness=2.5
            ),
            "sinusoids",
        ),
        (lambda: iso8608_psd("I", 0.1), "road_class"),
    ],
)
def test_bad_arguments_raise(build, match):
    with pytest.raises(ValueError, match=match):
        build()


def test_random_road_interpolates_and_batches():
    # One fine grid serves every check: dt = 2e-4 s is 11 samples per shortest
    # wavelength at 20 m/s. (Arithmetic in numpy: eager jax ops each compile.)
    speed, duration, dt = 20.0, 0.2, 2e-4
    build = lambda key: iso8608_road("D", speed, duration, key, dt=dt)
    road = build(jax.random.key(3))
    values, derivatives = np.asarray(road.values), np.asarray(road.derivatives)
    assert values.shape == (1001,) and values[0] == 0.0
    z, dz, *_ = _values(road, np.arange(0, 1001, 20) * dt)  # at the nodes
    np.testing.assert_allclose(z, values[::20], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(dz, derivatives[::20], rtol=1e-9, atol=1e-12)
    # The stored velocities are the exact derivative of the sum of sinusoids: central
    # differences of the samples are low by sin(w dt)/(w dt), about (w dt)^2 / 6, i.e.
    # 0.3 % at n_max (w dt = 0.14); a w = 2 road's velocity PSD is flat in n, so this
    # top-of-band error sets the scale of the differences.
    difference = (values[2:] - values[:-2]) / (2 * dt) - derivatives[1:-1]
    scale = np.std(derivatives)
    assert np.max(np.abs(difference)) < 0.01 * scale
    assert np.sqrt(np.mean(difference**2)) < 0.004 * scale
    off_nodes = (np.arange(1, 50) * 20 + 0.37) * dt
    _check_derivative(road, off_nodes, scale=scale)
    z_out, dz_out, *_ = _values(road, np.array([-1.0, 5.0]))
    np.testing.assert_allclose(z_out, values[[0, -1]])
    np.testing.assert_array_equal(dz_out, 0.0)
    lo, hi = road.bounds()
    assert float(lo) <= values.min() and float(hi) >= values.max()

    # Without derivatives: piecewise linear, velocity = the segment's slope.
    linear = RandomRoad(np.array([0.0, 0.01, -0.02, 0.0]), 0.1, start=1.0)
    z, slope, *_ = _values(linear, np.array([1.05, 1.15, 1.25]))
    np.testing.assert_allclose(z, [0.005, -0.005, -0.01], atol=1e-15)
    np.testing.assert_allclose(slope, [0.1, -0.3, 0.2], rtol=1e-12)

    # Jit-able and vmappable over keys (one compilation covers both).
    keys = jax.random.split(jax.random.key(0), 2)
    batch = np.asarray(jax.jit(jax.vmap(build))(keys).values)
    assert batch.shape == (2, 1001)
    np.testing.assert_allclose(batch[0], np.asarray(build(keys[0]).values), rtol=1e-12)
    assert np.std(batch[1] - batch[0]) > 0.1 * np.std(values)


def test_batched_roads_share_one_static_grid():
    # Roads batched with vmap keep their grid (dt, start) as plain numbers, so a
    # closed loop under vmap looks every road up at one sample index instead of
    # gathering per road; only the samples gain the batch axis.
    keys = jax.random.split(jax.random.key(1), 3)
    roads = jax.vmap(lambda key: iso8608_road("C", 20.0, 0.1, key))(keys)
    assert roads.dt == 1e-3 and isinstance(roads.dt, float)
    assert roads.start == 0.0 and isinstance(roads.start, float)
    assert roads.values.shape == roads.derivatives.shape == (3, 101)
    assert roads.times.shape == (3, 101) and roads.end == pytest.approx(0.1)
    arrays = [x for x in jax.tree.leaves(roads) if eqx.is_array(x)]
    assert {x.shape[0] for x in arrays} == {3}
    # Under vmap the index is shared: the jaxpr of a batched lookup has no gather
    # whose indices carry the batch.
    jaxpr = jax.make_jaxpr(jax.vmap(lambda road: road(0.0123)))(roads)
    gathers = [e for e in jaxpr.jaxpr.eqns if e.primitive.name == "gather"]
    assert gathers and all(e.invars[1].aval.shape == (1,) for e in gathers)
    # A grid is one concrete number: per-road or traced grids are refused by name.
    with pytest.raises(ValueError, match="share"):
        RandomRoad(np.zeros(5), np.array([1e-3, 2e-3]))
    with pytest.raises(TypeError, match="concrete"):
        jax.vmap(lambda dt: RandomRoad(np.zeros(5), dt))(np.array([1e-3, 2e-3]))


def test_white_noise_gain_is_not_the_printed_one():
    gd0, speed = 256e-6, 20.0
    gain = _white_noise_gain(gd0, speed)
    np.testing.assert_allclose(gain, np.pi * 0.1 * np.sqrt(2 * gd0 * speed), rtol=1e-15)
    printed = 2 * np.pi * 0.1 * np.sqrt(gd0 * speed)
    np.testing.assert_allclose((printed / gain) ** 2, 2.0, rtol=1e-15)


OCTAVES = [0.05, 0.1, 0.2, 0.4, 0.8, 1.6]  # cycle/m: above the cut-on, below n_max


@pytest.mark.parametrize(
    "method, road_class", [("sinusoids", "C"), ("white_noise", "E")]
)
def test_iso8608_spectrum(method, road_class):
    speed, duration, dt = 20.0, 30.0, 2e-3
    keys = jax.random.split(jax.random.key(11), 4)
    roads = jax.vmap(
        lambda key: iso8608_road(road_class, speed, duration, key, method=method, dt=dt)
    )(keys)
    n, psd = road_psd(roads.values, dt, speed, segment_length=100.0)
    ratio = psd / np.asarray(iso8608_psd(road_class, n))
    octave = np.array(
        [
            np.mean(ratio[(n >= lo) & (n < hi)])
            for lo, hi in zip(OCTAVES[:-1], OCTAVES[1:])
        ]
    )
    print(method, road_class, "PSD / ISO per octave", np.round(octave, 3))
    assert np.all(np.abs(np.log(octave)) < np.log(1.2)), octave
    assert abs(np.mean(np.log(octave))) < np.log(1.1), octave


def test_road_psd_of_a_sine():
    # A sinusoid of amplitude A at n1 has variance A^2/2, all of it near n1.
    dt, speed, n1, amplitude = 1e-3, 10.0, 0.5, 0.01
    t = np.arange(40000) * dt
    z = amplitude * np.sin(2 * np.pi * n1 * speed * t)
    n, psd = road_psd(z, dt, speed, segment_length=40.0)
    variance = np.sum(psd) * (n[1] - n[0])
    np.testing.assert_allclose(variance, amplitude**2 / 2, rtol=1e-3)
    assert abs(n[np.argmax(psd)] - n1) <= n[1] - n[0]
