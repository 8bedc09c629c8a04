"""`jaxmr fit`, `jaxmr predict` and `jaxmr report`, run in-process on small synthetic
CSV files: a Dahl damper at three currents, one 1 Hz cycle at 250 Hz, 0.5 % noise.

The fits compile once per data shape; the module fixture runs `fit --model auto`
first, whose refit on all three files compiles the shape that `fit --model dahl` then
reuses, to keep the file fast.
"""

import contextlib
import csv
import dataclasses
import errno
import importlib
import io
import json
import os
import re
import signal
import tempfile
import threading
import warnings
from pathlib import Path

import jax
import numpy as np
import pytest

import jaxmr
import jaxmr.data
import jaxmr.scores
from jaxmr._cli import fit as fit_command, main
from jaxmr._cli.fit import _FitLog
from jaxmr.templates import MODEL_TEMPLATES

CURRENTS = (0.0, 0.5, 1.0)  # A
AMPLITUDE, FREQUENCY, RATE = 0.01, 1.0, 250.0  # m, Hz, Hz
NOISE = 0.005  # of std(F)
# The truth: k_x = 800 + 1500 i N·s/m, k_w = 150 + 700 i N, rho = 800 1/m.
TRUTH = {".k_x.a": 800.0, ".k_x.b": 1500.0, ".k_w.a": 150.0, ".k_w.b": 700.0}
RHO = 800.0
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def dahl_under_sine(t, amplitude, frequency, k_x, k_w, rho):
    """The Dahl model's exact response to x = X sin(2πft) from z = 0: on each
    half-cycle of sign s, dz/dx = ρ(s - z), so z relaxes exponentially in x towards s."""
    w = 2 * np.pi * frequency
    x, v = amplitude * np.sin(w * t), amplitude * w * np.cos(w * t)
    # Half-cycle 0 is t < T/4 (s = +1); the reversals are at t = (1/4 + k/2) T.
    segment = np.floor((t * frequency - 0.25) / 0.5).astype(int) + 1
    z = np.zeros_like(t)
    x_start, z_start, s = 0.0, 0.0, 1.0
    for k in range(int(segment.max()) + 1):
        here = segment == k
        z[here] = s - (s - z_start) * np.exp(-rho * np.abs(x[here] - x_start))
        z_start = s - (s - z_start) * np.exp(-rho * abs(s * amplitude - x_start))
        x_start, s = s * amplitude, -s
    return x, v, k_x * v + k_w * z


def _experiment(current, rng, *, force=True, rotary=False, name=None):
    t = np.linspace(0.0, 1.0 / FREQUENCY, round(RATE / FREQUENCY) + 1)
    if rotary:  # the SAS brake's Dahl model, ±3.5°
        amplitude, k_x, k_w, rho = (
            np.deg2rad(3.5),
            0.001 + 0.001 * current,
            5.0 + 1.5 * current,
            5.0,
        )
    else:
        amplitude, rho = AMPLITUDE, RHO
        k_x = TRUTH[".k_x.a"] + TRUTH[".k_x.b"] * current
        k_w = TRUTH[".k_w.a"] + TRUTH[".k_w.b"] * current
    x, v, f = dahl_under_sine(t, amplitude, FREQUENCY, k_x, k_w, rho)
    if force:
        f = f + NOISE * np.std(f) * rng.standard_normal(f.shape)
    return jaxmr.data.Experiment(
        t,
        x,
        v,
        current,
        f if force else None,
        name=name or f"dahl_{current:g}A",
        rotary=rotary,
    )


def _run(argv):
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        status = main([str(a) for a in argv])
    return status, stdout.getvalue()


def _nrmse(predicted, measured):
    return np.sqrt(np.mean((predicted - measured) ** 2)) / np.std(measured)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    directory = tmp_path_factory.mktemp("data")
    rng = np.random.default_rng(0)
    paths = []
    for current in CURRENTS:
        path = directory / f"dahl_{current:g}A.csv"
        jaxmr.data.write_csv(_experiment(current, rng), path)
        paths.append(path)
    return paths


@pytest.fixture(scope="module")
def auto(files, tmp_path_factory):
    out = tmp_path_factory.mktemp("auto") / "auto.json"
    # A progress line every step (the output is not a terminal; by default every 10th,
    # and these fits stop within 5): `test_auto_prints_and_records_each_candidates_
    # stages` reads them.
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(fit_command, "PROGRESS_STEPS", 1)
        status, stdout = _run(
            ["fit", "--model", "auto", "--candidates", "bingham,dahl", "--out", out]
            + list(files)
        )
    return status, out, stdout


@pytest.fixture(scope="module")
def fitted(files, auto, tmp_path_factory):
    out = tmp_path_factory.mktemp("fit") / "params.json"
    status, stdout = _run(["fit", "--model", "dahl", "--out", out, *files])
    return status, out, stdout


def test_auto_selects_dahl(auto):
    status, out, stdout = auto
    assert status == 0
    data = json.loads(out.read_text())
    report = data["report"]
    assert report["template"] == "dahl"
    ranking = report["selection"]["ranking"]
    assert [r["template"] for r in ranking] == ["dahl", "bingham"]
    assert ranking[0]["median_test_nrmse"] < 0.02 < ranking[1]["median_test_nrmse"]
    # Two folds: the middle current held out, then the last third of every file; the
    # parsimony rule's decision as data.
    selection = report["selection"]
    assert selection["folds"][0].endswith(": dahl_0.5A")
    assert selection["folds"][1].startswith("held out the last 33%")
    assert selection["holdout"] == "; ".join(selection["folds"])
    rule = selection["parsimony"]
    assert rule["chosen"] == rule["best"] == "dahl"
    assert rule["num_records"] == 1 + 3
    assert [c["template"] for c in rule["candidates"]] == ["bingham", "dahl"]
    assert f"parsimony: {rule['reason']}" in stdout
    assert isinstance(jaxmr.load_model(out), jaxmr.Dahl)
    assert "rank  model" in stdout and "dahl: screened fit on 2 experiment(s)" in stdout


def test_fit_writes_model_and_report(fitted, files):
    status, out, stdout = fitted
    assert status == 0
    assert f"wrote {out}" in stdout and "NRMSE per experiment" in stdout
    model = jaxmr.load_model(out)
    assert isinstance(model, jaxmr.Dahl)
    report = json.loads(out.read_text())["report"]
    assert report["template"] == "dahl" and report["files"] == [str(f) for f in files]
    assert report["converged"] and not report["unidentified"]
    assert report["reason"]
    # Enough to rerun it: the options as given, the versions and the devices.
    assert report["settings"]["model"] == "dahl"
    assert report["settings"]["max_steps"] == 200 and report["settings"]["starts"] == 1
    environment = report["environment"]
    assert environment["jax"] == jax.__version__
    assert environment["jaxmr"] == jaxmr.__version__
    assert environment["devices"] == jax.device_count() >= 1
    # At the noise floor: NRMSE ≈ 0.005 in every file.
    for row in report["per_file"]:
        assert row["nrmse"] < 2 * NOISE, row
    # The parameters with their standard errors: within 5 standard errors of the truth.
    parameters = {p["name"]: p for p in report["parameters"]}
    assert set(parameters) == set(TRUTH) | {".rho"}
    for name, value in (TRUTH | {".rho": RHO}).items():
        p = parameters[name]
        assert abs(p["value"] - value) < 5 * p["std_error"] + 1e-3 * value, p
    # The covariance, for the prediction band: its diagonal is the squared errors
    # (1e-12: the same numbers through JSON's exact float text).
    covariance = report["covariance"]
    assert covariance["names"] == [p["name"] for p in report["parameters"]]
    np.testing.assert_allclose(
        np.sqrt(np.diag(np.asarray(covariance["matrix"], dtype=float))),
        [p["std_error"] for p in report["parameters"]],
        rtol=1e-12,
    )


@pytest.mark.parametrize(
    "model", [["--model", "dahl"], ["--model", "auto", "--candidates", "dahl"]]
)
def test_ctrl_c_writes_the_best_model_so_far(
    model, files, fitted, auto, tmp_path, monkeypatch, capsys
):
    """Ctrl-C (a real SIGINT) during the third Levenberg–Marquardt step: the fit
    stops after that step, the command writes the best model so far, says so, and
    exits 130. The shapes are the fixtures' (the same files and template), so
    nothing compiles again."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("Python handles signals in the main thread only")
    import jaxmr._identify.solver as solver

    step, calls = solver._step, []

    # One call per Levenberg–Marquardt step, the first made where the column scale
    # is measured (`solver.scale_and_first_step`: the step at the start with unit
    # scale, carried into the scaled variables).
    def interrupted(*args):
        calls.append(None)
        if len(calls) == 3:
            signal.raise_signal(signal.SIGINT)
        return step(*args)

    monkeypatch.setattr(solver, "_step", interrupted)
    out = tmp_path / "p.json"
    status, _ = _run(["fit", *model, "--out", out, *files])
    assert status == 130 and len(calls) == 3
    assert "interrupted; the best model so far is in" in capsys.readouterr().err
    report = json.loads(out.read_text())["report"]
    assert report["interrupted"] and report["stop"] == "interrupted"
    assert report["num_steps"] == 3 and "interrupted at step 3" in report["reason"]
    # Kept: the best point of two steps, better than the template's start.
    experiments = [jaxmr.data.read_csv(f) for f in files]
    start = MODEL_TEMPLATES["dahl"](experiments)
    kept = jaxmr.record_nrmse(jaxmr.load_model(out), experiments)
    assert np.median(kept) < np.median(jaxmr.record_nrmse(start, experiments))


def test_predict(fitted, files, tmp_path, capsys):
    _, params, _ = fitted
    out = tmp_path / "pred.csv"
    status, stdout = _run(["predict", params, files[1], "--out", out])
    assert status == 0 and f"wrote {out}" in stdout and "NRMSE" in stdout
    header = [
        line for line in out.read_text().splitlines() if not line.startswith("#")
    ][0]
    assert header == "t,x,v,i,F,F_measured,F_std,F_lower,F_upper"
    # Still a canonical CSV: `read_csv` reads past the measured force's and the
    # band's columns.
    predicted, measured = jaxmr.data.read_csv(out), jaxmr.data.read_csv(files[1])
    for key in ("t", "x", "v", "current"):
        np.testing.assert_array_equal(getattr(predicted, key), getattr(measured, key))
    assert _nrmse(np.asarray(predicted.force), np.asarray(measured.force)) < 2 * NOISE
    band = _columns(out)
    # The measured force beside the prediction, to the bit (shortest exact form).
    np.testing.assert_array_equal(band["F_measured"], np.asarray(measured.force))
    assert "F_measured: the force measured in" in out.read_text()
    assert np.all(band["F_std"] > 0)
    assert np.all((band["F_lower"] < band["F"]) & (band["F"] < band["F_upper"]))
    # A well-determined fit: the band is far narrower than the noise (0.5 % of std F).
    assert np.max(band["F_upper"] - band["F_lower"]) < NOISE * np.std(band["F"])
    # ... and the record's error is the noise: said on the terminal and in the file,
    # so that the band's edges are not read as bounds on the measurement.
    note = "the band holds the parameters' uncertainty only"
    assert note in stdout and note in out.read_text()
    assert predicted.smoothing == 0.0 and "moving average" not in stdout
    # A prediction through a moving average says so: on the terminal, in its '# F:'
    # line and in its own '# smoothing:' line (it had read 0).
    smoothed = tmp_path / "smoothed.csv"
    status, stdout = _run(
        ["predict", params, files[1], "--out", smoothed, "--smoothing", "0.01"]
    )
    assert status == 0 and "0.01 s moving average" in stdout
    assert jaxmr.data.read_csv(smoothed).smoothing == 0.01
    (line,) = [x for x in smoothed.read_text().splitlines() if x.startswith("# F:")]
    assert "0.01 s moving average" in line
    # A prediction is not a measurement: `jaxmr fit` refuses to fit a model to it
    # (it had fitted without a word), naming the file; nothing is written.
    refit = tmp_path / "refit.json"
    capsys.readouterr()
    err = _error(["fit", "--model", "dahl", "--out", refit, out], capsys)
    assert f"the force of {out} was predicted by jaxmr" in err and not refit.exists()


def test_a_fit_saved_from_python_reads_as_the_command_lines(
    dahl_fit, files, fitted, tmp_path, capsys
):
    """`jaxmr.save_fit` writes what `jaxmr fit` writes: the same report entries,
    a fitted range, and a `jaxmr report` that knows the fitted experiments by their
    numbers (here written to new files under other names) and draws their band;
    it never writes over a file unless told."""
    experiments = [jaxmr.data.read_csv(f) for f in files]
    params = tmp_path / "api.json"
    jaxmr.save_fit(dahl_fit, experiments, params)
    saved = json.loads(params.read_text())
    from_cli = json.loads(fitted[1].read_text())
    cli_only = {"fit_time_s", "warnings", "settings"}
    assert set(saved["report"]) == set(from_cli["report"]) - cli_only
    assert saved["report"]["files"] == [None] * len(files)
    assert jaxmr.load_model(params).fitted_range is not None
    copies = []
    for k, e in enumerate(experiments):
        copies.append(tmp_path / f"copy_{k}.csv")
        jaxmr.data.write_csv(e, copies[-1])
    status, _ = _run(["report", params, *copies, "--out", tmp_path / "rep"])
    assert status == 0
    with open(tmp_path / "rep" / "report.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["data"] for r in rows] == ["fitted"] * len(files)
    assert all(float(r["band_halfwidth_N"]) > 0 for r in rows)
    with pytest.raises(FileExistsError, match="overwrite=True"):
        jaxmr.save_fit(dahl_fit, experiments, params)
    jaxmr.save_fit(dahl_fit, experiments, params, overwrite=True, note="again")
    assert json.loads(params.read_text())["report"]["note"] == "again"
    with pytest.raises(ValueError, match="give the experiments it was fitted on"):
        jaxmr.save_fit(dahl_fit, experiments[:1], tmp_path / "x.json")


@pytest.mark.parametrize(
    "width, words",
    [
        (0.4, "well determined"),
        (0.6, "part of the error"),
        (1.5, "accounts for much"),
    ],
)
def test_the_band_verdict_has_three_levels(width, words):
    """The band's median half-width against the median RMSE: two nearly equal
    shares (48 % and 62 % in a user's report) no longer get opposite advice."""
    from jaxmr._cli.report import FITTED, _band_markdown

    # (file, experiment, status, input, discard, rmse, nrmse, band half-width)
    rows = [("a.csv", "a", FITTED, 0.0, 0.0, 1.0, 0.1, width)]
    text = "\n".join(_band_markdown(rows, 0.95, "N", None))
    assert words in text


def _columns(path) -> dict[str, np.ndarray]:
    """A CSV's columns by name (the band's too)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    return {
        name: np.array([float(r[k]) for r in rows[1:]])
        for k, name in enumerate(rows[0])
    }


def test_the_band_is_the_librarys(dahl_fit, files, tmp_path):
    """`predict` writes `jaxmr.prediction_band`'s numbers for a model saved as
    `jaxmr fit` saves it (its covariance in the report), at the level asked for; and
    the library's band is the first-order propagation of the covariance (central
    differences of `predict_all`) centred on `predict_all`'s force, also for an
    experiment that has a measured force."""
    from jaxmr._cli.fit import _fit_report

    experiments = [jaxmr.data.read_csv(f) for f in files]
    params = tmp_path / "p.json"
    report = _fit_report("dahl", files, experiments, dahl_fit, 1.0, None, [])
    jaxmr.save_model(dahl_fit.model, params, report=report)
    out = tmp_path / "pred.csv"
    status, _ = _run(["predict", params, files[2], "--out", out, "--band-level", "0.9"])
    assert status == 0
    (band,) = jaxmr.prediction_band(dahl_fit, experiments[2:], level=0.9)
    written = _columns(out)
    # The same computation through a JSON round trip (exact float text): to rounding.
    for name, column in band.columns().items():
        np.testing.assert_allclose(
            written[name.replace("_pred", "")], column, rtol=1e-9
        )
    (predicted,) = jaxmr.predict_all(dahl_fit.model, experiments[2:])
    np.testing.assert_allclose(band.force, predicted, rtol=1e-12)
    # z for 90 %: 1.6449.
    np.testing.assert_allclose(band.upper - band.force, 1.6448536 * band.std, rtol=1e-6)
    # gᵀΣg with g by central differences of relative step 1e-6 (truncation ~1e-12,
    # rounding ~1e-10 of the force): the std to 1e-5.
    leaves, treedef = jax.tree.flatten(dahl_fit.model)
    paths = [
        jax.tree_util.keystr(p)
        for p, _ in jax.tree_util.tree_flatten_with_path(dahl_fit.model)[0]
    ]
    gradient = []
    for name, value in zip(dahl_fit.names, dahl_fit.values):
        k, h = paths.index(name), 1e-6 * abs(value)
        shifted = []
        for sign in (1, -1):
            moved = list(leaves)
            moved[k] = value + sign * h
            (f,) = jaxmr.predict_all(
                jax.tree.unflatten(treedef, moved), experiments[2:]
            )
            shifted.append(np.asarray(f))
        gradient.append((shifted[0] - shifted[1]) / (2 * h))
    g = np.stack(gradient, axis=1)
    std = np.sqrt(np.einsum("ki,ij,kj->k", g, dahl_fit.covariance, g))
    np.testing.assert_allclose(band.std, std, rtol=1e-5)


def test_no_band_without_the_fits_covariance(fitted, files, tmp_path):
    """A parameter file of an older `jaxmr fit` (no covariance): `predict` writes the
    force without band columns and says why once; `report` draws no band and says
    why in report.md, where a file with the covariance has both."""
    import matplotlib.image

    _, params, _ = fitted
    data = json.loads(params.read_text())
    del data["report"]["covariance"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(data))
    out = tmp_path / "pred.csv"
    status, stdout = _run(["predict", old, files[0], "--out", out])
    assert status == 0
    # The measured force beside the prediction, and no band columns.
    assert list(_columns(out)) == ["t", "x", "v", "i", "F", "F_measured"]
    assert stdout.count("no prediction band") == 1
    assert "holds no covariance of the fitted parameters" in stdout
    images = []
    for name, source in (("old", old), ("new", params)):
        status, _ = _run(["report", source, files[0], "--out", tmp_path / name])
        assert status == 0
        markdown = (tmp_path / name / "report.md").read_text()
        with open(tmp_path / name / "report.csv", newline="") as f:
            (row,) = list(csv.DictReader(f))
        if name == "old":
            assert "No prediction band: it holds no covariance" in markdown
            assert row["band_halfwidth_N"] == ""
        else:
            assert "95% prediction band" in markdown and "band ± [N]" in markdown
            # Well determined (see `test_predict`): far narrower than the error.
            width = float(row["band_halfwidth_N"])
            assert 0 < width < 0.5 * float(row["rmse_N"])
            assert "the parameters are well determined for these inputs" in markdown
        images.append(matplotlib.image.imread(tmp_path / name / f"{files[0].stem}.png"))
    # The band drawn (its legend entry at least: it is thinner than a pixel here).
    assert images[0].shape == images[1].shape and np.any(images[0] != images[1])


def test_predict_rotary_without_force(tmp_path):
    """A brake (theta, omega, i; no torque column): the output names the torque T."""
    params = tmp_path / "brake.json"
    jaxmr.save_model(jaxmr.sas_brake_dahl(), params)
    data = tmp_path / "brake.csv"
    truth = _experiment(0.5, None, force=False, rotary=True, name="brake")
    jaxmr.data.write_csv(truth, data)
    out = tmp_path / "pred.csv"
    status, _ = _run(["predict", params, data, "--out", out])
    assert status == 0
    predicted = jaxmr.data.read_csv(out)
    assert predicted.rotary and predicted.name == "brake"
    _, _, exact = dahl_under_sine(
        np.asarray(truth.t), np.deg2rad(3.5), FREQUENCY, 0.0015, 5.75, 5.0
    )
    # RK4 at 0.5 ms against the exact solution.
    np.testing.assert_allclose(predicted.force, exact, atol=1e-6 * np.ptp(exact))


def test_report(fitted, files, tmp_path):
    import matplotlib.image

    _, params, _ = fitted
    out = tmp_path / "report"
    status, stdout = _run(["report", params, *files, "--out", out])
    assert status == 0
    for f in files:
        image_path = out / f"{f.stem}.png"
        assert image_path.read_bytes().startswith(PNG_SIGNATURE)
        assert np.ptp(matplotlib.image.imread(image_path)) > 0
    with open(out / "report.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["experiment"] for r in rows] == [f.stem for f in files]
    assert all(float(r["nrmse"]) < 2 * NOISE for r in rows)
    markdown = (out / "report.md").read_text()
    assert "| .k_w.b |" in markdown
    assert "Fit: converged" in markdown or "Fit: stalled" in markdown
    assert markdown.count("| dahl_") == 3
    assert "Median NRMSE" in stdout
    # The relative error is against the size the fit's warnings use, saved with each
    # parameter (`magnitude`), and marked where that is not the value.
    data = json.loads(params.read_text())
    (row,) = [p for p in data["report"]["parameters"] if p["name"] == ".k_w.b"]
    assert row["magnitude"] == abs(row["value"])  # a well-determined slope
    row["magnitude"] = 100 * abs(row["value"])
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data))
    _run(["report", edited, *files, "--out", tmp_path / "again"])
    markdown = (tmp_path / "again" / "report.md").read_text()
    (line,) = [x for x in markdown.splitlines() if x.startswith("| .k_w.b |")]
    relative = 100 * row["std_error"] / row["magnitude"]
    assert line.endswith(f"| {relative:.1f}%* |"), line
    assert "a small effect, not a poorly determined one" in markdown


def _error(argv, capsys) -> str:
    assert main([str(a) for a in argv]) == 1
    return capsys.readouterr().err


def test_errors(files, tmp_path, capsys):
    out = tmp_path / "p.json"
    err = _error(["fit", "--model", "spring", "--out", out, *files], capsys)
    assert "unknown model 'spring'" in err
    for name in MODEL_TEMPLATES:
        assert name in err
    err = _error(
        ["fit", "--model", "auto", "--candidates", "dahl,spring", "--out", out, *files],
        capsys,
    )
    assert "'spring'" in err
    missing = tmp_path / "missing.csv"
    err = _error(["fit", "--model", "dahl", "--out", out, missing], capsys)
    assert f"{missing}: no such file" in err
    bad = tmp_path / "bad.csv"
    bad.write_text("time,x,i,F\n0,0,0,0\n")
    err = _error(["fit", "--model", "dahl", "--out", out, bad], capsys)
    # The data layer's message, with its hint.
    assert "jaxmr fit: error:" in err and "'time' (did you mean 't'?)" in err
    no_force = tmp_path / "no_force.csv"
    jaxmr.data.write_csv(_experiment(0.0, None, force=False), no_force)
    err = _error(["fit", "--model", "dahl", "--out", out, no_force], capsys)
    assert "no measured force (column `F`)" in err
    err = _error(
        ["fit", "--model", "dahl", "--out", tmp_path / "no" / "p.json", *files], capsys
    )
    assert "does not exist" in err
    assert not out.exists()
    err = _error(
        ["predict", tmp_path / "none.json", files[0], "--out", tmp_path / "x.csv"],
        capsys,
    )
    assert "none.json: no such file" in err
    not_json = tmp_path / "not.json"
    not_json.write_text("{")
    err = _error(["report", not_json, *files, "--out", tmp_path / "r"], capsys)
    assert "not a JSON parameter file" in err


def test_fit_refuses_options_that_would_change_nothing(files, tmp_path, capsys):
    """The same file twice (it would count twice, its errors shrinking by √2), and
    auto's options with one model, are refused before any fit, naming them."""
    out = tmp_path / "p.json"
    twice = ["fit", "--model", "dahl", "--out", out, files[0], files[1]]
    err = _error(
        [*twice, files[0].parent / ".." / files[0].parent.name / files[0].name], capsys
    )
    assert "is given twice" in err
    err = _error(
        ["fit", "--model", "dahl", "--holdout", files[0], "--finalists", "2"]
        + ["--out", out, *files],
        capsys,
    )
    assert "--holdout, --finalists: only with --model auto" in err
    assert not out.exists()


def test_processing_longer_than_a_record_is_an_error(fitted, files, tmp_path, capsys):
    """A discarded start or smoothing longer than the record: one line naming the
    option and both durations, from every command (it had been a traceback from
    `predict` and `report`, and a fit to a flattened force from `fit`)."""
    _, params, _ = fitted
    err = _error(
        ["predict", params, files[0], "--out", tmp_path / "p.csv", "--discard", "100"],
        capsys,
    )
    assert "jaxmr predict: error: --discard:" in err and "leaves no sample" in err
    err = _error(
        ["fit", "--model", "dahl", "--smoothing", "100", "--out", tmp_path / "f.json"]
        + list(files),
        capsys,
    )
    assert "--smoothing:" in err and "wider than the record" in err
    long_discard = tmp_path / "long.csv"
    text = files[0].read_text()
    long_discard.write_text("# discard: 10 s\n" + text)
    err = _error(["report", params, long_discard, "--out", tmp_path / "r"], capsys)
    assert "jaxmr report: error:" in err and "leaves no sample" in err


def test_predict_and_report_check_the_files_device(fitted, files, tmp_path, capsys):
    """A model fitted to a damper driven by current refuses a brake's file and a file
    driven by voltage (read in the other units, its answer looked plausible), names
    a file beyond the fitted range (printed and in the written file), and says when
    the measured force is itself a jaxmr prediction."""
    _, params, _ = fitted
    brake = tmp_path / "brake.csv"
    jaxmr.data.write_csv(_experiment(0.5, None, force=False, rotary=True), brake)
    err = _error(["predict", params, brake, "--out", tmp_path / "b.csv"], capsys)
    assert "is a rotary device driven by current, but the model of" in err
    assert "fitted to a linear device driven by current" in err
    measured = jaxmr.data.read_csv(files[1])
    voltage = tmp_path / "voltage.csv"
    jaxmr.data.write_csv(dataclasses.replace(measured, drive="voltage"), voltage)
    err = _error(["report", params, voltage, "--out", tmp_path / "r"], capsys)
    assert "is a linear device driven by voltage" in err
    # Within the range: no warning. At 2 A: said, and written into the file.
    inside = tmp_path / "inside.csv"
    assert main(["predict", str(params), str(files[1]), "--out", str(inside)]) == 0
    assert "beyond the range" not in capsys.readouterr().err
    far = tmp_path / "far.csv"
    jaxmr.data.write_csv(
        dataclasses.replace(measured, current=np.full(len(measured), 2.0)), far
    )
    out = tmp_path / "far_pred.csv"
    assert main(["predict", str(params), str(far), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "jaxmr predict: warning: " in err and "lies beyond the range" in err
    assert "current spans [2, 2] A, the fitted range [0, 1] A" in err
    assert (
        "# warning: " in out.read_text() and "lies beyond the range" in out.read_text()
    )
    # Its own output as the measurement: said.
    assert (
        main(
            ["predict", str(params), str(inside), "--out", str(tmp_path / "again.csv")]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "the F column of" in err and "was predicted by jaxmr" in err


def test_fit_warns_when_no_file_reverses(files, tmp_path, capsys):
    """Records that never reverse the velocity show no hysteresis loop: `fit` says so
    (and records it in its report); a record that reverses raises no such warning."""
    t = np.linspace(0.0, 0.2, 101)
    one_way = jaxmr.data.Experiment.from_arrays(
        t,
        0.05 * t,
        current=0.0,
        force=500.0 + 2000.0 * 0.05 + 0.1 * np.sin(40 * t),
        name="ramp",
    )
    path = tmp_path / "ramp.csv"
    jaxmr.data.write_csv(one_way, path)
    out = tmp_path / "p.json"
    status, _ = _run(
        ["fit", "--model", "bingham", "--max-steps", "2", "--out", out, path]
    )
    assert status == 0
    err = capsys.readouterr().err
    assert "no file reverses its velocity" in err
    assert any(
        "no file reverses" in w
        for w in json.loads(out.read_text())["report"]["warnings"]
    )
    assert not fit_command._reverses(one_way)
    assert fit_command._reverses(jaxmr.data.read_csv(files[0]))


# ---------------------------------------------------------------------------------------
# Files: no command writes over its inputs, an existing output is replaced only with
# --force, and every file is written whole or not at all.


def _listing(directory):
    return sorted(p.name for p in directory.iterdir())


def _copies(files, directory):
    copies = [directory / f.name for f in files]
    for f, copy in zip(files, copies):
        copy.write_bytes(f.read_bytes())
    return copies


def test_predict_refuses_to_write_over_its_inputs(fitted, files, tmp_path, capsys):
    """`predict --out` the measured file (or a link to it, or the parameter file) is
    refused, with or without --force, and the inputs are unchanged byte for byte."""
    _, params, _ = fitted
    (data,) = _copies(files[1:2], tmp_path)
    link = tmp_path / "link.csv"
    link.symlink_to(data)
    before = data.read_bytes(), params.read_bytes()
    for out in (data, link, params):
        for force in ([], ["--force"]):
            err = _error(["predict", params, data, "--out", out, *force], capsys)
            assert "would write over the input file" in err, err
            assert "even with --force" in err
    assert (data.read_bytes(), params.read_bytes()) == before
    assert _listing(tmp_path) == ["dahl_0.5A.csv", "link.csv"]


def test_fit_refuses_to_write_over_an_input(files, tmp_path, capsys):
    """Refused before anything is fitted, also through `..` and for a held-out file."""
    data = _copies(files, tmp_path)
    before = [f.read_bytes() for f in data]
    roundabout = tmp_path / ".." / tmp_path.name / data[2].name
    for force in ([], ["--force"]):
        err = _error(
            ["fit", "--model", "dahl", "--out", data[0], *force, *data], capsys
        )
        assert f"would write over the input file {str(data[0])!r}" in err
        err = _error(
            ["fit", "--holdout", data[2], "--out", roundabout, *force, *data], capsys
        )
        assert "would write over the input file" in err
    assert [f.read_bytes() for f in data] == before


def test_report_refuses_an_input_in_its_directory(fitted, files, tmp_path, capsys):
    """`report --out DIR` where DIR holds an input that one of its figures (a data
    file named run.png gives the figure run.png) or tables (report.csv) would replace:
    refused before anything is written, with or without --force."""
    _, params, _ = fitted
    directory = tmp_path / "d"
    directory.mkdir()
    for name in ("run.png", "report.csv"):
        data = directory / name
        data.write_bytes(files[0].read_bytes())
        for force in ([], ["--force"]):
            err = _error(
                ["report", params, data, files[1], "--out", directory, *force], capsys
            )
            assert f"would write over the input file {str(data)!r}" in err
        assert data.read_bytes() == files[0].read_bytes()
        data.unlink()
        assert _listing(directory) == []


def test_an_existing_output_needs_force(fitted, files, tmp_path, capsys):
    """An existing file that is not an input: refused, unchanged, without --force;
    replaced with it, and the command says so."""
    _, params, _ = fitted
    out = tmp_path / "old.csv"
    out.write_text("precious\n")
    err = _error(["predict", params, files[1], "--out", out], capsys)
    assert f"{str(out)!r} already exists: pass --force" in err
    assert out.read_text() == "precious\n"
    status, stdout = _run(["predict", params, files[1], "--out", out, "--force"])
    assert status == 0 and f"wrote {out} (replaced the existing file)" in stdout
    assert jaxmr.data.read_csv(out).force is not None

    old = tmp_path / "old.json"
    old.write_text("{}")
    err = _error(["fit", "--model", "dahl", "--out", old, *files], capsys)
    assert "already exists: pass --force" in err and old.read_text() == "{}"
    status, stdout = _run(["fit", "--model", "dahl", "--out", old, "--force", *files])
    assert status == 0 and f"wrote {old} (replaced the existing file)" in stdout
    assert isinstance(jaxmr.load_model(old), jaxmr.Dahl)

    directory = tmp_path / "report"
    directory.mkdir()
    (directory / "report.md").write_text("mine")
    err = _error(["report", params, files[0], "--out", directory], capsys)
    assert f"{str(directory / 'report.md')!r} already exists: pass --force" in err
    assert _listing(directory) == ["report.md"]
    assert (directory / "report.md").read_text() == "mine"


def test_predict_constant_force(fitted, tmp_path):
    """A measured force that does not vary: the RMSE is printed, the NRMSE (RMSE/std)
    is said to be undefined, and the prediction is written."""
    _, params, _ = fitted
    e = _experiment(0.5, None, force=False)
    data = tmp_path / "constant.csv"
    jaxmr.data.write_csv(
        jaxmr.data.Experiment(e.t, e.x, e.v, 0.5, np.full(len(e), 120.0)), data
    )
    out = tmp_path / "pred.csv"
    status, stdout = _run(["predict", params, data, "--out", out])
    assert status == 0 and f"wrote {out}" in stdout
    assert f"{data}: RMSE " in stdout and "NRMSE undefined" in stdout
    assert "constant" in stdout and "NRMSE inf" not in stdout
    assert jaxmr.data.read_csv(out).force is not None


def _full_disk(path):
    """Write half a file at `path`, then fail as a full disk does."""
    Path(path).write_text("t,x,v,i,F\n0,0,")
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_failed_write_leaves_no_partial_file(
    fitted, files, tmp_path, monkeypatch, capsys
):
    """A disk that fills up while the prediction is written: an error naming the file,
    the file replaced (--force) left as it was, a new one not created, no temporary
    file left."""
    _, params, _ = fitted
    monkeypatch.setattr(jaxmr.data, "write_csv", lambda e, path, **_: _full_disk(path))
    out = tmp_path / "pred.csv"
    out.write_text("old\n")
    err = _error(["predict", params, files[1], "--out", out, "--force"], capsys)
    assert f"cannot write {str(out)!r}: {os.strerror(errno.ENOSPC)}" in err
    assert out.read_text() == "old\n" and _listing(tmp_path) == ["pred.csv"]
    out.unlink()
    _error(["predict", params, files[1], "--out", out], capsys)
    assert _listing(tmp_path) == []


def test_fit_that_cannot_write_saves_the_model_elsewhere(
    files, fitted, tmp_path, monkeypatch, capsys
):
    """The parameter file cannot be written after the fit (a full disk): nothing is
    left beside it, the model is saved in the temporary directory and the error names
    that file."""
    rescue = tmp_path / "tmp"
    rescue.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(rescue))
    directory = tmp_path / "out"
    directory.mkdir()
    save = jaxmr.save_model

    def save_model(model, path, **extra):
        if Path(path).parent == directory:
            _full_disk(path)
        save(model, path, **extra)

    monkeypatch.setattr(jaxmr, "save_model", save_model)
    out = directory / "p.json"
    err = _error(["fit", "--model", "dahl", "--out", out, *files], capsys)
    (rescued,) = rescue.iterdir()
    assert f"cannot write {str(out)!r}: {os.strerror(errno.ENOSPC)}" in err
    assert f"the model was saved to {rescued} instead" in err
    assert isinstance(jaxmr.load_model(rescued), jaxmr.Dahl)
    assert json.loads(rescued.read_text())["report"]["template"] == "dahl"
    assert _listing(directory) == []


@pytest.mark.parametrize(
    ("first", "second"),
    [("fit", "signal"), ("fit", "raise"), (None, "signal")],
)
def test_second_ctrl_c_while_saving(
    first, second, files, fitted, tmp_path, monkeypatch, capsys
):
    """A Ctrl-C (a real SIGINT) stops the fit at its third step (`first="fit"`), or
    the fit ends; then a Ctrl-C comes while the model is written: a SIGINT, which the
    command defers, or a `KeyboardInterrupt` raised in the write itself, which is then
    made again. No traceback: the model is written whole and the command exits 130."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("Python handles signals in the main thread only")
    import jaxmr._identify.solver as solver

    step, steps, saves = solver._step, [], []

    def interrupted_step(*args):
        steps.append(None)
        if len(steps) == 3:  # the fit's third step (see above)
            signal.raise_signal(signal.SIGINT)
        return step(*args)

    save = jaxmr.save_model

    def interrupted_save(model, path, **extra):
        saves.append(path)
        if len(saves) == 1:
            if second == "signal":
                signal.raise_signal(signal.SIGINT)
            else:
                raise KeyboardInterrupt
        save(model, path, **extra)

    if first == "fit":
        monkeypatch.setattr(solver, "_step", interrupted_step)
    monkeypatch.setattr(jaxmr, "save_model", interrupted_save)
    handler = signal.getsignal(signal.SIGINT)
    out = tmp_path / "p.json"
    try:
        status, _ = _run(["fit", "--model", "dahl", "--out", out, *files])
    except KeyboardInterrupt:
        pytest.fail("the second Ctrl-C escaped `jaxmr fit`")
    assert status == 130
    assert signal.getsignal(signal.SIGINT) is handler  # restored
    err = capsys.readouterr().err
    if first == "fit":
        assert f"interrupted; the best model so far is in {out}" in err
    else:
        assert f"interrupted while finishing; the fitted model is in {out}" in err
    report = json.loads(out.read_text())["report"]
    assert report["interrupted"] == (first == "fit")
    assert isinstance(jaxmr.load_model(out), jaxmr.Dahl)
    assert _listing(tmp_path) == ["p.json"]


def _from_jax(function):
    """`function`, called from a frame of a module named `jax.…` (as when XLA's
    compiler polls for Ctrl-C)."""
    namespace = {"__name__": "jax._polls_for_ctrl_c", "function": function}
    exec("def call(*args):\n    return function(*args)\n", namespace)
    return namespace["call"]


@pytest.mark.parametrize("where", ["jax", "jaxmr"])
def test_ctrl_c_while_the_fit_computes_its_report(
    where, files, fitted, tmp_path, monkeypatch, capsys
):
    """A first Ctrl-C after the fit's loop, while `fit` computes its statistics (in
    JAX, or in jaxmr's own code): not raised there, where it lost the model (and,
    raised through XLA's compiler, crashed the process at exit); the fit completes,
    its model is written and the command exits 130."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("Python handles signals in the main thread only")
    fit_module = importlib.import_module("jaxmr._identify.fitting")
    report = fit_module._report
    ctrl_c = signal.raise_signal
    if where == "jax":
        ctrl_c = _from_jax(ctrl_c)

    def interrupted(*args, **kwargs):
        ctrl_c(signal.SIGINT)
        return report(*args, **kwargs)

    monkeypatch.setattr(fit_module, "_report", interrupted)
    out = tmp_path / "p.json"
    try:
        status, _ = _run(["fit", "--model", "dahl", "--out", out, *files])
    except KeyboardInterrupt:
        pytest.fail("the Ctrl-C escaped `jaxmr fit`")
    assert status == 130
    err = capsys.readouterr().err
    assert "Ctrl-C: stopping at the fit's next step" in err
    assert f"interrupted while finishing; the fitted model is in {out}" in err
    assert not json.loads(out.read_text())["report"]["interrupted"]
    assert isinstance(jaxmr.load_model(out), jaxmr.Dahl)


# ---------------------------------------------------------------------------------------
# What `jaxmr fit` prints, and what its report records


@pytest.fixture(scope="module")
def dahl_fit():
    """A real `FitResult` of the files' data (2 steps: its words are what is tested)."""
    rng = np.random.default_rng(0)
    experiments = [_experiment(c, rng) for c in CURRENTS]
    model = MODEL_TEMPLATES["dahl"](experiments)
    return jaxmr.fit(
        model, experiments, max_steps=2, progress=False, statistics_refinement=1
    )


def _as(result, stop, unidentified=(), steps=25):
    return dataclasses.replace(
        result, stop=stop, unidentified=unidentified, num_steps=steps
    )


def test_outcome_words_follow_converged(dahl_fit):
    """A fit that stopped on stalled progress at the noise floor has converged (its
    report says `"converged": true`): the words say so, not "stalled"; the summary,
    the ranking and the report all use `FitResult.outcome`."""
    stop = jaxmr.StopReason
    stalled = _as(dahl_fit, stop.STALLED)
    assert stalled.converged and stalled.outcome == (
        "converged: no relative improvement left (a minimum)"
    )
    lm = "converged (Levenberg–Marquardt's tolerance met)"
    assert _as(dahl_fit, stop.TOLERANCE).outcome == lm
    unidentified = _as(dahl_fit, stop.STALLED, ("a",))
    assert not unidentified.converged
    assert unidentified.outcome == (
        "not converged: 1 parameter combination(s) not identified"
    )
    budget = _as(dahl_fit, stop.MAX_STEPS)
    assert budget.outcome == "not converged: reached max_steps = 25"
    stopped = _as(dahl_fit, stop.INTERRUPTED, steps=3)
    assert stopped.outcome.startswith("interrupted at step 3")
    for result in (stalled, unidentified, budget, stopped):
        assert result.outcome.startswith("converged") == result.converged
        assert str(result).startswith(f"fit: {result.outcome} (")
    # The candidates as `compare_models` ranks them.
    nan = np.full(1, np.nan)
    scores = [
        jaxmr.ModelScore(
            "dahl",
            stalled,
            ("b",),
            np.array([0.05]),
            np.array([0.0055]),
            6.5,
            3,
            screening_time=2.5,
            full_time=4.0,
        ),
        jaxmr.ModelScore(
            "bingham",
            budget,
            ("b",),
            np.array([0.3]),
            np.array([0.49]),
            1.0,
            4,
            stage="screened",
        ),
        jaxmr.ModelScore("broken", None, ("b",), nan, nan, 0.5, 0, error="E: no"),
    ]
    assert scores[0].outcome == "converged"
    assert scores[1].outcome == budget.outcome + " (screening only)"
    table = jaxmr.scores.score_table(scores)
    dahl, bingham, broken = table.splitlines()[1:]
    assert dahl.split()[3:5] == ["2.5", "4.0"] and dahl.endswith("converged")
    assert "stalled" not in table
    assert bingham.endswith("not converged: reached max_steps = 25 (screening only)")
    assert bingham.split()[3:5] == ["-", "-"]  # no time recorded: none made up
    assert broken.endswith("failed: E: no")


def test_fit_log_prints_the_librarys_lines(capsys):
    """`select_model`'s lines (its `log`), indented, and the step lines labelled with
    the fit under way (its `callback`)."""
    log = _FitLog(single=False, terminal=False)
    log.event(jaxmr.FitStarted("dahl", "screening", 2))
    log.line("dahl: screened fit on 2 experiment(s)...")
    log.step(10, 0.5)
    log.event(jaxmr.FitStarted("dahl", "refit", 3))
    log.step(20, 0.25)
    printed = capsys.readouterr().out.splitlines()
    assert printed == [
        "  dahl: screened fit on 2 experiment(s)...",
        "    dahl (screening) step   10: loss 0.5",
        "    dahl (refit) step   20: loss 0.25",
    ]


def test_fit_log_prints_steps_when_not_on_a_terminal(capsys):
    to_file = _FitLog(single=False, terminal=False)
    to_file.step.label = "dahl (screening)"
    for step in range(1, 25):
        to_file.step(step, 0.5)
    printed = capsys.readouterr().out.splitlines()
    assert printed == [
        "    dahl (screening) step   10: loss 0.5",
        "    dahl (screening) step   20: loss 0.5",
    ]
    on_terminal = _FitLog(single=False, terminal=True)  # `auto`: its candidates' lines
    on_terminal.step(10, 0.5)
    assert capsys.readouterr().out == ""


def test_auto_is_never_worse_than_its_template_fitted_alone(auto, fitted):
    """`auto` keeps the lower loss of its refit and of its template's own fit, which
    is what `fit --model dahl` runs: never a higher loss than that."""
    auto_report = json.loads(auto[1].read_text())["report"]
    plain = json.loads(fitted[1].read_text())["report"]
    assert auto_report["template"] == "dahl"
    assert auto_report["loss"] <= plain["loss"]
    selection = auto_report["selection"]
    assert selection["kept"] in ("refit", "template")
    assert selection["refit_time_s"] > 0 and selection["template_time_s"] > 0
    # One verdict: the summary line, the report and the ranking's words agree.
    assert auto_report["outcome"].startswith("converged") == auto_report["converged"]
    assert f"fit: {auto_report['outcome']} (" in auto[2]


def test_auto_prints_and_records_each_candidates_stages(auto):
    """Written to a file (the fixture's stdout is not a terminal), `auto` shows the
    steps of its fits; the JSON has each stage's time and the words of `converged`."""
    status, out, stdout = auto
    assert status == 0
    # A line every step of every fit (`auto`'s PROGRESS_STEPS), named by its
    # candidate and stage.
    stages = {"bingham": ("screening", "cv"), "dahl": ("screening", "cv", "template")}
    for candidate, its_stages in stages.items():
        for stage in its_stages:
            line = rf"^ +{candidate} \({stage}\) step +1: loss"
            assert re.search(line, stdout, re.M), (line, stdout)
    report = json.loads(out.read_text())["report"]
    assert report["outcome"].startswith("converged") == report["converged"]
    for row in report["selection"]["ranking"]:
        assert row["screening_time_s"] > 0 and row["full_time_s"] > 0
        # The total that `select_model` reports is the sum of the three stages (5 %
        # of slack: the clocks are read a few statements apart, and rounded).
        assert row["cv_time_s"] > 0  # both are finalists: fitted on the second fold
        total = row["screening_time_s"] + row["full_time_s"] + row["cv_time_s"]
        assert abs(row["fit_time_s"] - total) < 0.05 * total
        assert row["outcome"] in stdout


def test_fit_summary_agrees_with_the_report(fitted):
    _, out, stdout = fitted
    report = json.loads(out.read_text())["report"]
    (line,) = [x for x in stdout.splitlines() if x.startswith("fit: ")]
    assert line.startswith(f"fit: {report['outcome']} (")
    assert line.startswith("fit: converged") == report["converged"]


def test_fit_records_warnings_in_its_report(tmp_path, capsys):
    """A file in millimetres fitted with --accept-units (without it `jaxmr fit`
    refuses, tests/test_table.py): the warning names the file, is printed once and is
    kept in the parameter file's report."""
    e = _experiment(0.5, np.random.default_rng(1))
    mm = tmp_path / "mm.csv"
    # A 1 mm stroke (the record's 10 mm scaled) in millimetres, read as 1 m: past the
    # 0.5 m that warns, with a tenth of the RK4 steps that 10 m takes under the fit's
    # travel limit (the test took 12.6 s, 7.6 s of it packing those steps; now 3.5 s).
    with pytest.warns(UserWarning, match="millimetres"):
        in_mm = jaxmr.data.Experiment(e.t, 1e2 * e.x, 1e2 * e.v, 0.5, e.force)
    jaxmr.data.write_csv(in_mm, mm)
    out = tmp_path / "p.json"
    argv = ["fit", "--model", "bingham", "--max-steps", "2", "--accept-units"]
    argv += ["--out", out, mm]
    status, _ = _run(argv)
    assert status == 0
    err = capsys.readouterr().err
    (warning,) = json.loads(out.read_text())["report"]["warnings"]
    assert (
        warning.startswith(f"{mm}: the displacement amplitude")
        and "millimetres" in warning
    )
    assert err.count(f"jaxmr fit: warning: {warning}") == 1


def test_report_marks_fitted_and_unseen_files(fitted, files, tmp_path):
    """A fitted file is known by its bytes under any name, a new one is unseen; the
    start the fit discarded is left out of the errors (an unseen file without its own
    `# discard:` line gets the fit's, which was one for all), and the RMSE has its
    unit."""
    _, params, _ = fitted
    data = json.loads(params.read_text())
    data["report"]["discard_s"] = [0.3] * len(files)  # as if fitted with --discard 0.3
    edited = tmp_path / "p.json"
    edited.write_text(json.dumps(data))
    renamed = tmp_path / "renamed.csv"
    renamed.write_bytes(files[0].read_bytes())
    unseen = tmp_path / "dahl_0.25A.csv"
    jaxmr.data.write_csv(_experiment(0.25, np.random.default_rng(2)), unseen)
    out = tmp_path / "report"
    status, stdout = _run(["report", edited, renamed, files[2], unseen, "--out", out])
    assert status == 0
    with open(out / "report.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["data"] for r in rows] == ["fitted", "fitted", "unseen"]
    assert [float(r["discard_s"]) for r in rows] == [0.3] * 3
    model = jaxmr.load_model(edited)
    for row, path in zip(rows, (renamed, files[2], unseen)):
        e = jaxmr.data.read_csv(path)
        (predicted,) = jaxmr.predict_all(model, [e])
        keep = np.asarray(e.t) >= 0.3
        error = np.asarray(predicted)[keep] - np.asarray(e.force)[keep]
        # The same simulation and arithmetic: equal to rounding (1e-9 relative).
        np.testing.assert_allclose(
            float(row["rmse_N"]), np.sqrt(np.mean(error**2)), rtol=1e-9
        )
    markdown = (out / "report.md").read_text()
    assert "| RMSE [N] |" in markdown and "| unseen |" in markdown
    assert "over 2 fitted file(s)" in markdown and "over 1 unseen" in markdown


# ---------------------------------------------------------------------------------------
# Where the model was fitted (`jaxmr.FittedRange`), and the report's verdict


def test_fit_saves_its_fitted_range(fitted, files, tmp_path):
    """`jaxmr fit` saves the extremes of its files' x, v and current with the model;
    `save_model`/`load_fitted_range` round-trip it exactly (JSON's float text is
    exact), and a file without one reads as None."""
    _, params, _ = fitted
    saved = jaxmr.load_fitted_range(params)
    experiments = [jaxmr.data.read_csv(f) for f in files]
    x = np.concatenate([np.asarray(e.x) for e in experiments])
    v = np.concatenate([np.asarray(e.v) for e in experiments])
    assert saved == jaxmr.FittedRange(
        (x.min(), x.max()), (v.min(), v.max()), (min(CURRENTS), max(CURRENTS))
    )
    # One 1 Hz cycle of ±1 cm sampled at 250 Hz: its peak within a sample of it.
    assert AMPLITUDE * 0.999 < saved.displacement[1] <= AMPLITUDE
    assert saved.units() == {"displacement": "m", "velocity": "m/s", "input": "A"}
    copy = tmp_path / "copy.json"
    jaxmr.save_model(jaxmr.load_model(params), copy, fitted_range=saved)
    assert jaxmr.load_fitted_range(copy) == saved
    # The loaded model holds it (`load_model`), and `save_model` writes the model's
    # own; a model without one writes none.
    own = tmp_path / "own.json"
    jaxmr.save_model(jaxmr.load_model(params), own)
    assert jaxmr.load_fitted_range(own) == saved
    bare = tmp_path / "bare.json"
    jaxmr.save_model(jaxmr.with_fitted_range(jaxmr.load_model(params), None), bare)
    assert jaxmr.load_fitted_range(bare) is None


def test_simulations_warn_beyond_the_fitted_range(fitted):
    """Within the fitted range no warning; at 3x the amplitude and 2x the frequency,
    and 1.5 A, `simulate`, `sweep` and `simulate_system` warn once with the interval
    exceeded and by how much."""
    _, params, _ = fitted
    model, fitted_range = jaxmr.load_model(params), jaxmr.load_fitted_range(params)
    ts = np.linspace(0.0, 1.0, 201)  # holds the peaks of the sines below
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxmr.OutsideFittedRange)
        jaxmr.simulate(
            model, jaxmr.Sine(0.5 * AMPLITUDE, FREQUENCY), 0.5, ts,
            fitted_range=fitted_range,
        )  # fmt: skip
    beyond = jaxmr.Sine(3 * AMPLITUDE, 2 * FREQUENCY)
    with pytest.warns(jaxmr.OutsideFittedRange) as caught:
        jaxmr.simulate(model, beyond, 1.5, ts, fitted_range=fitted_range)
    (message,) = [str(w.message) for w in caught]
    # The peak 0.03 m against a fitted peak within 0.1 % of 0.01 m: 0.02 m beyond it
    # to the 4 digits printed.
    assert "displacement spans [-0.03, 0.03] m" in message
    assert "beyond it by 0.02 m" in message
    assert "current spans [1.5, 1.5] A, the fitted range [0, 1] A" in message
    with pytest.warns(jaxmr.OutsideFittedRange, match="jaxmr.sweep .* velocity"):
        jaxmr.sweep(model, beyond, [0.5, 1.0], ts, fitted_range=fitted_range)
    # Traced (the amplitude under jit): the values are unknown, the check is skipped
    # and tracing goes through (a warning here would be an error: pyproject's
    # filterwarnings).
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxmr.OutsideFittedRange)
        peak = jax.jit(
            lambda a: jaxmr.simulate(
                model, jaxmr.Sine(a, 2 * FREQUENCY), 1.5, ts, fitted_range=fitted_range
            ).displacement.max()
        )(3 * AMPLITUDE)
    # The sine's peak sits on a sample (t = 0.125 s): equal to rounding.
    assert float(peak) == pytest.approx(3 * AMPLITUDE, rel=1e-12)
    # In a car, on a 2 cm 1.5 Hz road: the damper moves beyond ±1 cm.
    car = jaxmr.passenger_car(model)
    road = jaxmr.Sine(0.02, 1.5)
    with pytest.warns(jaxmr.OutsideFittedRange, match="simulate_system .* velocity"):
        jaxmr.simulate_system(car, road, 0.5, 1.0, fitted_range=fitted_range)


def test_report_says_whether_to_trust_the_fit(files, tmp_path):
    """Bingham fitted to one Dahl file at 0.5 A, 5 steps: the data barely constrain
    its parameters (a relative error beyond 100 %). The report gives the verdict, the
    poorly determined warnings the fit saved, the parameters with relative errors and
    units, the fitted range, and names the file that leaves it (twice the motion)."""
    out = tmp_path / "p.json"
    argv = ["fit", "--model", "bingham", "--max-steps", "5", "--out", out, files[1]]
    status, _ = _run(argv)
    assert status == 0
    report = json.loads(out.read_text())["report"]
    assert report["poorly_determined"]
    e = jaxmr.data.read_csv(files[1])
    wider = tmp_path / "wider.csv"
    jaxmr.data.write_csv(
        jaxmr.data.Experiment(e.t, 2 * e.x, 2 * e.v, 0.5, e.force, name="wider"), wider
    )
    status, _ = _run(["report", out, files[1], wider, "--out", tmp_path / "r"])
    assert status == 0
    markdown = (tmp_path / "r" / "report.md").read_text()
    assert f"Fit: {report['outcome']}." in markdown
    for warning in report["poorly_determined"]:
        assert f"- WARNING: {warning}" in markdown
    assert "| parameter | value | std error | relative |" in markdown
    assert "force in N, displacement in m, velocity in m/s, input in A" in markdown
    fitted_range = jaxmr.load_fitted_range(out)
    low, high = fitted_range.displacement
    assert f"| displacement | {low:.4g} | {high:.4g} | m |" in markdown
    assert "| current | 0.5 | 0.5 | A |" in markdown
    (outside,) = [
        line
        for line in markdown.splitlines()
        if line.startswith("- ")
        and "spans" in line
        and "fitted range" in line
        and "WARNING" not in line
    ]
    assert outside.startswith(f"- {wider}: displacement spans")


def test_predict_never_writes_a_force_beyond_the_models_reach(tmp_path, capsys):
    """Two runs of one 3 Hz ±5 mm test at 1 kHz joined at 0.5 s, the second from a
    quarter cycle on (a 1.7 mm step in x, v continuous; issue 27): the step is named
    when the file is read, and `jaxmr predict` with a Dahl model either writes forces
    within its reach |F| <= k_x |v| + k_w (|z| <= 1) or fails naming the experiment
    and time. (Steps chosen from v alone gave 2.6e10 N, exit 0.)"""
    t = np.arange(0.0, 1.0, 1e-3)
    w = 2 * np.pi * 3.0
    x, v = 5e-3 * np.sin(w * t), 5e-3 * w * np.cos(w * t)
    x[t >= 0.5] += 1.7e-3
    data = tmp_path / "joined.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", jaxmr.data.DataWarning)
        jaxmr.data.write_csv(jaxmr.data.Experiment(t, x, v, 0.0, None), data)
    params = tmp_path / "dahl.json"
    jaxmr.save_model(jaxmr.Dahl(k_x=500.0, k_w=800.0, rho=2e4), params)
    out = tmp_path / "pred.csv"
    status = main([str(a) for a in ["predict", params, data, "--out", out]])
    err = capsys.readouterr().err
    assert "between t = 0.499 s and 0.5 s `x` steps" in err  # named when read, once
    assert err.count("`x` steps") == 1
    if status == 0:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", jaxmr.data.DataWarning)
            force = np.asarray(jaxmr.data.read_csv(out).force)
        # 1 % slack: RK4's own overshoot of the saturating state.
        assert np.max(np.abs(force)) <= 500.0 * np.max(np.abs(v)) + 800.0 * 1.01
    else:
        assert "diverged at t = " in err and not out.exists()


def test_a_state_that_leaves_its_bounds_is_a_failure_not_a_force(
    files, tmp_path, capsys
):
    """A Dahl model whose state relaxes within 1 µm (rho = 1e6 1/m): the default steps
    of 25 µm travel are 25 relaxation lengths, RK4 overshoots |z| <= 1 and diverges;
    `predict` runs it again with 16 times shorter steps (1.6 µm), says so, and writes
    forces within the model's reach. Within 0.01 µm (rho = 1e8) even those diverge:
    `predict` and `report` fail naming the experiment and the time instead of
    writing forces or a report of them."""
    params = tmp_path / "stiff.json"
    jaxmr.save_model(jaxmr.Dahl(k_x=800.0, k_w=500.0, rho=1e6), params)
    out = tmp_path / "pred.csv"
    assert main([str(a) for a in ["predict", params, files[1], "--out", out]]) == 0
    assert "(16x) diverged with the step policy's steps" in capsys.readouterr().err
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", jaxmr.data.DataWarning)
        written = jaxmr.data.read_csv(out)
    # 1 % slack: RK4's own overshoot of the saturating state.
    reach = 800.0 * np.max(np.abs(written.v)) + 500.0 * 1.01
    assert np.max(np.abs(np.asarray(written.force))) <= reach
    # The file says how it was made.
    header = [line for line in out.read_text().splitlines() if line.startswith("#")]
    assert any("(16x) diverged with the step policy's steps" in h for h in header)
    out.unlink()
    params = tmp_path / "stiffer.json"
    jaxmr.save_model(jaxmr.Dahl(k_x=800.0, k_w=500.0, rho=1e8), params)
    err = _error(["predict", params, files[1], "--out", out], capsys)
    assert f"the simulation of {files[1]} (experiment " in err
    assert "diverged at t = " in err and not out.exists()
    err = _error(["report", params, *files, "--out", tmp_path / "r"], capsys)
    assert "diverged at t = " in err
    assert not (tmp_path / "r" / "report.md").exists()


def test_fit_with_a_saturating_law(files, tmp_path, capsys):
    """`--saturating FIELD` bends the named model's law for FIELD into a
    `SaturatingLaw` (saved and read back by `jaxmr report`); it is refused with
    auto, and for a field that is not a linear law, with the reason. An output
    path under a file is named as such (it said "does not exist")."""
    out = tmp_path / "sat.json"
    status, stdout = _run(
        ["fit", "--model", "dahl", "--saturating", "k_w", "--out", out, *files]
    )
    assert status == 0 and "fitting dahl (saturating k_w)" in stdout
    model = jaxmr.load_model(out)
    assert isinstance(model.k_w, jaxmr.SaturatingLaw)
    assert json.loads(out.read_text())["report"]["template"] == "dahl (saturating k_w)"
    err = _error(
        ["fit", "--saturating", "k_w", "--out", tmp_path / "a.json", *files], capsys
    )
    assert "--saturating bends a named model's laws: give --model" in err
    err = _error(
        ["fit", "--model", "dahl", "--saturating", "rho", "--out", tmp_path / "b.json",
         *files], capsys,
    )  # fmt: skip
    assert "`rho` of the template's Dahl is not a linear law" in err
    err = _error(["fit", "--model", "dahl", "--out", out / "p.json", *files], capsys)
    assert "which is a file, not a directory" in err
