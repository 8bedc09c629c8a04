"""`jaxmr fit`: fit a damper model (or select one, `--model auto`) to measured CSV
files and write it with a report.

`run` reads the files (`_read`), fits (`_fit_model`: one template, `_fit_one`, or a
selection among candidates, `_select`), then reports and writes the model
(`_fit_report`, `_save_model`). While it fits, `_FitLog` prints its progress (the
steps, and `select_model`'s own lines) and `_Interrupts` turns a Ctrl-C into the `stop`
event of `fit` and `select_model`: stop at the next step with the best model so far.
"""

import argparse
import os
import signal
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

import jaxmr

from .errors import INTERRUPTED, CLIError
from .files import (
    ACCEPT_UNITS_HELP,
    FORCE_HELP,
    check_writable_file,
    plan_outputs,
    predicted_by_jaxmr,
    read_experiments,
    same_file,
    units,
    with_processing,
    write_atomically,
)

AUTO = "auto"
# Starts per fit with --model auto: `jaxmr._identify.select.AUTO_STARTS` (that module
# imports JAX, which `jaxmr fit --help` does not; tests/test_cli.py checks they agree).
AUTO_STARTS = 1
# How `jaxmr fit --channel-delay` names a model seen through a fitted channel delay.
DELAY_SUFFIX = " + channel delay"
# The names of `jaxmr.templates.MODEL_TEMPLATES`, for the help (that module imports
# JAX; tests/test_cli.py checks that the lists agree).
TEMPLATE_NAMES = (
    "bingham",
    "bouc_wen",
    "normalized_bouc_wen",
    "dahl",
    "lugre",
    "spencer",
    "shear_thinning_spencer",
    "bouc_wen_lag",
    "spencer_lag",
    "shear_thinning_spencer_lag",
    "dahl_saturating",
    "lugre_saturating",
    "bouc_wen_saturating",
    "spencer_saturating",
    "bouc_wen_lag_saturating",
    "spencer_lag_saturating",
)


def add_parser(subparsers) -> None:
    """Register `jaxmr fit`."""
    names = ", ".join(TEMPLATE_NAMES)
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
            "file, why the fit stopped, unidentified parameters) and the operating "
            "range it was fitted on (displacement, velocity, input), which "
            "jaxmr.load_model gives back to the model."
        ),
    )
    command.add_argument(
        "--model",
        default=AUTO,
        metavar="NAME",
        help=f"{names}, or {AUTO} (default)",
    )
    command.add_argument(
        "--out",
        required=True,
        metavar="PARAMS.json",
        help="the parameter file to write (never one of the input files)",
    )
    command.add_argument("--force", action="store_true", help=FORCE_HELP)
    command.add_argument(
        "--candidates",
        metavar="NAMES",
        default=None,
        help=(
            "with --model auto: the comma-separated models to choose from (default: "
            "one of each family, bingham, dahl, lugre, bouc_wen, spencer, "
            "shear_thinning_spencer, the _lag variants of the last three when the "
            "input varies within a file, and the _saturating variants with 3 or more "
            "input levels: jaxmr.templates.default_candidates)"
        ),
    )
    command.add_argument(
        "--holdout",
        action="append",
        default=None,
        metavar="FILE",
        help=(
            "with --model auto: a file (one of FILE) held out to score the candidates "
            "on; repeat for several (default: two folds, chosen from the files "
            "(jaxmr.scores.cv_folds): every other interior input level held out, and "
            "every third file; a time fold (the last third, then the last half, of "
            "each file) fills in where there are too few levels or files)"
        ),
    )
    command.add_argument(
        "--finalists",
        type=int,
        default=None,
        metavar="N",
        help=(
            "with --model auto: the fewest screened candidates (a short fit on one "
            "cycle of each file) that get a full fit; every one within 1.5x of the "
            "best screened score does too (default 2)"
        ),
    )
    command.add_argument(
        "--smoothing",
        default="file",
        metavar="SECONDS",
        help=(
            "the width [s] of the moving average the measured force went through, "
            "applied to the model's force too; 'file' (default): each file's "
            "'# smoothing:' line, else 0"
        ),
    )
    command.add_argument(
        "--discard",
        default="file",
        metavar="SECONDS",
        help=(
            "the start [s] of each file left out of the error (the model still runs "
            "through it); 'file' (default): each file's '# discard:' line, else 0"
        ),
    )
    command.add_argument(
        "--saturating",
        action="append",
        default=None,
        metavar="FIELD",
        help=(
            "with a named --model: its current law for FIELD (e.g. alpha, the "
            "hysteretic force of bouc_wen or spencer; f_c for bingham) levels off "
            "with current (jaxmr.SaturatingLaw, started at the template's line); "
            "repeat for several; needs 3 or more input levels"
        ),
    )
    command.add_argument(
        "--channel-delay",
        action="store_true",
        help=(
            "fit a delay of the force channel against the motion channels too (each "
            "model seen through jaxmr.ChannelDelay, |delay| up to 10 ms or 5 sample "
            "intervals): for rigs whose force and motion are sampled or filtered apart"
        ),
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
        default=None,
        metavar="N",
        help="starts per fit: the data-scaled guess plus N-1 random ones (default "
        f"1; with --model auto {AUTO_STARTS}, chosen by benchmarks/starts_choice.py)",
    )
    command.add_argument("--accept-units", action="store_true", help=ACCEPT_UNITS_HELP)
    command.add_argument("files", nargs="+", metavar="FILE", help="CSV experiments")
    command.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr fit` (see `add_parser`)."""
    _check_options(args)
    out = Path(args.out)
    replacing = plan_outputs([out], args.files + (args.holdout or []), force=args.force)
    check_writable_file(out)
    folder = getattr(args, "compilation_cache_folder", None)
    # Where the compiled programs are kept, which a second fit of the same shapes
    # reads back (`cache.py`).
    print(
        f"compilation cache: {folder}" if folder else "compilation cache: off",
        flush=True,
    )
    experiments = _read(args)
    log = _FitLog(single=args.model != AUTO, terminal=sys.stdout.isatty())
    with _Interrupts() as interrupts:
        options = {"max_steps": args.max_steps}
        if args.starts > 1:
            options["starts"] = args.starts
            print(
                f"starts per fit: {args.starts} (the data-scaled guess and "
                f"{args.starts - 1} random one(s); the lowest loss is kept)",
                flush=True,
            )
        # The steps' progress (`log.step`, counted by `interrupts`), and the event
        # that a Ctrl-C sets to stop the fit with its best model so far.
        options["progress"] = interrupts.progress(log.step)
        options["stop"] = interrupts.stop
        start = time.perf_counter()
        try:
            name, result, selection = _fit_model(args, experiments, options, log)
        except KeyboardInterrupt:
            print(
                "\njaxmr fit: interrupted before any model was fitted; nothing written",
                file=sys.stderr,
            )
            return INTERRUPTED
        # From here on a Ctrl-C is deferred: the model is reported and written first.
        interrupts.finishing = True
        elapsed = time.perf_counter() - start
        warned = list(getattr(args, "warnings", []))
        report = _fit_report(
            name, args.files, experiments, result, elapsed, selection, warned
        )
        report["settings"] = _settings(args)
        _print_summary(name, result, elapsed, selection is not None)
        # Where the model was fitted, saved beside it (`jaxmr.load_model` gives it back).
        fitted_range = jaxmr.FittedRange.from_experiments(experiments)
        if _save_model(
            result.model, out, report, fitted_range, replacing=out in replacing
        ):
            interrupts.count += 1
        if _diverged(report, out):
            return 1
        return _exit_status(result, interrupts, out)


def _diverged(report: dict, out: Path) -> bool:
    """Say so (and return True) when the fitted model's simulation of an experiment
    diverged: its state left its bounds or stopped being finite (its RMSE is then
    not finite: null in the report's `per_file` rows, which pair each experiment
    with its file), so its forces are no fit, however finite."""
    bad = [
        f"{row['file']} (experiment {row['experiment']!r})"
        + (
            f" at t = {row['diverged_at_s']:g} s"
            if row["diverged_at_s"] is not None
            else ""
        )
        for row in report["per_file"]
        if row["rmse"] is None
    ]
    if bad:
        print(
            f"jaxmr fit: failed: the fitted model's simulation diverged on "
            f"{', '.join(bad)} (its state left its bounds or stopped being finite); "
            f"the parameters are in {out}, but they are no fit. Check that the "
            "displacement and velocity columns agree there (a step in one that the "
            "other does not show), or try another model or more starts (--starts)",
            file=sys.stderr,
        )
    return bool(bad)


def _check_options(args: argparse.Namespace) -> None:
    if args.model != AUTO and args.model not in TEMPLATE_NAMES:
        raise CLIError(
            f"unknown model {args.model!r}; choose one of "
            f"{', '.join(TEMPLATE_NAMES)}, or {AUTO}"
        )
    finalists = 1 if args.finalists is None else args.finalists
    if args.starts is None:
        args.starts = AUTO_STARTS if args.model == AUTO else 1
    if args.max_steps < 1 or args.starts < 1 or finalists < 1:
        raise CLIError("--max-steps, --starts and --finalists must be at least 1")
    if args.model != AUTO:
        # Said rather than ignored: the user meant them to change something.
        given = [
            flag
            for flag, value in (
                ("--candidates", args.candidates),
                ("--holdout", args.holdout),
                ("--finalists", args.finalists),
            )
            if value is not None
        ]
        if given:
            raise CLIError(
                f"{', '.join(given)}: only with --model {AUTO} (it chooses among "
                f"candidates); --model {args.model} fits that model alone"
            )
    for k, path in enumerate(args.files):
        for other in args.files[:k]:
            if same_file(path, other):
                raise CLIError(
                    f"{path} is given twice (as {other}): each file would count "
                    "twice in the fit and its standard errors shrink as if it held "
                    "twice the data"
                )


def _read(args: argparse.Namespace) -> list:
    """Read the files, with their smoothing and discarded start as the options say
    (`Experiment.smoothing`, `.discard`), and say what was read."""
    # An implausible unit stops the fit (a file in mm fits to nonsense) unless
    # --accept-units.
    experiments = read_experiments(
        args.files, need_force=True, why="fitting", accept_units=args.accept_units
    )
    # A file `jaxmr predict` wrote holds the model's force, not a measurement: a fit
    # to it fits a model to a model (`jaxmr report` only warns, as comparing is
    # harmless).
    predicted = [str(p) for p in args.files if predicted_by_jaxmr(p)]
    if predicted:
        raise CLIError(
            f"the force of {', '.join(predicted)} was predicted by jaxmr (its "
            "'# F:' or '# T:' line says 'predicted by jaxmr'), not measured: fit the "
            "measured files"
        )
    experiments = with_processing(
        experiments, args.smoothing, "smoothing", "--smoothing"
    )
    experiments = with_processing(experiments, args.discard, "discard", "--discard")
    _, input_unit = units(experiments[0])
    print(f"read {len(experiments)} file(s):", flush=True)
    for path, e in zip(args.files, experiments):
        i = np.asarray(e.current)
        level = f"{i[0]:g}" if e.is_constant_current else f"{i.min():g}..{i.max():g}"
        extra = "".join(
            [
                f", smoothed over {e.smoothing:g} s" if e.smoothing else "",
                f", first {e.discard:g} s discarded" if e.discard else "",
            ]
        )
        print(
            f"  {path}: {len(e)} samples, {e.duration:g} s, {level} {input_unit}{extra}",
            flush=True,
        )
    if not any(_reverses(e) for e in experiments):
        # A constant-speed test is fine among others (a brake's torque against
        # current at several speeds), but with no reversal anywhere a hysteresis
        # model's state and loop are not seen at all.
        warnings.warn(
            "no file reverses its velocity (each moves one way only): the fit sees "
            "no hysteresis loop, so a hysteretic model's parameters are guesses; fit "
            "records of whole cycles",
            UserWarning,
            stacklevel=2,
        )
    return experiments


def _reverses(experiment) -> bool:
    """Whether the velocity changes sign (beyond 1 % of its largest size)."""
    v = np.asarray(experiment.v, dtype=float)
    floor = 0.01 * float(np.max(np.abs(v)))
    return bool(np.any(v > floor) and np.any(v < -floor))


def _fit_model(args, experiments: list, options: dict, log: "_FitLog"):
    """Fit the model of `--model`, or select one (`auto`).

    **Returns:** its name, its `FitResult`, and the `Selection` (None for one model).
    """
    if args.model == AUTO:
        if args.saturating:
            raise CLIError(
                "--saturating bends a named model's laws: give --model (e.g. "
                "--model bouc_wen --saturating alpha)"
            )
        selection = _select(args, experiments, options, log)
        return selection.name, selection.result, selection
    name, result = _fit_one(args, experiments, options)
    return name, result, None


def _fit_one(args, experiments: list, options: dict):
    """Fit the template `--model` (through a channel delay with `--channel-delay`)."""
    import jaxmr.templates

    name = args.model
    template = jaxmr.templates.MODEL_TEMPLATES[name]
    if args.saturating:
        template = jaxmr.templates.with_saturation(template, tuple(args.saturating))
        name = f"{name} (saturating {', '.join(args.saturating)})"
    if args.channel_delay:
        template = jaxmr.templates.with_channel_delay(template)
        name = f"{name}{DELAY_SUFFIX}"
    try:
        model = template(experiments)
    except ValueError as e:
        raise CLIError(str(e)) from e
    print(f"fitting {name}...", flush=True)
    try:
        # Each experiment's own smoothing and discard (`Experiment`'s).
        result = jaxmr.fit(model, experiments, **options)
    except ValueError as e:  # data `fit` refuses, e.g. a constant force
        raise CLIError(str(e)) from e
    return name, result


def _candidates(args, experiments) -> list[str] | dict:
    """The candidates of `auto`: the names of `--candidates` (default the library's,
    `jaxmr.templates.default_candidates`), or
    with `--channel-delay` their templates behind a channel delay, by name."""
    import jaxmr.templates

    if args.candidates is None:
        names = jaxmr.templates.default_candidates(experiments)
    else:
        names = [c.strip() for c in args.candidates.split(",") if c.strip()]
        unknown = [c for c in names if c not in TEMPLATE_NAMES]
        if unknown or not names:
            raise CLIError(
                f"--candidates: unknown model(s) {', '.join(map(repr, unknown))}; "
                f"choose from {', '.join(TEMPLATE_NAMES)}"
                if unknown
                else "--candidates names no model"
            )
    if not args.channel_delay:
        return names
    return {
        f"{c}{DELAY_SUFFIX}": jaxmr.templates.with_channel_delay(
            jaxmr.templates.MODEL_TEMPLATES[c]
        )
        for c in names
    }


def _held_out(args, experiments: list) -> tuple:
    """The experiments as `select_model` takes them: `(train, test)` with
    `--holdout`, else `(all,)` (it holds out a part itself)."""
    if not args.holdout:
        return (experiments,)
    held = {os.path.abspath(p) for p in args.holdout}
    unknown = held - {os.path.abspath(p) for p in args.files}
    if unknown:
        raise CLIError(
            "--holdout: not among the input files: " + ", ".join(sorted(unknown))
        )
    keep = [os.path.abspath(p) not in held for p in args.files]
    if all(keep) or not any(keep):
        raise CLIError("--holdout must leave at least one file to fit on")
    train = [e for e, k in zip(experiments, keep) if k]
    test = [e for e, k in zip(experiments, keep) if not k]
    return train, test


def _select(args, experiments: list, options: dict, log: "_FitLog"):
    """`--model auto`: `jaxmr.select_model` among the candidates; prints the
    ranking."""
    import jaxmr.scores

    candidates = _candidates(args, experiments)
    data = _held_out(args, experiments)
    print(f"selecting among {', '.join(candidates)} by held-out NRMSE...", flush=True)
    try:
        selection = jaxmr.select_model(
            candidates,
            *data,  # each experiment with its own smoothing and discard
            # The library's default unless given (`jaxmr.select_model`'s).
            **({} if args.finalists is None else {"finalists": args.finalists}),
            callback=log.event,
            log=log.line,
            **options,
        )
    except (RuntimeError, ValueError) as e:  # every candidate failed, or bad data
        raise CLIError(str(e)) from e
    print(f"({selection.holdout})")
    print(jaxmr.scores.score_table(selection.scores))
    if selection.kept == "refit":
        print(
            f"kept {selection.name}'s refit from its training fit: a lower loss than "
            "its fit from its own start"
        )
    return selection


def _print_summary(name: str, result, elapsed: float, selected: bool) -> None:
    """`FitResult`'s own summary (its verdict in the words of `FitResult.outcome`,
    which the report records too), after the command's time: the whole selection's
    when `selected` (`auto`)."""
    what = "selected and fitted in" if selected else "fitted in"
    print(f"\n{name}: {what} {elapsed:.1f} s")
    print(result)


def _exit_status(result, interrupts: "_Interrupts", out: Path) -> int:
    """0, or `INTERRUPTED` (saying so) when a Ctrl-C stopped the fit or came while
    the model was finished."""
    if result.interrupted:
        print(
            f"jaxmr fit: interrupted; the best model so far is in {out}",
            file=sys.stderr,
        )
        return INTERRUPTED
    if interrupts.count:
        print(
            f"jaxmr fit: interrupted while finishing; the fitted model is in {out}",
            file=sys.stderr,
        )
        return INTERRUPTED
    return 0


# ---------------------------------------------------------------------------------------
# While it fits: Ctrl-C and progress


def _in_jax(frame) -> bool:
    """Whether the stack from `frame` down holds JAX's own code (by its modules'
    names: XLA's compiler polls for Ctrl-C from there)."""
    while frame is not None:
        name = frame.f_globals.get("__name__", "")
        if name in ("jax", "jaxlib") or name.startswith(("jax.", "jaxlib.")):
            return True
        frame = frame.f_back
    return False


class _Interrupts:
    """Ctrl-C (SIGINT) while `jaxmr fit` runs, as a context manager.

    The first Ctrl-C sets `stop`, the event that `fit` and `select_model` check after
    every Levenberg–Marquardt step: the fit under way stops there with its best model
    so far, and no other starts. Before the first step it raises `KeyboardInterrupt`
    at once instead (nothing to lose), unless JAX is running (an exception raised
    through XLA's compiler crashed the process later). Every later Ctrl-C, and any
    while the command is `finishing` (reporting and writing the model), is only
    counted and acknowledged: it cannot lose the model. `count` is how many came.
    Python allows signal handlers in the main thread only; elsewhere nothing changes.
    """

    def __init__(self):
        self.count = 0
        self.steps = 0
        self.finishing = False
        self.stop = threading.Event()
        self._installed = False
        self._previous = None

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(self, *exc_info):
        if self._installed:
            previous = signal.SIG_DFL if self._previous is None else self._previous
            signal.signal(signal.SIGINT, previous)
        return False

    def _handle(self, signum, frame):
        self.count += 1
        if self.count > 1 or self.finishing:
            _say("Ctrl-C again: ignored while the model is finished and written")
        elif not self.steps and not _in_jax(frame):
            raise KeyboardInterrupt
        else:
            self.stop.set()
            _say(
                "Ctrl-C: stopping at the fit's next step (after JAX's current "
                "computation or compilation); the best model so far will be written"
            )

    def progress(self, report: Callable[[int, float], None]):
        """A fit's `progress(step, loss)`: counts the steps, then `report`."""

        def call(step, loss):
            self.steps += 1
            report(step, loss)

        return call


def _say(line: str) -> None:
    print(f"\njaxmr fit: {line}", file=sys.stderr, flush=True)


# A line of progress every this many Levenberg–Marquardt steps when the output is not a
# terminal (a log file, a pipe): on a terminal a single fit prints every 2 s and
# `auto` only its candidates' lines, which left a log file silent for minutes.
PROGRESS_STEPS = 10


class _FitLog:
    """What `jaxmr fit` prints while it fits.

    `step` is the fits' `progress(step, loss)` (a `jaxmr.ProgressPrinter`, its label
    the fit under way); `event` is the `callback` of `select_model` (`--model auto`),
    which labels the step lines with the fit that starts; `line` is its `log`, which
    prints `select_model`'s own lines (one per start and end of each fit).
    """

    def __init__(self, *, single: bool, terminal: bool):
        if not terminal:
            seconds, steps = None, PROGRESS_STEPS
        else:  # `auto` on a terminal: its candidates' lines only
            seconds, steps = (2.0 if single else None), None
        self.step = jaxmr.ProgressPrinter(
            "fit", seconds=seconds, steps=steps, indent="    "
        )

    def event(self, event) -> None:
        if isinstance(event, jaxmr.FitStarted):
            self.step.label = f"{event.name} ({event.stage})"

    @staticmethod
    def line(text: str) -> None:
        print(f"  {text}", flush=True)


# ---------------------------------------------------------------------------------------
# What it reports and writes


def _save_model(
    model, out: Path, report: dict, fitted_range, *, replacing: bool
) -> bool:
    """Write the parameter file atomically (`_write_atomically`). A write stopped by a
    `KeyboardInterrupt` (a Ctrl-C that came past `_Interrupts`) is made again. If the
    file cannot be written, the model goes to a new file in the temporary directory,
    which the error names.

    **Returns:** whether a `KeyboardInterrupt` came during the write.
    """

    def write(path):
        # `path` is a file this command made for it (the atomic write's temporary
        # file, or the rescue's `mkstemp`): the user's `--out` is guarded above.
        jaxmr.save_model(
            model, path, fitted_range=fitted_range, report=report, overwrite=True
        )

    interrupted = False
    for _ in range(3):
        try:
            write_atomically(out, write, replacing=replacing)
            return interrupted
        except KeyboardInterrupt:
            interrupted = True
            print(
                "\njaxmr fit: Ctrl-C while writing the model; writing it again",
                file=sys.stderr,
                flush=True,
            )
        except CLIError as e:
            raise CLIError(f"{e}{_rescue(write)}") from e
    raise CLIError(f"interrupted 3 times while writing {str(out)!r}{_rescue(write)}")


def _rescue(write) -> str:
    """Save the model (`write(path)`) to a new file in the temporary directory; the
    end of the error message that says where (or that it could not)."""
    try:
        descriptor, name = tempfile.mkstemp(prefix="jaxmr-fit-", suffix=".json")
    except OSError as e:
        return f"; the model could not be saved elsewhere either ({e.strerror or e})"
    os.close(descriptor)
    try:
        write(Path(name))
    except (OSError, KeyboardInterrupt) as e:
        Path(name).unlink(missing_ok=True)
        return f"; the model could not be saved elsewhere either ({e})"
    return f"; the model was saved to {name} instead"


def _settings(args) -> dict:
    """The options that chose and ran the fit, as given (a colleague reruns the same
    command from them; the files are the report's `files`)."""
    return {
        "model": args.model,
        "candidates": args.candidates,
        "holdout": [str(p) for p in args.holdout] if args.holdout else None,
        "saturating": args.saturating,
        "channel_delay": args.channel_delay,
        "max_steps": args.max_steps,
        "starts": args.starts,
        "finalists": args.finalists,
        "smoothing": args.smoothing,
        "discard": args.discard,
        "accept_units": args.accept_units,
    }


def _fit_report(name, files, experiments, result, elapsed, selection, warnings) -> dict:
    """The report saved with the model (`jaxmr.fit_report`, which `jaxmr report`
    reads), with the command's own entries: the fit's wall time and its warnings."""
    report = jaxmr.fit_report(
        selection if selection is not None else result,
        experiments,
        files=files,
        template=name,
    )
    report["fit_time_s"] = round(elapsed, 3)
    report["warnings"] = warnings
    return report
