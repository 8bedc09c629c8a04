"""Single precision is never silently wrong: simulations say float64 is needed instead of
"increase max_steps", and float32 sample times still count as uniform.

The suite runs in float64 (conftest.py); the float32 cases run inside
`jax.enable_x64(False)`, which scopes single precision to the `with` block. Models and
signals are built inside the block so that their arrays are float32 too.
"""

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr

FLOAT32_WARNING = r"is running in float32: simulations need float64"


def bouc_wen():
    return jaxmr.BoucWen(alpha=100.0, c0=10.0, A=1.0, beta=50.0, gamma=50.0, n=2.0)


def test_default_integrator_in_float32_says_float64_is_needed():
    # At rtol 1e-8 float32 steps shrink until `max_steps` runs out (the SAS brake, 10 s:
    # 1e6 steps): refused at trace time with the cure, not after a million steps.
    with jax.enable_x64(False):
        ts = jnp.linspace(0.0, 0.5, 11)
        with (
            pytest.warns(UserWarning, match=r"jaxmr\.simulate " + FLOAT32_WARNING),
            pytest.raises(ValueError, match=r"rtol = 1e-08 cannot be met in float32"),
        ):
            jaxmr.simulate(bouc_wen(), jaxmr.Sine(0.01, 2.0), 0.0, ts)


def test_running_out_of_steps_in_float32_is_its_own_result_code():
    # An rtol float32 can meet, but so few steps that the solve runs out: the code
    # names float32 and float64, not only `max_steps`.
    integrator = jaxmr.Adaptive(dfx.Tsit5(), rtol=1e-5, atol=1e-8, max_steps=4)
    with jax.enable_x64(False):
        ts = jnp.linspace(0.0, 0.5, 11)
        with pytest.warns(UserWarning, match=FLOAT32_WARNING):
            sol = jaxmr.simulate(
                bouc_wen(),
                jaxmr.Sine(0.01, 2.0),
                0.0,
                ts,
                integrator=integrator,
                throw=False,
            )
    assert sol.result == jaxmr.RESULTS.max_steps_float32
    assert "float64" in jaxmr.RESULTS[sol.result]


def test_fixed_step_in_float32_runs_and_warns():
    with jax.enable_x64(False):
        ts = jnp.linspace(0.0, 0.5, 11)
        motion = jaxmr.Sine(0.01, 2.0)
        with pytest.warns(UserWarning, match=r"jaxmr\.sweep " + FLOAT32_WARNING):
            sol = jaxmr.sweep(
                bouc_wen(),
                motion,
                jnp.array([0.0, 1.0]),
                ts,
                integrator=jaxmr.FixedStep(1),
            )
    assert sol.force.dtype == jnp.float32
    assert np.all(np.asarray(sol.result == jaxmr.RESULTS.successful))


# ---------------------------------------------------------------------------------------
# Uniform sample times: float32 rounding moves a 1 ms step by up to ~1e-3 of it at 10 s,
# far beyond the 1e-9 of a step that float64 grids are held to.

T32 = np.linspace(0.0, 10.0, 10_001, dtype=np.float32)


def test_float32_grid_is_uniform_in_float32():
    with jax.enable_x64(False):
        sampled = jaxmr.Sampled(T32, np.sin(T32))
        record = jaxmr.SystemRecord(T32, np.sin(T32))  # was: "resample the record"
    assert sampled.uniform
    assert record.ts.dtype == jnp.float32


def test_float32_grid_is_uniform_in_float64():
    # float32 data (a float32 file) converted to float64 keep float32's rounding.
    sampled = jaxmr.Sampled(T32, np.sin(T32))
    assert sampled.times.dtype == jnp.float64
    assert sampled.uniform
    jaxmr.SystemRecord(T32, np.sin(T32))


def test_a_non_uniform_float32_grid_is_still_refused():
    bent = T32.copy()
    bent[5000] += np.float32(2e-4)  # a fifth of a step: far above rounding
    assert not jaxmr.Sampled(bent, np.sin(bent)).uniform
    with pytest.raises(ValueError, match=r"`ts` must be uniformly spaced"):
        jaxmr.SystemRecord(bent, np.sin(bent))
    # Steps that drift by 8e-10 s per sample: each within float32 rounding of the mean
    # (4e-6 s at most), but the middle samples lie 10 steps from k·dt, where the O(1)
    # lookup (one index correction) would pick the wrong interval.
    k = np.arange(10_001, dtype=np.float64)
    drift = (1e-3 * k + 4e-10 * (k**2 - 10_001 * k)).astype(np.float32)
    assert np.max(np.abs(np.diff(drift.astype(float)) - 1e-3)) < 4.8e-6
    assert not jaxmr.Sampled(drift, np.zeros(10_001)).uniform


@eqx.filter_jit
def _interpolate(signal, t):
    return jax.vmap(signal)(t), jax.vmap(signal.derivative)(t)


def test_uniform_lookup_is_exact_on_a_float32_grid():
    # The O(1) lookup on a float32 grid finds the same interval as binary search.
    with jax.enable_x64(False):
        values = np.sin(3.0 * T32) + 0.1 * T32
        uniform = jaxmr.Sampled(T32, values)
        searched = jaxmr.Sampled(T32, values, uniform=False)
        t = jnp.asarray(np.concatenate([T32, T32[:-1] + np.float32(3e-4)]))
        got, want = _interpolate(uniform, t), _interpolate(searched, t)
    assert uniform.uniform
    np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(want[0]))
    np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(want[1]))


def test_simulate_system_warns_in_float32():
    with jax.enable_x64(False):
        system = jaxmr.SingleDegreeOfFreedom(2.0, bouc_wen(), stiffness=5e4)
        with pytest.warns(
            UserWarning,
            match=r"jaxmr\.simulate_system is running in float32: closed-loop",
        ):
            sol = jaxmr.simulate_system(
                system, 0.0, 0.5, 0.01, initial_state=jnp.array([1e-3, 0.0])
            )
    assert sol.states.dtype == jnp.float32
