"""Mechanical systems and the closed loop (issue 5): quarter car and SDOF physics,
energy balances, sample-and-hold semantics, gradients, bad input.

Tolerances: RK4 at 0.25 ms loses energy at a relative rate ∝ (ω h)^6 per step:
~1e-9 over 2 s for the 1-12 Hz car, 4e-7 for the 25 Hz SDOF (ω h = 0.04), so 1e-6
catches any modelling error (a wrong sign or factor changes the energy at O(1)); the damper's work is summed by the trapezoid
rule at 1 kHz, accurate to ~(ω dt)² ≈ 1e-4 relative for the 1 Hz body mode.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.data
import jaxmr.metrics

from .helpers import FITTED_SPENCER, shared_data

NO_DAMPER = jaxmr.Bingham(f_c=0.0, c0=0.0)
MR = jaxmr.Damper(jaxmr.review_quarter_car_damper(), jaxmr.FirstOrderLag(150.0))


def car(damper=MR, **kw):
    return jaxmr.passenger_car(damper, **kw)


def test_natural_frequencies_of_the_passenger_car():
    body, wheel = car().natural_frequencies()
    # Two-mass eigenvalues: body ≈ sqrt(ks kt/(ks + kt)/ms)/2π, wheel ≈
    # sqrt((ks + kt)/mu)/2π when mu ≪ ms.
    assert body == pytest.approx(
        np.sqrt(20e3 * 200e3 / 220e3 / 350) / (2 * np.pi), 0.02
    )
    assert wheel == pytest.approx(np.sqrt(220e3 / 40) / (2 * np.pi), 0.03)


@pytest.mark.parametrize(
    "system, q0",
    [
        (jaxmr.passenger_car(NO_DAMPER), [0.05, 0.0, -0.01, 0.3]),
        (jaxmr.SingleDegreeOfFreedom(2.0, NO_DAMPER, stiffness=5e4), [1e-3, 0.1]),
    ],
)
def test_energy_is_conserved_without_damping_or_excitation(system, q0):
    q0 = jnp.asarray(q0)
    sol = jaxmr.simulate_system(system, 0.0, 0.0, 2.0, initial_state=q0)
    energy = jax.vmap(system.energy)(sol.states[:, :4][:, : len(q0)])
    e0 = system.energy(q0)
    assert float(e0) > 0
    np.testing.assert_allclose(energy, e0, rtol=1e-6)
    np.testing.assert_allclose(system.energy(sol.final_state[: len(q0)]), e0, rtol=1e-6)


def test_damper_work_equals_the_energy_lost():
    system = car()
    q0 = jnp.array([0.05, 0.0, 0.0, 0.0])
    sol = jaxmr.simulate_system(
        system, 0.0, 0.5, 4.0, initial_state=q0, sampling=jaxmr.Sampling(dt=5e-4)
    )
    lost = system.energy(q0) - system.energy(sol.final_state[:4])
    work = jaxmr.metrics.dissipated_work(sol)
    assert float(lost) > 0.3 * float(system.energy(q0))  # it did damp
    assert float(work) == pytest.approx(float(lost), rel=1e-4)


def test_force_excited_quarter_car_and_sdof_resonance():
    # The SDOF with no device is a linear oscillator: at resonance the steady amplitude
    # is F0/(c ω).
    m, k, c = 2.0, 5e4, 20.0
    w = np.sqrt(k / m)
    sdof = jaxmr.SingleDegreeOfFreedom(m, NO_DAMPER, damping=c, stiffness=k)
    force = jaxmr.Sine(10.0, w / (2 * np.pi))
    sol = jaxmr.simulate_system(
        sdof,
        force,
        0.0,
        3.0,
        sampling=jaxmr.Sampling(dt=2e-4),
        integrator=jaxmr.FixedStep(substeps=2),
    )
    late = sol["body_position"][sol.ts > 2.0]
    assert float(jnp.max(jnp.abs(late))) == pytest.approx(10.0 / (c * w), rel=0.01)
    # Force-excited quarter car: the ground stays at zero, the force acts on the wheel.
    forced = jaxmr.passenger_car(MR, excitation="force")
    sol = jaxmr.simulate_system(forced, jaxmr.Sine(500.0, 11.0), 0.0, 0.5)
    assert float(jnp.max(jnp.abs(sol["wheel_position"]))) > 1e-4
    assert float(jnp.max(jnp.abs(sol["excitation"]))) == pytest.approx(500.0, 1e-3)


class Ramp(jaxmr.AbstractController):
    """Commands k·dt·(sample index): reveals when a command acts."""

    i_max: jax.Array = eqx.field(converter=jnp.asarray, default=10.0)

    def init(self, measurement):
        return jnp.zeros(())

    def __call__(self, measurement, state, plant):
        return state, state + 1.0


def test_sample_and_hold_with_delay():
    damper = jaxmr.Damper(NO_DAMPER)
    sdof = jaxmr.SingleDegreeOfFreedom(1.0, damper, stiffness=1.0)
    for delay in (0, 1, 2):
        sol = jaxmr.simulate_system(
            sdof, 0.0, Ramp(), 0.008, sampling=jaxmr.Sampling(delay=delay)
        )
        np.testing.assert_array_equal(sol.command, np.arange(8.0))
        # The command computed at sample k acts from sample k + delay; before that,
        # the first command (0) is held.
        expected = np.maximum(np.arange(8.0) - delay, 0.0)
        np.testing.assert_array_equal(sol.applied, expected)


def test_closed_loop_gradient_matches_finite_differences():
    road = jaxmr.Sine(0.01, 1.5)

    def loss(current):
        control = jaxmr.ConstantCurrent(current, 1.0)
        sol = jaxmr.simulate_system(car(), road, control, 1.0)
        return jnp.mean(sol["body_acceleration"] ** 2)

    grad = jax.grad(loss)(0.3)
    h = 1e-4
    fd = (loss(0.3 + h) - loss(0.3 - h)) / (2 * h)
    # Central differences of a smooth loss: O(h²) truncation, far below 1e-5.
    assert float(grad) == pytest.approx(float(fd), rel=1e-5)
    assert float(grad) != 0.0


def test_batches_of_roads_under_vmap():
    amplitudes = jnp.array([0.005, 0.01, 0.02])

    def peak(a):
        sol = jaxmr.simulate_system(car(), jaxmr.Sine(a, 1.5), 0.0, 1.0)
        return jnp.max(jnp.abs(sol["body_position"]))

    batched = jax.vmap(peak)(amplitudes)
    one = peak(amplitudes[1])
    np.testing.assert_allclose(batched[1], one, rtol=1e-12)
    assert np.all(np.diff(np.asarray(batched)) > 0)


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="body mass `ms` must be > 0"):
        jaxmr.passenger_car(MR, ms=-1.0)
    with pytest.raises(ValueError, match="negative damping"):
        jaxmr.passenger_car(MR, cs=-100.0)
    with pytest.raises(ValueError, match='`excitation` must be "road"'):
        jaxmr.passenger_car(MR, excitation="wind")
    with pytest.raises(ValueError, match="`mass` must be > 0"):
        jaxmr.SingleDegreeOfFreedom(0.0, MR)
    # (The jaxtyping hook of the test run reports it first; without it, jaxmr's own
    # message "`system` must be a jaxmr system (QuarterCar, ...)".)
    with pytest.raises(TypeError, match="system"):
        jaxmr.simulate_system(MR, 0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="`dt` must be a positive"):
        jaxmr.Sampling(dt=0.0)
    with pytest.raises(ValueError, match="`delay` must be a whole number"):
        jaxmr.Sampling(delay=-1)
    # (As for `system`, the jaxtyping hook reports these two first; jaxmr's own
    # messages say "`integrator` must be jaxmr.FixedStep(substeps)" and "`sampling`
    # must be a jaxmr.Sampling(dt, delay)".)
    with pytest.raises(TypeError, match="integrator"):
        jaxmr.simulate_system(car(), 0.0, 0.0, 1.0, integrator=jaxmr.Adaptive())
    with pytest.raises(TypeError, match="sampling"):
        jaxmr.simulate_system(car(), 0.0, 0.0, 1.0, sampling=1e-3)  # pyright: ignore
    with pytest.raises(TypeError, match="unexpected keyword argument 'dtt'"):
        jaxmr.simulate_system(car(), 0.0, 0.0, 1.0, dtt=1e-3)
    with pytest.raises(ValueError, match="`initial_state` must have shape"):
        jaxmr.simulate_system(car(), 0.0, 0.0, 0.1, initial_state=jnp.zeros(3))
    with pytest.raises(ValueError, match=r"lie in \[0, i_max\]"):
        jaxmr.ConstantCurrent(2.0, 1.0)


class TooMuch(jaxmr.AbstractController):
    i_max: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)

    def __call__(self, measurement, state, plant):
        return 2.0 + 0.0 * measurement["body_velocity"], state


def test_a_controller_leaving_the_current_range_is_an_error():
    with pytest.raises(Exception, match="outside \\[0, i_max\\]"):
        jaxmr.simulate_system(car(), 0.0, TooMuch(), 0.05)
    sol = jaxmr.simulate_system(car(), 0.0, TooMuch(), 0.05, throw=False)
    assert sol.result == jaxmr.RESULTS.command_out_of_range


def test_unstable_parameters_found_under_jit_raise():
    # Traced parameters are checked when simulated, not at construction.
    @jax.jit
    def run(ks):
        system = eqx.tree_at(lambda s: s.ks, car(), ks)
        return jaxmr.simulate_system(system, 0.0, 0.0, 0.01).final_state

    with pytest.raises(Exception, match="spring `ks` must be > 0"):
        run(jnp.array(-5.0))


def test_inverse_damper_model_is_exact_for_an_affine_law():
    plant = jaxmr.DamperPlant(
        jaxmr.Damper(jaxmr.review_quarter_car_damper()),
        jnp.array([0.3]),
        jnp.array(0.01),
        jnp.array(0.2),
    )
    for target_current in (0.0, 0.4, 1.0):
        force = plant.force_at(jnp.array(target_current))
        current = plant.current_for_force(force, jnp.array(1.0))
        assert float(current) == pytest.approx(target_current, abs=1e-12)
    # Beyond the reachable band: clipped to it.
    top = plant.force_at(jnp.array(1.0))
    assert float(plant.current_for_force(top * 10, jnp.array(1.0))) == 1.0
    assert float(plant.current_for_force(-top, jnp.array(1.0))) == 0.0


def test_a_road_too_coarse_or_too_short_for_the_simulation_is_an_error():
    key = jax.random.key(0)
    coarse = jaxmr.iso8608_road("C", 5.0, 1.0, key, dt=2e-3)
    with pytest.raises(Exception, match="sampled more coarsely"):
        jaxmr.simulate_system(car(), coarse, 0.0, 0.5, sampling=jaxmr.Sampling(dt=1e-3))
    short = jaxmr.iso8608_road("C", 20.0, 0.2, key)
    with pytest.raises(Exception, match="ends before"):
        jaxmr.simulate_system(car(), short, 0.0, 0.5)
    # A duration between samples ran the whole samples before it, silently.
    with pytest.raises(ValueError, match=r"not a whole number of samples .* 0.01 s"):
        jaxmr.simulate_system(car(), short, 0.0, 0.0105)
    # A measured profile as a `Sampled` signal, too short: it held its last height.
    times = jnp.linspace(0.0, 0.2, 201)
    profile = jaxmr.Sampled(times, 0.01 * jnp.sin(20 * times))
    with pytest.raises(ValueError, match=r"ends at 0.2 s, before the simulation's"):
        jaxmr.simulate_system(car(), profile, 0.0, 0.5)
    sol = jaxmr.simulate_system(car(), profile, 0.0, 0.2)
    assert bool(jnp.all(jnp.isfinite(sol.states)))
    # `dissipated_work` is a closed-loop run's; a prescribed-motion run is named.
    assert float(jaxmr.metrics.dissipated_work(sol)) >= 0.0
    plain = jaxmr.simulate(MR, jaxmr.Sine(0.01, 2.0), 0.0, jnp.linspace(0, 0.5, 51))
    with pytest.raises(
        TypeError, match="dissipated_work takes a closed-loop run|'solution'"
    ):
        jaxmr.metrics.dissipated_work(plain)  # pyright: ignore[reportArgumentType]


def test_the_deprecated_loop_keywords_warn_and_give_the_same_run():
    # `dt`, `substeps` and `delay` became `sampling=Sampling(dt, delay)` and
    # `integrator=FixedStep(substeps)`; for one release the old keywords still work,
    # with a warning naming the replacement, and run the very same simulation (equal
    # to the last bit: the same static settings reach the same compiled function).
    args = (car(), jaxmr.Sine(0.01, 2.0), jaxmr.OnOffSkyhook(1.0), 0.1)
    new = jaxmr.simulate_system(
        *args, sampling=jaxmr.Sampling(dt=5e-4, delay=2), integrator=jaxmr.FixedStep(2)
    )
    replacement = (
        r"pass sampling=jaxmr.Sampling\(dt=0.0005, delay=2\) and "
        r"integrator=jaxmr.FixedStep\(substeps=2\) instead"
    )
    with pytest.warns(DeprecationWarning, match=replacement):
        old = jaxmr.simulate_system(*args, dt=5e-4, substeps=2, delay=2)
    for field in ("states", "command", "applied"):
        np.testing.assert_array_equal(getattr(old, field), getattr(new, field))
    assert old.dt == new.dt == 5e-4
    # Not the defaults: the keywords were relayed, not dropped.
    assert jaxmr.simulate_system(*args).ts.shape != new.ts.shape
    with pytest.raises(TypeError, match="give `sampling` alone"):
        jaxmr.simulate_system(*args, sampling=jaxmr.Sampling(), dt=1e-3)
    with pytest.raises(TypeError, match="give `integrator` alone"):
        jaxmr.simulate_system(*args, integrator=jaxmr.FixedStep(), substeps=4)

    rig = jaxmr.sas_rig()
    new = jaxmr.free_decay(
        rig, 0.0, duration=0.02, sampling=jaxmr.Sampling(dt=2e-3, delay=0)
    )
    with pytest.warns(DeprecationWarning, match=r"free_decay: `dt`, `delay` are"):
        old = jaxmr.free_decay(rig, 0.0, duration=0.02, dt=2e-3, delay=0)
    np.testing.assert_array_equal(old.states, new.states)
    assert new.ts.shape == (10,)


def test_a_fitted_spencer_damper_runs_in_the_passenger_car_at_default_settings():
    """Issue 27: at 0 A on an ISO C road at 20 m/s the car drives the fitted damper at
    ~2 m/s, 20x its data's ±0.09 m/s. The default step is chosen from the damper's
    stiffness (64 substeps here), so the run is finite, with a warning naming the
    fitted range; with the old default, `FixedStep()`, it diverges, and the error
    says what to change."""
    files = jaxmr.data.load_utfsm(shared_data("utfsm_mr_damper", "sine"))
    names = ("2mm5Hz0A", "5mm3Hz0x25A", "5mm3Hz1A")
    fitted_range = jaxmr.FittedRange.from_experiments(
        [e for e in files if e.name in names]
    )
    system = car(FITTED_SPENCER)
    road = jaxmr.iso8608_road("C", 20.0, 1.0, jax.random.key(0))
    with pytest.warns(jaxmr.OutsideFittedRange, match=r"velocity spans .* the fitted"):
        solution = jaxmr.simulate_system(
            system, road, 0.0, 1.0, fitted_range=fitted_range
        )
    assert solution.result == jaxmr.RESULTS.successful
    assert np.all(np.isfinite(solution.states))
    assert np.max(np.abs(solution["damper_velocity"])) > 10 * fitted_range.velocity[1]
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"FixedStep\(substeps=16\)"):
        jaxmr.simulate_system(system, road, 0.0, 1.0, integrator=jaxmr.FixedStep())
