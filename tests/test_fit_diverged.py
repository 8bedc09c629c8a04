"""`fit` reports a model whose state leaves its bounds as a failure that names the
experiment and the time, as `jaxmr predict` and `jaxmr report` do (issue 27)."""

import numpy as np

import jaxmr


def _rest_then_sine(start: float, name: str):
    """At rest until `start` [s], then a 2 Hz ±5 mm sine (v continuous from 0 to its
    peak: a kink in x), sampled at 500 Hz for 0.6 s; a saturating force."""
    t = np.arange(0.0, 0.6, 2e-3)
    w = 2 * np.pi * 2.0
    moving = t >= start
    x = np.where(moving, 5e-3 * np.sin(w * (t - start)), 0.0)
    v = np.where(moving, 5e-3 * w * np.cos(w * (t - start)), 0.0)
    force = 800.0 * np.tanh(v / 0.01) + 50.0 * v
    return jaxmr.data.Experiment(t, x, v, 0.0, force, name=name)


def test_a_state_that_leaves_its_bounds_fails_the_fit_naming_experiment_and_time():
    """A Dahl model whose state relaxes within 1 µm (rho = 1e6 1/m, fixed): `fit`'s
    steps of 25 µm travel are 25 relaxation lengths, RK4 overshoots |z| <= 1 as soon
    as the piston moves. At rest nothing happens, so each experiment diverges where
    its motion starts (0.3 s, 0.45 s): `diverged_at` gives those times per
    experiment, the same `predict` finds, and `outcome` names both."""
    runs = [_rest_then_sine(0.3, "late"), _rest_then_sine(0.45, "later")]
    model = jaxmr.Dahl(k_x=50.0, k_w=800.0, rho=jaxmr.Fixed(1e6))
    result = jaxmr.fit(model, runs, progress=False, max_steps=2)
    assert not result.converged
    assert np.all(np.isinf(result.rmse))
    at = result.diverged_at
    assert at is not None and at.shape == (2,)
    for run, t in zip(runs, at):
        # Where `predict` (the same guarded simulation and steps) stops giving forces.
        predicted = jaxmr.predict(result.model, run)
        first = np.asarray(run.t)[np.argmax(~np.isfinite(predicted))]
        assert t == first, (t, first)
    # Within a step or two of the motion's start (2 ms samples), never before it.
    assert 0.3 <= at[0] <= 0.305 and 0.45 <= at[1] <= 0.455, at
    for name, t in zip(("late", "later"), at):
        assert f"experiment {name!r} at t = {t:g} s" in result.outcome, result.outcome
    assert "its state left its bounds" in result.outcome


def test_a_fit_that_holds_names_no_divergence():
    """The same experiments with a state that relaxes over 5 mm (rho = 200 1/m; the
    same shapes: the same compilation): the fit's simulation holds, `diverged_at`
    is NaN and `outcome` says nothing of divergence."""
    runs = [_rest_then_sine(0.3, "late"), _rest_then_sine(0.45, "later")]
    model = jaxmr.Dahl(k_x=50.0, k_w=800.0, rho=jaxmr.Fixed(200.0))
    result = jaxmr.fit(model, runs, progress=False, max_steps=2)
    assert np.all(np.isfinite(result.rmse))
    assert result.diverged_at is not None and np.all(np.isnan(result.diverged_at))
    assert result.divergence is None and "diverged" not in result.outcome
