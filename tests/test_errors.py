"""Bad input gets a clear error naming the argument and the fix; solver failure comes
back as a result code (`throw=False`) or a readable exception (`throw=True`).

Errors about values that are known before the simulation (concrete arrays) are raised
at once as `ValueError`/`TypeError`. Values only known under `jit` are checked inside
the compiled simulation with `equinox.error_if`, which raises
`equinox.EquinoxRuntimeError` (a `RuntimeError`) from `eqx.filter_jit`; from a caller's
`jax.jit` it arrives as `jax.errors.JaxRuntimeError` (also a `RuntimeError`) whose text
contains the same message.

The test suite runs with jaxtyping + beartype checking jaxmr's signatures, which rejects
a wrong type (or a 2-D `ts`) before jaxmr's own check does. Both name the argument:
beartype as "parameter 'motion'", jaxmr as "`motion`". Those tests accept either.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.data
import jaxmr.metrics
import jaxmr.scores

MOTION = jaxmr.Sine(0.01, 2.0)  # 10 mm, 2 Hz: peak velocity 0.126 m/s
TS = jnp.linspace(0.0, 0.5, 11)
# One RK4 step per 50 ms output interval: cheap to compile, and stable for the
# moderate Bouc-Wen below (h * |df/dz| ~ 0.1).
FIXED = jaxmr.FixedStep(substeps=1)


def bouc_wen(**changes):
    parameters = dict(alpha=100.0, c0=10.0, A=1.0, beta=50.0, gamma=50.0, n=2.0)
    parameters.update(changes)
    return jaxmr.BoucWen(**parameters)


def names(argument: str) -> str:
    """Regex for a message naming `argument` the way jaxmr (`x`) or beartype ('x') do."""
    return rf"[`']{argument}[`']"


@eqx.filter_jit
def traced_force(model, motion, current, ts):
    """A caller's jitted function: every array in its arguments is traced."""
    return jaxmr.simulate(model, motion, current, ts, integrator=FIXED).force


# ---------------------------------------------------------------------------------------
# Output times


@pytest.mark.parametrize(
    "ts, match",
    [
        (
            jnp.array([0.0, 0.1, 0.1, 0.2]),
            r"`ts` must be strictly increasing, but ts\[1\] = 0.1 >= ts\[2\] = 0.1",
        ),
        (jnp.array([0.0, 0.2, 0.1]), r"`ts` must be strictly increasing.*sort"),
        (jnp.array([0.0, jnp.nan, 0.2]), r"`ts` contains NaN or inf \(ts\[1\]"),
        (jnp.array([0.0, 0.1, jnp.inf]), r"`ts` contains NaN or inf"),
        (jnp.array([0.0]), r"`ts` must be a 1-D array of at least two output times"),
    ],
    ids=["repeated", "decreasing", "nan", "inf", "one-element"],
)
def test_bad_ts(ts, match):
    with pytest.raises(ValueError, match=match):
        jaxmr.simulate(bouc_wen(), MOTION, 0.0, ts)


def test_two_dimensional_ts():
    with pytest.raises((TypeError, ValueError), match=names("ts")):
        jaxmr.simulate(bouc_wen(), MOTION, 0.0, jnp.zeros((2, 3)))


def test_missing_ts():
    with pytest.raises(ValueError, match=r"`ts` is required"):
        jaxmr.simulate(bouc_wen(), MOTION, 0.0)


def test_bad_ts_in_sweep():
    with pytest.raises(ValueError, match=r"`ts` must be strictly increasing"):
        jaxmr.sweep(bouc_wen(), MOTION, [0.0, 1.0], jnp.array([0.0, 0.2, 0.1]))


def test_ts_closed_over_in_callers_jit_is_checked_before_tracing():
    # Inside a caller's jit, `ts` closed over is a concrete array: its check must not
    # trip over jnp producing tracers (it uses numpy).
    bad = jnp.array([0.0, 0.2, 0.1])
    with pytest.raises(ValueError, match=r"`ts` must be strictly increasing"):
        jax.jit(lambda: jaxmr.simulate(bouc_wen(), MOTION, 0.0, bad).force)()


def test_non_increasing_ts_under_jit():
    bad = TS.at[6].set(TS[4])  # same shape as TS: reuses traced_force's compilation
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"`ts` must be strictly incr"):
        traced_force(bouc_wen(), MOTION, jaxmr.Constant(0.0), bad)


def test_nan_ts_under_jit():
    bad = TS.at[3].set(jnp.nan)
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"`ts` contains NaN or inf"):
        traced_force(bouc_wen(), MOTION, jaxmr.Constant(0.0), bad)


# ---------------------------------------------------------------------------------------
# NaN or inf in the inputs


def test_nan_in_sampled_values_at_construction():
    with pytest.raises(ValueError, match=r"Sampled: `values` contain NaN or inf"):
        jaxmr.Sampled(jnp.arange(3.0), jnp.array([0.0, jnp.nan, 1.0]))


def test_nan_in_sampled_times_at_construction():
    # Not reported as "not increasing", which would send the user the wrong way.
    with pytest.raises(ValueError, match=r"Sampled: `times` contain NaN or inf"):
        jaxmr.Sampled(jnp.array([0.0, jnp.nan, 1.0]), jnp.arange(3.0))


def test_inf_in_sampled_derivatives_at_construction():
    with pytest.raises(ValueError, match=r"Sampled: `derivatives` contain NaN or inf"):
        jaxmr.Sampled(jnp.arange(3.0), jnp.arange(3.0), jnp.array([1.0, jnp.inf, 1.0]))


def test_nan_in_steps_at_construction():
    with pytest.raises(ValueError, match=r"Steps: `times` and `values` must be finite"):
        jaxmr.Steps(jnp.array([0.0, 0.1]), jnp.array([0.0, jnp.nan]))


def _sampled_with_nan():
    """A Sampled signal whose NaN slipped past construction (as traced values do)."""
    good = jaxmr.Sampled(TS, 0.01 * jnp.sin(4 * jnp.pi * TS))
    return eqx.tree_at(lambda s: s.values, good, good.values.at[4].set(jnp.nan))


@pytest.mark.parametrize("argument", ["motion", "current"])
def test_nan_in_sampled_signal_under_jit(argument):
    good = jaxmr.Sampled(TS, 0.01 * jnp.sin(4 * jnp.pi * TS))
    signals = {"motion": good, "current": good, argument: _sampled_with_nan()}
    with pytest.raises(
        eqx.EquinoxRuntimeError,
        match=rf"`{argument}`: Sampled: its data contain NaN or inf; give finite",
    ):
        traced_force(bouc_wen(), signals["motion"], signals["current"], TS)


def test_nan_constant_current():
    # Refused when built from a number; built under jit from a traced NaN, the
    # simulation's runtime check names it.
    with pytest.raises(ValueError, match=r"Constant: `value` must be finite"):
        jaxmr.Constant(jnp.nan)
    with pytest.raises(
        eqx.EquinoxRuntimeError, match=r"`current`: Constant: its data contain NaN"
    ):
        eqx.filter_jit(
            lambda c: (
                jaxmr.simulate(
                    bouc_wen(), MOTION, jaxmr.Constant(c), TS, integrator=FIXED
                ).force
            )
        )(jnp.asarray(jnp.nan))


# ---------------------------------------------------------------------------------------
# Wrong shapes


@pytest.mark.parametrize(
    "make, match",
    [
        (
            lambda: jaxmr.Sampled(jnp.arange(3.0), jnp.arange(4.0)),
            r"Sampled: `times` and `values` must be 1-D arrays of equal length, got "
            r"shapes \(3,\) and \(4,\)",
        ),
        (
            lambda: jaxmr.Sampled(jnp.arange(3.0), jnp.arange(3.0), jnp.zeros(2)),
            r"Sampled: `derivatives` must have the shape of `times`",
        ),
        (
            lambda: jaxmr.Sampled(jnp.zeros(1), jnp.zeros(1)),
            r"Sampled: give at least two samples",
        ),
        (
            lambda: jaxmr.Steps(jnp.arange(3.0), jnp.arange(4.0)),
            r"Steps: `times` and `values` must be 1-D arrays of equal length",
        ),
        (
            lambda: jaxmr.Multisine(jnp.ones(3), jnp.ones(2)),
            r"Multisine: `amplitudes`, `frequencies` \(and `phases`\) must be 1-D "
            r"arrays of equal length",
        ),
        (
            lambda: jaxmr.Multisine(jnp.ones(2), jnp.ones(2), jnp.zeros(3)),
            r"Multisine: .*`phases`",
        ),
        (
            lambda: jaxmr.TableLaw(jnp.arange(3.0), jnp.arange(2.0)),
            r"TableLaw: `currents` and `values` must be 1-D arrays of equal length",
        ),
        (
            lambda: jaxmr.PolynomialLaw(jnp.ones((2, 2))),
            r"PolynomialLaw: `coefficients` must be a non-empty 1-D array",
        ),
    ],
    ids=[
        "sampled",
        "sampled-derivatives",
        "sampled-one",
        "steps",
        "multisine",
        "multisine-phases",
        "table",
        "polynomial",
    ],
)
def test_wrong_shapes(make, match):
    with pytest.raises((ValueError, TypeError), match=match):
        make()


def test_initial_state_of_wrong_shape():
    with pytest.raises(
        ValueError,
        match=r"`initial_state` must have shape \(1,\) for states \('z',\), got \(2,\)",
    ):
        jaxmr.simulate(bouc_wen(), MOTION, 0.0, TS, initial_state=jnp.zeros(2))


def test_array_of_currents_in_simulate_points_to_sweep():
    with pytest.raises((TypeError, ValueError), match=names("current")):
        jaxmr.simulate(bouc_wen(), MOTION, jnp.array([0.0, 1.0]), TS)


def test_a_2d_array_of_currents_in_sweep_is_named():
    # It told the user to "use `sweep`" from inside `sweep`. (jaxmr's own check:
    # the suite's typechecker answers first in `sweep`.)
    from jaxmr._signal import as_signal
    from jaxmr._simulate import _items

    with pytest.raises(ValueError, match=r"must be 1-D, one constant current per run"):
        _items(jnp.ones((2, 2)), as_signal, "current")
    with pytest.raises((TypeError, ValueError), match=names("current")):
        jaxmr.sweep(bouc_wen(), MOTION, jnp.ones((2, 2)), TS)


def test_array_of_currents_names_sweep_without_typechecker():
    # jaxmr's own message (the typechecker may answer first in `simulate`).
    from jaxmr._signal import as_signal

    with pytest.raises(
        ValueError, match=r"`current` as a number must be a scalar.*`sweep`"
    ):
        as_signal(jnp.array([0.0, 1.0]), "current")


# ---------------------------------------------------------------------------------------
# Unphysical parameters, known at construction


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: bouc_wen(n=0.0), r"BoucWen: the exponent `n` must be > 0, got 0.0"),
        (lambda: bouc_wen(n=-1.0), r"BoucWen: the exponent `n` must be > 0"),
        (lambda: bouc_wen(gamma=-1.0), r"BoucWen: `gamma` must be >= 0"),
        (lambda: bouc_wen(A=0.0), r"BoucWen: `A` must be > 0"),
        (lambda: bouc_wen(alpha=-1.0), r"BoucWen: `alpha` must be >= 0"),
        (lambda: bouc_wen(c0=-1.0), r"BoucWen: `c0` must be >= 0"),
        (lambda: jaxmr.Dahl(k_x=-1.0, k_w=1.0, rho=1.0), r"Dahl: `k_x` must be >= 0"),
        (lambda: jaxmr.Dahl(k_x=1.0, k_w=1.0, rho=0.0), r"Dahl: `rho` must be > 0"),
        (
            lambda: jaxmr.LuGre(
                sigma0=0.0, sigma1=1.0, sigma2=1.0, F_c=1.0, F_s=2.0, v_s=0.1
            ),
            r"LuGre: `sigma0` must be > 0",
        ),
        (
            lambda: jaxmr.Bingham(f_c=-1.0, c0=1.0),
            r"Bingham: the yield force `f_c` must be >= 0",
        ),
        (
            lambda: jaxmr.FirstOrderLag(0.0),
            r"FirstOrderLag: `rate` must be positive",
        ),
        (
            lambda: jaxmr.FirstOrderLag(-5.0),
            r"FirstOrderLag: `rate` must be positive",
        ),
        (
            lambda: jaxmr.BoucWenBaberNoori(
                k=1.0, alpha=0.5, c=1.0, A0=1.0, beta=1.0, gamma=1.0, n=1.0, zeta_s=1.0
            ),
            r"BoucWenBaberNoori: `zeta_s` must be in \[0, 1\)",
        ),
        (
            lambda: jaxmr.NormalizedBoucWen(
                kappa_x=0.0, kappa_w=1.0, c0=1.0, rho=0.0, sigma=0.5, n=1.0
            ),
            r"NormalizedBoucWen: `rho` must be > 0",
        ),
        (lambda: jaxmr.Sine(1.0, 0.0), r"Sine: `frequency` must be > 0 Hz"),
        (lambda: jaxmr.Triangle(1.0, -1.0), r"Triangle: `frequency` must be > 0 Hz"),
        (lambda: jaxmr.Chirp(1.0, 1.0, 5.0, 0.0), r"Chirp: `duration` must be > 0 s"),
        (
            lambda: jaxmr.Steps(jnp.array([0.0, 0.2, 0.1]), jnp.zeros(3)),
            r"Steps: `times` must be strictly increasing",
        ),
        (
            lambda: jaxmr.TableLaw(jnp.array([1.0, 0.0]), jnp.array([1.0, 2.0])),
            r"TableLaw: `currents` must be strictly increasing",
        ),
        (
            lambda: jaxmr.FixedStep(substeps=0),
            r"FixedStep: `substeps` must be a positive integer",
        ),
    ],
    ids=[
        "bw-n0",
        "bw-n-neg",
        "bw-gamma",
        "bw-A",
        "bw-alpha",
        "bw-c0",
        "dahl-kx",
        "dahl-rho",
        "lugre-sigma0",
        "bingham-fc",
        "lag-rate0",
        "lag-rate-neg",
        "bwbn-zeta_s",
        "normalized-rho",
        "sine-frequency",
        "triangle-frequency",
        "chirp-duration",
        "steps-times",
        "table-currents",
        "fixedstep-substeps",
    ],
)
def test_unphysical_parameters_at_construction(make, match):
    with pytest.raises(ValueError, match=match):
        make()


# ---------------------------------------------------------------------------------------
# Unphysical parameters only known under jit


@pytest.mark.parametrize("jit", [eqx.filter_jit, jax.jit], ids=["filter_jit", "jit"])
def test_traced_parameter_checked_at_run_time(jit):
    @jit
    def force(n):
        return jaxmr.simulate(bouc_wen(n=n), MOTION, 0.0, TS, integrator=FIXED).force

    assert np.all(np.isfinite(force(jnp.array(2.0))))
    # eqx.filter_jit raises EquinoxRuntimeError; under jax.jit jax wraps the same message
    # in an error of its own (JaxRuntimeError or ValueError "INTERNAL: CpuCallback
    # error", depending on where the check fires).
    expected = eqx.EquinoxRuntimeError if jit is eqx.filter_jit else Exception
    with pytest.raises(expected, match=r"BoucWen: the exponent `n` must be > 0\.") as e:
        force(jnp.array(-1.0))
    assert "Tracer" not in str(e.value)  # no meaningless tracer repr in the message


def test_check_quotes_a_value_only_when_it_is_concrete():
    check = jaxmr.Check(jnp.array(-1.0) >= 0, "`k` must be >= 0", jnp.array(-1.0))
    assert check.message() == "`k` must be >= 0, got -1.0."
    pair = jaxmr.Check(
        False, "`beta + gamma` must be > 0", {"beta": 1.0, "gamma": -2.0}
    )
    assert pair.message() == "`beta + gamma` must be > 0, got beta=1.0, gamma=-2.0."
    assert check.named("Model").message() == "Model: `k` must be >= 0, got -1.0."
    # Under jit the value is a tracer: the message states the rule alone.
    traced = []

    @jax.jit
    def record(k):
        traced.append(jaxmr.Check(k >= 0, "`k` must be >= 0", k).message())
        return k

    record(jnp.array(-1.0))
    assert traced == ["`k` must be >= 0."]


@pytest.mark.parametrize("jit", [eqx.filter_jit, jax.jit], ids=["filter_jit", "jit"])
def test_traced_system_parameter_message_has_no_tracer(jit):
    system = jaxmr.SingleDegreeOfFreedom(2.0, bouc_wen(), stiffness=5e4)

    @jit
    def run(mass):
        bad = eqx.tree_at(lambda s: s.mass, system, mass)
        return jaxmr.simulate_system(bad, 0.0, 0.05, 0.01, initial_state=Q0).states

    expected = eqx.EquinoxRuntimeError if jit is eqx.filter_jit else Exception
    with pytest.raises(
        expected,
        match=r"SingleDegreeOfFreedom: `mass` must be > 0 kg\. \(found while simulating\)",
    ) as e:
        run(jnp.array(-2.0))
    assert "Tracer" not in str(e.value) and "Traced<" not in str(e.value)
    # The same rule with a concrete value quotes it.
    with pytest.raises(ValueError, match=r"`mass` must be > 0 kg, got -2\.0\.$"):
        jaxmr.SingleDegreeOfFreedom(-2.0, bouc_wen(), stiffness=5e4)


def test_traced_lag_rate_checked_at_run_time():
    good = jaxmr.Damper(bouc_wen(), jaxmr.FirstOrderLag(50.0))
    bad = eqx.tree_at(lambda d: d.dynamics.rate, good, jnp.array(-50.0))
    assert np.all(np.isfinite(traced_force(good, MOTION, jaxmr.Constant(0.5), TS)))
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"FirstOrderLag: `rate` must"):
        traced_force(bad, MOTION, jaxmr.Constant(0.5), TS)


# A model with laws: alpha tabulated on 0..1 A, n = -0.5 + 2 i (n < 0 below 0.25 A).
# Both tests below use the same structure, so `simulate` compiles once for them.
LAW_MODEL = bouc_wen(
    alpha=jaxmr.TableLaw(jnp.array([0.0, 1.0]), jnp.array([100.0, 300.0])),
    n=jaxmr.LinearLaw(-0.5, 2.0),
)


def test_law_resolving_to_unphysical_value_at_the_run_current():
    # Adaptive: at 0.5 A (n = 0.5, z0 = 1e-4 m) one fixed step per 50 ms overshoots z0.
    run = lambda current: jaxmr.simulate(LAW_MODEL, MOTION, current, TS)
    assert np.all(np.isfinite(run(0.5).force))
    with pytest.raises(
        eqx.EquinoxRuntimeError,
        match=r"BoucWen \(its current laws checked over the input's range\): the "
        r"exponent `n` must be > 0",
    ):
        run(0.1)


def test_law_checked_over_the_whole_current_range():
    # Valid at the current at ts[0] (0.5 A), not at the one it steps down to (0.1 A,
    # n = -0.3): the check covers every current the run reaches, not its first.
    steps = jaxmr.Steps(jnp.array([0.0, 0.5]), jnp.array([0.5, 0.1]))
    with pytest.raises(
        eqx.EquinoxRuntimeError,
        match=r"checked over the input's range\): the exponent `n` must be > 0",
    ):
        jaxmr.simulate(LAW_MODEL, MOTION, steps, TS)
    # With concrete inputs the message names where the law breaks it and the range
    # the current covers (it named neither); a sweep names the current's index.
    with pytest.raises(
        eqx.EquinoxRuntimeError,
        match=r"must be > 0, at an input of 0.1 A \(or V\): `current` spans "
        r"\[0.1, 0.5\] for the model",
    ):
        jaxmr.simulate(LAW_MODEL, MOTION, steps, TS)
    with pytest.raises(
        eqx.EquinoxRuntimeError, match=r"at an input of 0.2 A .*`current\[1\]` is 0.2"
    ):
        jaxmr.sweep(LAW_MODEL, MOTION, [0.5, 0.2], TS)


def test_nan_parameter_is_named():
    # A NaN fails every comparison: named as NaN, not as a sign error.
    with pytest.raises(ValueError, match=r"BoucWen: `alpha` is NaN or infinite"):
        bouc_wen(alpha=float("nan"))
    with pytest.raises(ValueError, match=r"LinearLaw: `a` must be finite"):
        jaxmr.LinearLaw(float("nan"), 1.0)
    # A law built under jit from a traced NaN: named by the simulation's check.
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"`c0` is NaN or infinite"):
        eqx.filter_jit(
            lambda a: (
                jaxmr.simulate(
                    bouc_wen(c0=jaxmr.LinearLaw(a, 1.0)),
                    MOTION,
                    0.5,
                    TS,
                    integrator=FIXED,
                ).force
            )
        )(jnp.asarray(jnp.nan))


def test_closed_loop_checks_the_laws_over_the_commandable_range():
    # n = 1.5 − 2 i: valid at 0 A (the only current the closed loop used to check),
    # negative above 0.75 A, which a controller with i_max = 1 A may command.
    model = bouc_wen(n=jaxmr.LinearLaw(1.5, -2.0))
    system = jaxmr.SingleDegreeOfFreedom(2.0, model, stiffness=5e4)
    fine = jaxmr.simulate_system(system, 0.0, 0.5, 0.01, initial_state=Q0)
    assert np.all(np.isfinite(fine.states))
    with pytest.raises(
        eqx.EquinoxRuntimeError,
        match=r"checked over the input's range\): the exponent `n` must be > 0",
    ):
        jaxmr.simulate_system(system, 0.0, 1.0, 0.01, initial_state=Q0)


Q0 = jnp.array([1e-3, 0.0])  # [m, m/s]


def test_current_outside_table_law():
    with pytest.raises(
        eqx.EquinoxRuntimeError,
        match=r"`current` leaves the current range of a TableLaw.*extend the table",
    ):
        jaxmr.simulate(LAW_MODEL, MOTION, 2.0, TS, integrator=FIXED)


# ---------------------------------------------------------------------------------------
# Wrong types


@pytest.mark.parametrize(
    "argument, call",
    [
        ("device", lambda: jaxmr.simulate("BoucWen", MOTION, 0.0, TS)),
        ("motion", lambda: jaxmr.simulate(bouc_wen(), 0.01, 0.0, TS)),
        ("current", lambda: jaxmr.simulate(bouc_wen(), MOTION, "1 A", TS)),
        (
            "integrator",
            lambda: jaxmr.simulate(bouc_wen(), MOTION, 0.0, TS, integrator="rk4"),
        ),
    ],
    ids=["device", "motion", "current", "integrator"],
)
def test_wrong_type(argument, call):
    with pytest.raises(TypeError, match=names(argument)):
        call()


@pytest.mark.parametrize(
    "argument, arguments",
    [
        ("device", ("BoucWen", MOTION, 0.0, None)),
        ("motion", (bouc_wen(), 0.01, 0.0, None)),
        ("current", (bouc_wen(), MOTION, "1 A", None)),
        ("integrator", (bouc_wen(), MOTION, 0.0, "rk4")),
    ],
    ids=["device", "motion", "current", "integrator"],
)
def test_wrong_type_jaxmr_message(argument, arguments):
    # jaxmr's own check (the typechecker answers first in the public functions under
    # this test suite; users without it see these messages).
    from jaxmr._simulate import _prepare

    with pytest.raises(TypeError, match=rf"`{argument}` must be .*got (str|float)"):
        _prepare(*arguments)


def test_text_for_a_number_is_named():
    # NumPy reads the text "2000" as a number; a model or law handed text (a value
    # read from a file and not converted) is refused, not silently converted. (The
    # suite's typechecker may answer first, naming the converter's parameter 'x'.)
    jaxmr_or_checker = r"expected a number .*got '{}'|parameter '\w+'"
    with pytest.raises(TypeError, match=jaxmr_or_checker.format(2000)):
        jaxmr.Skyhook("2000", 1.0)
    with pytest.raises(TypeError, match=jaxmr_or_checker.format("1e3")):
        bouc_wen(alpha="1e3")
    # jaxmr's own check, beneath the typechecker (what users without it see).
    from jaxmr._misc import as_float_array

    convert = getattr(as_float_array, "__wrapped__", as_float_array)
    with pytest.raises(TypeError, match=r"expected a number .*got '2000'"):
        convert("2000")
    with pytest.raises(TypeError, match=r"expected a number .*got \['1', '2'\]"):
        convert(["1", "2"])
    assert float(convert(np.float32(2.5))) == 2.5


def test_a_controller_checks_its_estimator_against_the_sample_rate():
    law = jaxmr.Skyhook(2000.0, 1.0)
    with pytest.raises(ValueError, match=r"`crossover` \(600.0 Hz\) must lie below "
                       r"half the sample rate \(500 Hz"):  # fmt: skip
        jaxmr.ObserverBasedController(
            law, estimator=jaxmr.VelocityEstimator(crossover=600.0)
        )
    inner = jaxmr.ObserverBasedController(law)
    with pytest.raises(TypeError, match="itself an ObserverBasedController"):
        jaxmr.ObserverBasedController(inner)


def test_damper_wrong_types():
    with pytest.raises(TypeError, match=names("hysteresis")):
        jaxmr.Damper("BoucWen")
    with pytest.raises(TypeError, match=names("dynamics")):
        jaxmr.Damper(bouc_wen(), 190.0)


# ---------------------------------------------------------------------------------------
# Solver failure


TS_2S = jnp.linspace(0.0, 2.0, 5)


def test_max_steps_reached_is_a_result_code_or_an_error():
    integrator = jaxmr.Adaptive(max_steps=10)  # Dopri8 at rtol 1e-8 needs far more
    sol = jaxmr.simulate(
        bouc_wen(), MOTION, 0.0, TS_2S, integrator=integrator, throw=False
    )
    assert sol.result == jaxmr.RESULTS.max_steps_reached
    assert int(sol.num_steps) == 10
    with pytest.raises(
        eqx.EquinoxRuntimeError, match=r"maximum number of solver steps"
    ):
        jaxmr.simulate(bouc_wen(), MOTION, 0.0, TS_2S, integrator=integrator)


# gamma = 50 + 1e6 i [1/m²]: at 0 A one RK4 step of 50 ms is stable (h |df/dz| =
# h 2 gamma |v| |z| ~ 1e-2), at 1 A z saturates at ~1e-3 m, h |df/dz| ~ 13 (RK4 is
# stable below 2.8), and each overshoot squares |z|: inf within three steps.
STIFF_AT_1A = bouc_wen(gamma=jaxmr.LinearLaw(50.0, 1e6))


def test_fixed_step_divergence_is_a_result_code_or_an_error():
    sol = jaxmr.simulate(STIFF_AT_1A, MOTION, 1.0, TS, integrator=FIXED, throw=False)
    assert sol.result in (jaxmr.RESULTS.nonfinite, jaxmr.RESULTS.nonfinite_force)
    assert not np.all(np.isfinite(sol.force))
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"[Nn]on-?finite"):
        jaxmr.simulate(STIFF_AT_1A, MOTION, 1.0, TS, integrator=FIXED)


def test_sweep_returns_a_result_code_per_run():
    sol = jaxmr.sweep(
        STIFF_AT_1A, MOTION, jnp.array([0.0, 1.0]), TS, integrator=FIXED, throw=False
    )
    assert sol.force.shape == (2, TS.shape[0])
    ok = np.asarray(sol.result == jaxmr.RESULTS.successful)
    nonfinite = np.asarray(sol.result == jaxmr.RESULTS.nonfinite)
    np.testing.assert_array_equal(ok, [True, False])
    np.testing.assert_array_equal(nonfinite, [False, True])
    assert np.all(np.isfinite(sol.force[0]))  # the good run is untouched by the bad one
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"[Nn]on-?finite"):
        jaxmr.sweep(STIFF_AT_1A, MOTION, jnp.array([0.0, 1.0]), TS, integrator=FIXED)


def test_bouc_wen_may_soften_without_bound():
    """beta + gamma <= 0 is a valid (unbounded) Bouc-Wen: the benchmark oscillator's."""
    model = bouc_wen(beta=-1100.0, gamma=800.0, n=1.0)
    assert float(model.state_bounds()[0]) == float("inf")


def test_scores_models_and_metrics_name_a_wrong_call(tmp_path):
    """Mistakes that had been answered with a plausible number or an unreadable
    file: forces of two shapes (NumPy broadcast (n,) against (n, 1) and scored the
    (n, n) table), something other than a model saved, a frequency given for the
    period, and one road given to `evaluate` without its batch axis."""
    a = np.linspace(0.0, 1.0, 50)
    with pytest.raises(ValueError, match=r"one shape .* got \(50,\) and \(50, 1\)"):
        jaxmr.scores.nrmse(a, a[:, None])
    with pytest.raises(ValueError, match="one shape"):
        jaxmr.scores.rmse(a, a[:, None])
    assert jaxmr.scores.nrmse(a, a) == 0.0
    with pytest.raises(TypeError, match=names("model")):  # jaxmr's or the checker's
        jaxmr.save_model({"a": 1}, tmp_path / "m.json")  # pyright: ignore[reportArgumentType]
    run = jaxmr.data.Experiment.from_arrays(a, 0.01 * np.sin(6 * a))
    with pytest.raises(TypeError, match="Experiment, which `load_model` cannot read"):
        jaxmr.save_model(run, tmp_path / "e.json")
    assert not any(tmp_path.iterdir())
    ts = jnp.linspace(0.0, 1.0, 101)
    sol = jaxmr.simulate(bouc_wen(), MOTION, 0.0, ts, integrator=FIXED)
    assert float(jaxmr.metrics.energy_per_cycle(sol, 0.5)) > 0  # 2 Hz: 1 cycle
    for period, match in ((2.0, r"longer than the solution \(1 s\)"), (0.0, "> 0")):
        with pytest.raises(ValueError, match=match):
            jaxmr.metrics.energy_per_cycle(sol, period)
    road = jaxmr.iso8608_road("C", 20.0, 1.0, jax.random.key(0))
    car = jaxmr.spencer_quarter_car(jaxmr.passenger_car_mr_damper())
    with pytest.raises(ValueError, match="this looks like one road"):
        jaxmr.evaluate(car, jaxmr.Skyhook(2000.0, 2.0), road, 1.0)


def test_audit_mistakes_are_named_before_any_simulation():
    """Mistakes a docs-and-API audit (session 28) found answered by a wrong name, a
    raw JAX error, a deep equinox failure or a plausible number."""
    # Two kinds of brake in one sweep: named by their models (not "Damper", the
    # wrapper every device gets before stacking).
    with pytest.raises(ValueError, match=r"BoucWen \(in a Damper\).*Dahl \(in a Dam"):
        jaxmr.sweep(
            [jaxmr.sas_brake_bouc_wen(), jaxmr.sas_brake_dahl()], MOTION, [0.0], TS
        )
    # A NaN in a signal or a law, when it is built (it surfaced inside a simulation
    # whose traceback showed an earlier call's line).
    for build, match in (
        (lambda: jaxmr.Sine(jnp.nan, 1.0), "Sine: `amplitude` must be finite"),
        (lambda: jaxmr.Constant(jnp.inf), "Constant: `value` must be finite"),
        (lambda: jaxmr.LinearLaw(jnp.nan, 1.0), "LinearLaw: `a` must be finite"),
        # An integrator's tolerances and budget (rtol -1 was told to enable x64).
        (lambda: jaxmr.Adaptive(rtol=-1.0), r"`rtol` must be a number > 0"),
        (lambda: jaxmr.Adaptive(atol=jnp.nan), r"`atol` must be a number >= 0"),
        (lambda: jaxmr.Adaptive(max_steps=0), "`max_steps` must be a positive"),
    ):
        with pytest.raises(ValueError, match=match):
            build()
    assert jaxmr.Adaptive(atol=0.0).atol == 0.0  # a pure relative tolerance is valid
    # An array for a scalar parameter broadcast into a (samples, 3) force.
    with pytest.raises(ValueError, match=r"`alpha` must be a number or a current law"):
        bouc_wen(alpha=jnp.ones(3))
    # Under vmap each member's parameter is a scalar: a batch of models is built so.
    assert jax.vmap(lambda a: bouc_wen(alpha=a).alpha)(jnp.ones(3)).shape == (3,)
    # The metrics: samples that do not match, time running backwards (a negative
    # energy), a negative sample interval (negative frequencies), a wrong solution.
    t = jnp.linspace(0.0, 1.0, 20)
    # (The suite's type checker refuses the shapes first, naming the argument.)
    with pytest.raises(
        (ValueError, TypeError), match=r"same number of samples|'force'"
    ):
        jaxmr.metrics.dissipated_energy(t[:10], t, t)
    with pytest.raises(ValueError, match="`t` must be increasing"):
        jaxmr.metrics.dissipated_energy(t[::-1], t, t)
    with pytest.raises(ValueError, match=r"`dt` must be > 0 \[s\]"):
        jaxmr.road_psd(np.ones(1000), -1e-3, 10.0)
    sol = jaxmr.simulate(bouc_wen(), MOTION, 0.0, TS, integrator=FIXED)
    with pytest.raises(
        TypeError, match=rf"comfort takes a closed-loop|{names('solution')}"
    ):
        jaxmr.metrics.comfort(sol)  # pyright: ignore[reportArgumentType]
    with pytest.raises(TypeError, match=names("solution")):
        jaxmr.metrics.energy_per_cycle({"force": 1.0}, 0.5)  # pyright: ignore[reportArgumentType]
    # Arrays given for experiments: "has no attribute 't'" before.
    with pytest.raises(TypeError, match=r"`experiments\[0\]` is a ndarray, which has"):
        jaxmr.fit(bouc_wen(), [np.zeros((3, 100))])  # pyright: ignore[reportArgumentType]


def test_tune_names_parameters_that_select_nothing():
    car = jaxmr.spencer_quarter_car(jaxmr.passenger_car_mr_damper())
    roads = jax.vmap(lambda k: jaxmr.iso8608_road("C", 20.0, 1.0, k))(
        jax.random.split(jax.random.key(0), 2)
    )
    with pytest.raises(TypeError, match=names("parameters")):
        jaxmr.tune(car, jaxmr.Skyhook(2000.0, 2.0), roads, 1.0, parameters=None)  # pyright: ignore[reportArgumentType]
