"""The `jaxmr` command line: `jaxmr demo`, `jaxmr fit`, `jaxmr predict`, `jaxmr report`.

Each subcommand is a `_add_<name>(subparsers)` that registers its arguments and a
`_<name>(args) -> int` that runs it; `main` parses, dispatches and turns a `CLIError`
into a message on stderr and exit status 1 (argparse's usage errors exit with 2).
"""

import argparse
import csv
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

import jaxmr
import jaxmr.data
import jaxmr.plot  # light: it imports matplotlib only when it draws
from jaxmr._model_library import MODEL_TEMPLATES
from jaxmr._select import predict_all, prediction_errors, score_table, select_model


class CLIError(Exception):
    """A failure the user can fix (a bad path, ...): printed without a traceback."""


def main(argv: Sequence[str | os.PathLike] | None = None) -> int:
    """Run the `jaxmr` command line with `argv` (default: `sys.argv[1:]`).

    **Returns:** the exit status: 0 on success, 1 on an error reported on stderr
    (argparse exits with 2 on a usage error).
    """
    # jaxmr never changes JAX's configuration on import; the command line is an
    # application and wants the accuracy of double precision (Adaptive's rtol 1e-8).
    jax.config.update("jax_enable_x64", True)
    parser = _parser()
    args = parser.parse_args(None if argv is None else [os.fspath(a) for a in argv])
    try:
        return args.run(args)
    except CLIError as e:
        print(f"jaxmr {args.command}: error: {e}", file=sys.stderr)
        return 1


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxmr",
        description="Differentiable physics of magnetorheological dampers and brakes.",
    )
    parser.add_argument(
        "--version", action="version", version=f"%(prog)s {jaxmr.__version__}"
    )
    subparsers = parser.add_subparsers(
        title="commands", dest="command", metavar="COMMAND", required=True
    )
    _add_demo(subparsers)
    _add_fit(subparsers)
    _add_predict(subparsers)
    _add_report(subparsers)
    return parser


# ---------------------------------------------------------------------------------------
# jaxmr demo

# The SAS study's test: its brake under a 1 Hz sine of ±3.5°, currents 0 → 1 A.
DEMO_CURRENTS = (0.0, 0.25, 0.5, 0.75, 1.0)  # A
DEMO_AMPLITUDE_DEG = 3.5
DEMO_FREQUENCY = 1.0  # Hz
DEMO_DURATION = 3.0  # s: two cycles of transient from the virgin state, one kept
DEMO_RATE = 1000.0  # Hz, output samples


def _add_demo(subparsers) -> None:
    demo = subparsers.add_parser(
        "demo",
        help="simulate the SAS rotary MR brake at five currents; write loops and a table",
        description=(
            "Simulate the SAS study's rotary MR brake (Bouc-Wen, its published "
            f"parameters) under a {DEMO_FREQUENCY:g} Hz sine of ±{DEMO_AMPLITUDE_DEG:g}° "
            f"at currents {', '.join(f'{c:g}' for c in DEMO_CURRENTS)} A, and write "
            "torque loops (last cycle), energy per cycle against current, and a table "
            "of peak torque and energy per cycle (summary.csv, summary.md)."
        ),
    )
    demo.add_argument(
        "--out",
        metavar="DIR",
        default="demo_out",
        help="directory for the figures and tables (created; default: demo_out)",
    )
    demo.set_defaults(run=_demo)


def _demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    _prepare_directory(out)
    # Before pyplot is imported (by jaxmr.plot, on use): no display is needed.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    currents = np.array(DEMO_CURRENTS)
    period = 1 / DEMO_FREQUENCY
    ts = np.linspace(0.0, DEMO_DURATION, round(DEMO_DURATION * DEMO_RATE) + 1)
    motion = jaxmr.Sine(np.deg2rad(DEMO_AMPLITUDE_DEG), DEMO_FREQUENCY)
    print(
        f"simulating {len(currents)} currents (SAS brake, Bouc-Wen; "
        f"{DEMO_FREQUENCY:g} Hz, ±{DEMO_AMPLITUDE_DEG:g}°, {DEMO_DURATION:g} s at "
        f"{DEMO_RATE / 1000:g} kHz, RK4 0.5 ms steps)...",
        flush=True,
    )
    start = time.perf_counter()
    # Fixed-step RK4 at 0.5 ms: on this excitation it agrees with the adaptive default
    # (Dopri8, rtol 1e-8) to 5e-5 of the peak torque and 1e-6 in energy per cycle, and
    # the demo takes half the CPU time (mostly compilation).
    solution = jaxmr.sweep(
        jaxmr.sas_brake_bouc_wen(),
        motion,
        currents,
        ts,
        integrator=jaxmr.FixedStep(substeps=2),
    )
    energy = np.asarray(jaxmr.energy_per_cycle(solution, period))
    print(f"simulated in {time.perf_counter() - start:.1f} s", flush=True)

    # The last full cycle; half a sample of slack so rounding in ts keeps its first one.
    last_cycle_from = ts[-1] - period - 0.5 / DEMO_RATE
    last = ts >= last_cycle_from
    peak = np.max(np.abs(np.asarray(solution.force)[:, last]), axis=-1)

    labels = [f"{c:g} A" for c in currents]
    title = (
        f"SAS MR brake, Bouc-Wen: {DEMO_FREQUENCY:g} Hz, ±{DEMO_AMPLITUDE_DEG:g}°, "
        "last cycle"
    )
    for name, against in (
        ("torque_angle.png", "displacement"),
        ("torque_velocity.png", "velocity"),
        ("torque_time.png", "time"),
    ):
        ax = jaxmr.plot.loop(
            solution,
            against,
            units="rotary",
            labels=labels,
            last_cycles_from=last_cycle_from,
        )
        ax.set_title(title, fontsize="medium")
        _save(plt, ax.figure, out / name)
    ax = jaxmr.plot.energy_vs_current(currents, energy)
    ax.set_title("SAS MR brake, Bouc-Wen: energy per cycle", fontsize="medium")
    _save(plt, ax.figure, out / "energy_vs_current.png")

    header = ("current [A]", "peak torque [N·m]", "energy per cycle [J]")
    rows = list(zip(currents, peak, energy))
    _write(
        out / "summary.csv",
        lambda f: _write_csv(f, ("current_A", "peak_torque_Nm", "energy_J"), rows),
    )
    table = _markdown_table(header, rows)
    _write(out / "summary.md", lambda f: f.write(table))
    print()
    print(table, end="")
    return 0


def _prepare_directory(out: Path) -> None:
    """Create `out` and check that a file can be written there, before simulating."""
    if out.exists() and not out.is_dir():
        raise CLIError(f"the output path {str(out)!r} exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as e:
        raise CLIError(
            f"cannot write to the output directory {str(out)!r}: {e.strerror or e}"
        ) from e


def _save(plt, figure, path: Path) -> None:
    try:
        figure.savefig(path, dpi=120)
    except OSError as e:
        raise CLIError(f"cannot write {str(path)!r}: {e.strerror or e}") from e
    finally:
        plt.close(figure)
    print(f"wrote {path}", flush=True)


def _write(path: Path, write) -> None:
    try:
        with open(path, "w", newline="", encoding="utf-8") as f:
            write(f)
    except OSError as e:
        raise CLIError(f"cannot write {str(path)!r}: {e.strerror or e}") from e
    print(f"wrote {path}", flush=True)


def _write_csv(f, header: Sequence[str], rows) -> None:
    writer = csv.writer(f, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([[f"{float(x):.10g}" for x in row] for row in rows])


def _markdown_table(header: Sequence[str], rows) -> str:
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---:" for _ in header) + "|",
    ]
    for current, peak, energy in rows:
        lines.append(f"| {current:.2f} | {peak:.4f} | {energy:.4f} |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------
# Shared by fit, predict and report

AUTO = "auto"


def _read_experiments(paths: Sequence[str], *, need_force: bool, why: str) -> list:
    """Read canonical CSV files; every problem becomes a `CLIError` with the data
    layer's message (which names the file, the line and the fix)."""
    experiments = []
    for path in paths:
        if not Path(path).is_file():
            what = "is a directory" if Path(path).is_dir() else "no such file"
            raise CLIError(f"{path}: {what}")
        try:
            experiment = jaxmr.data.read_csv(path)
        except ValueError as e:
            raise CLIError(str(e)) from e
        except (OSError, UnicodeDecodeError) as e:
            reason = getattr(e, "strerror", None) or e
            raise CLIError(f"cannot read {path}: {reason}") from e
        if need_force and experiment.force is None:
            load = "T" if experiment.rotary else "F"
            raise CLIError(
                f"{path}: no measured force (column `{load}`); {why} needs it"
            )
        experiments.append(experiment)
    kinds = {(e.rotary, e.drive) for e in experiments}
    if len(kinds) > 1:
        listed = ", ".join(
            f"{p} ({'rotary' if e.rotary else 'linear'}, {e.drive})"
            for p, e in zip(paths, experiments)
        )
        raise CLIError(
            "the files mix linear and rotary devices or current and voltage inputs "
            f"({listed}); give files of one device"
        )
    return experiments


def _check_writable_file(path: Path) -> None:
    """Fail before a long fit rather than after it."""
    if path.is_dir():
        raise CLIError(f"the output path {str(path)!r} is a directory")
    parent = path.parent
    if not parent.is_dir():
        raise CLIError(f"the directory of the output file {str(path)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise CLIError(f"cannot write to the directory of {str(path)!r}")


def _load_model(path: str):
    """The model and the raw JSON (with the fit report, if any) of a parameter file."""
    if not Path(path).is_file():
        raise CLIError(f"{path}: no such file (a parameter file from `jaxmr fit`)")
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        model = jaxmr.model_from_dict(data)
    except json.JSONDecodeError as e:
        raise CLIError(f"{path}: not a JSON parameter file ({e})") from e
    except (ValueError, TypeError, AttributeError) as e:
        raise CLIError(f"{path}: not a jaxmr parameter file ({e})") from e
    if not isinstance(model, (jaxmr.AbstractHysteresis, jaxmr.Damper)):
        raise CLIError(
            f"{path}: holds a {type(model).__name__}, not a damper model "
            "(a hysteresis model or Damper)"
        )
    return model, data


def _json_number(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _units(experiment) -> tuple[str, str]:
    """(force unit, input unit)."""
    force = "N·m" if experiment.rotary else "N"
    return force, "V" if experiment.drive == "voltage" else "A"


def _model_parameters(model) -> list[tuple[str, float]]:
    """(name, value) of every numeric parameter, named by its path as `fit` names
    them (e.g. `.alpha.a`)."""
    rows = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(model)[0]:
        name = jax.tree_util.keystr(path)
        values = np.ravel(np.asarray(leaf))
        if values.size == 1:
            rows.append((name, float(values[0])))
        else:
            rows += [(f"{name}[{k}]", float(v)) for k, v in enumerate(values)]
    return rows


# ---------------------------------------------------------------------------------------
# jaxmr fit


def _add_fit(subparsers) -> None:
    names = ", ".join(MODEL_TEMPLATES)
    command = subparsers.add_parser(
        "fit",
        help="fit a damper model to measured CSV files; write its parameters (JSON)",
        description=(
            "Fit a model to experiments in jaxmr's canonical CSV format (columns t, x "
            "or theta, optionally v or omega, i or u, and the measured F or T) by "
            "Levenberg-Marquardt, from an initial guess scaled from the data. "
            f"Models: {names}, or auto (fit every model on part of the data, select the "
            "one with the lowest held-out error, refit it on all the files). Writes "
            "the fitted model with a report (parameters, standard errors, NRMSE per "
            "file, why the fit stopped, unidentified parameters)."
        ),
    )
    command.add_argument(
        "--model",
        required=True,
        metavar="NAME",
        help=f"{names}, or {AUTO}",
    )
    command.add_argument(
        "--out",
        required=True,
        metavar="PARAMS.json",
        help="the parameter file to write",
    )
    command.add_argument(
        "--candidates",
        metavar="NAMES",
        default=",".join(MODEL_TEMPLATES),
        help="with --model auto: the comma-separated models to choose from (default: all)",
    )
    command.add_argument(
        "--max-steps",
        type=int,
        default=200,
        metavar="N",
        help="largest number of Levenberg-Marquardt steps per fit (default 200)",
    )
    command.add_argument(
        "--starts",
        type=int,
        default=1,
        metavar="N",
        help="starts per fit: the data-scaled guess plus N-1 random ones (default 1)",
    )
    command.add_argument("files", nargs="+", metavar="FILE", help="CSV experiments")
    command.set_defaults(run=_fit)


def _fit(args: argparse.Namespace) -> int:
    if args.model != AUTO and args.model not in MODEL_TEMPLATES:
        raise CLIError(
            f"unknown model {args.model!r}; choose one of "
            f"{', '.join(MODEL_TEMPLATES)}, or {AUTO}"
        )
    candidates = [c.strip() for c in args.candidates.split(",") if c.strip()]
    unknown = [c for c in candidates if c not in MODEL_TEMPLATES]
    if unknown or not candidates:
        raise CLIError(
            f"--candidates: unknown model(s) {', '.join(map(repr, unknown))}; choose "
            f"from {', '.join(MODEL_TEMPLATES)}"
            if unknown
            else "--candidates names no model"
        )
    if args.max_steps < 1 or args.starts < 1:
        raise CLIError("--max-steps and --starts must be at least 1")
    out = Path(args.out)
    _check_writable_file(out)
    experiments = _read_experiments(args.files, need_force=True, why="fitting")
    _, input_unit = _units(experiments[0])
    print(f"read {len(experiments)} file(s):", flush=True)
    for path, e in zip(args.files, experiments):
        i = np.asarray(e.current)
        level = f"{i[0]:g}" if e.is_constant_current else f"{i.min():g}..{i.max():g}"
        print(
            f"  {path}: {len(e)} samples, {e.duration:g} s, {level} {input_unit}",
            flush=True,
        )
    fit_kwargs = {"max_steps": args.max_steps}
    if args.starts > 1:
        fit_kwargs["starts"] = args.starts
    start = time.perf_counter()
    selection = None
    if args.model == AUTO:
        print(
            f"selecting among {', '.join(candidates)} by held-out NRMSE...",
            flush=True,
        )
        try:
            selection = select_model(
                candidates,
                experiments,
                log=lambda line: print(f"  {line}", flush=True),
                **fit_kwargs,
            )
        except (RuntimeError, ValueError) as e:  # every candidate failed, or bad data
            raise CLIError(str(e)) from e
        print(f"({selection.holdout})")
        print(score_table(selection.scores))
        name, result = selection.name, selection.result
    else:
        name = args.model
        try:
            model = MODEL_TEMPLATES[name](experiments)
        except ValueError as e:
            raise CLIError(str(e)) from e
        print(f"fitting {name} ({type(model).__name__})...", flush=True)
        try:
            result = jaxmr.fit(model, experiments, progress=True, **fit_kwargs)
        except ValueError as e:  # data `fit` refuses, e.g. a constant force
            raise CLIError(str(e)) from e
    elapsed = time.perf_counter() - start
    print(f"\n{name}: {elapsed:.1f} s")
    print(result)
    report = _fit_report(name, args.files, experiments, result, elapsed, selection)
    try:
        jaxmr.save_model(result.model, out, report=report)
    except OSError as e:
        raise CLIError(f"cannot write {str(out)!r}: {e.strerror or e}") from e
    print(f"wrote {out}", flush=True)
    return 0


def _fit_report(name, files, experiments, result, elapsed, selection) -> dict:
    force_unit, input_unit = _units(experiments[0])
    report = {
        "template": name,
        "device": "rotary" if experiments[0].rotary else "linear",
        "force_unit": force_unit,
        "input": f"{experiments[0].drive} [{input_unit}]",
        "files": [str(f) for f in files],
        "parameters": [
            {"name": n, "value": _json_number(v), "std_error": _json_number(se)}
            for n, v, se in zip(result.names, result.values, result.std_errors)
        ],
        "per_file": [
            {
                "file": str(f),
                "experiment": str(n),
                "rmse": _json_number(r),
                "nrmse": _json_number(e),
            }
            for f, n, r, e in zip(
                files, result.experiment_names, result.rmse, result.nrmse
            )
        ],
        "reason": result.reason,
        "converged": bool(result.converged),
        "num_steps": int(result.num_steps),
        "loss": _json_number(result.loss),
        "unidentified": list(result.unidentified),
        "fit_time_s": round(elapsed, 3),
    }
    if selection is not None:
        report["selection"] = {
            "holdout": selection.holdout,
            "ranking": [
                {
                    "template": s.name,
                    "num_parameters": s.num_parameters,
                    "fit_time_s": round(s.fit_time, 3),
                    "median_train_nrmse": _json_number(s.median_train_nrmse),
                    "median_test_nrmse": _json_number(s.median_test_nrmse),
                    "error": s.error,
                }
                for s in selection.scores
            ],
        }
    return report


# ---------------------------------------------------------------------------------------
# jaxmr predict


def _add_predict(subparsers) -> None:
    command = subparsers.add_parser(
        "predict",
        help="predict the force of a fitted model for a CSV experiment",
        description=(
            "Simulate the model of a parameter file (from `jaxmr fit`) under the motion "
            "and input of a CSV experiment and write the predicted force (or torque) "
            "in jaxmr's canonical CSV format: t, x, v, i (or theta, omega, u) as read, "
            "and F (T) predicted. A measured force in FILE is only used to print the "
            "error."
        ),
    )
    command.add_argument("params", metavar="PARAMS.json", help="the fitted model")
    command.add_argument("file", metavar="FILE", help="the CSV experiment")
    command.add_argument(
        "--out", required=True, metavar="PRED.csv", help="the CSV file to write"
    )
    command.set_defaults(run=_predict)


def _predict(args: argparse.Namespace) -> int:
    out = Path(args.out)
    _check_writable_file(out)
    model, _ = _load_model(args.params)
    (experiment,) = _read_experiments([args.file], need_force=False, why="")
    (predicted,) = predict_all(model, [experiment])
    if not np.all(np.isfinite(predicted)):
        raise CLIError(
            f"the simulation of {args.file} diverged (non-finite force): the model's "
            "parameters do not suit this input"
        )
    result = jaxmr.data.Experiment(
        experiment.t,
        experiment.x,
        experiment.v,
        experiment.current,
        predicted,
        name=experiment.name,
        rotary=experiment.rotary,
        drive=experiment.drive,
        velocity_source=experiment.velocity_source,
    )
    load = "T" if experiment.rotary else "F"
    comment = (
        f"{load}: predicted by jaxmr {jaxmr.__version__} with the "
        f"{type(model).__name__} model of {args.params}, from the motion and input of "
        f"{args.file}"
    )
    try:
        jaxmr.data.write_csv(result, out, comment=comment)
    except OSError as e:
        raise CLIError(f"cannot write {str(out)!r}: {e.strerror or e}") from e
    if experiment.force is not None:
        rmse, nrmse = prediction_errors(predicted, np.asarray(experiment.force))
        force_unit, _ = _units(experiment)
        print(f"{args.file}: RMSE {rmse:.6g} {force_unit}, NRMSE {nrmse:.4f}")
    print(f"wrote {out}", flush=True)
    return 0


# ---------------------------------------------------------------------------------------
# jaxmr report


def _add_report(subparsers) -> None:
    command = subparsers.add_parser(
        "report",
        help="compare a fitted model with measured CSV files: figures and a table",
        description=(
            "Simulate the model of a parameter file under each CSV experiment and "
            "write, per file, a figure of measured and predicted force against "
            "displacement, velocity and time (<file stem>.png), and a table of RMSE "
            "and NRMSE per file with the model's parameters (report.csv, report.md)."
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
    command.set_defaults(run=_report)


def _figure_names(paths: Sequence[str]) -> list[str]:
    names, used = [], set()
    for path in paths:
        stem, k = Path(path).stem, 1
        name = f"{stem}.png"
        while name in used or name in ("report.png",):
            k += 1
            name = f"{stem}_{k}.png"
        used.add(name)
        names.append(name)
    return names


def _report(args: argparse.Namespace) -> int:
    model, data = _load_model(args.params)
    experiments = _read_experiments(
        args.files, need_force=True, why="the comparison with the model"
    )
    out = Path(args.out)
    _prepare_directory(out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    predicted = predict_all(model, experiments)
    force_unit, input_unit = _units(experiments[0])
    rows = []
    for path, e, p, figure_name in zip(
        args.files, experiments, predicted, _figure_names(args.files)
    ):
        rmse, nrmse = prediction_errors(p, np.asarray(e.force))
        i = np.asarray(e.current)
        rows.append((str(path), e.name, float(np.mean(i)), rmse, nrmse))
        figure = jaxmr.plot.measured_vs_predicted_loops(
            e,
            p,
            title=(
                f"{e.name}: {type(model).__name__}, NRMSE {nrmse:.4f} "
                f"(RMSE {rmse:.4g} {force_unit})"
            ),
        )
        _save(plt, figure, out / figure_name)
    fit_report = data.get("report") if isinstance(data.get("report"), dict) else {}
    parameters = _parameter_rows(model, fit_report)

    def write_table(f):
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(
            ("file", "experiment", f"mean_input_{input_unit}", "rmse", "nrmse")
        )
        for path, name, level, rmse, nrmse in rows:
            writer.writerow(
                (path, name, f"{level:.6g}", f"{rmse:.10g}", f"{nrmse:.10g}")
            )

    _write(out / "report.csv", write_table)
    markdown = _report_markdown(args.params, model, rows, parameters, fit_report)
    _write(out / "report.md", lambda f: f.write(markdown))
    print()
    print(markdown, end="")
    return 0


def _parameter_rows(model, fit_report: dict) -> list[tuple[str, float, str]]:
    """(name, value, standard error or 'fixed') per parameter of the model."""
    errors = {
        p.get("name"): p.get("std_error")
        for p in fit_report.get("parameters", [])
        if isinstance(p, dict)
    }
    rows = []
    for name, value in _model_parameters(model):
        if name in errors:
            se = errors[name]
            rows.append((name, value, "n/a" if se is None else f"{se:.3g}"))
        else:
            rows.append((name, value, "fixed" if errors else ""))
    return rows


def _report_markdown(params, model, rows, parameters, fit_report) -> str:
    nrmse = np.array([r[4] for r in rows])
    lines = [
        f"# jaxmr report: {type(model).__name__} from {params}",
        "",
        f"Median NRMSE (RMSE/std of the measured force) over {len(rows)} file(s): "
        f"{np.median(nrmse):.4f}.",
        "",
        "| file | experiment | mean input | RMSE | NRMSE |",
        "|---|---|---:|---:|---:|",
    ]
    for path, name, level, rmse, e in rows:
        lines.append(f"| {path} | {name} | {level:.4g} | {rmse:.4g} | {e:.4f} |")
    lines += [
        "",
        "| parameter | value | std error |",
        "|---|---:|---:|",
    ]
    for name, value, se in parameters:
        lines.append(f"| {name} | {value:.6g} | {se} |")
    if fit_report:
        lines += ["", f"Fit: {fit_report.get('reason', 'unknown')}."]
        for warning in fit_report.get("unidentified", []):
            lines.append(f"WARNING: {warning}")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
