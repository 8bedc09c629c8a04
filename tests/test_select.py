"""Model templates and model selection: Bouc–Wen beats Bingham on held-out data of the
published Bouc–Wen brake; the templates' initial guesses fit the data's scales."""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.data
from jaxmr import predict, predict_all
from jaxmr._identify.select import compare_models, holdout_split, score_table
from jaxmr._identify.templates import MODEL_TEMPLATES, data_scales
from jaxmr._parameter import unwrap

CURRENTS = (0.0, 0.5, 1.0)  # A
NOISE = 0.01  # of std(T)


@pytest.fixture(scope="module")
def brake():
    """The SAS brake at three currents: one 1 Hz, ±3.5° cycle at 250 Hz, 1 % noise."""
    truth = jaxmr.sas_brake_bouc_wen()
    ts = jnp.linspace(0.0, 1.0, 251)
    sol = jaxmr.sweep(truth, jaxmr.Sine(jnp.deg2rad(3.5), 1.0), jnp.array(CURRENTS), ts)
    rng = np.random.default_rng(0)
    experiments = []
    for k, current in enumerate(CURRENTS):
        torque = np.asarray(sol.force[k])
        experiments.append(
            jaxmr.data.Experiment(
                ts,
                sol.displacement[k],
                sol.velocity[k],
                current,
                torque + NOISE * np.std(torque) * rng.standard_normal(torque.shape),
                name=f"{current:g} A",
                rotary=True,
            )
        )
    return truth, sol, experiments


def test_bouc_wen_ranks_first_on_held_out_data(brake):
    _, _, (low, middle, high) = brake
    lines = []
    # Held out: the middle current, so the current laws are tested on interpolation.
    # 40 steps reach the noise floor from the template (the rest is a slow drift of
    # the unidentifiable c0.a, whose effect is below the noise).
    scores = compare_models(
        ["bingham", "bouc_wen"], [low, high], [middle], log=lines.append, max_steps=40
    )
    assert [s.name for s in scores] == ["bouc_wen", "bingham"]
    bouc_wen, bingham = scores
    assert bouc_wen.error is None and bingham.error is None
    assert bouc_wen.median_test_nrmse < 2 * NOISE
    # Bingham has no memory: the brake's torque flips about 0.5° after each reversal,
    # which no function of the velocity alone follows.
    assert bingham.median_test_nrmse > 0.3
    # Bouc–Wen: α, c0 laws (4), β, γ, n, the accumulator's k0 and f0.
    assert (bouc_wen.num_parameters, bingham.num_parameters) == (9, 4)
    assert bouc_wen.fit_time > 0 and bouc_wen.test_names == ("0.5 A",)
    assert isinstance(bouc_wen.model, jaxmr.BoucWen)
    # The score is the error of `predict` on the held-out experiment.
    predicted = predict(bouc_wen.model, middle)
    error = np.sqrt(np.mean((predicted - np.asarray(middle.force)) ** 2))
    np.testing.assert_allclose(error, bouc_wen.test_rmse[0], rtol=1e-10)
    table = score_table(scores)
    assert table.splitlines()[1].split()[:2] == ["1", "bouc_wen"]
    assert any(line.startswith("bouc_wen: screened fit") for line in lines)
    assert any(line.startswith("bouc_wen: full fit") for line in lines)


def test_predict_matches_simulate(brake):
    truth, sol, experiments = brake
    predicted = predict_all(truth, experiments)
    for k, p in enumerate(predicted):
        # RK4 at 0.5 ms against the adaptive Dopri8 solution (README: ≤ 7e-4 of the
        # peak torque for this brake).
        exact = np.asarray(sol.force[k])
        np.testing.assert_allclose(p, exact, atol=7e-4 * np.max(np.abs(exact)))


@pytest.mark.parametrize("name", list(MODEL_TEMPLATES))
def test_templates_scale_to_the_data(brake, name):
    _, _, experiments = brake
    model = MODEL_TEMPLATES[name](experiments)
    if name.endswith("_lag"):  # a fitted input lag in front of the model
        assert isinstance(model, jaxmr.Damper)
        assert isinstance(model.dynamics, jaxmr.FirstOrderLag)
        model = model.hysteresis
    assert isinstance(model, jaxmr.AbstractHysteresis)
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(unwrap(model)))
    # Current-dependent parameters are laws when the current varies, and constants
    # with one current (a slope could not be identified).
    assert _laws(model), name
    assert not _laws(MODEL_TEMPLATES[name](experiments[:1])), name


def _laws(model):
    laws = (jaxmr.LinearLaw, jaxmr.PolynomialLaw, jaxmr.ExponentialLaw)
    is_law = lambda x: isinstance(x, laws)
    return [x for x in jax.tree.leaves(model, is_leaf=is_law) if is_law(x)]


def test_template_initial_guesses_simulate(brake):
    """Every template's guess simulates to a finite torque of the data's magnitude."""
    _, _, experiments = brake
    scale = data_scales(experiments).force
    for name, template in MODEL_TEMPLATES.items():
        (torque,) = predict_all(template(experiments), experiments[1:2])
        assert np.all(np.isfinite(torque)), name
        assert 0.1 * scale < np.max(np.abs(torque)) < 10 * scale, name


def test_bouc_wen_template_fixes_the_redundancy(brake):
    _, _, experiments = brake
    model = MODEL_TEMPLATES["bouc_wen"](experiments)
    assert isinstance(model.A, jaxmr.Fixed)
    # β + γ = A: z saturates at ±1, so α starts at the yield torque.
    beta, gamma = model.beta.value(), model.gamma.value()
    np.testing.assert_allclose(beta + gamma, model.A.value())
    scales = data_scales(experiments)
    np.testing.assert_allclose(1 / model.A.value(), scales.saturation)
    # The brake's torque flips about 0.5° after each reversal, at half the peak
    # velocity: a function of the velocity sees no yield torque, the Dahl state sees
    # the saturated torque α_a z0 = 1.16 N·m (at 0 A; 1.24 N·m at 1 A).
    lo, hi = scales.hysteretic_force
    assert 1.0 < lo < hi < 1.4, scales.hysteretic_force
    assert scales.yield_force[0] < 0.1 < 1.0 < scales.viscous[0], scales
    np.testing.assert_allclose(model.alpha.a.value(), lo)


def test_templates_fit_an_accumulators_offset(brake):
    # A pre-charged accumulator pushes with a constant force (and a small
    # stiffness): 30 % of the torque amplitude here, in every experiment. The
    # template fits it with the hysteresis (without the offset it could not: the
    # loop would be shifted by 0.3 of its amplitude).
    _, _, experiments = brake
    shifted = []
    for e in experiments:
        offset = 0.3 * 0.5 * np.ptp(np.asarray(e.force))
        shifted.append(
            jaxmr.data.Experiment(
                e.t, e.x, e.v, e.current, np.asarray(e.force) + offset,
                name=e.name, rotary=True,
            )
        )  # fmt: skip
    result = jaxmr.fit(
        MODEL_TEMPLATES["bouc_wen"](shifted), shifted, progress=False, max_steps=40
    )
    # At the noise (1 %), with the margin of the held-out test above.
    assert np.max(result.nrmse) < 2 * NOISE, result.nrmse


def test_candidate_errors(brake):
    _, _, experiments = brake
    with pytest.raises(ValueError, match="unknown model template 'spring'.*bouc_wen"):
        compare_models(["spring"], experiments, experiments)
    with pytest.raises(ValueError, match="`test` is empty"):
        compare_models(["bingham"], experiments, [])
    with pytest.raises(ValueError, match="`score_from` = 5.0 s leaves fewer"):
        compare_models(["bingham"], experiments, experiments, score_from=5.0)


def _fake(current, name, duration=1.0):
    t = np.linspace(0.0, duration, 11)
    return SimpleNamespace(
        t=t, x=np.sin(t), v=np.cos(t), current=current, force=np.cos(t), name=name
    )


def test_holdout_split_by_input_level():
    # Given out of order: the levels are sorted.
    experiments = [_fake(c, f"{c} A") for c in (1.0, 0.0, 0.75, 0.25, 0.5, 1.25)]
    experiments.append(_fake(0.25, "0.25 A again"))
    train, test, score_from, description = holdout_split(experiments)
    # Levels 0, .25, .5, .75, 1, 1.25: the 2nd and 4th; both lists keep the order given.
    assert [e.name for e in test] == ["0.75 A", "0.25 A", "0.25 A again"]
    assert [e.name for e in train] == ["1.0 A", "0.0 A", "0.5 A", "1.25 A"]
    assert score_from is None
    assert "held out 3 of 7 (input level(s) 0.25, 0.75)" in description


def test_holdout_split_by_experiment():
    """One input level: every third experiment, never the last."""
    experiments = [_fake(1.0, name) for name in "abcde"]
    train, test, _, description = holdout_split(experiments)
    assert [e.name for e in test] == ["b"]
    assert "every third experiment" in description


def test_holdout_split_in_time():
    experiments = [_fake(0.0, "a", duration=3.0), _fake(1.0, "b", duration=3.0)]
    train, test, score_from, _ = holdout_split(experiments)
    assert test == experiments
    np.testing.assert_allclose(score_from, [2.0, 2.0])
    for e in train:  # t = 0, 0.3, ..., 1.8 of 0, 0.3, ..., 3
        np.testing.assert_allclose(e.t, np.linspace(0.0, 1.8, 7))


def test_saturation_laws_only_under_a_constant_input(brake):
    """β(i), γ(i) of the shear-thinning template are laws when each experiment runs at
    one current, constants when the current varies within an experiment: there a z
    saturated at a high current lies outside the bound of a lower one and, with
    β > γ, diverges (the NEES record did)."""
    _, _, experiments = brake
    per_run = MODEL_TEMPLATES["shear_thinning_spencer"](experiments)
    assert isinstance(per_run.beta, jaxmr.ExponentialLaw)
    assert isinstance(per_run.gamma, jaxmr.ExponentialLaw)
    low, _, high = experiments
    half = len(low) // 2
    stepped = jaxmr.data.Experiment(
        low.t,
        low.x,
        low.v,
        np.where(np.arange(len(low)) < half, 0.0, 1.0),
        low.force,
        rotary=True,
    )
    varying = MODEL_TEMPLATES["shear_thinning_spencer_lag"]([stepped, high])
    hysteresis = varying.hysteresis
    assert isinstance(hysteresis.beta, jaxmr.Positive)
    assert isinstance(hysteresis.gamma, jaxmr.Positive)
    # The force laws stay: they cannot make the state diverge.
    assert isinstance(hysteresis.alpha, jaxmr.PolynomialLaw)
