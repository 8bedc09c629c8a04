"""Tuning through the whole chain (issue 29, item 3): a law and its controller's
velocity estimator tuned together by gradients through sampled sensor noise, robustly
over damper samples; relaxation and hardening reaching a wrapped law.

One short run (two 0.5 s roads, a 500 Hz controller) carries the closed-loop checks:
its compilation (the realistic sensors, the estimator and the observer under a
reverse pass, over two damper samples) is what costs, so the tune, its gradient and
its scores share it."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.metrics
from jaxmr._tune.common import prepare, sensor_noise
from jaxmr._tune.loss import loss_and_grad
from jaxmr._tune.space import as_space, from_values, to_values

T = 0.5  # [s] of road
DAMPER = jaxmr.passenger_car_mr_damper()
CAR = jaxmr.passenger_car(DAMPER)
SENSORS = jaxmr.realistic_sensors(CAR)
KEY = jax.random.key(7)  # the sensors' noise
# The controller's own timing, not the loop's default: the tuners must take it.
SAMPLING = jaxmr.Sampling(dt=2e-3, delay=1)


def _roads():
    keys = jax.vmap(jax.random.key)(jnp.arange(2))
    return jax.vmap(lambda k: jaxmr.iso8608_road("C", 20.0, T, k))(keys)


def c_sky(pair):
    return pair[1].c_sky


def _realistic(law):
    return jaxmr.ObserverBasedController(
        law,
        estimator=jaxmr.VelocityEstimator(),
        observer=jaxmr.DamperObserver(DAMPER),
        sampling=SAMPLING,
    )


def _scaled(f):
    """The car with its damper's yield law scaled by `f`."""
    law = CAR.damper.hysteresis.alpha
    return eqx.tree_at(
        lambda s: (s.damper.hysteresis.alpha.a, s.damper.hysteresis.alpha.b),
        CAR,
        (f * law.a, f * law.b),
    )


def test_temperature_reaches_the_wrapped_law():
    controller = _realistic(jaxmr.Skyhook(2000.0, 1.0, temperature=0.1))
    soft = jaxmr.with_temperature(controller, 0.3)
    assert float(soft.law.temperature) == 0.3

    # Only the law's temperature changes; the filters are as they were.
    def rest(c):
        return c.estimator, c.observer, c.law.c_sky, c.sampling

    assert bool(eqx.tree_equal(rest(soft), rest(controller)))
    hard = jaxmr.with_temperature({"a": soft, "b": jaxmr.Skyhook(1.0, 1.0, 0.2)}, 0.0)
    assert float(hard["a"].law.temperature) == 0.0
    assert float(hard["b"].temperature) == 0.0


@pytest.fixture(scope="module")
def robust_run():
    """Skyhook ten times too stiff in an observer-based controller on the car's
    realistic sensors, its gain and its estimator's crossover and high-pass corner
    tuned together over two damper samples (yield laws x0.6 and x1.5), on the worse
    one (`worst_share=0.5`), the law relaxed at T = 0.1 while the start is given at
    T = 0.05 (the tuners judge and return the hard law)."""
    controller = _realistic(jaxmr.Skyhook(20_000.0, 1.0, temperature=0.05))
    keywords = controller.tunable(c_sky, estimator=("crossover", "high_pass"))
    samples = jax.vmap(_scaled)(jnp.array([0.6, 1.5]))
    roads = _roads()
    result = jaxmr.tune(
        CAR,
        controller,
        roads,
        T,
        samples=samples,
        worst_share=0.5,
        sensors=SENSORS,
        sensor_key=KEY,
        temperature=0.1,
        steps=2,
        check_every=1,
        learning_rate=1.5,
        progress=False,
        **keywords,
    )
    return controller, keywords, samples, roads, result


def _worst_mean(controller, roads):
    """The worse damper sample's mean comfort [m/s²] over the roads, scored by
    `evaluate` on the tuners' fixed noise draw."""
    return max(
        float(
            np.mean(
                jaxmr.evaluate(
                    _scaled(f), controller, roads, T, sensors=SENSORS, sensor_key=KEY
                )["comfort"]
            )
        )
        for f in (0.6, 1.5)
    )


def test_joint_tuning_through_sensor_noise_lowers_the_worst_sample_s_loss(
    robust_run,
):
    start, _, _, roads, result = robust_run
    # The law returned hard, as it is judged.
    assert float(result.controller.law.temperature) == 0.0
    # The losses reported are the worse sample's mean on the fixed draw of noise,
    # road i's from fold_in(KEY, i), as `evaluate` draws it (the same runs: equal to
    # 1e-10, XLA fusing the batched programs differently).
    hard_start = jaxmr.with_temperature(start, 0.0)
    assert result.initial_loss == pytest.approx(
        _worst_mean(hard_start, roads), rel=1e-10
    )
    assert result.loss == pytest.approx(
        _worst_mean(result.controller, roads), rel=1e-10
    )
    # Ten times too stiff, the start is far from the optimum: two steps gain more
    # than a quarter (measured: 0.93 to 0.52 m/s²), far beyond the noise's share.
    assert result.loss < 0.75 * result.initial_loss, (result.loss, result.initial_loss)
    # Law and estimator moved together (each step moves every log value by about
    # the learning rate).
    c_sky_, crossover, high_pass = (float(v) for v in result.values)
    assert c_sky_ < 0.5 * 20_000.0
    assert crossover != 5.0 and high_pass != 0.1
    assert float(result.controller.estimator.crossover) == crossover


def test_the_gradient_flows_to_law_and_estimator_through_the_noise(robust_run):
    controller, keywords, samples, roads, _ = robust_run
    _, setup, pair, u, batch = prepare(
        "tune",
        CAR,
        controller,
        roads,
        samples,
        keywords["parameters"],
        keywords["log_space"],
        keywords["bounds"],
        jaxmr.metrics.comfort,
        T,
        SAMPLING,
        jaxmr.FixedStep(4),
        0.5,
    )
    relaxed = (pair[0], jaxmr.with_temperature(pair[1], 0.1))

    def gradient(key):
        noise = sensor_noise(SENSORS, key, "test")
        value, grads, _ = loss_and_grad(u, relaxed, samples, batch, setup, noise)
        return float(value), np.array([float(g) for g in grads])

    value, grads = gradient(KEY)
    # Finite, and felt by every parameter: the gain directly, the corners through
    # the estimated velocities the law reads and the observer integrates.
    assert np.isfinite(value) and np.all(np.isfinite(grads)), grads
    assert np.all(grads != 0.0), grads
    # The noise enters the loss and its gradient: another draw, another value.
    other, other_grads = gradient(jax.random.key(8))
    assert other != value and np.all(other_grads != grads)


def test_a_search_scores_on_tune_s_fixed_draw(robust_run):
    # Random search over the same runs: its start is scored on the same noise as
    # tune's (equal to 1e-10, the same runs batched otherwise), and its other
    # candidate on that noise too, as `evaluate` scores it.
    controller, keywords, samples, roads, result = robust_run
    search = jaxmr.random_search(
        CAR,
        controller,
        roads,
        T,
        samples=samples,
        worst_share=0.5,
        sensors=SENSORS,
        sensor_key=KEY,
        simulations=2 * 4,  # the start and one candidate, on 2 samples x 2 roads
        population=2,
        spread=3.0,
        key=jax.random.key(1),
        **keywords,
    )
    assert search.initial_loss == pytest.approx(result.initial_loss, rel=1e-10)
    assert search.loss == pytest.approx(
        _worst_mean(search.controller, roads), rel=1e-10
    )


def test_sensor_keys_are_checked():
    law = _realistic(jaxmr.Skyhook(2000.0, 1.0))
    roads = _roads()
    with pytest.raises(TypeError, match="sensor_key=jax.random.key"):
        jaxmr.tune(CAR, law, roads, T, parameters=c_sky, sensors=SENSORS)
    with pytest.raises(ValueError, match="not with the perfect readings"):
        jaxmr.evaluate(CAR, law, roads, T, sensor_key=KEY)
    with pytest.raises(TypeError, match="must be a jaxmr.Sensors"):
        jaxmr.random_search(
            CAR,
            law,
            roads,
            T,
            parameters=c_sky,
            simulations=4,
            sensors="realistic",
            sensor_key=KEY,
        )


def test_tunable_selects_the_law_then_the_filters():
    scales = (0.08, 1.3, 0.27, 0.008, 0.27)  # feature sizes (m/s, m/s², m/s, m, m/s)
    law = jaxmr.ForceFeedback.mlp(scales, 1.0, width=4, depth=1)
    controller = _realistic(law)
    keywords = controller.tunable(
        jaxmr.ForceFeedback.weights,
        law_log_space=False,
        estimator=("crossover",),
        observer=("gain",),
    )
    weights = jaxmr.ForceFeedback.weights((CAR, law))
    selected = keywords["parameters"]((CAR, controller))
    assert len(selected) == len(weights) + 2
    for a, b in zip(selected, weights, strict=False):
        assert a is b
    assert selected[-2] is controller.estimator.crossover
    assert selected[-1] is controller.observer.gain
    # Signed weights in values; the corner in log space; the gain within (0, 1].
    assert keywords["log_space"] == (False,) * len(weights) + (True, True)
    assert keywords["bounds"] == (None,) * (len(weights) + 1) + ((1e-4, 1.0),)
    # The same choice, the same selector: a second tune reuses the compiled loss.
    again = controller.tunable(
        jaxmr.ForceFeedback.weights,
        law_log_space=False,
        estimator=("crossover",),
        observer=("gain",),
    )
    assert again["parameters"] is keywords["parameters"]
    with pytest.raises(ValueError, match="no tunable field 'bandwidth'"):
        controller.tunable(estimator=("bandwidth",))
    bare = jaxmr.ObserverBasedController(law, oracle=True)
    with pytest.raises(ValueError, match="does not have"):
        bare.tunable(jaxmr.ForceFeedback.weights)


def test_mixed_spaces_map_each_parameter_in_its_own():
    # A signed weight in values, a positive corner in log space and a gain within
    # bounds: each mapped its own way, and back (to 1e-15: exp and log round trips).
    space = as_space((False, True, True), [None, None, (1e-4, 1.0)], "test")
    assert space == (False, True, (1e-4, 1.0))
    values = (jnp.array([-0.5, 2.0]), jnp.array(5.0), jnp.array(0.1))
    us = from_values(values, space, "test")
    np.testing.assert_array_equal(us[0], values[0])
    assert float(us[1]) == pytest.approx(np.log(5.0), rel=1e-15)
    back = to_values(us, space)
    for a, b in zip(back, values, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-14)
    with pytest.raises(ValueError, match="need `log_space=True`"):
        as_space((False, True), [(1.0, 2.0), None], "test")
    with pytest.raises(ValueError, match="one entry per parameter"):
        as_space((False, True), [None], "test")
    with pytest.raises(TypeError, match="one bool per parameter"):
        as_space((0, 1), None, "test")
