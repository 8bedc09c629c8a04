"""Signals where gradients and adaptive steps meet their corners: a Triangle's peaks
(finite derivatives with respect to every field) and the jumps of `Steps` and linear
`Sampled` signals (the adaptive integrator steps to them instead of hunting them)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxmr

# f = 2 Hz, phase 0.7 rad: peaks at t = (1/4 - 0.7/2π)/2 + k/2, troughs a half period on.
TRIANGLE = jaxmr.Triangle(0.5, 2.0, phase=0.7, offset=-0.2)
PEAK = (0.25 - 0.7 / (2 * np.pi)) / 2.0
CORNERS = PEAK + np.arange(-2, 4) * 0.25  # peaks and troughs alternately


@eqx.filter_jit
def _field_grads(signal, ts):
    return jax.vmap(eqx.filter_grad(lambda s, t: s(t)), in_axes=(None, 0))(signal, ts)


@eqx.filter_jit
def _time_grads(signal, ts):
    return jax.vmap(jax.grad(lambda t: signal(t)))(ts)


def test_triangle_gradients_are_finite_at_the_corners():
    # arcsin(sin θ) had d/dθ = cos θ / |cos θ| = 0/0 at the corners: inf or nan with
    # respect to frequency, phase and time there.
    ts = jnp.asarray(CORNERS)
    grads = _field_grads(TRIANGLE, ts)
    for name in ("amplitude", "frequency", "phase", "offset"):
        g = np.asarray(getattr(grads, name))
        assert np.all(np.isfinite(g)), (name, g)
    assert np.all(np.isfinite(np.asarray(_time_grads(TRIANGLE, ts))))
    # Within the one-sided slopes (0 exactly at a corner): |ds/dφ| <= a·2/π.
    assert np.all(np.abs(np.asarray(grads.phase)) <= 0.5 * 2 / np.pi + 1e-12)
    # d/d(amplitude) at a corner is the unit wave there: +1 at peaks, -1 at troughs.
    np.testing.assert_allclose(grads.amplitude, np.tile([1.0, -1.0], 3), atol=1e-12)


def test_triangle_gradients_match_the_wave_between_corners():
    # s = s0 + a·w(θ), w the unit triangle, θ = 2πft + φ: off the corners
    # ds/df = a·w'(θ)·2πt, ds/dφ = a·w'(θ), ds/dt = a·w'(θ)·2πf with w' = ±2/π.
    ts = np.linspace(-1.0, 1.0, 401) + 1e-3  # misses every corner
    theta = 2 * np.pi * 2.0 * ts + 0.7
    slope = (2 / np.pi) * np.sign(np.cos(theta))
    grads = _field_grads(TRIANGLE, jnp.asarray(ts))
    np.testing.assert_allclose(grads.frequency, 0.5 * slope * 2 * np.pi * ts, atol=1e-9)
    np.testing.assert_allclose(grads.phase, 0.5 * slope, atol=1e-12)
    np.testing.assert_allclose(
        _time_grads(TRIANGLE, jnp.asarray(ts)), 0.5 * slope * 4 * np.pi, atol=1e-9
    )
    # The value is still (2/π) arcsin(sin θ), and derivative() its slope.
    values = jax.vmap(TRIANGLE)(jnp.asarray(ts))
    expected = -0.2 + 0.5 * (2 / np.pi) * np.arcsin(np.sin(theta))
    np.testing.assert_allclose(values, expected, atol=1e-13)
    np.testing.assert_allclose(
        jax.vmap(TRIANGLE.derivative)(jnp.asarray(ts)), 4 * 0.5 * 2.0 * np.sign(slope)
    )


def test_gradient_of_a_simulation_under_a_triangle_is_finite():
    # The output times hit the corners (1 Hz, phase 0: peaks at 0.25 s, 0.75 s); the
    # arcsin form gave nan with respect to frequency and phase.
    ts = jnp.linspace(0.0, 1.0, 21)
    model = jaxmr.BoucWen(alpha=100.0, c0=10.0, A=1.0, beta=50.0, gamma=50.0, n=2.0)

    @eqx.filter_grad
    def grad(motion):
        sol = jaxmr.simulate(model, motion, 0.0, ts, integrator=jaxmr.FixedStep(1))
        return jnp.sum(sol.force**2)

    grads = grad(jaxmr.Triangle(0.01, 1.0))
    for name in ("amplitude", "frequency", "phase", "offset"):
        assert np.isfinite(float(getattr(grads, name))), name


# ---------------------------------------------------------------------------------------
# Jump times for the adaptive integrator


def test_jump_times_of_the_signals():
    times = jnp.array([0.0, 0.3, 0.7])
    np.testing.assert_array_equal(
        jaxmr.Steps(times, jnp.array([1.0, 2.0, 0.0])).jump_times(), times
    )
    np.testing.assert_array_equal(
        jaxmr.Sampled(times, jnp.array([1.0, 2.0, 0.0])).jump_times(), times
    )
    # Hermite pieces join with continuous slope: no jumps to step to.
    hermite = jaxmr.Sampled(times, jnp.zeros(3), jnp.ones(3))
    assert hermite.jump_times() is None
    assert jaxmr.Sine(1.0, 1.0).jump_times() is None
    assert jaxmr.Constant(1.0).jump_times() is None


# A lagged current (FirstOrderLag) makes the state's rate jump with each current step.
LAGGED = jaxmr.Damper(jaxmr.sas_brake_bouc_wen(), jaxmr.FirstOrderLag(50.0))
SWITCH_TIMES = jnp.array([0.0, 0.2537, 0.5113, 0.7771])  # off the output grid


def _adaptive_steps(current):
    sol = jaxmr.simulate(
        LAGGED, jaxmr.Sine(jnp.deg2rad(3.5), 1.0), current, jnp.linspace(0, 1, 101)
    )
    return int(sol.num_steps)


def test_adaptive_steps_to_the_switching_times_of_steps():
    # Measured: without jump times the three steps cost 224 extra (mostly rejected)
    # steps over a run whose current never changes (494 against 270); with them 22
    # (281 against 259: stop before each, restart after). Both runs here pass the same
    # jump times; the bound, 20 a step, sits between the two.
    jumping = _adaptive_steps(
        jaxmr.Steps(SWITCH_TIMES, jnp.array([0.2, 1.0, 0.0, 0.6]))
    )
    flat = _adaptive_steps(jaxmr.Steps(SWITCH_TIMES, jnp.full(4, 0.5)))
    assert jumping <= flat + 3 * 20, (jumping, flat)


def test_vmapped_sweep_batches_the_jump_times_with_the_currents():
    # Each run steps to its own switching times: as few steps as alone, the same force
    # to the tolerance (a vmapped adaptive solve takes other steps: ~1e-5 of peak).
    motion = jaxmr.Sine(jnp.deg2rad(3.5), 1.0)
    ts = jnp.linspace(0, 1, 101)
    currents = [
        jaxmr.Steps(SWITCH_TIMES, jnp.array([0.2, 1.0, 0.0, 0.6])),
        jaxmr.Steps(SWITCH_TIMES + 0.01, jnp.array([1.0, 0.0, 0.5, 0.1])),
    ]
    sol = jaxmr.sweep(LAGGED, motion, currents, ts, batching="vmap")
    for k, current in enumerate(currents):
        single = jaxmr.simulate(LAGGED, motion, current, ts)
        peak = float(jnp.max(jnp.abs(single.force)))
        np.testing.assert_allclose(sol.force[k], single.force, atol=3e-5 * peak)
        assert int(sol.num_steps[k]) <= int(single.num_steps) + 30


def test_adaptive_steps_to_the_knots_of_a_linear_sampled_motion():
    # Linear interpolation: the velocity jumps at every knot. Measured on 1001 knots:
    # 1113 steps with the knots as jump times, 9387 without (and 7e-5 of peak torque
    # error against 1e-10).
    t = jnp.linspace(0.0, 1.0, 1001)
    motion = jaxmr.Sampled(t, jnp.deg2rad(3.5) * jnp.sin(2 * jnp.pi * t))
    sol = jaxmr.simulate(jaxmr.sas_brake_bouc_wen(), motion, 0.5, t[::10])
    assert int(sol.num_steps) < 2 * t.shape[0], int(sol.num_steps)
