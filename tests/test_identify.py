"""`fit`: synthetic identification of the published Bouc–Wen brake (issue 3's first
acceptance case) and the identifiability report."""

from types import SimpleNamespace

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr

from .helpers import dahl_guess, dahl_runs

CURRENTS = (0.0, 0.25, 0.5, 0.75, 1.0)


@pytest.fixture(scope="module")
def synthetic():
    """The published brake at 5 currents, one 1 Hz ±3.5° cycle at 500 Hz, 1 % noise."""
    truth = jaxmr.sas_brake_bouc_wen()
    ts = jnp.linspace(0.0, 1.0, 501)
    sol = jaxmr.sweep(truth, jaxmr.Sine(jnp.deg2rad(3.5), 1.0), jnp.array(CURRENTS), ts)
    rng = np.random.default_rng(0)
    experiments = []
    for k, c in enumerate(CURRENTS):
        force = np.asarray(sol.force[k])
        noisy = force + 0.01 * np.std(force) * rng.standard_normal(force.shape)
        experiments.append(
            SimpleNamespace(
                t=np.asarray(ts),
                x=np.asarray(sol.displacement[k]),
                v=np.asarray(sol.velocity[k]),
                current=np.full(ts.shape, c),
                force=noisy,
                name=f"{c} A",
            )
        )
    return truth, experiments


def _guess(fix_A: bool):
    P, zero = jaxmr.Positive, jaxmr.Fixed(0.0)
    return jaxmr.BoucWen(
        alpha=jaxmr.LinearLaw(P(2.5), P(0.2)),
        c0=jaxmr.LinearLaw(P(0.004), P(0.15)),
        A=jaxmr.Fixed(843.0) if fix_A else P(843.0 * 2.0),
        beta=P(737.0 * 2.5),
        gamma=P(2.5),
        n=P(0.9 * 1.3),
        k0=zero,
        x0=zero,
        f0=zero,
    )


def test_seven_brake_parameters_recovered(synthetic):
    truth, experiments = synthetic
    result = jaxmr.fit(_guess(fix_A=True), experiments, progress=False)
    assert result.converged, result.reason
    assert not result.unidentified
    # The residual is at the noise floor: NRMSE ≈ 0.01 in every experiment.
    np.testing.assert_allclose(result.nrmse, 0.01, rtol=0.15)
    true = {
        ".alpha.a": 1.0,
        ".alpha.b": 0.07,
        ".c0.a": 0.0015,
        ".c0.b": 0.07,
        ".beta": 737.0,
        ".gamma": 1.0,
        ".n": 0.9,
    }
    for name, value, se in zip(result.names, result.values, result.std_errors):
        # Parameters whose effect is above the noise (relative standard error < 2 %)
        # are recovered within 2 %, and every estimate lies within 4 standard errors.
        if se / abs(value) < 0.02:
            assert abs(value / true[name] - 1) < 0.02, (name, value)
        assert abs(value - true[name]) < 4 * se + 1e-12, (name, value, se)
    assert isinstance(result.model, jaxmr.BoucWen)
    assert "alpha" in result.table()
    _check_samples(result)


def _check_samples(result):
    # `FitResult.sample` (robust tuning's input): every value drawn log-normal around
    # the fit with the fit's relative standard errors; fixed parameters repeated.
    import jax

    n = 4000
    models = result.sample(n, jax.random.key(0))
    assert models.alpha.a.shape == (n,) and models.A.shape == (n,)
    np.testing.assert_array_equal(models.A, result.model.A)
    draws = np.stack(
        [
            models.alpha.a,
            models.alpha.b,
            models.c0.a,
            models.c0.b,
            models.beta,
            models.gamma,
            models.n,
        ],
        axis=1,
    )
    assert list(result.names) == [
        ".alpha.a",
        ".alpha.b",
        ".c0.a",
        ".c0.b",
        ".beta",
        ".gamma",
        ".n",
    ]
    assert np.all(draws > 0)
    logs = np.log(draws)
    # The median of a log-normal is the fitted value; with 4000 draws its estimate
    # lies within 4 sigma/sqrt(n) (times 1.25 for the median's efficiency).
    relative = result.std_errors / result.values
    tol = 4 * 1.25 * relative / np.sqrt(n)
    np.testing.assert_array_less(
        np.abs(np.median(logs, axis=0) - np.log(result.values)), tol + 1e-15
    )
    # The spread and the correlations are the fit's (sampling error ~2 % at n=4000):
    # log variances d with the fit's variance in value, e^d (e^d - 1) = relative²
    # (about relative² where that is small; c0.a's 62 % gives 0.51).
    expected = np.sqrt(np.log((1 + np.sqrt(1 + 4 * relative**2)) / 2))
    np.testing.assert_allclose(np.std(logs, axis=0), expected, rtol=0.1)
    np.testing.assert_allclose(np.std(draws, axis=0), result.std_errors, rtol=0.15)
    np.testing.assert_allclose(
        np.corrcoef(logs.T), np.nan_to_num(result.correlation), atol=0.1
    )


def test_eight_brake_parameters_flagged_as_not_identified(synthetic):
    _, experiments = synthetic
    # The flag comes from the Jacobian's null vector, an exact symmetry at any step:
    # the fit's own steps serve (no refined Jacobian, another compilation).
    result = jaxmr.fit(
        _guess(fix_A=False),
        experiments,
        progress=False,
        max_steps=40,
        statistics_refinement=1,
    )
    assert result.unidentified, "the (alpha, A, beta, gamma) scaling must be flagged"
    message = result.unidentified[0]
    # The null vector of z -> z/s: log A - log alpha + (n - 1)(log beta + log gamma).
    for name in (".A", ".alpha.a", ".alpha.b", ".beta", ".gamma"):
        assert name in message
    assert not result.converged
    # A direction the data do not see has no finite variance: each parameter moving
    # along it has an infinite standard error (the pseudo-inverse gave about 0, as if
    # it were exact), and the report says so.
    errors = dict(zip(result.names, result.std_errors))
    assert all(np.isinf(errors[n]) for n in (".A", ".beta", ".gamma")), errors
    assert any("no finite standard error" in m for m in result.poorly_determined)


def test_fit_each_fits_independent_runs_in_one_batch():
    rhos, k_ws = (3.0, 5.0, 8.0, 12.0), (1.0, 2.0, 3.0, 4.0)
    # The fit's own Jacobian for the statistics (not what is tested here; the refined
    # one is, in tests/test_uncertainty.py): one compiled shape fewer.
    options = dict(progress=False, statistics_refinement=1)
    results = jaxmr.fit_each(dahl_guess(), dahl_runs(rhos, k_ws), **options)
    assert len(results) == 4
    for result, rho, k_w in zip(results, rhos, k_ws):
        values = dict(zip(result.names, result.values))
        # k_w and rho dominate the loop: within 2 % at 1 % noise.
        assert abs(values[".rho"] / rho - 1) < 0.02, values
        assert abs(values[".k_w"] / k_w - 1) < 0.02, values
        assert result.nrmse[0] < 0.013
        # Each run's own history, up to its own stop (it was the batch's best loss
        # at every step, as long as the slowest run's).
        assert result.history[-1] == result.loss
        assert len(result.history) == result.num_steps
        assert np.all(np.diff(result.history) <= 0)
    assert len({len(r.history) for r in results}) > 1  # the runs stop apart here
    # One start per experiment (here all the same): the same compiled batch, the
    # same results, exactly.
    again = jaxmr.fit_each([dahl_guess()] * 4, dahl_runs(rhos, k_ws), **options)
    for result, other in zip(results, again):
        np.testing.assert_array_equal(result.values, other.values)
    with pytest.raises(ValueError, match="one per experiment"):
        jaxmr.fit_each([dahl_guess()] * 3, dahl_runs(rhos, k_ws), progress=False)


def test_fit_each_result_does_not_depend_on_the_other_problems(monkeypatch):
    """In chunks of 2 (the package's is 16: too many for a quick test), two runs fitted
    alone and the same two beside two others give the same bits: the same compiled
    shapes, and a problem that has stopped keeps its answer however long the batch
    steps on for the others."""
    from jaxmr._identify import fitting

    monkeypatch.setattr(fitting, "FIT_EACH_CHUNK", 2)
    runs = dahl_runs((3.0, 5.0, 8.0, 12.0), (1.0, 2.0, 3.0, 4.0))
    kwargs = dict(progress=False, statistics_refinement=1)
    four = jaxmr.fit_each(dahl_guess(), runs, **kwargs)
    two = jaxmr.fit_each(dahl_guess(), runs[:2], **kwargs)
    for alone, beside in zip(two, four[:2]):
        np.testing.assert_array_equal(alone.values, beside.values)
        assert alone.num_steps == beside.num_steps
    # Each problem's own step count, not the batch's.
    assert len({r.num_steps for r in four}) > 1, [r.num_steps for r in four]


def test_fit_each_scales_each_problem_by_its_own_jacobian():
    """A run whose torque is 1000x the other's, placed second, is fitted as it is
    alone: the same steps and values (to 1e-9, the chunk's last bits). With the
    first problem's column scale for both it took 47 steps against 33 alone (and a
    larger spread of scales stalled at NRMSE 0.25)."""
    runs = dahl_runs((3.0, 5.0), (1.0, 1000.0))
    kwargs = dict(progress=False, statistics_refinement=1)
    both = jaxmr.fit_each(dahl_guess(), runs, **kwargs)
    (alone,) = jaxmr.fit_each(dahl_guess(), runs[1:], **kwargs)
    assert both[1].num_steps == alone.num_steps
    np.testing.assert_allclose(both[1].values, alone.values, rtol=1e-9)
    assert both[1].nrmse[0] < 0.013 and both[0].nrmse[0] < 0.013


def test_multistart_keeps_the_best_and_interrupt_keeps_progress():
    runs = dahl_runs((5.0,), (3.0,))
    result = jaxmr.fit(
        dahl_guess(),
        runs,
        starts=3,
        spread=4.0,
        progress=False,
        statistics_refinement=1,  # the fit's own Jacobian: one compilation less
    )
    assert result.converged and result.nrmse[0] < 0.013

    def interrupt(step, loss):
        if step == 3:
            raise KeyboardInterrupt

    stopped = jaxmr.fit(dahl_guess(), runs, progress=interrupt)
    assert stopped.reason.startswith("interrupted at step 3")
    assert stopped.num_steps == 3 and not stopped.converged
    # The best parameters so far are kept: better than the start.
    assert stopped.loss < stopped.history[0]


def test_fit_warns_in_float32(monkeypatch):
    import jax

    monkeypatch.setattr(jax.numpy, "result_type", lambda *a: np.dtype("float32"))
    with pytest.warns(UserWarning, match="float32"):
        with pytest.raises(Exception):  # noqa: B017 - only the warning matters here
            jaxmr.fit(dahl_guess(), [], progress=False)


def test_fit_each_with_two_host_devices_keeps_to_one():
    import os
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent(
        """
        import jax
        jax.config.update("jax_enable_x64", True)
        import numpy as np, jaxmr
        from tests.helpers import dahl_guess, dahl_runs
        assert jax.local_device_count() == 2
        runs = dahl_runs((3.0, 8.0), (1.0, 3.0))
        # One process's CPU devices: the batch stays on one (a large batch over two
        # hung); the fits are right. Statistics from the fit's own Jacobian.
        results = jaxmr.fit_each(
            dahl_guess(), runs, progress=False, statistics_refinement=1
        )
        for result, rho in zip(results, (3.0, 8.0)):
            assert abs(dict(zip(result.names, result.values))[".rho"] / rho - 1) < 0.02
        print("sharded fit ok")
        """
    )
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ)
    # The session's flags (conftest: jaxmr.devices.configure_cpu) and 2 CPU devices.
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    )
    env["JAX_PLATFORMS"] = "cpu"
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        cwd=root,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "sharded fit ok" in out.stdout


def test_one_current_cannot_identify_a_current_law(synthetic):
    _, experiments = synthetic
    with pytest.raises(ValueError, match="same current"):
        jaxmr.fit(_guess(fix_A=True), experiments[:1], progress=False)


def test_a_parameter_set_with_tree_at_is_fitted():
    """`equinox.tree_at` bypasses a model's constructor, so a parameter set with it
    stays a Python float: `fit` and `fit_only` still fit it (it had been left out
    without a word, and `fit_only` of it said every parameter was Fixed); `fit_only`
    fixes the others, `Positive` ones included (they had stayed free)."""
    runs = dahl_runs((5.0,), (3.0,), samples=61, substeps=2)
    edited = eqx.tree_at(lambda m: m.k_w, dahl_guess(), 2.0)
    assert type(edited.k_w) is float
    result = jaxmr.fit(edited, runs, max_steps=30, progress=False)
    assert ".k_w" in result.names
    # 1 % noise on one cycle: k_w within 5 % of the truth (its error about 0.3 %).
    assert abs(result.values[result.names.index(".k_w")] - 3.0) < 0.15
    only = jaxmr.fit_only(edited, lambda m: m.k_w)
    assert jaxmr.fit(only, runs, max_steps=2, progress=False).names == (".k_w",)


def test_fit_names_a_wrong_call_before_compiling():
    """One experiment without its list, and a step budget below 1, are refused at the
    call, naming what to give. (The suite's type checker refuses the lone experiment
    first, naming the parameter `experiments`; without it jaxmr's message says to
    give a list.)"""
    (run,) = dahl_runs((5.0,), (3.0,), samples=61, substeps=2)
    lone = r"one experiment; give a list of them|parameter 'experiments'"
    with pytest.raises(TypeError, match=lone):
        jaxmr.fit(dahl_guess(), run)
    with pytest.raises(TypeError, match=lone):
        jaxmr.predict_all(dahl_guess(), run)
    with pytest.raises(ValueError, match=r"`max_steps` must be at least 1, got 0"):
        jaxmr.fit(dahl_guess(), [run], max_steps=0)
    with pytest.raises(
        TypeError, match=r"`patience` must be an integer|parameter .patience."
    ):
        jaxmr.fit_each(dahl_guess(), [run], patience=2.5)  # pyright: ignore[reportArgumentType]
    forceless = SimpleNamespace(**{**vars(run), "force": None})
    with pytest.raises(ValueError, match="has no measured force to score"):
        jaxmr.record_nrmse(dahl_guess(), [forceless])


def test_a_fit_that_breaks_its_models_constraints_says_so():
    """A plain parameter is fitted without bounds: on data that ask for it (a force
    that falls with the velocity) the fitted dashpot goes negative, a model that its
    simulations refuse. `fit` warns, naming the constraint; the template, whose
    parameters are `Positive`, stays inside and warns nothing."""
    import jaxmr.data
    import jaxmr.templates

    t = np.linspace(0.0, 1.0, 201)
    w = 2 * np.pi
    v = 0.01 * w * np.cos(w * t)
    force = 300 * np.tanh(v / 0.01) - 500 * v
    run = jaxmr.data.Experiment(t, 0.01 * np.sin(w * t), v, 0.0, force, name="run")
    plain = jaxmr.Bingham(100.0, 500.0, velocity_scale=jaxmr.Fixed(0.01))
    with pytest.warns(UserWarning, match=r"breaks its own constraints: Bingham: the "):
        result = jaxmr.fit(plain, [run], max_steps=20, progress=False)
    assert result.values[1] < 0  # c0
    template = jaxmr.templates.MODEL_TEMPLATES["bingham"]([run])
    jaxmr.fit(
        template, [run], max_steps=20, progress=False
    )  # no warning (an error here)


def test_a_model_broken_only_below_zero_input_says_to_clip_the_input():
    """An input that dips below zero (an amplifier's offset or noise) takes a current
    law fitted for inputs at or above zero below its bound. The warning says that it
    is broken only there and to clip the input, not to constrain parameters that
    already are."""
    import jaxmr.data

    t = np.linspace(0.0, 1.0, 201)
    w = 2 * np.pi
    v = 0.01 * w * np.cos(w * t)
    current = 0.5 + 0.6 * np.sin(3 * w * t)  # down to -0.1 A
    f_c = jaxmr.LinearLaw(jaxmr.Fixed(5.0), jaxmr.Fixed(300.0))  # -25 N at -0.1 A
    force = (5.0 + 300.0 * current) * np.tanh(v / 0.01) + 500 * v
    run = jaxmr.data.Experiment(t, 0.01 * np.sin(w * t), v, current, force, name="r")
    model = jaxmr.Bingham(f_c, jaxmr.Positive(400.0), velocity_scale=jaxmr.Fixed(0.01))
    with pytest.warns(UserWarning, match="only where the input is below zero") as got:
        jaxmr.fit(model, [run], max_steps=5, progress=False)
    (message,) = [str(w.message) for w in got if "constraints" in str(w.message)]
    assert "-0.1 A or V" in message and "clip the input at zero" in message
    assert "constrain those parameters" not in message


def test_the_constraint_check_compiles_once_whatever_the_fitted_range():
    """The check after a fit (`broken_constraints`) is one compiled program per
    model structure. A model's fitted range is a static field of its pytree: a
    loaded model, or one fitted on other data, compiled the check again for each
    range, as the simulations would have had they not left it out."""
    import jax

    import jaxmr.data
    from jaxmr import FittedRange, with_fitted_range
    from jaxmr._identify.fitting import broken_constraints

    t = np.linspace(0.0, 0.1, 101)
    runs = [
        jaxmr.data.Experiment(t, 0.1 * t, 0.1 + 0 * t, i, 100 + 0 * t, name=f"{i} A")
        for i in (0.0, 1.0)
    ]
    model = jaxmr.Bingham(jaxmr.LinearLaw(-5.0, 300.0), 400.0)  # f_c < 0 at 0 A
    traced = []

    def count(event, seconds, fun_name="", **kwargs):
        if event.endswith("jaxpr_trace_duration") and fun_name == "_checks_over":
            traced.append(fun_name)

    jax.monitoring.register_event_duration_secs_listener(count)
    try:
        messages = [
            broken_constraints(with_fitted_range(model, r), runs)
            for r in (None, *(FittedRange.from_experiments(runs[:k]) for k in (1, 2)))
        ]
    finally:
        jax.monitoring.unregister_event_duration_listener(count)
    assert messages[0] and all(m == messages[0] for m in messages), messages
    assert len(traced) <= 1, traced  # 0 where an earlier test compiled it


def test_a_parameter_at_a_mode_of_its_model_is_left_alone():
    """Bingham's `velocity_scale` of 0 (its default) is the exact sign, a form of the
    model rather than a size: the force does not change with it there. A fit of a
    plain `Bingham(f_c, c0)` leaves it alone and converges (it had varied it and
    reported it unidentified, "not converged", on every such fit); a positive one is
    fitted."""
    import jaxmr.data

    t = np.linspace(0.0, 1.0, 201)
    w = 2 * np.pi
    v = 0.01 * w * np.cos(w * t)
    noise = np.random.default_rng(7).normal(0.0, 1.0, t.size)  # [N], 0.3 % of f_c
    force = 300 * np.sign(v) + 2000 * v + noise
    run = jaxmr.data.Experiment(t, 0.01 * np.sin(w * t), v, 0.0, force, name="run")
    result = jaxmr.fit(jaxmr.Bingham(100.0, 500.0), [run], max_steps=30, progress=False)
    assert result.names == (".f_c", ".c0", ".f0") and result.converged, result.outcome
    assert float(result.model.velocity_scale) == 0.0
    # Within 4 standard errors of the truth (measured 0.2 and 3.6 N, 1.1 and 1.4 sd).
    truth = np.array([300.0, 2000.0])
    assert np.all(np.abs(result.values[:2] - truth) < 4 * result.std_errors[:2])
    smooth = jaxmr.Bingham(100.0, 500.0, velocity_scale=jaxmr.Positive(0.01))
    assert (
        ".velocity_scale" in jaxmr.fit(smooth, [run], max_steps=2, progress=False).names
    )
