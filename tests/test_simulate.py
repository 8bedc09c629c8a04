"""`simulate` and `sweep`: integrators agree, sweeps equal single runs, measured inputs,
user-defined models, and sharding over several devices."""

import os
import subprocess
import sys
import textwrap
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.metrics

MOTION = jaxmr.Sine(jnp.deg2rad(3.5), 1.0)
TS = jnp.linspace(0.0, 1.0, 201)
FIXED = jaxmr.FixedStep(substeps=10)


def test_stiff_integrator_agrees_with_adaptive_on_spencer():
    ts = jnp.linspace(0.0, 0.4, 401)
    motion = jaxmr.Sine(0.015, 2.5)
    explicit = jaxmr.simulate(jaxmr.spencer_1997(), motion, 2.25, ts)
    implicit = jaxmr.simulate(
        jaxmr.spencer_1997(), motion, 2.25, ts, integrator=jaxmr.Stiff()
    )
    peak = float(jnp.max(jnp.abs(explicit.force)))
    # Kvaerno5 at rtol 1e-6 against Dopri8 at 1e-8: ~1e-5 of peak; 1e-3 is a bound.
    assert float(jnp.max(jnp.abs(implicit.force - explicit.force))) < 1e-3 * peak


def test_sweep_grid_equals_single_runs():
    devices = [jaxmr.sas_brake_bouc_wen(), jaxmr.sas_brake_bouc_wen().at(0.3)]
    motions = [jaxmr.Sine(jnp.deg2rad(a), f) for a, f in ((2.0, 1.0), (3.5, 2.0))]
    currents = jnp.array([0.0, 0.5, 1.0])
    # The two devices must share a structure to be stacked: resolve the first too.
    devices[0] = devices[0].at(0.7)
    sol = jaxmr.sweep(devices, motions, currents, TS, integrator=FIXED)
    assert sol.force.shape == (2, 2, 3, TS.shape[0])
    assert sol.num_steps.shape == (2, 2, 3)
    assert np.all(sol.result == jaxmr.RESULTS.successful)
    for d in range(2):
        for m in range(2):
            for c in range(3):
                single = jaxmr.simulate(
                    devices[d], motions[m], currents[c], TS, integrator=FIXED
                )
                # Batched and single runs do the same arithmetic: equal to rounding.
                np.testing.assert_allclose(
                    sol.force[d, m, c], single.force, rtol=1e-10, atol=1e-13
                )


@pytest.mark.parametrize("batching", ["vmap", "map"])
def test_sweep_zip_and_batching_modes_agree(batching):
    motions = [jaxmr.Sine(jnp.deg2rad(a), 1.0) for a in (1.0, 2.0, 3.0)]
    currents = [0.0, 0.5, 1.0]
    sol = jaxmr.sweep(
        jaxmr.sas_brake_bouc_wen(),
        motions,
        currents,
        TS,
        grid=False,
        batching=batching,
        batch_size=2,
    )
    assert sol.force.shape == (3, TS.shape[0])
    for k in range(3):
        single = jaxmr.simulate(jaxmr.sas_brake_bouc_wen(), motions[k], currents[k], TS)
        # Each run keeps its own step-size controller, but batched code rounds
        # differently and the controller's accept/reject decisions follow: agreement to
        # the solve's accuracy (1e-4 of peak, see test_physics), not to rounding.
        np.testing.assert_allclose(sol.force[k], single.force, atol=2e-4 * 1.3)


def test_sweep_rejects_unequal_zip_lengths_and_mixed_types():
    with pytest.raises(ValueError, match="equal lengths"):
        jaxmr.sweep(
            jaxmr.sas_brake_bouc_wen(),
            [MOTION, MOTION],
            [0.0, 1.0, 2.0],
            TS,
            grid=False,
        )
    with pytest.raises(ValueError, match="same type"):
        jaxmr.sweep(
            jaxmr.sas_brake_bouc_wen(), [MOTION, jaxmr.Triangle(0.1, 1.0)], 0.0, TS
        )
    with pytest.raises(ValueError, match="at least one sequence"):
        jaxmr.sweep(jaxmr.sas_brake_bouc_wen(), MOTION, 0.0, TS)


def test_measured_motion_reproduces_the_analytic_run():
    """A motion given as samples with its measured velocity (cubic Hermite) reproduces
    the run with the analytic sine."""
    fine = jnp.linspace(0.0, 1.0, 2001)
    sampled = jaxmr.Sampled(
        fine, jax_vmap(MOTION)(fine), jax_vmap(MOTION.derivative)(fine)
    )
    a = jaxmr.simulate(jaxmr.sas_brake_dahl(), MOTION, 0.5, TS)
    b = jaxmr.simulate(jaxmr.sas_brake_dahl(), sampled, 0.5, TS)
    # Hermite interpolation error at 0.5 ms spacing: ~h^4 |x''''| ~ 1e-12 rad.
    np.testing.assert_allclose(b.force, a.force, atol=1e-6)
    np.testing.assert_allclose(b.displacement, a.displacement, atol=1e-10)


def jax_vmap(f):
    import jax

    return jax.vmap(f)


def test_sampled_current_and_steps_current():
    """A current given as samples of a step and as `Steps` gives the same force once the
    lag has settled."""
    damper = jaxmr.Damper(jaxmr.sas_brake_bouc_wen(), jaxmr.FirstOrderLag(200.0))
    steps = jaxmr.Steps(jnp.array([0.0, 0.5]), jnp.array([0.2, 0.8]))
    samples = jaxmr.Sampled(
        jnp.array([0.0, 0.4999, 0.5001, 1.0]), jnp.array([0.2, 0.2, 0.8, 0.8])
    )
    a = jaxmr.simulate(damper, MOTION, steps, TS)
    b = jaxmr.simulate(damper, MOTION, samples, TS)
    late = np.asarray(TS) > 0.6
    np.testing.assert_allclose(a.effective_current[late], 0.8, atol=1e-3)
    np.testing.assert_allclose(a.force[late], b.force[late], atol=1e-4)


class Elastic(jaxmr.AbstractHysteresis):
    """A user's model: a spring with a first-order relaxing state, F = k x + s,
    ṡ = (c v - s)/τ (a Maxwell element)."""

    k: jnp.ndarray
    c: jaxmr.AbstractCurrentLaw | jnp.ndarray
    tau: jnp.ndarray
    state_names: ClassVar[tuple[str, ...]] = ("s",)

    def rates(self, state, x, v):
        return (self.c * v - state) / self.tau

    def force(self, state, x, v):
        return self.k * x + state[0]


def test_user_defined_model_works_everywhere():
    model = Elastic(
        k=jnp.array(2.0),
        c=jaxmr.LinearLaw(jnp.array(1.0), jnp.array(3.0)),
        tau=jnp.array(0.05),
    )
    sol = jaxmr.sweep(model, MOTION, jnp.array([0.0, 1.0]), TS)
    assert sol.state_names == ("s",)
    # Maxwell element at 1 Hz: dissipates, and more with the larger c at 1 A.
    energy = jaxmr.metrics.energy_per_cycle(sol, 1.0)
    assert 0 < energy[0] < energy[1]
    with pytest.raises(KeyError, match="states are"):
        sol.state("z")


def test_static_model_needs_no_integration():
    sol = jaxmr.simulate(jaxmr.sas_brake_bingham(0.2), MOTION, 0.0, TS)
    v = np.asarray(sol.velocity)
    np.testing.assert_allclose(sol.force, 0.2 * np.sign(v) + 0.002 * v, atol=1e-15)
    assert sol.states.shape == (TS.shape[0], 0) and int(sol.num_steps) == 0


def test_sweep_shards_over_several_devices():
    """With two host devices the batch is split by `jax.shard_map`; results equal the
    single-device ones."""
    code = textwrap.dedent(
        """
        import jax
        jax.config.update("jax_enable_x64", True)
        import jax.numpy as jnp, numpy as np, jaxmr
        assert jax.local_device_count() == 2, jax.devices()
        ts = jnp.linspace(0.0, 1.0, 101)
        m = jaxmr.Sine(jnp.deg2rad(3.5), 1.0)
        currents = jnp.array([0.0, 0.25, 0.5, 1.0])
        fixed = jaxmr.FixedStep(4)
        # A lagged current: the state depends on it, one run per current (full path).
        lagged = jaxmr.Damper(jaxmr.sas_brake_bouc_wen(), jaxmr.FirstOrderLag(50.0))
        sol = jaxmr.sweep(lagged, m, currents, ts, integrator=fixed)
        shards = {d for d in sol.force.sharding.device_set}
        assert len(shards) == 2, shards
        # Split, each device holding its own runs (not gathered whole onto both).
        assert not sol.force.sharding.is_fully_replicated, sol.force.sharding
        for k, c in enumerate(currents):
            one = jaxmr.simulate(lagged, m, c, ts, integrator=fixed)
            np.testing.assert_allclose(sol.force[k], one.force, rtol=1e-10, atol=1e-13)
        # The SAS brake shares its states over the currents: the (device, motion)
        # pairs are sharded.
        motions = [m, jaxmr.Sine(jnp.deg2rad(2.0), 2.0)]
        sol = jaxmr.sweep(
            jaxmr.sas_brake_bouc_wen(), motions, currents, ts, integrator=fixed
        )
        shards = {d for d in sol.force.sharding.device_set}
        assert len(shards) == 2, shards
        # Split, each device holding its own runs (not gathered whole onto both).
        assert not sol.force.sharding.is_fully_replicated, sol.force.sharding
        for j, motion in enumerate(motions):
            for k, c in enumerate(currents):
                one = jaxmr.simulate(
                    jaxmr.sas_brake_bouc_wen(), motion, c, ts, integrator=fixed
                )
                np.testing.assert_allclose(
                    sol.force[j, k], one.force, rtol=1e-10, atol=1e-13
                )
        print("sharded ok")
        """
    )
    env = dict(os.environ)
    # The session's flags (conftest: jaxmr.devices.configure_cpu) and 2 CPU devices.
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    )
    env["JAX_PLATFORMS"] = "cpu"
    out = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "sharded ok" in out.stdout


def test_solution_is_a_pytree_of_arrays():
    sol = jaxmr.simulate(jaxmr.sas_brake_dahl(), MOTION, 0.0, TS)
    leaves = eqx.filter(sol, eqx.is_array)
    assert all(leaf.shape[0] == TS.shape[0] for leaf in [leaves.force, leaves.states])


def test_a_sweep_of_devices_edited_with_tree_at():
    """`eqx.tree_at(..., 300.0)`, the edit the docs show, leaves a Python float where
    the other device holds an array: the sweep stacks them (it had refused them as
    "not of the same type ... got ['Damper']") and each run is its own simulation."""
    damper = jaxmr.passenger_car_mr_damper()
    edited = eqx.tree_at(lambda m: m.hysteresis.beta, damper, 300.0)
    motion, ts = jaxmr.Sine(0.01, 2.0), jnp.linspace(0.0, 0.5, 51)
    sol = jaxmr.sweep([damper, edited], motion, [0.5], ts, integrator=FIXED)
    for k, device in enumerate((damper, edited)):
        alone = jaxmr.simulate(device, motion, 0.5, ts, integrator=FIXED)
        np.testing.assert_allclose(sol.force[k, 0], alone.force, rtol=1e-12, atol=1e-9)
    assert not np.allclose(sol.force[0], sol.force[1])  # the edit took effect
