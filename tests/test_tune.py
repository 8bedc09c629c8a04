"""Gradient tuning through the closed loop (issue 5): `tune`, `random_search`,
`evaluate`, `CurrentSchedule`.

Short runs (1 s roads, two of them) keep the compile and run time small; the physics
(that tuning helps on held-out roads) is checked at scale in notebook 04 and the
benchmark."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr

T = 1.0
CAR = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())


def roads(seeds):
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
    return jax.vmap(lambda k: jaxmr.iso8608_road("C", 20.0, T, k))(keys)


TRAIN = roads([0, 1])


def c_sky(pair):
    return pair[1].c_sky


def test_tune_improves_the_training_loss_and_keeps_the_best():
    start = jaxmr.Skyhook(300.0, 1.0)
    result = jaxmr.tune(
        CAR,
        start,
        TRAIN,
        T,
        parameters=c_sky,
        steps=4,
        learning_rate=0.5,
        progress=False,
    )
    assert result.loss < result.initial_loss
    assert list(result.history) == sorted(result.history, reverse=True)
    assert result.simulations == 4 * 2
    # The reported loss is that of the returned controller.
    again = jaxmr.evaluate(CAR, result.controller, TRAIN, T)["comfort"]
    assert float(np.mean(again)) == pytest.approx(result.loss, rel=1e-10)
    assert isinstance(result.controller, jaxmr.Skyhook)


def test_random_search_spends_the_same_budget():
    start = jaxmr.Skyhook(300.0, 1.0)
    search = jaxmr.random_search(CAR, start, TRAIN, T, parameters=c_sky, simulations=6)
    assert search.simulations == 6
    assert len(search.history) == 3
    assert search.loss <= search.initial_loss


def test_tuning_gradient_matches_finite_differences():
    # The gradient tune follows, d loss / d log c_sky, through the relaxed on/off law's
    # switching condition (zero for the hard law).
    from jaxmr._tune import _as_tuple_where, _loss, _loss_and_grad

    def i_on(pair):
        return pair[1].i_max

    where = _as_tuple_where(i_on)
    smooth = jaxmr.OnOffSkyhook(0.3, temperature=0.2)
    args = (True, where, TRAIN, jaxmr.comfort, T, 1e-3, 4, 1)
    x = (jnp.log(jnp.array(0.3)),)
    value, grad = _loss_and_grad(x, (CAR, smooth), *args)
    h = 1e-5
    up = _loss((x[0] + h,), (CAR, smooth), *args)
    down = _loss((x[0] - h,), (CAR, smooth), *args)
    fd = (up - down) / (2 * h)
    assert float(grad[0]) == pytest.approx(float(fd), rel=1e-5)


def test_current_schedule_tuned_in_value_space():
    samples = int(round(T / 1e-3))
    start = jaxmr.CurrentSchedule.constant(0.1, samples, 1.0)
    sol = jaxmr.simulate_system(CAR, jax.tree.map(lambda x: x[0], TRAIN), start, T)
    np.testing.assert_allclose(sol.command, 0.1, rtol=1e-12)
    one = jax.tree.map(lambda x: x[:1], TRAIN)
    result = jaxmr.tune(
        CAR,
        start,
        one,
        T,
        parameters=lambda p: p[1].logits,
        log_space=False,
        steps=3,
        learning_rate=0.5,
        progress=False,
    )
    assert result.loss < result.initial_loss
    assert result.controller.logits.shape == (samples,)


def test_bad_tuning_input():
    with pytest.raises(ValueError, match="must be positive"):
        jaxmr.tune(
            CAR,
            jaxmr.Skyhook(0.0, 1.0),
            TRAIN,
            T,
            parameters=c_sky,
            steps=1,
            progress=False,
        )
    with pytest.raises(ValueError, match="batch of road signals"):
        jaxmr.tune(
            CAR,
            jaxmr.Skyhook(10.0, 1.0),
            jaxmr.Sine(0.01, 1.0),
            T,
            parameters=c_sky,
            steps=1,
            progress=False,
        )
