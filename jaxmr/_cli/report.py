"""`jaxmr report`: a fitted model against measured CSV files, as figures and a table
(fitted and unseen files told apart)."""

import argparse
import csv
import dataclasses
import math
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

import jaxmr
import jaxmr.plot

from .errors import CLIError
from .files import (
    BAND_LEVEL_HELP,
    FORCE_HELP,
    band_level,
    beyond_range,
    check_device,
    fitted_range,
    load_model,
    plan_outputs,
    predicted_by_jaxmr,
    prediction_bands,
    prepare_directory,
    read_experiments,
    same_file,
    save_figure,
    units,
    write_text,
)
from .predict import diverged_message

if TYPE_CHECKING:
    import jaxmr.data  # at run time `jaxmr.data` is imported on first use (it imports JAX)


def add_parser(subparsers) -> None:
    """Register `jaxmr report`."""
    command = subparsers.add_parser(
        "report",
        help="compare a fitted model with measured CSV files: figures and a table",
        description=(
            "Simulate the model of a parameter file under each CSV experiment and "
            "write, per file, a figure of measured and predicted force against "
            "displacement, velocity and time (<file stem>.png), and a table of RMSE "
            "[N or N·m] and NRMSE per file (report.csv), the same with the model's "
            "parameters in report.md. Each file is marked 'fitted' (the fit of PARAMS.json used "
            "it, whatever its name now) or 'unseen' (the model never saw it: a test of "
            "prediction). The start-up transient is left out of the errors and "
            "figures, as the fit left it out: a fitted file's discarded start is the "
            "fit's; an unseen file's is its own ('# discard:' line), or if it has "
            "none the fit's when it used one value for every file. Smoothing follows "
            "the same rule. The figures shade the model's prediction band from the "
            "fitted parameters' uncertainty, and the tables give its median "
            "half-width per file (none for a parameter file without the fit's "
            "covariance). report.md also gives the fit's verdict, its poorly "
            "determined parameters, and the operating range it was fitted on "
            "(displacement, velocity, current), naming the files beyond it."
        ),
    )
    command.add_argument("params", metavar="PARAMS.json", help="the fitted model")
    command.add_argument("files", nargs="+", metavar="FILE", help="CSV experiments")
    command.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="directory for the figures and tables (created)",
    )
    command.add_argument("--force", action="store_true", help=FORCE_HELP)
    command.add_argument(
        "--band-level",
        type=band_level,
        default=0.95,
        metavar="P",
        help=BAND_LEVEL_HELP,
    )
    command.set_defaults(run=run)


def _figure_names(paths: Sequence[str]) -> list[str]:
    names, used = [], set()
    for path in paths:
        stem, k = jaxmr.data.experiment_name(path), 1
        name = f"{stem}.png"
        while name in used or name in ("report.png",):
            k += 1
            name = f"{stem}_{k}.png"
        used.add(name)
        names.append(name)
    return names


FITTED, UNSEEN, UNKNOWN = "fitted", "unseen", "unknown"


def _fitted_index(path, experiment, fit_report: dict) -> int | None:
    """The position of `path` among the fit's files: the same bytes (`sha256`, any
    name or directory), the same numbers (`data_sha256`: an experiment fitted from
    Python and written to another file, `jaxmr.save_fit`), or the same file under
    the name the fit was given."""
    per_file = fit_report.get("per_file") or []
    digest = jaxmr.data.file_digest(path)
    for k, row in enumerate(per_file):
        if isinstance(row, dict) and digest is not None and row.get("sha256") == digest:
            return k
    numbers = jaxmr.data.experiment_digest(experiment)
    for k, row in enumerate(per_file):
        if isinstance(row, dict) and row.get("data_sha256") == numbers:
            return k
    for k, row in enumerate(per_file):
        if isinstance(row, dict) and isinstance(row.get("file"), str):
            if same_file(path, row["file"]):
                return k
    return None


def _as_fitted(files, experiments, fit_report: dict) -> tuple[list, list[str]]:
    """The experiments with the smoothing and discarded start [s] as `jaxmr report`'s
    help says, and whether the fit used each file (fitted, unseen, or unknown for a
    parameter file without a fit report)."""
    if not fit_report:
        return list(experiments), [UNKNOWN] * len(files)

    def used(key) -> list:
        values = fit_report.get(f"{key}_s")
        if isinstance(values, list) and all(
            isinstance(v, (int, float)) for v in values
        ):
            return values
        return []

    fitted = {key: used(key) for key in ("smoothing", "discard")}
    common = {
        key: float(v[0]) if v and all(x == v[0] for x in v) else None
        for key, v in fitted.items()
    }
    result, status = [], []
    for path, e in zip(files, experiments):
        k = _fitted_index(path, e, fit_report)
        status.append(UNSEEN if k is None else FITTED)
        changes = {}
        for key, values in fitted.items():
            if k is not None and k < len(values):  # as it was fitted
                changes[key] = float(values[k])
            elif k is None and not getattr(e, key) and common[key] is not None:
                changes[key] = common[key]  # unseen, none of its own: the fit's
        if changes:
            # Rebuilding checks the data again: its warnings were said, naming the
            # file, when it was read.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", jaxmr.data.DataWarning)
                e = dataclasses.replace(e, **changes)
        result.append(e)
    return result, status


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr report` (see `add_parser`)."""
    from jaxmr.scores import nrmse, rmse  # imports JAX: not at `jaxmr --help`

    model, data = load_model(args.params)
    experiments = read_experiments(
        args.files, need_force=True, why="the comparison with the model"
    )
    fitted = check_device(args.params, data, args.files, experiments)
    for path, e in zip(args.files, experiments):
        beyond = beyond_range(fitted, path, e)
        if beyond is not None:
            # Said here as the command's warnings are; the report's own section on
            # the fitted range lists it (not again among its warnings).
            print(f"jaxmr report: warning: {beyond}", file=sys.stderr, flush=True)
        if predicted_by_jaxmr(path):
            load = "T" if e.rotary else "F"
            warnings.warn(
                f"the {load} column of {path} was predicted by jaxmr (its "
                f"'# {load}:' line), not measured: the report compares the model "
                "with a prediction",
                UserWarning,
                stacklevel=2,
            )
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"the output path {str(out)!r} exists and is not a directory")
    figure_names = _figure_names(args.files)
    tables = [out / "report.csv", out / "report.md"]
    replacing = plan_outputs(
        [out / n for n in figure_names] + tables,
        [args.params, *args.files],
        force=args.force,
    )
    prepare_directory(out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fit_report = data.get("report") if isinstance(data.get("report"), dict) else {}
    experiments, status = _as_fitted(args.files, experiments, fit_report)
    # Through each experiment's own smoothing (`Experiment.smoothing`).
    predicted = jaxmr.predict_all(model, experiments)
    for path, e, p in zip(args.files, experiments, predicted):
        if not np.all(np.isfinite(p)):  # a failure, not a figure of absurd forces
            raise CLIError(diverged_message(path, e, p))
    bands, no_band = prediction_bands(
        model, data, experiments, args.params, args.band_level
    )
    force_unit, input_unit = units(experiments[0])
    rows = []
    for path, e, p, band, figure_name, seen in zip(
        args.files,
        experiments,
        predicted,
        bands or [None] * len(experiments),
        figure_names,
        status,
    ):
        t, d = np.asarray(e.t), e.discard
        keep = t >= t[0] + d
        if not np.any(keep):
            raise CLIError(f"{path}: the discarded start ({d:g} s) leaves no sample")
        error, relative = rmse(p, e.force, keep), nrmse(p, e.force, keep)
        level = float(np.mean(np.asarray(e.current)))
        if band is not None:  # the band over the scored samples, as the figure
            band = dataclasses.replace(
                band,
                **{
                    k: np.asarray(getattr(band, k))[keep]
                    for k in ("t", "force", "std", "lower", "upper")
                },
            )
        # The band's median half-width [force unit] over the scored samples.
        width = (
            math.nan
            if band is None
            else float(np.median((band.upper - band.lower) / 2))
        )
        rows.append((str(path), e.name, seen, level, d, error, relative, width))
        after = f", from {d:g} s" if d else ""
        figure = jaxmr.plot.measured_vs_predicted_loops(
            e.window(t[0] + d),
            np.asarray(p)[keep],
            title=(
                f"{e.name} ({seen}{after}): {type(model).__name__}, NRMSE "
                f"{relative:.4f}, RMSE {error:.4g} {force_unit}"
            ),
            band=band,
        )
        path = out / figure_name
        save_figure(plt, figure, path, replacing=path in replacing)
    parameters = _parameter_rows(model, fit_report)
    unit = force_unit.replace("·", "")

    def write_table(f):
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(
            (
                "file",
                "experiment",
                "data",
                f"mean_input_{input_unit}",
                "discard_s",
                f"rmse_{unit}",
                "nrmse",
                f"band_halfwidth_{unit}",
            )
        )
        for path, name, seen, level, d, error, relative, width in rows:
            writer.writerow(
                (
                    path,
                    name,
                    seen,
                    f"{level:.6g}",
                    f"{d:.6g}",
                    f"{error:.10g}",
                    f"{relative:.10g}",
                    "" if math.isnan(width) else f"{width:.10g}",
                )
            )

    write_text(tables[0], write_table, replacing=tables[0] in replacing)
    band_text = _band_markdown(rows, args.band_level, force_unit, no_band)
    range_text = _range_markdown(args.params, data, args.files, experiments)
    unit_text = _units_caption(experiments[0], force_unit)
    markdown = _report_markdown(
        args.params,
        model,
        rows,
        parameters,
        fit_report,
        force_unit,
        args,
        band_text,
        [*unit_text, "", *range_text],
    )
    write_text(tables[1], lambda f: f.write(markdown), replacing=tables[1] in replacing)
    print()
    print(markdown, end="")
    return 0


def _parameter_rows(model, fit_report: dict) -> list[tuple[str, float, str, str]]:
    """(name, value, standard error or 'fixed', relative standard error) per
    parameter of the model."""
    entries = [p for p in fit_report.get("parameters", []) if isinstance(p, dict)]
    errors = {p.get("name"): p.get("std_error") for p in entries}
    # What the fit's warnings take each error relative to (`FitResult.magnitudes`;
    # absent from older reports): a force offset fitted to ~0 read "88575 %" here
    # beside the command's own "163 %*".
    sizes = {p.get("name"): p.get("magnitude") for p in entries}
    rows = []
    for name, value in _model_parameters(model):
        if name in errors:
            se = errors[name]
            size = sizes.get(name)
            size = abs(value) if not isinstance(size, (int, float)) else size
            if se is None:  # saved as null: not finite
                rows.append((name, value, "n/a", "n/a"))
            else:
                mark = "*" if size != abs(value) else ""
                relative = f"{abs(se / size):.1%}{mark}" if size != 0 else "n/a"
                rows.append((name, value, f"{se:.3g}", relative))
        else:
            rows.append((name, value, "fixed" if errors else "", ""))
    return rows


def _units_caption(experiment, force_unit: str) -> list[str]:
    """The unit system of the parameter table: jaxmr's models do not record their
    parameters' units, so the table states the system they follow."""
    motion, speed = ("rad", "rad/s") if experiment.rotary else ("m", "m/s")
    drive = "V" if experiment.drive == "voltage" else "A"
    return [
        f"Units of the parameters: SI, in the system of the data: force in "
        f"{force_unit}, displacement in {motion}, velocity in {speed}, input in "
        f"{drive}, time in s. Each parameter is in the unit that makes the model's "
        f"force come out in {force_unit} from these (a viscous coefficient in "
        f"{force_unit}·s/{motion}, a stiffness in {force_unit}/{motion}, a current "
        f"law's slope per {drive}); a standard error is in its parameter's unit, "
        "and value ± 1.96 std error is a 95 % interval."
    ]


def _range_markdown(params, data: dict, files, experiments) -> list[str]:
    """The operating range the model was fitted on (`jaxmr.FittedRange`, saved by
    `jaxmr fit`), and the files of this report that leave it."""
    fitted = fitted_range(params, data)
    if fitted is None:
        return [
            "## Fitted operating range",
            "",
            f"Unknown: {params} holds no fitted range (written by an older `jaxmr "
            "fit`, or by `jaxmr.save_model` without `fitted_range`).",
        ]
    units = fitted.units()
    names = {
        "displacement": "angle" if fitted.rotary else "displacement",
        "velocity": "angular velocity" if fitted.rotary else "velocity",
        "input": fitted.drive,
    }
    lines = [
        "## Fitted operating range",
        "",
        "The model was fitted on these extremes of its files' samples; beyond them "
        "its force is extrapolation (`jaxmr.simulate`, `sweep` and `simulate_system` "
        "warn there: `jaxmr.load_model` gives the model this range).",
        "",
        "| quantity | low | high | unit |",
        "|---|---:|---:|---|",
    ]
    for key, label in names.items():
        low, high = getattr(fitted, key)
        lines.append(f"| {label} | {low:.4g} | {high:.4g} | {units[key]} |")
    lines.append("")
    outside = []
    for path, e in zip(files, experiments):
        found = fitted.exceeded(e.x, e.v, e.current)
        if found:
            outside.append(f"- {path}: {'; '.join(found)}.")
    if outside:
        lines += ["Files of this report beyond the fitted range:", "", *outside]
    else:
        lines.append("Every file of this report lies within the fitted range.")
    return lines


def _report_markdown(
    params, model, rows, parameters, fit_report, force_unit, args, band_text, more
) -> str:
    """report.md: the verdict, the errors per file and what the band says of them,
    the parameters, and `more` (the parameters' units, the fitted range)."""
    lines = [f"# jaxmr report: {type(model).__name__} from {params}", ""]
    lines += _verdict_markdown(fit_report)
    for status, what in ((FITTED, "fitted"), (UNSEEN, "unseen (not fitted)")):
        scores = [r[6] for r in rows if r[2] == status]
        if scores:
            lines.append(
                f"Median NRMSE (RMSE/std of the measured force) over {len(scores)} "
                f"{what} file(s): {np.median(scores):.4f}."
            )
    if not fit_report:
        scores = [r[6] for r in rows]
        lines.append(
            f"Median NRMSE (RMSE/std of the measured force) over {len(rows)} file(s): "
            f"{np.median(scores):.4f} ({params} has no fit report: which files were "
            "fitted is unknown)."
        )
    lines += [
        "",
        "Errors after each file's discarded start (the hysteretic state is unknown "
        "there).",
        "",
        f"| file | experiment | data | mean input | discarded [s] | RMSE [{force_unit}] "
        f"| NRMSE | band ± [{force_unit}] |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for path, name, seen, level, d, error, e, width in rows:
        band = "n/a" if math.isnan(width) else f"{width:.3g}"
        lines.append(
            f"| {path} | {name} | {seen} | {level:.4g} | {d:g} | {error:.4g} "
            f"| {e:.4f} | {band} |"
        )
    lines += ["", *band_text]
    lines += [
        "",
        "## Parameters",
        "",
        "| parameter | value | std error | relative |",
        "|---|---:|---:|---:|",
    ]
    for name, value, se, relative in parameters:
        lines.append(f"| {name} | {value:.6g} | {se} | {relative} |")
    if any(relative.endswith("*") for *_, relative in parameters):
        lines += [
            "",
            "\\* relative to the size at which the parameter would move the force "
            "by 1 % of the model's largest term (its value is smaller: a small "
            "effect, not a poorly determined one), as in the fit's warnings.",
        ]
    lines += ["", *more]
    warnings = getattr(args, "warnings", [])
    if warnings:
        lines.append("")
    for warning in warnings:
        lines.append(f"WARNING (this report): {warning}")
    return "\n".join(lines) + "\n"


def _verdict_markdown(fit_report: dict) -> list[str]:
    """Can the fit be trusted: its verdict (`FitResult.outcome`, as saved), the
    parameter combinations it did not identify, the poorly determined groups, and
    what the fit warned of."""
    if not fit_report:
        return [
            "## Verdict",
            "",
            "Unknown: the parameter file holds no fit report.",
            "",
        ]
    outcome = fit_report.get("outcome", fit_report.get("reason", "unknown"))
    lines = ["## Verdict", "", f"Fit: {outcome}."]
    if fit_report.get("interrupted"):
        lines.append("The fit was interrupted: the parameters are its best so far.")
    unidentified = list(fit_report.get("unidentified", []))
    weak = list(fit_report.get("poorly_determined", []))
    if "poorly_determined" in fit_report:
        if weak:
            lines.append(
                f"{len(weak)} warning(s) of poorly determined parameters (a group "
                "the data determine only in combination, or one with a large or no "
                "finite standard error): the force may still be predicted well, "
                "their values are not to be relied on one by one:"
            )
        else:
            lines.append(
                "Every fitted parameter is determined by the data: no redundant "
                "group, no parameter without a finite or with a large standard error."
            )
    lines.append("")
    for warning in unidentified:
        lines.append(f"- WARNING: {warning}")
    for warning in weak:
        lines.append(f"- WARNING: {warning}")
    for warning in fit_report.get("warnings", []):
        lines.append(f"- WARNING (while fitting): {warning}")
    if unidentified or weak or fit_report.get("warnings"):
        lines.append("")
    return lines


def _band_markdown(rows, level: float, force_unit: str, no_band) -> list[str]:
    """What the prediction band means, and what it says of these files: is the
    model's error its parameters' uncertainty, or its structure (or noise)?"""
    if no_band is not None:
        return [f"No prediction band: {no_band}."]
    lines = [
        f"The shaded band in each figure is the model's {level:.0%} prediction band "
        "(its median half-width per file in the table): the predicted force ± "
        "z standard errors carried to first order from the fitted parameters' "
        "covariance. It shows where the model is unsure of its force because its "
        "parameters are uncertain: the force the same model would predict, refitted "
        "to repeats of the fitted tests with new noise, lies in it with that "
        "probability. It does not hold the measurement: the noise and the model's "
        "own error (a structure that misses the data) lie outside it, and it "
        "describes the minimum the fit landed in, not other minima.",
        "",
    ]
    # (A band needs the fit's report, which tells fitted files from unseen ones.)
    for status in (FITTED, UNSEEN):
        chosen = [r for r in rows if r[2] == status]
        if not chosen:
            continue
        width = float(np.median([r[7] for r in chosen]))
        error = float(np.median([r[5] for r in chosen]))
        share = width / error if error > 0 else math.inf
        # Three levels, so that two nearly equal shares do not get opposite advice.
        if share < 0.5:
            verdict = (
                "the parameters are well determined for these inputs, and the error "
                "is the noise or the model's structure, which more tests of the same "
                "kind will not remove"
            )
        elif share < 1.0:
            verdict = (
                "the parameters' uncertainty is part of the error here, beside the "
                "noise and the model's structure: tests that excite these inputs "
                "(jaxmr design) would narrow the band, not the rest"
            )
        else:
            verdict = (
                "the parameters' uncertainty accounts for much of the error here: "
                "tests that excite these inputs (jaxmr design) would narrow it"
            )
        lines.append(
            f"On the {len(chosen)} {status} file(s): median band half-width {width:.3g} {force_unit} against a "
            f"median RMSE of {error:.3g} {force_unit} ({share:.0%}): {verdict}."
        )
    return lines


def _model_parameters(model) -> list[tuple[str, float]]:
    """(name, value) of every numeric parameter, named by its path as `fit` names
    them (e.g. `.alpha.a`)."""
    import jax

    rows = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(model)[0]:
        name = jax.tree_util.keystr(path)
        values = np.ravel(np.asarray(leaf))
        if values.size == 1:
            rows.append((name, float(values[0])))
        else:
            rows += [(f"{name}[{k}]", float(v)) for k, v in enumerate(values)]
    return rows
