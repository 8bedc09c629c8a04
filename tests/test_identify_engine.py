"""The identification engine: packed layout, per-experiment steps, starts, compilation
reuse and the honest report (issue 9)."""

import threading
from types import SimpleNamespace

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import jaxmr
from jaxmr._identify.data import StepPolicy, pack
from jaxmr._identify.residual import residuals_jit
from jaxmr._identify.solver import iterate, spread_starts
from jaxmr._parameter import free_filter

from .helpers import dahl_guess, dahl_runs


def _brake_runs():
    """The published brake at 3 currents, 1 Hz ±3.5°, of different lengths and sample
    rates (1.2 s at 500 Hz, 0.8 s at 250 Hz, 1.0 s at 1 kHz), noise-free."""
    truth = jaxmr.sas_brake_bouc_wen()
    # Each run simulated on one 1 kHz grid over 1.2 s (one compiled solve) and cut to
    # its length and rate.
    ts = jnp.linspace(0.0, 1.2, 1201)
    runs = []
    for current, duration, rate in ((0.0, 1.2, 500), (0.5, 0.8, 250), (1.0, 1.0, 1000)):
        sol = jaxmr.simulate(truth, jaxmr.Sine(jnp.deg2rad(3.5), 1.0), current, ts)
        keep = slice(0, round(duration * 1000) + 1, 1000 // rate)
        runs.append(
            SimpleNamespace(
                t=np.asarray(ts)[keep],
                x=np.asarray(sol.displacement)[keep],
                v=np.asarray(sol.velocity)[keep],
                current=np.full(np.asarray(ts)[keep].shape, current),
                force=np.asarray(sol.force)[keep],
                name=f"{current} A",
                rotary=True,
            )
        )
    return truth, runs


@pytest.fixture(scope="module")
def brake():
    return _brake_runs()


def test_packed_and_padded_layouts_give_the_same_residuals(brake):
    truth, runs = brake
    model = eqx.tree_at(lambda m: m.beta, truth, 700.0)  # not at the optimum
    free, static = eqx.partition(model, free_filter(model))
    options = dict(discard=[0.1, 0.0, 0.2], smoothing=[0.0, 0.05, 0.02])
    packed = pack(runs, lanes=1, **options)
    padded = pack(runs, lanes=len(runs), **options)
    assert packed.step.shape[0] == 1 and padded.step.shape[0] == 3
    # Packed: exactly the steps the data need; padded: every lane as long as the
    # longest experiment.
    assert packed.num_steps == packed.data_steps < padded.num_steps
    a = np.asarray(residuals_jit(free, static, packed))
    b = np.asarray(residuals_jit(free, static, padded))
    assert a.shape == b.shape and np.max(np.abs(a)) > 1e-3
    # The same arithmetic in another order of lanes: equal to rounding.
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * np.max(np.abs(a)))


def test_each_experiment_gets_its_own_steps_and_they_meet_the_stated_accuracy(brake):
    truth, runs = brake
    policy = StepPolicy()
    data = pack(runs, policy, lanes=1)
    # A brake: steps of at most 0.5 ms, so the 250 Hz run takes more steps per
    # interval than the 1 kHz one (each experiment its own step).
    for e in runs:
        assert np.all(np.diff(e.t) / policy.counts(e.t, e.v, True) <= 5e-4 * (1 + 1e-9))
    assert np.max(policy.counts(runs[1].t, runs[1].v, True)) == 8
    assert np.max(policy.counts(runs[2].t, runs[2].v, True)) == 2
    # A linear damper: per interval, the travel at the larger end speed is at most
    # 25 µm and the step at most 2.5 ms.
    t = np.linspace(0.0, 2.0, 401)
    v = 2 * np.pi * 0.01 * np.cos(2 * np.pi * t)
    counts = policy.counts(t, v)
    speed = np.maximum(np.abs(v[:-1]), np.abs(v[1:]))
    assert np.all(np.diff(t) / counts * speed <= 2.5e-5 * (1 + 1e-9))
    assert np.all(np.diff(t) / counts <= 2.5e-3 * (1 + 1e-9))
    assert counts.max() == np.ceil(0.005 * 2 * np.pi * 0.01 / 2.5e-5)  # at peak speed
    assert counts.min() == 2  # at rest: the 2.5 ms limit
    assert data.num_steps == data.data_steps
    # Stated accuracy (StepPolicy's docstring): within 1e-4 of the peak torque of
    # the adaptive reference (Dopri8, rtol 1e-8, which generated the data; measured
    # 3.5e-5), far below measurement noise (~1 %).
    predicted = jaxmr.predict_all(truth, runs)
    for p, e in zip(predicted, runs):
        error = np.max(np.abs(p - e.force)) / np.max(np.abs(e.force))
        assert error < 1e-4, (e.name, error)


def test_random_starts_spread_by_the_factor_in_value_space():
    model = jaxmr.BoucWen(
        alpha=jaxmr.Positive(2.0),
        c0=jaxmr.Bounded(0.5, 0.0, 10.0),
        A=jaxmr.Fixed(843.0),
        beta=300.0,
        gamma=0.0,
        n=jaxmr.Positive(1.0),
    )
    free = eqx.filter(model, free_filter(model))
    scale = jax.tree.map(lambda a: jnp.full_like(a, 0.5), free)
    starts = spread_starts(model, 400, 3.0, jax.random.key(1), scale)
    models = [
        jaxmr._parameter.unwrap(
            eqx.combine(
                jax.tree.map(lambda a, k=k: a[k], starts),
                eqx.filter(model, free_filter(model), inverse=True),
            )
        )
        for k in range(400)
    ]
    for field, value in (("alpha", 2.0), ("c0", 0.5), ("beta", 300.0)):
        ratios = np.array([float(getattr(m, field)) for m in models]) / value
        assert ratios[0] == pytest.approx(1.0)  # the first start is the model
        # Log-uniform in [1/3, 3]: both ends reached, nothing beyond (not powers).
        assert 1 / 3 - 1e-9 <= ratios.min() < 1 / 2.7, field
        assert 2.7 < ratios.max() <= 3 + 1e-9, field
        assert abs(np.mean(np.log(ratios))) < 0.15, field
    # A zero value moves by up to ±(spread − 1) × its scale.
    gammas = np.array([float(m.gamma) for m in models])
    assert np.all(np.abs(gammas) <= 2 * 0.5 + 1e-12) and np.std(gammas) > 0.3


def test_a_second_fit_with_a_new_solver_instance_does_not_recompile():
    runs = dahl_runs((5.0,), (3.0,))
    jaxmr.fit(dahl_guess(), runs, solver=jaxmr.FastLevenbergMarquardt(), progress=False)
    compiled = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        result = jaxmr.fit(
            dahl_guess(), runs, solver=jaxmr.FastLevenbergMarquardt(), progress=False
        )
    finally:
        jax.monitoring.clear_event_listeners()
    assert result.converged, result.reason
    assert compiled == []


def test_the_first_trust_region_is_the_solver_s_and_must_be_positive():
    # Radius 1 is the default (benchmarks/trust_region_choice.py); a bolder first
    # step takes another path to the same optimum on this well-posed fit.
    runs = dahl_runs((5.0,), (3.0,), samples=41)
    default, bold = (
        jaxmr.fit(
            dahl_guess(),
            runs,
            solver=jaxmr.FastLevenbergMarquardt(initial_radius=r),
            progress=False,
        )
        for r in (1.0, 1e3)
    )
    assert jaxmr.FastLevenbergMarquardt().initial_radius == 1.0
    assert default.history[1] != bold.history[1]  # the first damped step differs
    # Both stop at the noise floor: within the stopping rule's relative `ftol`
    # (1e-4) of each other's loss.
    assert bold.loss == pytest.approx(default.loss, rel=1e-4)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="initial_radius"):
            jaxmr.FastLevenbergMarquardt(initial_radius=bad)


def test_packing_data_and_building_parameters_compile_nothing():
    # Sample counts no other test uses, so that JAX's in-process cache of eager
    # programs cannot hide a compilation: outside a trace `jnp.asarray` of a NumPy
    # array compiles `lax.stage` once per shape (JAX 0.10), as `pack` did for each of
    # its arrays, and an eager `jnp.log` or comparison once per shape and dtype.
    runs = [
        SimpleNamespace(**{**vars(r), "name": f"odd {k}"})
        for k, r in enumerate(dahl_runs((5.0, 7.0), (3.0, 2.0), samples=97))
    ]
    compiled = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(kwargs.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        data = pack(runs, StepPolicy(substeps=3), lanes=2)
        positive = jaxmr.Positive(np.linspace(1.0, 2.0, 13))
        bounded = jaxmr.Bounded(np.full(11, 0.25), 0.0, 1.0)
        with pytest.raises(ValueError, match="must be > 0"):
            jaxmr.Positive(np.array([1.0, -1.0, 2.0, 3.0, 5.0]))
    finally:
        # This listener only: others (the session's, another test's) stay.
        jax.monitoring.unregister_event_duration_listener(listen)
    assert compiled == []
    # The values are those `jnp` gave (float64 under the tests' x64).
    assert data.t.dtype == jnp.float64 and data.kept.dtype == jnp.int64
    np.testing.assert_allclose(np.exp(positive.log_value), np.linspace(1.0, 2.0, 13))
    assert np.all(np.abs(np.asarray(bounded.raw) - np.log(1 / 3)) < 1e-15)


def test_zero_loss_is_not_convergence_and_bad_data_is_refused():
    truth = jaxmr.Dahl(k_x=0.01, k_w=3.0, rho=5.0)
    (run,) = dahl_runs((5.0,), (3.0,))
    # Data the model reproduces exactly (same steps): a loss of exactly 0.
    exact = SimpleNamespace(**{**vars(run), "force": jaxmr.predict(truth, run)})
    model = jaxmr.Dahl(k_x=0.01, k_w=jaxmr.Fixed(3.0), rho=jaxmr.Fixed(5.0))
    result = jaxmr.fit(model, [exact], progress=False)
    assert result.loss == 0.0
    assert result.stop is jaxmr.StopReason.DEGENERATE
    assert not result.converged and result.reason.startswith("not converged")
    bad = SimpleNamespace(
        **{**vars(run), "force": np.where(run.t > 0.5, np.nan, run.force)}
    )
    with pytest.raises(ValueError, match="column `F` has a non-finite value"):
        jaxmr.fit(model, [bad], progress=False)
    # A force in the wrong unit by 300 decades: its spread overflows, which used to
    # weight it by 0 and report a loss of 0 with standard errors of 0.
    huge = SimpleNamespace(**{**vars(run), "force": 1e300 * np.sign(run.v)})
    with pytest.raises(ValueError, match="spread of its force overflows"):
        jaxmr.fit(model, [huge], progress=False)
    # No more scored samples than free parameters: underdetermined, refused.
    columns = ("t", "x", "v", "current", "force")
    few = SimpleNamespace(
        **{k: np.broadcast_to(getattr(run, k), run.t.shape)[:3] for k in columns}
    )
    few.name = "three samples"
    free = jaxmr.Dahl(k_x=0.01, k_w=3.0, rho=5.0)
    with pytest.raises(ValueError, match="3 scored sample.*3 free parameter"):
        jaxmr.fit(free, [few], progress=False)
    with pytest.raises(ValueError, match="'three samples': 3 scored sample"):
        jaxmr.fit_each(free, [few], progress=False)


def test_poorly_determined_parameters_are_named():
    (run,) = dahl_runs((5.0,), (3.0,))
    # k0 of a Bouc–Wen on a Dahl loop with 1 % noise: a stiffness the data do not
    # ask for, and alpha trades against it.
    P = jaxmr.Positive
    model = jaxmr.BoucWen(
        alpha=P(3.0),
        c0=P(0.002),
        A=jaxmr.Fixed(5.0),
        beta=P(2.5),
        gamma=P(2.5),
        n=jaxmr.Fixed(1.0),
        k0=1e-6,
        x0=jaxmr.Fixed(0.0),
        f0=jaxmr.Fixed(0.0),
    )
    result = jaxmr.fit(model, [run], progress=False, max_steps=40)
    assert any(".k0" in w for w in result.poorly_determined), result.poorly_determined
    assert "poorly determined" in str(result)


# ---------------------------------------------------------------------------------------
# Why a fit stops: each `StopReason` where it names, and the caller's stop flag

# The fit's own Jacobian for the statistics (one compilation less) and no printing.
_QUICK = dict(progress=False, statistics_refinement=1)


class _FailingSolver(jaxmr.FastLevenbergMarquardt):
    """Reports a failed solve (as for a non-finite step) after every step."""

    def terminate(self, fn, y, args, options, state, tags):
        return state.terminate, optx.RESULTS.nonfinite


def test_each_stop_reason_where_it_names():
    runs = dahl_runs((5.0,), (3.0,))
    Stop = jaxmr.StopReason
    # The budget: one step, before LM's test (never on the first step) or a stall.
    budget = jaxmr.fit(dahl_guess(), runs, max_steps=1, **_QUICK)
    assert budget.stop is Stop.MAX_STEPS and budget.num_steps == 1
    assert budget.reason == "reached max_steps = 1" and not budget.converged
    # A stall: every step must lower the loss by 99 %, which none after the first
    # does; `patience` 2 then stops it (LM's own test, 1e-8, is far off).
    stall = jaxmr.fit(dahl_guess(), runs, ftol=0.99, patience=2, **_QUICK)
    assert stall.stop is Stop.STALLED and stall.converged and stall.num_steps < 10
    # LM's test, with tolerances of 10 %: met at the first accepted step after the
    # first (no stall: any improvement counts with ftol 0, and patience is long).
    loose = jaxmr.FastLevenbergMarquardt(rtol=0.1, atol=0.1)
    tolerance = jaxmr.fit(
        dahl_guess(), runs, ftol=0.0, patience=100, solver=loose, **_QUICK
    )
    assert tolerance.stop is Stop.TOLERANCE and tolerance.converged
    assert tolerance.num_steps < 10
    # A failed solve: the failure is reported, the start's parameters kept.
    failed = jaxmr.fit(dahl_guess(), runs, solver=_FailingSolver(), **_QUICK)
    assert failed.stop is Stop.SOLVER_FAILED and failed.num_steps == 1
    assert not failed.converged and failed.reason.startswith("failed")
    # The verdict is the enum's and the identification's, nothing else.
    for result in (budget, stall, tolerance, failed):
        assert result.converged == (result.stop.converged and not result.unidentified)


def _linear(y, static, data, extra):
    """A residual linear in `y["a"]`, minimum at 3."""
    return jnp.array([1.0, 2.0]) * (y["a"] - 3.0)


def _not_finite(y, static, data, extra):
    return jnp.array([1.0, 2.0]) * y["a"] * jnp.nan


def test_a_loss_never_finite_is_reported_as_such():
    """Every evaluated point non-finite: `NONFINITE`, with an infinite loss (the
    solver's initial state used to read as a loss of 0 at the origin)."""
    ys = {"a": jnp.ones((2,))}
    args = (_not_finite, None, None, None)
    solver = jaxmr.FastLevenbergMarquardt()
    _, outcomes = iterate(solver, ys, args, None, 3, 8, 1e-4, lambda k, loss: None)
    assert [o.stop for o in outcomes] == [jaxmr.StopReason.NONFINITE] * 2
    assert all(o.loss == np.inf for o in outcomes)


def _blown_up_beyond_2(bad):
    """`_linear`, whose Jacobian is `bad` (nan, or an overflowing 1e100) where
    a > 2, its residual finite everywhere: a fixed-step simulation past its
    stability limit, whose sensitivities blow up before its state does."""

    @jax.custom_jvp
    def r(a):
        return _linear({"a": a}, None, None, None)

    @r.defjvp
    def r_jvp(primals, tangents):
        (a,), (t,) = primals, tangents
        # `_linear`'s slope, [1, 2] (`bad` beyond a = 2).
        slope = jnp.where(a > 2.0, bad, 1.0) * jnp.array([1.0, 2.0])
        return r(a), slope * t

    return lambda y, static, data, extra: r(y["a"])


@pytest.mark.parametrize("bad", [np.nan, 1e100])
def test_a_point_whose_linearisation_is_not_sound_is_rejected(bad):
    """Accepted, a non-finite Jacobian made the next step nan (the fit "failed"),
    and a blown-up one (JᵀJ ~1e200) froze every other direction under the least
    damping (the fit "converged" there). Rejected, the fit goes on in a smaller
    region and ends at the edge of the sound one (a ≤ 2), not failed."""
    ys = {"a": jnp.ones((1,))}
    args = (_blown_up_beyond_2(bad), None, None, None)
    best, (outcome,) = iterate(
        jaxmr.FastLevenbergMarquardt(),
        ys,
        args,
        None,
        60,
        8,
        1e-4,
        lambda k, loss: None,
    )
    assert outcome.stop in (jaxmr.StopReason.TOLERANCE, jaxmr.StopReason.STALLED)
    a = float(best["a"][0])
    # Within 1 % of the edge: the rejections shrink the region 4x each time.
    assert 1.98 <= a <= 2.0, (a, outcome)


def test_the_stop_flag_stops_between_steps_and_keeps_the_best():
    runs = dahl_runs((5.0,), (3.0,))
    stop = threading.Event()
    losses = []

    def progress(step, loss):  # the caller sets the flag during step 3
        losses.append(loss)
        if step == 3:
            stop.set()

    result = jaxmr.fit(
        dahl_guess(), runs, progress=progress, stop=stop, statistics_refinement=1
    )
    assert result.stop is jaxmr.StopReason.INTERRUPTED and result.interrupted
    assert result.num_steps == 3 and len(losses) == 3 and not result.converged
    assert result.reason == (
        "interrupted at step 3; the best parameters so far are kept"
    )
    # The best parameters so far: those of the lowest loss, below the start's.
    assert result.loss == min(losses) < losses[0]
    refit = jaxmr.fit(result.constrained, runs, max_steps=1, **_QUICK)
    # (rtol: the start goes through the column scaling and back.)
    np.testing.assert_allclose(refit.history[0], result.loss, rtol=1e-12)
    # A flag set before the fit: it stops after the first step (the starts'
    # evaluation), for every member of a batch.
    ys = {"a": jnp.ones((2,))}
    args = (_linear, None, None, None)
    solver = jaxmr.FastLevenbergMarquardt()
    best, outcomes = iterate(
        solver, ys, args, None, 50, 8, 1e-4, lambda k, loss: None, stop=stop
    )
    assert [(o.stop, o.steps) for o in outcomes] == [
        (jaxmr.StopReason.INTERRUPTED, 1)
    ] * 2
    np.testing.assert_array_equal(best["a"], [1.0, 1.0])


def test_fit_uses_each_experiments_own_smoothing_and_discard():
    (run,) = dahl_runs((5.0,), (3.0,))
    columns = (run.t, run.x, run.v, run.current, run.force)
    processed = jaxmr.data.Experiment(*columns, smoothing=0.05, discard=0.2)
    plain = jaxmr.data.Experiment(*columns)
    options = dict(max_steps=3, **_QUICK)
    own = jaxmr.fit(dahl_guess(), [processed], **options)
    given = jaxmr.fit(dahl_guess(), [plain], smoothing=0.05, discard=0.2, **options)
    # The same computation: the same bits.
    assert own.loss == given.loss and np.array_equal(own.values, given.values)
    # An explicit argument overrides the experiment's own.
    raw = jaxmr.fit(dahl_guess(), [processed], smoothing=0.0, discard=0.0, **options)
    unprocessed = jaxmr.fit(dahl_guess(), [plain], **options)
    assert raw.loss == unprocessed.loss != own.loss
    # So do the scores.
    model = own.model
    np.testing.assert_array_equal(
        jaxmr.record_nrmse(model, [processed]),
        jaxmr.record_nrmse(model, [plain], smoothing=0.05, discard=0.2),
    )


def _joined_record():
    """Two runs of one 3 Hz ±5 mm test at 1 kHz joined at 0.5 s, the second from a
    quarter cycle on: a 1.7 mm step in x where they meet, v continuous (issue 27)."""
    t = np.arange(0.0, 1.0, 1e-3)
    w = 2 * np.pi * 3.0
    x, v = 5e-3 * np.sin(w * t), 5e-3 * w * np.cos(w * t)
    x[t >= 0.5] += 1.7e-3
    return SimpleNamespace(t=t, x=x, v=v, current=np.zeros_like(t), name="joined")


def test_steps_follow_the_interpolated_motion_and_a_diverged_state_is_nan():
    """The travel limit holds along the Hermite interpolant actually simulated (its
    peak slope across the step is 1.5 × 1.7 mm / 1 ms, 27 × the velocity column's
    peak), so the Dahl state stays within |z| <= 1; a step count too small for the
    step gives NaN from the step on, never a finite absurd force."""
    e = _joined_record()
    policy = StepPolicy()
    k = int(np.argmax(e.t >= 0.5)) - 1  # the interval with the step
    from_v = policy.counts(e.t, e.v)
    counts = policy.counts(e.t, e.v, False, e.x)
    # At least 1.5 · 1.7 mm / 25 µm steps there (the interpolant's midpoint slope,
    # less the velocities' small contribution); elsewhere as from v (rounding aside).
    assert from_v[k] == 4 and counts[k] >= 0.95 * 1.5 * 1.7e-3 / 2.5e-5
    assert np.sum(counts != from_v) <= 3
    dahl = jaxmr.Dahl(k_x=500.0, k_w=800.0, rho=2e4)
    (predicted,) = jaxmr.predict_all(dahl, [e])
    # |F| <= k_x |v| + k_w |z| with |z| <= 1 (1 % slack: RK4's own overshoot).
    reach = 500.0 * np.max(np.abs(e.v)) + 800.0 * 1.01
    assert np.all(np.isfinite(predicted)) and np.max(np.abs(predicted)) <= reach
    # One step per interval: the state leaves its bound at the step (it gave forces
    # of 2.6e10 N before the guard).
    (coarse,) = jaxmr.predict_all(
        dahl, [e], integrator=StepPolicy(substeps=1), refine_diverged=False
    )
    bad = ~np.isfinite(coarse)
    assert np.all(np.isfinite(coarse[: k + 1])) and np.all(bad[k + 2 :])
    assert np.max(np.abs(coarse[: k + 1])) <= reach


def test_a_diverged_prediction_is_run_again_with_shorter_steps():
    """A Dahl state that relaxes within 1 µm (rho = 1e6 1/m) overshoots |z| <= 1 with
    the default 25 µm steps; `predict_all` runs that experiment again with 4, then
    16 times shorter steps (1.6 µm: rho·h = 1.6, inside RK4's stability limit of
    2.8), says so once, naming it, and leaves the experiment that did not diverge
    (a damper at rest) as its first run gave it. The band's centre takes the same
    steps."""
    t = np.arange(0.0, 0.4, 1e-3)
    w = 2 * np.pi * 3.0
    sine = SimpleNamespace(
        t=t,
        x=5e-3 * np.sin(w * t),
        v=5e-3 * w * np.cos(w * t),
        current=np.zeros_like(t),
        name="sine",
    )
    still = SimpleNamespace(t=t, x=0 * t, v=0 * t, current=0 * t, name="still")
    dahl = jaxmr.Dahl(k_x=500.0, k_w=800.0, rho=1e6)
    raw = jaxmr.predict_all(dahl, [sine, still], refine_diverged=False)
    assert not np.all(np.isfinite(raw[0])) and np.all(np.isfinite(raw[1]))
    with pytest.warns(jaxmr.StepsRefined) as caught:
        refined = jaxmr.predict_all(dahl, [sine, still])
    assert len(caught) == 1 and "'sine' (16x)" in str(caught[0].message)
    assert caught[0].filename == __file__  # the caller's line, not jaxmr's
    assert "still" not in str(caught[0].message)
    (finer,) = jaxmr.predict_all(dahl, [sine], integrator=StepPolicy(refinement=16))
    # The same program on the same steps: equal to the last bit.
    np.testing.assert_array_equal(refined[0], finer)
    np.testing.assert_array_equal(refined[1], raw[1])
    # |F| <= k_x |v| + k_w |z|, |z| <= 1 (1 % slack: RK4's own overshoot).
    assert np.max(np.abs(finer)) <= 500.0 * np.max(np.abs(sine.v)) + 800.0 * 1.01
    with pytest.warns(jaxmr.StepsRefined):
        bands = jaxmr.prediction_band_from_covariance(
            dahl, [".k_w"], [[25.0]], [sine, still]
        )
    # The band's centre is the forward-mode pass's force, the prediction's to
    # rounding (1e-9 of the peak force).
    np.testing.assert_allclose(bands[0].force, finer, rtol=0, atol=1e-9 * 1e3)
    # d F / d k_w = z: the band's half-width is 1.96 · 5 · |z|, at most 9.9 N.
    assert np.all(np.isfinite(bands[0].std)) and np.max(bands[0].std) <= 5 * 1.01
    assert np.max(bands[0].std) >= 4.9


def test_a_state_relaxing_to_a_bound_that_shrank_with_the_input_is_no_divergence():
    """LuGre's bound max(F_c, F_s)/σ0 shrinks when the current falls: the state
    saturated at 1 A is then 8x over the 0 A bound and relaxes to it within a few
    samples, which is no divergence (every LuGre fit on the NEES record read as
    diverged). Guarded prediction and `simulate` judge against the widest bound so
    far; a solve that does diverge is still caught (the test above)."""
    t = np.arange(0.0, 1.0, 1e-3)
    w = 2 * np.pi * 3.0
    x, v = 5e-3 * np.sin(w * t), 5e-3 * w * np.cos(w * t)
    current = np.where(t < 0.4, 1.0, 0.0)  # falls while the damper moves
    lugre = jaxmr.LuGre(
        sigma0=1e6,
        sigma1=0.0,
        sigma2=jaxmr.LinearLaw(50.0, 0.0),
        F_c=jaxmr.LinearLaw(100.0, 900.0),
        F_s=jaxmr.LinearLaw(120.0, 1080.0),
        v_s=0.01,
    )
    run = SimpleNamespace(t=t, x=x, v=v, current=current, name="falling")
    (force,) = jaxmr.predict_all(lugre, [run])
    assert np.all(np.isfinite(force))
    # The state really was outside the present bound after the fall: |F| beyond
    # what the 0 A law allows (F_s + σ2 |v|) just after it.
    after = (t > 0.4) & (t < 0.41)
    assert np.max(np.abs(force[after])) > 2 * (120.0 + 50.0 * np.max(np.abs(v)))
    solution = jaxmr.simulate(
        lugre,
        jaxmr.Sampled(jnp.asarray(t), jnp.asarray(x)),
        jaxmr.Sampled(jnp.asarray(t), jnp.asarray(current)),
        jnp.asarray(t),
        integrator=jaxmr.FixedStep(4),
        throw=False,
    )
    assert solution.result == jaxmr.RESULTS.successful, solution.result


def _counted(monkeypatch, module, name: str) -> list:
    """`module.name` replaced by a wrapper that calls it and appends to the list
    returned (one entry per call)."""
    calls, function = [], getattr(module, name)

    def counting(*args, **kwargs):
        calls.append(1)
        return function(*args, **kwargs)

    monkeypatch.setattr(module, name, counting)
    return calls


def test_a_fit_runs_the_model_s_python_once_per_data_shape(monkeypatch):
    # The residual is a jitted call inside the fit's programs (`traced_once`): the
    # model's Python runs once for the fit's (guarded) residual, once for the
    # guarded simulation that checks the start and scores the report, and once for
    # the statistics' finer steps (`statistics_refinement`); the solver's `_init`,
    # its step's trial point and Jacobian reuse the first trace. Each of them ran it
    # anew (4 runs for the residual alone), about a sixth of a second fit's tracing
    # on the UTFSM files (1.09 s, now 0.90 s). Without refinement the statistics'
    # data are the fit's and they reuse its trace: 2 runs in all (3 when the scaled
    # residual did not go through the unscaled one's trace, or the statistics
    # through the fit's residual).
    import jaxmr._identify.residual as residual_module

    calls = _counted(monkeypatch, residual_module, "_simulated")
    # Runs of a length no other test fits: a shape never traced in this process.
    runs = dahl_runs((3.0, 5.0), (1.0, 2.0), samples=87)
    result = jaxmr.fit(dahl_guess(), runs, max_steps=3, progress=False)
    assert result.num_steps >= 2  # the step ran more than once
    assert len(calls) == 3, len(calls)
    calls.clear()
    runs = dahl_runs((3.0, 5.0), (1.0, 2.0), samples=89)
    jaxmr.fit(dahl_guess(), runs, max_steps=3, progress=False, statistics_refinement=1)
    assert len(calls) == 2, len(calls)


def test_one_start_evaluates_its_first_step_once(monkeypatch):
    """The column scale comes from the solver's first step at the start with unit
    scale; that step, carried into the scaled variables (JᵀJ → D JᵀJ D, Jᵀr → D Jᵀr,
    the damped step solved anew), is the fit's first: `max_steps` steps make
    `max_steps` calls of the compiled step, not one more (a residual and a Jacobian
    at the start each fit had evaluated twice). The path is the one the start gets
    stepped from scratch in the scaled variables (`starts=[model]`, whose first step
    `iterate` makes itself): the same losses and parameters to rounding (1e-9
    relative: D JᵀJ D against (JD)ᵀ(JD), and what follows from it)."""
    import jaxmr._identify.solver as solver_module

    calls = _counted(monkeypatch, solver_module, "_step")
    runs = dahl_runs((3.0, 5.0), (1.0, 2.0))
    carried = jaxmr.fit(dahl_guess(), runs, max_steps=6, ftol=0.0, **_QUICK)
    assert carried.num_steps == 6 and len(calls) == 6, (carried.num_steps, len(calls))
    calls.clear()
    anew = jaxmr.fit(
        dahl_guess(), runs, starts=[dahl_guess()], max_steps=6, ftol=0.0, **_QUICK
    )
    assert len(calls) == 7  # the column scale's step, then iterate's six
    np.testing.assert_allclose(carried.history, anew.history, rtol=1e-9)
    np.testing.assert_allclose(carried.values, anew.values, rtol=1e-9)


def test_the_carried_first_step_compiles_nothing(monkeypatch):
    """The first step's move into the scaled variables (p numbers and a p × p
    eigendecomposition) is made on the host: as a jitted program it compiled for
    0.1 s of every cold one-start fit. A fresh shape (97 samples, three parameters:
    no program of another test can serve it) and a listener on XLA's compilations
    while it runs; the path it starts is checked against stepping anew in
    `test_one_start_evaluates_its_first_step_once`."""
    import jaxmr._identify.solver as solver_module

    compiled, calls = [], []
    carry = solver_module._rescaled_first_step

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(kwargs.get("fun_name"))

    def watched(*args, **kwargs):
        calls.append(1)
        jax.monitoring.register_event_duration_secs_listener(listen)
        try:
            return carry(*args, **kwargs)
        finally:
            jax.monitoring.unregister_event_duration_listener(listen)

    monkeypatch.setattr(solver_module, "_rescaled_first_step", watched)
    runs = dahl_runs((4.0, 6.0), (1.5, 2.5), samples=97)
    result = jaxmr.fit(dahl_guess(), runs, max_steps=3, **_QUICK)
    assert len(calls) == 1 and result.num_steps == 3
    assert compiled == [], compiled


def test_a_step_evaluates_its_trial_point_once():
    """`FastLevenbergMarquardt` takes a trial point's residual as the primal of its
    forward-mode Jacobian: one evaluation of the residual per step, whether the step
    is accepted or not. (Evaluating the residual first and the Jacobian only where
    the step was accepted simulated every accepted point twice: 12 evaluations for
    these 8 steps.) Counted by a host callback in the residual, which runs each time
    the compiled step evaluates it; Rosenbrock's residual from its classic start, so
    that steps are both accepted and rejected."""
    from jaxmr._identify.solver import FastLevenbergMarquardt

    calls = []

    def residuals_fn(free, static, data, extra):
        jax.debug.callback(lambda: calls.append(1))
        x = free["x"]
        return jnp.stack([x[0] - 1.0, 10.0 * (x[1] - x[0] ** 2)])

    ys = {"x": jnp.array([[-1.2, 1.0]])}
    losses = []
    _, (outcome,) = iterate(
        FastLevenbergMarquardt(),
        ys,
        (residuals_fn, None, None, None),
        None,
        max_steps=8,
        patience=100,
        ftol=0.0,
        report=lambda step, loss: losses.append(loss),
    )
    assert outcome.steps == 8
    # Some steps were rejected (the best loss stayed), and some accepted.
    assert len(set(losses)) < len(losses) and len(set(losses)) > 2, losses
    assert len(calls) == 8, len(calls)


def test_an_experiment_shorter_than_the_parameters_is_named():
    # Each experiment's normalised error counts equally: a 3-sample cut beside a
    # whole test would weigh like one. `fit` (and each problem of `fit_each`)
    # names it instead of fitting.
    from .helpers import dahl_guess, dahl_runs

    whole, other = dahl_runs((4.0, 5.0), (3.0, 3.0))
    cut = SimpleNamespace(**vars(other))
    for name in ("t", "x", "v", "current", "force"):
        setattr(cut, name, getattr(other, name)[:3])
    cut.name = "cut"
    with pytest.raises(
        ValueError, match=r"no more samples than the 3 free .*'cut' \(3\)"
    ):
        jaxmr.fit(dahl_guess(), [whole, cut], progress=False)


def _exp_residual(y, static, data, extra):
    """exp(a) - target per member (`data`, batched): from a = 0 to 1 in a step or
    two; from a = -30 to 1e6 a long climb."""
    return jnp.stack([jnp.exp(y["a"]) - data, 0.0 * y["a"]])


def test_an_interrupt_leaves_the_problems_that_had_stopped_their_verdicts():
    """Independent problems (`fit_each`'s batch): stopped while one still runs, the
    one that had converged keeps its verdict and steps; only the running one is
    interrupted (every problem was "interrupted" before, its real outcome lost)."""
    stop = threading.Event()

    def progress(k, loss):
        if k == 6:
            stop.set()

    _, outcomes = iterate(
        jaxmr.FastLevenbergMarquardt(),
        {"a": jnp.array([0.0, -30.0])},
        (_exp_residual, None, jnp.array([1.0, 1e6]), None),
        0,  # the data batched along their first axis: independent problems
        200,
        8,
        1e-4,
        progress,
        stop=stop,
    )
    assert outcomes[0].stop is jaxmr.StopReason.TOLERANCE and outcomes[0].steps < 6
    assert (outcomes[1].stop, outcomes[1].steps) == (jaxmr.StopReason.INTERRUPTED, 6)


def test_a_ctrl_c_while_a_finished_fit_reports_does_not_lose_it(monkeypatch, capsys):
    """A Ctrl-C (SIGINT) while `fit` and `fit_each` compute their reports after the
    loop: said, set aside, and the results returned (it raised out of the fit and
    every finished fit was lost); a second one interrupts as usual."""
    import os
    import signal

    from jaxmr._identify import fitting

    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    runs = dahl_runs((5.0,), (3.0,))
    report, pad_all = fitting._report, fitting.pad_all

    def interrupted(function, times):
        def wrapper(*args, **kwargs):
            for _ in range(times):
                os.kill(os.getpid(), signal.SIGINT)
            return function(*args, **kwargs)

        return wrapper

    options = dict(max_steps=3, **_QUICK)
    monkeypatch.setattr(fitting, "_report", interrupted(report, 1))
    result = jaxmr.fit(dahl_guess(), runs, **options)
    assert result.num_steps == 3 and np.all(np.isfinite(result.std_errors))
    assert (
        "jaxmr.fit: Ctrl-C while the fitted model's errors" in capsys.readouterr().err
    )
    # `fit_each`'s report starts by padding the problems.
    monkeypatch.setattr(fitting, "pad_all", interrupted(pad_all, 1))
    (each,) = jaxmr.fit_each(dahl_guess(), runs, **options)
    assert each.num_steps == 3 and "jaxmr.fit_each: Ctrl-C" in capsys.readouterr().err
    monkeypatch.setattr(fitting, "_report", interrupted(report, 2))
    with pytest.raises(KeyboardInterrupt):
        jaxmr.fit(dahl_guess(), runs, **options)
    # Python's own handler is back.
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
