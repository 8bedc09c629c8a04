"""Optimal experiment design (`jaxmr.design_experiments`, `jaxmr design`): the choice
against brute force over every plan, its predicted standard errors against those of a
fit to the planned tests, sequential design, and that it never reads a candidate's
force.

One small model throughout: a Dahl damper with current laws (5 free parameters, one
state), on a menu of 12 short sine tests sampled at 200 Hz."""

import contextlib
import csv
import io
import itertools
import json
import warnings

import numpy as np
import pytest

import jaxmr
import jaxmr.data
from jaxmr._cli import main

P = jaxmr.Positive
MENU = dict(
    amplitudes=(0.005, 0.01),
    frequencies=(0.5, 2.0),
    currents=(0.0, 0.5, 1.0),
    cycles=2.0,
    sample_rate=200.0,
)


def truth():
    return jaxmr.Dahl(
        k_x=jaxmr.LinearLaw(P(800.0), P(1500.0)),
        k_w=jaxmr.LinearLaw(P(200.0), P(600.0)),
        rho=P(300.0),
    )


@pytest.fixture(scope="module")
def menu():
    return jaxmr.sine_grid(**MENU)


@pytest.fixture(scope="module")
def design(menu):
    return jaxmr.design_experiments(truth(), menu, 3)


def test_sine_grid(menu):
    assert len(menu) == 12 and all(e.force is None for e in menu)
    e = menu[-1]  # 10 mm, 2 Hz, 1 A
    assert e.name == "sine_10mm_2Hz_1A"
    t = np.asarray(e.t)
    # The motion and its velocity are the sine's own (the velocity is not a finite
    # difference: 1e-12 is rounding).
    np.testing.assert_allclose(e.x, 0.01 * np.sin(4 * np.pi * t), atol=1e-12)
    np.testing.assert_allclose(e.v, 0.04 * np.pi * np.cos(4 * np.pi * t), atol=1e-12)
    np.testing.assert_allclose(e.duration, 1.0)
    np.testing.assert_allclose(e.current, 1.0)


def test_d_optimal_plan_is_the_best_of_all_plans(design):
    """Greedy choice and exchanges find the plan that brute force over all
    C(12, 3) = 220 plans finds, from the design's own per-test information."""
    plans = list(itertools.combinations(range(12), 3))
    log_dets = np.array([design.log_det_of(plan) for plan in plans])
    best = plans[int(np.argmax(log_dets))]
    assert design.indices == best
    # Not every plan is good: the best is well above the median one (a test that
    # compared with a flat landscape would prove nothing).
    assert design.log_det > np.median(log_dets) + 1.0
    np.testing.assert_allclose(design.log_det, log_dets.max(), rtol=1e-12)
    # Each contribution is the log det lost without that test.
    for index, drop in zip(design.indices, design.contributions):
        rest = [k for k in design.indices if k != index]
        np.testing.assert_allclose(drop, design.log_det - design.log_det_of(rest))


def test_a_optimal_plan_is_the_best_of_all_plans(menu, design):
    names = (".k_w.b", ".rho")
    a = jaxmr.design_experiments(truth(), menu, 3, parameters=names)
    named = np.isin(design.names, names)

    def criterion(plan):
        return np.sum((design.std_errors_of(plan)[named] / design.values[named]) ** 2)

    plans = list(itertools.combinations(range(12), 3))
    values = np.array([criterion(plan) for plan in plans])
    assert a.criterion == "A" and a.parameters == names
    # rtol 1e-6: the design's criterion carries a ridge of 1e-9 (relative).
    np.testing.assert_allclose(criterion(a.indices), values.min(), rtol=1e-6)
    assert values.min() < 0.6 * np.median(values)


def test_i_optimal_plan_is_the_best_of_all_plans(menu, design):
    """I-optimality: the smallest tr(M_all M⁻¹), the predicted variance of the fitted
    (weighted) force summed over every candidate, against brute force."""
    i = jaxmr.design_experiments(truth(), menu, 3, criterion="I")
    total = design.information.sum(axis=0)

    def criterion(plan):
        M = design.information_of(plan)
        if np.linalg.matrix_rank(M) < M.shape[0]:
            return np.inf  # a plan that leaves a parameter undetermined
        return np.trace(total @ np.linalg.inv(M))

    plans = list(itertools.combinations(range(12), 3))
    values = np.array([criterion(plan) for plan in plans])
    assert i.criterion == "I" and "I-optimal" in str(i)
    # rtol 1e-6: the design's criterion carries a ridge of 1e-9 (relative).
    np.testing.assert_allclose(criterion(i.indices), values.min(), rtol=1e-6)
    assert values.min() < 0.6 * np.median(values)


def test_exchange_repairs_the_greedy_choice():
    """Random rank-1 informations (one observation each; p = 4, 5 of 10 chosen): in
    8 of these 100 cases the greedy plan is not the best of the 252, and the exchanges
    then reach brute force's optimum (exchanges are a local search: the cases are
    fixed by their seeds)."""
    from jaxmr._identify.design import _choose, _objective

    plans = np.array(list(itertools.combinations(range(10), 5)))
    suboptimal = repaired = 0
    for seed in range(100):
        rng = np.random.default_rng(seed)
        rows = rng.normal(size=(10, 4)) * rng.uniform(0.2, 2.0, size=(10, 1))
        information = rows[:, :, None] * rows[:, None, :]
        plan, greedy, swaps = _choose(
            information, np.zeros((4, 4)), 5, _objective(4, None)
        )
        optimum = np.linalg.slogdet(information[plans].sum(1))[1].max()
        found = np.linalg.slogdet(information[plan].sum(0))[1]
        first = np.linalg.slogdet(information[greedy].sum(0))[1]
        assert found >= first and (swaps > 0) == (plan != greedy)
        if first < optimum - 1e-9:
            suboptimal += 1
            repaired += found >= optimum - 1e-9
    assert suboptimal >= 5 and repaired == suboptimal


def test_predicted_standard_errors_match_a_fit(menu, design):
    """The design's standard errors are those `fit` reports after fitting the planned
    tests' data (white force noise of 5 N, `weighting="force"`)."""
    sigma = 5.0
    planned = jaxmr.design_experiments(truth(), menu, 4, weighting="force", noise=sigma)
    forces = jaxmr.predict_all(truth(), planned.plan)
    rng = np.random.default_rng(0)
    data = [
        jaxmr.data.Experiment(
            e.t, e.x, e.v, e.current, f + sigma * rng.normal(size=f.shape), name=e.name
        )
        for e, f in zip(planned.plan, forces)
    ]
    result = jaxmr.fit(
        truth(),
        data,
        weighting="force",
        progress=False,
        statistics_refinement=1,
    )
    assert result.names == planned.names
    # 10 %: the fit's s estimates σ from N ≈ 1300 residuals (relative spread
    # 1/sqrt(2N) ≈ 2 %), and its Jacobian is at the fitted, not the true, values
    # (they differ by about one standard error, < 1 % of each value here).
    np.testing.assert_allclose(result.std_errors, planned.std_errors, rtol=0.1)
    # The plan matters: the worst 4-test plan predicts at least 1.5 times larger
    # errors for some parameter, far outside that tolerance.
    worst = min(
        itertools.combinations(range(12), 4), key=lambda c: planned.log_det_of(c)
    )
    assert np.max(planned.std_errors_of(worst) / planned.std_errors) > 1.5
    # With all 12 tests no standard error is larger.
    assert np.all(planned.std_errors_all <= planned.std_errors * (1 + 1e-9))


def test_sequential_design_adds_the_tests_already_run(menu, design):
    """`already` counts the tests run so far: the next 2 tests are the best 2-test
    extension of them, by brute force over the menu (a test already run may be
    chosen again: a repeat adds its information once more)."""
    first = list(design.indices)
    more = jaxmr.design_experiments(truth(), menu, 2, already=[menu[k] for k in first])
    # The same information, computed with the tests packed differently (1e-9:
    # rounding of sums over a different lane layout).
    np.testing.assert_allclose(
        more.prior_information,
        design.information[first].sum(0),
        rtol=1e-9,
        atol=1e-9 * np.abs(design.information).max(),
    )
    best = max(
        itertools.combinations(range(12), 2),
        key=lambda c: design.log_det_of(first + list(c)),
    )
    assert more.indices == best
    np.testing.assert_allclose(more.log_det, design.log_det_of(first + list(best)))


class _Record:
    """A measured record that is not an `Experiment` (which refuses NaN)."""

    def __init__(self, e, force):
        self.t, self.x, self.v, self.current = e.t, e.x, e.v, e.current
        self.force, self.name = force, e.name


def test_design_never_reads_forces(menu, design):
    """Candidates whose forces are NaN, garbage or absent give the same design."""
    rng = np.random.default_rng(1)
    for fill in (np.nan, None):
        records = [
            _Record(
                e, rng.normal(size=len(e)) if fill is None else np.full(len(e), fill)
            )
            for e in menu
        ]
        again = jaxmr.design_experiments(truth(), records, 3)
        assert again.indices == design.indices
        np.testing.assert_array_equal(again.information, design.information)


def test_batches_give_the_same_information(menu, design):
    """`batch_size` (tests simulated 5 at a time, the batches padded to one shape under
    one compilation) changes nothing but the memory: the same per-test information to
    rounding (1e-9 relative, sums in another order)."""
    batched = jaxmr.design_experiments(truth(), menu, 3, batch_size=5)
    scale = np.abs(design.information).max()
    np.testing.assert_allclose(
        batched.information, design.information, rtol=1e-9, atol=1e-12 * scale
    )
    assert batched.indices == design.indices


def test_parameters_no_candidate_determines_are_named(menu):
    """Candidates at one current cannot tell a law's intercept from its slope: every
    plan is singular. Said, naming the parameters (the plan was written silently,
    its log det -inf)."""
    one_current = [e for e in menu if float(np.mean(e.current)) == 0.5]
    with pytest.warns(UserWarning, match=r"determines .*\.k_x\.a.*\.k_x\.b"):
        plan = jaxmr.design_experiments(truth(), one_current, 2)
    assert not np.all(np.isfinite(plan.std_errors_all))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a menu that determines them: no warning
        assert np.isfinite(jaxmr.design_experiments(truth(), menu, 3).log_det)


def test_arguments_are_checked(menu):
    with pytest.raises(ValueError, match="`k` must be an integer from 1 to"):
        jaxmr.design_experiments(truth(), menu, 13)
    with pytest.raises(ValueError, match="not among the model's free parameters"):
        jaxmr.design_experiments(truth(), menu, 2, parameters=".alpha")
    with pytest.raises(ValueError, match="`criterion` must be 'D', 'A' or 'I'"):
        jaxmr.design_experiments(truth(), menu, 2, criterion="E")
    with pytest.raises(ValueError, match="A-optimality needs `parameters`"):
        jaxmr.design_experiments(truth(), menu, 2, criterion="A")
    with pytest.raises(ValueError, match="one per test"):
        jaxmr.design_experiments(
            truth(), menu, 2, discard=[0.1] * 12, already=[menu[0]]
        )
    # At -1 A the linear laws turn negative: a test the model cannot run is named,
    # not planned (`jaxmr design` had planned it).
    reversed_current = jaxmr.sine_grid(**(MENU | dict(currents=(-1.0, 1.0))))
    with pytest.raises(ValueError, match="breaks its own constraints at the inputs"):
        jaxmr.design_experiments(truth(), reversed_current, 2)


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()


def test_cli_writes_the_plan_and_never_overwrites(tmp_path, design):
    """`jaxmr design` on a `jaxmr fit`-style parameter file (plain values, the fitted
    parameters named in its report): the plan table and one canonical CSV per test,
    the same plan as the function's; a second run refuses and changes nothing."""
    model = jaxmr.Dahl(
        k_x=jaxmr.LinearLaw(800.0, 1500.0),
        k_w=jaxmr.LinearLaw(200.0, 600.0),
        rho=300.0,
    )
    params = tmp_path / "params.json"
    report = [{"name": n} for n in design.names]
    # As `jaxmr fit` writes it: the parameters named in its report (a design of
    # such a file had failed: it read them at the top only).
    jaxmr.save_model(model, params, report={"parameters": report})
    out = tmp_path / "plan"
    argv = ["design", params, "-k", 3, "--out", out, "--discard", 0]
    argv += ["--amplitudes", *MENU["amplitudes"], "--frequencies", *MENU["frequencies"]]
    argv += ["--currents", *MENU["currents"], "--cycles", MENU["cycles"]]
    argv += ["--sample-rate", MENU["sample_rate"]]
    status, stdout, stderr = _run(argv)
    assert status == 0, stderr
    assert "jaxmr fit --starts 4" in stdout  # the fit it advises for the plan
    assert "--noise 1, white: scale them to your rig's noise" in stdout
    with open(out / "plan.csv", newline="") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    assert [r["test"] for r in rows] == [
        design.candidate_names[k] for k in design.indices
    ]
    for row, test in zip(rows, design.plan):
        written = jaxmr.data.read_csv(out / row["file"])
        assert written.force is None
        np.testing.assert_array_equal(written.x, test.x)
        np.testing.assert_array_equal(written.current, test.current)
        expected = (test.x.max() - test.x.min()) / 2, float(test.current[0])
        np.testing.assert_allclose(
            [float(row["amplitude"]), float(row["current"])], expected, rtol=1e-9
        )
        # The crossing-rate frequency of a sine of whole periods: exact to rounding.
        assert float(row["frequency"]) == pytest.approx(
            float(row["test"].split("_")[2][:-2]), rel=1e-9
        )
        assert float(row["duration"]) == pytest.approx(test.duration)
    # The predicted standard errors, as data: the function's, to the printed digits.
    with open(out / "errors.csv", newline="") as f:
        errors = list(csv.DictReader(line for line in f if not line.startswith("#")))
    assert [r["parameter"] for r in errors] == list(design.names)
    np.testing.assert_allclose(
        [float(r["std_error_plan"]) for r in errors], design.std_errors, rtol=1e-9
    )
    np.testing.assert_allclose(
        [float(r["std_error_all"]) for r in errors], design.std_errors_all, rtol=1e-9
    )
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    status, _, stderr = _run(argv)
    assert status == 1 and "never replaces a file" in stderr
    # A plan file absent but a test's file present: refused too, before writing.
    (out / "plan.csv").unlink()
    status, _, stderr = _run(argv)
    assert status == 1 and "already exist" in stderr
    assert not (out / "plan.csv").exists()
    after = {p.name: p.read_bytes() for p in out.iterdir()}
    assert after == {k: v for k, v in before.items() if k != "plan.csv"}
    # A plain model without a report cannot say what to design for.
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps(jaxmr.model_to_dict(model)))
    status, _, stderr = _run(argv[:1] + [bare] + argv[2:4] + ["--out", tmp_path / "x"])
    assert status == 1 and "no fit report" in stderr
    # A design refused after its folder was made (criterion A without parameters):
    # nothing is left behind (an empty folder was).
    refused = tmp_path / "refused"
    status, _, stderr = _run(
        argv[:4] + ["--out", refused, "--criterion", "A"] + argv[6:]
    )
    assert status == 1 and "criterion" in stderr and not refused.exists()
