"""`sweep` over constant currents solves the states once per (device, motion) when the
state equation does not depend on the current (the SAS brake's laws act only on its
output gains), and runs every current when it does."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.plot
from jaxmr import _simulate

TS = jnp.linspace(0.0, 0.5, 51)
MOTIONS = [jaxmr.Sine(jnp.deg2rad(3.5), 2.0), jaxmr.Sine(jnp.deg2rad(2.0), 3.0)]
CURRENTS = jnp.array([0.0, 0.4, 1.0])
FIELDS = ("ts", "displacement", "velocity", "current", "effective_current", "force")
FIELDS += ("states", "num_steps")


@pytest.fixture
def paths(monkeypatch):
    """The `shared` flag of every `sweep` call: which path it took."""
    taken = []
    original = _simulate._sweep

    def spy(*args):
        taken.append(args[10])  # `shared`, after the sweep's 10 other arguments
        return original(*args)

    monkeypatch.setattr(_simulate, "_sweep", spy)
    return taken


def _assert_same(a, b, atol=1e-12):
    assert jnp.shape(a.result._value) == jnp.shape(b.result._value)
    np.testing.assert_array_equal(a.result._value, b.result._value)
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape, name
        np.testing.assert_allclose(x, y, rtol=0, atol=atol, err_msg=name)


@pytest.mark.parametrize(
    "integrator", [jaxmr.Adaptive(), jaxmr.FixedStep(3)], ids=["adaptive", "fixed"]
)
def test_sas_brake_shares_states_and_equals_the_full_solve(
    integrator, paths, monkeypatch
):
    model = jaxmr.sas_brake_bouc_wen()
    shared = jaxmr.sweep(model, MOTIONS, CURRENTS, TS, integrator=integrator)
    assert paths == [True]
    assert shared.force.shape == (2, 3, TS.shape[0])
    assert shared.states.shape == (2, 3, TS.shape[0], 1)
    # z is the same for every current under one motion; the torque is not.
    np.testing.assert_array_equal(shared.states[:, 0], shared.states[:, 2])
    assert not np.allclose(shared.force[:, 0], shared.force[:, 2])

    monkeypatch.setattr(_simulate, "_state_ignores_current", lambda *_: False)
    full = jaxmr.sweep(model, MOTIONS, CURRENTS, TS, integrator=integrator)
    assert paths == [True, False]
    _assert_same(shared, full)
    one = jaxmr.simulate(model, MOTIONS[1], CURRENTS[2], TS, integrator=integrator)
    np.testing.assert_allclose(shared.force[1, 2], one.force, rtol=0, atol=1e-12)


def test_currents_alone_and_zipped_share_states(paths):
    model = jaxmr.sas_brake_bouc_wen()
    fixed = jaxmr.FixedStep(3)
    alone = jaxmr.sweep(model, MOTIONS[0], CURRENTS, TS, integrator=fixed)
    zipped = jaxmr.sweep(model, MOTIONS[0], list(CURRENTS), TS, integrator=fixed)
    assert paths == [True, True]
    assert alone.force.shape == (3, TS.shape[0])
    _assert_same(alone, zipped, atol=0)
    for k, c in enumerate(CURRENTS):
        one = jaxmr.simulate(model, MOTIONS[0], c, TS, integrator=fixed)
        np.testing.assert_allclose(alone.force[k], one.force, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", ["beta_law", "lag"])
def test_state_that_depends_on_current_takes_the_full_path(kind, paths):
    brake = jaxmr.sas_brake_bouc_wen()
    if kind == "beta_law":
        model = dataclasses.replace(brake, beta=jaxmr.LinearLaw(737.0, 200.0))
    else:
        model = jaxmr.Damper(brake, jaxmr.FirstOrderLag(50.0))
    fixed = jaxmr.FixedStep(3)
    sol = jaxmr.sweep(model, MOTIONS, CURRENTS, TS, integrator=fixed)
    assert paths == [False]
    for j, motion in enumerate(MOTIONS):
        for k, c in enumerate(CURRENTS):
            one = jaxmr.simulate(model, motion, c, TS, integrator=fixed)
            np.testing.assert_allclose(sol.force[j, k], one.force, rtol=0, atol=1e-12)
            np.testing.assert_allclose(sol.states[j, k], one.states, atol=1e-12)


def test_signals_and_zipped_motions_take_the_full_path(paths):
    model = jaxmr.sas_brake_bouc_wen()
    fixed = jaxmr.FixedStep(3)
    steps = [jaxmr.Constant(0.5), jaxmr.Constant(1.0)]
    jaxmr.sweep(model, MOTIONS, steps, TS, integrator=fixed)  # Constants: shared
    jaxmr.sweep(model, MOTIONS, CURRENTS[:2], TS, integrator=fixed, grid=False)
    jaxmr.sweep(model, MOTIONS, 0.5, TS, integrator=fixed)  # no current batch
    assert paths == [True, False, False]


@pytest.mark.parametrize("share", [True, False], ids=["shared", "full"])
def test_keep_returns_the_same_force_alone(share, paths, monkeypatch):
    """`keep=("force",)` drops the other fields on either path; the force is the
    whole solution's, bit for bit (the same operations, fewer outputs)."""
    model = jaxmr.sas_brake_bouc_wen()
    if not share:
        monkeypatch.setattr(_simulate, "_state_ignores_current", lambda *_: False)
    fixed = jaxmr.FixedStep(3)
    whole = jaxmr.sweep(model, MOTIONS, CURRENTS, TS, integrator=fixed)
    force = jaxmr.sweep(model, MOTIONS, CURRENTS, TS, integrator=fixed, keep="force")
    assert paths == [share, share]
    np.testing.assert_array_equal(force.force, whole.force)
    np.testing.assert_array_equal(force.num_steps, whole.num_steps)
    np.testing.assert_array_equal(force.result._value, whole.result._value)
    dropped = [name for name in FIELDS if getattr(force, name) is None]
    assert dropped == [n for n in FIELDS if n not in ("force", "num_steps")]
    with pytest.raises(ValueError, match="without its states"):
        force.state("z")
    # What reads a dropped field says so, and how to keep it (`plot.loop` stopped
    # on an IndexError).
    with pytest.raises(ValueError, match=r"ts, displacement.*sweep\(\.\.\., keep=\)"):
        jaxmr.plot.loop(force)
    with pytest.raises(ValueError, match=r"keep="):
        jaxmr.metrics.energy_per_cycle(force, 0.5)


def test_keep_names_unknown_fields():
    with pytest.raises(ValueError, match=r"unknown: \['torque'\]"):
        jaxmr.sweep(jaxmr.sas_brake_bouc_wen(), MOTIONS, CURRENTS, TS, keep=("torque",))


def test_shared_path_keeps_table_checks():
    """A current outside a TableLaw on an output gain: an error, or with `throw=False`
    that run's result code while the others succeed."""
    brake = jaxmr.sas_brake_bouc_wen()
    model = dataclasses.replace(
        brake, alpha=jaxmr.TableLaw(jnp.array([0.0, 1.0]), jnp.array([1.0, 1.07]))
    )
    assert _simulate._state_ignores_current(jaxmr.Damper(model), jnp.float64)
    fixed = jaxmr.FixedStep(3)
    currents = jnp.array([0.5, 2.0])
    with pytest.raises(eqx.EquinoxRuntimeError, match="TableLaw"):
        jaxmr.sweep(model, MOTIONS, currents, TS, integrator=fixed)
    sol = jaxmr.sweep(model, MOTIONS, currents, TS, integrator=fixed, throw=False)
    ok = sol.result == jaxmr.RESULTS.successful
    outside = sol.result == jaxmr.RESULTS.current_outside_table
    np.testing.assert_array_equal(ok, [[True, False], [True, False]])
    np.testing.assert_array_equal(outside, [[False, True], [False, True]])
