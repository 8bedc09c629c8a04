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
        # Where `predict` (the same guarded simulation and steps, not run again with
        # shorter ones) stops giving forces.
        predicted = jaxmr.predict(result.model, run, refine_diverged=False)
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


def test_a_fit_started_inside_the_bounds_stops_inside_them():
    """Data a fit's own discretisation gives only past RK4's stability limit: a Dahl
    damper with rho = 2.5e4 1/m simulated with one RK4 step per 2 ms sample (rho·|v|·h
    = 3.1 at the 2 Hz, ±5 mm sine's peak speed, past the limit 2.785; its state
    leaves |z| <= 1, as `simulate`'s result says), the same steps in the fit
    (`FixedStep(1)`). From rho = 1e4 (inside) the loss falls all the way to the
    data's rho. A fit that starts inside the bounds rejects every point whose state
    leaves them (`guarded_residuals`): it ends below the limit on a sound
    simulation, where its report agrees (finite scores, no divergence). Unguarded it
    went to rho = 2.5e4, a loss of 2e-21 there, and its report scored the first
    experiment inf (diverged at 4 ms)."""
    t = np.arange(0.0, 0.6, 2e-3)
    truth = jaxmr.Dahl(k_x=50.0, k_w=800.0, rho=2.5e4)
    runs = []
    for amplitude, name in ((5e-3, "past the limit"), (4e-3, "within it")):
        solution = jaxmr.simulate(
            truth,
            jaxmr.Sine(amplitude, 2.0),
            0.0,
            t,
            integrator=jaxmr.FixedStep(1),
            throw=False,
        )
        runs.append(
            jaxmr.data.Experiment(
                t,
                np.asarray(solution.displacement),
                np.asarray(solution.velocity),
                0.0,
                np.asarray(solution.force),
                name=name,
            )
        )
        expected = (
            jaxmr.RESULTS.state_out_of_bounds
            if name == "past the limit"
            else jaxmr.RESULTS.successful
        )
        assert solution.result == expected, (name, solution.result)
    model = jaxmr.Dahl(k_x=50.0, k_w=800.0, rho=jaxmr.Positive(1e4))
    result = jaxmr.fit(
        model, runs, integrator=jaxmr.FixedStep(1), progress=False, max_steps=40
    )
    assert np.all(np.isfinite(result.rmse)), result.outcome
    assert result.diverged_at is not None and np.all(np.isnan(result.diverged_at))
    # It climbed from 1e4 to just below the limit (2.785 / (2 pi 2 Hz · 5 mm · 2 ms)
    # = 2.2e4; a point's steps at lower speeds are further inside), not past it.
    assert 2.0e4 < float(result.model.rho) < 2.4e4, result.model.rho
