"""`fit_system`: a whole system (mass, springs, its Bouc–Wen damper) identified from
its simulated noisy response, the identifiability report, and the argument errors."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
from jaxmr._identify.system import (
    SystemRecord,
    _simulate_records,
    _Simulation,
    _stack_records,
    _system_residuals,
    fit_system,
)
from jaxmr._parameter import free_filter, unwrap
from jaxmr._systems.oscillator import (
    band_limited_input,
    hysteretic_benchmark_oscillator,
)

FS = 750.0
SUBSTEPS = 8  # 6 kHz RK4; the data are made by the same integrator, so its error
# does not enter the recovery
NOISE = 0.02  # of the response's std


def _multisine(n, seed):
    """A 50 N rms random-phase multisine, 5–100 Hz, periodic over n samples."""
    rng = np.random.default_rng(seed)
    lines = np.arange(4, 80)  # bins of FS/n = 1.25 Hz at n = 600
    t = np.arange(n) / FS
    u = sum(
        np.sin(2 * np.pi * k * FS / n * t + rng.uniform(0, 2 * np.pi)) for k in lines
    )
    return band_limited_input(50 * u / np.std(u), FS, 2 * SUBSTEPS, periodic=True)


def _simulate(system, excitation, n, initial_state=None):
    solution = jaxmr.simulate_system(
        system,
        excitation,
        0.0,
        n / FS,
        sampling=jaxmr.Sampling(dt=1 / FS),
        integrator=jaxmr.FixedStep(SUBSTEPS),
        initial_state=initial_state,
    )
    return np.asarray(solution.outputs["body_position"])


@pytest.fixture(scope="module")
def records():
    """Two records of different lengths and kinds: 0.8 s of forced response, and
    0.5 s of free decay from a displaced start (a constant zero excitation)."""
    truth = hysteretic_benchmark_oscillator()
    rng = np.random.default_rng(1)
    forced = _multisine(600, seed=0)
    y1 = _simulate(truth, forced, 600)
    q0 = jnp.array([2e-3, 0.0])
    y2 = _simulate(truth, 0.0, 375, initial_state=q0)
    out = []
    for name, y, excitation, state in (
        ("forced", y1, forced, None),
        ("free decay", y2, 0.0, q0),
    ):
        noisy = y + NOISE * np.std(y) * rng.standard_normal(y.shape)
        ts = np.arange(y.size) / FS
        out.append(SystemRecord(ts, noisy, excitation, state, name=name))
    return out


def _benchmark_start(**values):
    """The benchmark oscillator with only the named parameters free, at `values`."""
    paths = {
        "A": lambda s: s.damper.hysteresis.A,
        "beta": lambda s: s.damper.hysteresis.beta,
        "gamma": lambda s: s.damper.hysteresis.gamma,
        "c0": lambda s: s.damper.hysteresis.c0,
        "damping": lambda s: s.damping,
        "stiffness": lambda s: s.stiffness,
    }
    system = hysteretic_benchmark_oscillator()
    system = eqx.tree_at(
        lambda s: [paths[k](s) for k in values],
        system,
        [jnp.asarray(v, dtype=float) for v in values.values()],
    )
    return jaxmr.fit_only(system, lambda s: [paths[k](s) for k in values])


def test_three_damper_parameters_recovered_from_the_response(records):
    # A and the shape parameters βγ, βδ of the benchmark oscillator, 2–3x off, from
    # 2 % noise on two records of different lengths (padded and masked).
    start = _benchmark_start(A=2e4, beta=-500.0, gamma=2000.0)
    start = eqx.tree_at(
        lambda s: (s.damper.hysteresis.A, s.damper.hysteresis.gamma),
        start,
        (jaxmr.Positive(2e4), jaxmr.Positive(2000.0)),
    )
    result = fit_system(
        start, records, substeps=SUBSTEPS, discard=[0.05, 0.0], progress=False
    )
    assert result.converged, result.reason
    assert not result.unidentified
    assert result.experiment_names == ("forced", "free decay")
    assert result.names == (
        ".damper.hysteresis.A",
        ".damper.hysteresis.beta",
        ".damper.hysteresis.gamma",
    )
    true = np.array([5e4, -1100.0, 800.0])
    # Tolerance: 1 % of each value, several times the standard errors (0.04–0.15 %,
    # measured) that 2 % noise on ~1000 samples leaves; and within 4 of them.
    np.testing.assert_allclose(result.values, true, rtol=1e-2)
    assert np.all(np.abs(result.values - true) < 4 * result.std_errors)
    # At the noise floor in both records.
    np.testing.assert_allclose(result.nrmse, NOISE, rtol=0.2)
    # The fitted system is a plain model, ready to simulate.
    assert isinstance(result.model.damper.hysteresis.A, jnp.ndarray)


def test_a_correlated_but_determined_group_raises_no_warning(records):
    """Mass, stiffness, A, beta and gamma of the benchmark oscillator share one
    near-null direction of their correlation matrix (eigenvalue ~0.009, below the
    0.01 that names a redundant group), yet each is known to ~0.15 % from these
    records: a determined fit, so no warning (the group would be named if any of
    them were uncertain beyond 10 %). From the truth, a few steps: the statistics at
    the optimum are what is tested, not the search."""
    truth = hysteretic_benchmark_oscillator()
    start = jaxmr.fit_only(
        truth,
        lambda s: [s.mass, s.stiffness, s.damper.hysteresis.A,
                   s.damper.hysteresis.beta, s.damper.hysteresis.gamma],
    )  # fmt: skip
    result = fit_system(
        start, records, substeps=SUBSTEPS, discard=[0.05, 0.0], max_steps=5,
        progress=False,
    )  # fmt: skip
    correlation = np.asarray(result.correlation)
    assert np.min(np.linalg.eigvalsh(correlation)) < 0.01  # a group by correlation
    assert np.all(result.std_errors / np.abs(result.values) < 0.01), result.table()
    assert result.poorly_determined == (), result.poorly_determined
    assert "WARNING" not in str(result)


def test_a_redundant_dashpot_is_flagged(records):
    # The oscillator's dashpot and the damper's c0 only act as their sum (comparable
    # values: the report is in relative terms, and a tiny c0 would hide the other).
    start = _benchmark_start(damping=5.0, c0=5.0, stiffness=5e4)
    result = fit_system(
        start, records[:1], substeps=SUBSTEPS, max_steps=2, progress=False
    )
    assert len(result.unidentified) == 1
    message = result.unidentified[0]
    assert "damping" in message and "c0" in message and "stiffness" not in message
    assert not result.converged


def test_a_fit_compiles_its_step_once(records):
    """The column scale comes from the solver's first step, whose compiled program
    the fit then reuses: one compilation of the step per `fit_system` call (its
    residual closes over new functions, so each call compiles afresh). Given other
    arguments there than in the loop, the step compiled twice (the Bouc–Wen
    benchmark: 1.4 s of its 3.6 s)."""
    compiled = []

    def listen(event, duration, fun_name="", **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(fun_name)

    start = _benchmark_start(damping=5.0, stiffness=5e4)
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        fit_system(start, records[:1], substeps=SUBSTEPS, max_steps=2, progress=False)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert compiled.count("jit(_step)") == 1, compiled


def test_an_invalid_start_is_refused_with_the_rule_it_breaks(records):
    # The start stands in for every invalid trial point, so it must be valid itself.
    start = _benchmark_start(gamma=-5.0)
    with pytest.raises(ValueError, match=r"start is not a valid .*`gamma` must be"):
        fit_system(start, records[:1], substeps=SUBSTEPS, progress=False)


def test_a_step_out_of_the_valid_region_is_a_large_residual_not_an_error(records):
    start = _benchmark_start(gamma=800.0)
    free, static = eqx.partition(start, free_filter(start))
    data = _stack_records(records[:1], start, None, None)
    sim = _Simulation(jaxmr.ConstantCurrent(0.0), unwrap(start), "body_position",
                      SUBSTEPS, 1)  # fmt: skip
    # gamma < 0: simulate_system's own check would raise inside the fit.
    invalid = jax.tree.map(lambda a: jnp.full_like(a, -1.0), free)
    r = np.asarray(eqx.filter_jit(_system_residuals)(invalid, static, data, sim))
    assert np.all(r == 1e6)
    r = np.asarray(eqx.filter_jit(_system_residuals)(free, static, data, sim))
    assert np.all(np.abs(r) < 1)


def test_a_finer_dt_compares_every_stride_th_sample(records):
    truth = hysteretic_benchmark_oscillator()

    def simulated(dt, substeps):
        data = _stack_records(records, truth, dt, None)
        sim = _Simulation(jaxmr.ConstantCurrent(0.0), truth, "body_position",
                          substeps, 1)  # fmt: skip
        return np.asarray(_simulate_records(truth, data, sim)[0]), data

    coarse, _ = simulated(None, SUBSTEPS)
    fine, data = simulated(1 / (2 * FS), SUBSTEPS // 2)
    assert data.strides == (2, 2)
    # The same RK4 steps (1/6000 s), so the same response to rounding.
    np.testing.assert_allclose(fine, coarse, rtol=0, atol=1e-12)


def _record(**overrides):
    fields = dict(ts=np.arange(10) / FS, measured=np.linspace(0, 1, 10), name="r")
    fields.update(overrides)
    return SystemRecord(**fields)


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"measured": np.ones(9)}, "equal length"),
        ({"measured": np.r_[np.zeros(4), np.nan, np.zeros(5)]}, "index 4"),
        ({"ts": np.r_[0.0, np.cumsum(np.linspace(1, 2, 9)) / FS]}, "uniformly spaced"),
        ({"ts": 1.0 + np.arange(10) / FS}, "start at 0"),
    ],
)
def test_record_errors(overrides, match):
    with pytest.raises(ValueError, match=match):
        _record(**overrides)


def test_fit_system_errors():
    system = _benchmark_start(gamma=800.0)
    record = _record()
    with pytest.raises(ValueError, match="body_acceleration, body_position"):
        fit_system(system, record, output="position")
    with pytest.raises(ValueError, match="divide the sample time"):
        fit_system(system, record, dt=0.7 / FS)
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        fit_system(system, _record(initial_state=np.zeros(3)))
    with pytest.raises(ValueError, match="one per record"):
        fit_system(system, [record, record], discard=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="leaves no sample"):
        fit_system(system, record, discard=1.0)
    with pytest.raises(ValueError, match="empty"):
        fit_system(system, [])
    with pytest.raises(ValueError, match="nothing to fit"):
        fit_system(jax.tree.map(jaxmr.Fixed, unwrap(system)), record)
    # A record of fewer samples than free parameters would weigh like a whole one
    # (each record's normalised error counts equally): named, not fitted.
    two = _benchmark_start(gamma=800.0, beta=-500.0, A=2e4)
    short = _record(ts=np.arange(3) / FS, measured=np.arange(3.0), name="cut")
    with pytest.raises(
        ValueError, match=r"no more samples than the 3 free .*'cut' \(3\)"
    ):
        fit_system(two, [_record(), short])
