"""The tuners, `evaluate` and `free_decay` choose their RK4 substeps from the
damper's stiffness when no `integrator` is given, as `simulate_system` does (issue
27): unchanged where the damper is not stiff, enough where it is, and an error that
says what to change where a given step is too long."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr

from .helpers import FITTED_SPENCER

T = 1.0
# test_tune.py's car, roads and start: the same shapes, the same compilations.
CAR = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
KEYS = jax.vmap(jax.random.key)(jnp.asarray([0, 1]))
TRAIN = jax.vmap(lambda k: jaxmr.iso8608_road("C", 20.0, T, k))(KEYS)
# Skyhook inverts the damper: with perfect information (`sensors="oracle"`), as in
# test_tune.py.
FAR = jaxmr.Skyhook(20_000.0, 1.0)

# The UTFSM Spencer fit (tests/helpers.py): the car needs 64 substeps where
# `FixedStep()` (4) diverges.
STIFF = jaxmr.passenger_car(FITTED_SPENCER)


def c_sky(pair):
    return pair[1].c_sky


def test_default_steps_are_unchanged_where_the_damper_is_not_stiff():
    """The passenger-car damper is not stiff on these roads: `tune` with no
    `integrator` takes `FixedStep()`, its result the same bits as with it given."""
    settings = dict(
        parameters=c_sky, steps=2, learning_rate=1.5, progress=False, sensors="oracle"
    )
    chosen = jaxmr.tune(CAR, FAR, TRAIN, T, **settings)
    given = jaxmr.tune(CAR, FAR, TRAIN, T, integrator=jaxmr.FixedStep(), **settings)
    assert chosen.integrator == jaxmr.FixedStep() == given.integrator
    assert chosen.history == given.history and chosen.loss == given.loss
    assert float(chosen.values[0]) == float(given.values[0])
    # `evaluate` chooses the same way: the tuned loss, evaluated again. Its damper
    # holds a fitted range of ±1 mm/s (it changes no result): the roads drive it far
    # beyond, and `evaluate` warns once, from its own runs.
    narrow = jaxmr.FittedRange((-0.05, 0.05), (-1e-3, 1e-3), (0.0, 2.5))
    ranged = jaxmr.with_fitted_range(CAR, narrow)
    with pytest.warns(jaxmr.OutsideFittedRange, match="^evaluate drove .* m/s") as w:
        scores = jaxmr.evaluate(ranged, chosen.controller, TRAIN, T, sensors="oracle")
    assert len(w) == 1
    scores = scores["comfort"]
    assert float(np.mean(scores)) == pytest.approx(chosen.loss, rel=1e-10)


def test_a_stiff_damper_gets_enough_substeps_and_a_too_long_step_says_so():
    """The stiff fitted damper on one road: `random_search` with no `integrator`
    chooses more than `FixedStep()`'s 4 substeps and scores a finite loss, the one
    `evaluate` gives at those steps; given `FixedStep()` every run diverges, and
    the errors of `random_search` and `evaluate` say what to pass."""
    road = jax.tree.map(lambda a: a[:1], TRAIN)
    settings = dict(parameters=c_sky, simulations=1, sensors="oracle")
    result = jaxmr.random_search(STIFF, FAR, road, T, **settings)
    assert result.integrator is not None and result.integrator.substeps > 4
    assert np.isfinite(result.loss)
    scores = jaxmr.evaluate(
        STIFF, FAR, road, T, integrator=result.integrator, sensors="oracle"
    )
    assert float(scores["comfort"][0]) == pytest.approx(result.loss, rel=1e-10)
    # `evaluate` with no `integrator` chooses from its own (vmapped) runs the
    # substeps `random_search` chose from each road run alone: the same score.
    chosen = jaxmr.evaluate(STIFF, FAR, road, T, sensors="oracle")
    assert float(chosen["comfort"][0]) == pytest.approx(result.loss, rel=1e-10)
    advice = r"pass `integrator=jaxmr.FixedStep\(substeps=16\)` or more, or no"
    with pytest.raises(ValueError, match=r"random_search: every parameter .*" + advice):
        jaxmr.random_search(
            STIFF, FAR, road, T, integrator=jaxmr.FixedStep(), **settings
        )
    # `evaluate` at `FixedStep()`: the run diverges, and the error says so.
    with pytest.raises(eqx.EquinoxRuntimeError, match="road 0 diverged .*" + advice):
        jaxmr.evaluate(
            STIFF, FAR, road, T, integrator=jaxmr.FixedStep(), sensors="oracle"
        )


def test_free_decay_chooses_its_steps_too():
    """`free_decay` with no `integrator` runs as `simulate_system` with none: for
    the source's brake (not stiff) the same bits as `FixedStep()`; for a brake whose
    state relaxes 30 times faster (A, beta and gamma scaled alike: the same
    saturated state and torque), finite where `FixedStep()` diverges, and that error
    says what to change."""
    rig = jaxmr.sas_rig()
    chosen = jaxmr.free_decay(rig, 0.5, duration=0.5)
    given = jaxmr.free_decay(rig, 0.5, duration=0.5, integrator=jaxmr.FixedStep())
    assert np.array_equal(chosen.states, given.states)
    brake = rig.damper.hysteresis
    fast = eqx.tree_at(
        lambda b: (b.A, b.beta, b.gamma),
        brake,
        tuple(30.0 * jnp.asarray(p) for p in (brake.A, brake.beta, brake.gamma)),
    )
    stiff = eqx.tree_at(lambda r: r.damper.hysteresis, rig, fast)
    solution = jaxmr.free_decay(stiff, 0.5, duration=0.5)
    assert np.all(np.isfinite(solution.states))
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"FixedStep\(substeps=16\)"):
        jaxmr.free_decay(stiff, 0.5, duration=0.5, integrator=jaxmr.FixedStep())
