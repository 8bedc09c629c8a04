"""`fit`: synthetic identification of the published Bouc–Wen brake (issue 3's first
acceptance case) and the identifiability report."""

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr

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
    np.testing.assert_allclose(result.nrmse, 0.01, rtol=0.1)
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


def test_eight_brake_parameters_flagged_as_not_identified(synthetic):
    _, experiments = synthetic
    result = jaxmr.fit(_guess(fix_A=False), experiments, progress=False, max_steps=40)
    assert result.unidentified, "the (alpha, A, beta, gamma) scaling must be flagged"
    message = result.unidentified[0]
    # The null vector of z -> z/s: log A - log alpha + (n - 1)(log beta + log gamma).
    for name in (".A", ".alpha.a", ".alpha.b", ".beta", ".gamma"):
        assert name in message
    assert not result.converged
