"""`jaxmr design`: plan the tests that identify a model best (`jaxmr.design_experiments`)
and write them ready to drive a rig.

The command line's rules hold (a `CLIError` for what the user can fix, never over an
input, every file whole or not at all), but unlike the other commands it never replaces
a file, not even on request: a plan is a record of what was decided, so an existing
output is an error and nothing is written.
"""

import argparse
import csv
import dataclasses
import math
import re
from pathlib import Path

import numpy as np

import jaxmr

from .errors import CLIError
from .files import (
    load_model,
    prepare_directory,
    read_experiments,
    refuse_inputs,
    with_processing,
    write_atomically,
    write_text,
)

PLAN = "plan.csv"
# The predicted standard errors, as data (they were printed only, so a plan could not
# be archived with them).
ERRORS = "errors.csv"
ERROR_COLUMNS = ("parameter", "value", "std_error_plan", "std_error_all")
PLAN_COLUMNS = ("test", "file", "amplitude", "frequency", "current", "duration")
# The starts the command's last line advises for the fit of the planned tests.
ADVISED_STARTS = 4


def add_parser(subparsers) -> None:
    """Register `jaxmr design`."""
    command = subparsers.add_parser(
        "design",
        help="choose the tests that identify a model best; write them as CSV files",
        description=(
            "Choose K tests from a menu (canonical CSV files of motions and inputs, "
            "or a grid of sine tests) that identify MODEL's fitted parameters best: "
            "D-optimal (largest log det of the Fisher information from the exact "
            "Jacobian), or A-optimal for --parameters. Writes DIR/plan.csv (one row "
            "per test: amplitude [m or rad], frequency [Hz], current [A or V], "
            "duration [s]), DIR/errors.csv (each fitted parameter's predicted "
            "standard error with the plan and with every candidate) and one "
            "canonical CSV per test (motion and input, no force), ready to drive a "
            "rig. Never replaces an existing file."
        ),
    )
    command.add_argument(
        "model",
        metavar="MODEL",
        help="a parameter file: the JSON `jaxmr fit` writes (its report names the "
        "fitted parameters, which are designed for), or a model saved by "
        "jaxmr.save_model with its constraint wrappers (jaxmr.Fixed, Positive, ...)",
    )
    command.add_argument(
        "-k", type=int, required=True, metavar="K", help="how many tests to choose"
    )
    command.add_argument("--out", required=True, metavar="DIR", help="output directory")
    menu = command.add_argument_group(
        "the menu: candidate files, or a grid of sine tests (every combination)"
    )
    menu.add_argument(
        "--candidates",
        nargs="+",
        metavar="FILE",
        help="canonical CSV files of candidate tests (a force column is not read)",
    )
    menu.add_argument(
        "--amplitudes", nargs="+", type=float, metavar="A", help="[m] ([rad], --rotary)"
    )
    menu.add_argument("--frequencies", nargs="+", type=float, metavar="F", help="[Hz]")
    menu.add_argument(
        "--currents", nargs="+", type=float, metavar="I", help="[A] ([V], --voltage)"
    )
    menu.add_argument(
        "--cycles", type=float, default=3.0, help="periods per sine test (default 3)"
    )
    menu.add_argument(
        "--sample-rate",
        type=float,
        default=1000.0,
        metavar="HZ",
        help="the rig's sampling rate for sine tests (default 1000)",
    )
    menu.add_argument("--rotary", action="store_true", help="sine tests of a brake")
    menu.add_argument(
        "--voltage", action="store_true", help="the sine tests' input is a voltage"
    )
    command.add_argument(
        "--already",
        nargs="+",
        metavar="FILE",
        default=[],
        help="canonical CSV files of tests already run: their information is "
        "counted before choosing (sequential design)",
    )
    command.add_argument(
        "--parameters",
        nargs="+",
        metavar="NAME",
        help="A-optimal for these parameters (names as `jaxmr fit` reports them, "
        "e.g. .alpha.b) instead of D-optimal for all",
    )
    command.add_argument(
        "--criterion",
        choices=("D", "A", "I"),
        help="D-optimal (default), A-optimal for --parameters (the default with "
        "them), or I-optimal: the smallest predicted variance of the fitted force "
        "over every candidate, for a model meant to predict the menu",
    )
    command.add_argument(
        "--weighting",
        choices=("nrmse", "force"),
        default="nrmse",
        help="how the fit will weigh the tests, as `jaxmr fit` (default nrmse)",
    )
    command.add_argument(
        "--noise",
        type=float,
        default=1.0,
        help="the weighted residual's standard deviation (with --weighting force: "
        "the force noise [N or N·m]); scales the predicted standard errors only",
    )
    command.add_argument(
        "--discard",
        default="file",
        metavar="SECONDS",
        help="the start of each test left out of the fit: a number, or 'file' "
        "(default: each file's `# discard:` line; one period for a sine test)",
    )
    command.add_argument(
        "--smoothing",
        default="file",
        metavar="SECONDS",
        help="the moving average the force goes through: a number, or 'file' "
        "(default: each file's `# smoothing:` line; none for a sine test)",
    )
    command.set_defaults(run=run)


def _free_model(model, data: dict, path: str):
    """The model with the wrappers a design needs: as saved if it has any, else the
    parameters its fit report names free (`Positive` where positive), the rest
    `Fixed`."""
    import jax

    def is_parameter(x) -> bool:
        return isinstance(x, jaxmr.AbstractParameter)

    if any(is_parameter(x) for x in jax.tree.leaves(model, is_leaf=is_parameter)):
        return model
    # `jaxmr fit` (and `jaxmr.save_fit`) name them in the fit report; a file saved
    # by hand may name them at the top.
    saved = data.get("report")
    fit_report: dict = saved if isinstance(saved, dict) else {}
    report = data.get("parameters") or fit_report.get("parameters")
    if not isinstance(report, list) or not report:
        raise CLIError(
            f"{path}: no fit report naming the fitted parameters and no constraint "
            "wrappers: use the file `jaxmr fit` wrote, or save the model with its "
            "wrappers (jaxmr.save_model(result.constrained, path))"
        )
    named = {str(entry.get("name")) for entry in report if isinstance(entry, dict)}

    def wrap(key_path, leaf):
        name = jax.tree_util.keystr(key_path)
        value = np.asarray(leaf)
        names = (
            {name} if value.ndim == 0 else {f"{name}[{k}]" for k in range(value.size)}
        )
        if not names & named:
            return jaxmr.Fixed(value)
        return jaxmr.Positive(value) if np.all(value > 0) else leaf

    return jax.tree_util.tree_map_with_path(wrap, model)


def _file_name(name: str, taken: set) -> str:
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "test"
    candidate, k = f"{stem}.csv", 2
    while candidate.lower() in taken or candidate.lower() == PLAN:
        candidate, k = f"{stem}_{k}.csv", k + 1
    taken.add(candidate.lower())
    return candidate


def _menu(args):
    """The candidates, each with its discard and smoothing [s] (`Experiment.discard`,
    `.smoothing`), and their names for the output files."""
    grid = (args.amplitudes, args.frequencies, args.currents)
    if args.candidates and any(g is not None for g in grid):
        raise CLIError("give either --candidates or a sine grid, not both")
    if args.candidates:
        tests = _processed(
            read_experiments(args.candidates, need_force=False, why=""), args
        )
        return tests, [Path(p).stem for p in args.candidates]
    if any(g is None for g in grid):
        raise CLIError(
            "no menu: give --candidates FILE..., or --amplitudes, --frequencies and "
            "--currents for a grid of sine tests"
        )
    for values, flag in zip(grid, ("--amplitudes", "--frequencies")):
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise CLIError(f"{flag}: every value must be > 0")
    if not (math.isfinite(args.cycles) and args.cycles > 0):
        raise CLIError("--cycles must be > 0")
    if not (math.isfinite(args.sample_rate) and args.sample_rate > 0):
        raise CLIError("--sample-rate must be > 0 Hz")
    tests = jaxmr.sine_grid(
        args.amplitudes,
        args.frequencies,
        args.currents,
        cycles=args.cycles,
        sample_rate=args.sample_rate,
        rotary=args.rotary,
        drive="voltage" if args.voltage else "current",
    )
    # A sine test's default ('file'): one period discarded, no smoothing.
    periods = [
        1.0 / f
        for _ in args.amplitudes
        for f in args.frequencies
        for _ in args.currents
    ]
    tests = [dataclasses.replace(t, discard=p) for t, p in zip(tests, periods)]
    return _processed(tests, args), [t.name for t in tests]


def _processed(tests, args) -> list:
    """The tests with the smoothing and discard of --smoothing and --discard."""
    tests = with_processing(tests, args.discard, "discard", "--discard")
    return with_processing(tests, args.smoothing, "smoothing", "--smoothing")


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr design` (see `add_parser`)."""
    import jaxmr.data

    model, data = load_model(args.model)
    model = _free_model(model, data, args.model)
    tests, stems = _menu(args)
    if not 1 <= args.k <= len(tests):
        raise CLIError(f"-k must be from 1 to the number of candidates ({len(tests)})")
    already = _processed(read_experiments(args.already, need_force=False, why=""), args)
    kinds = {(t.rotary, t.drive) for t in list(tests) + already}
    if len(kinds) > 1:
        raise CLIError(
            "the candidates and --already mix linear and rotary devices or current "
            "and voltage inputs; give tests of one device"
        )

    # Every output path is known before the design runs: check them first.
    out = Path(args.out)
    taken: set = set()
    files = [_file_name(stem, taken) for stem in stems]
    inputs = [args.model] + list(args.candidates or []) + list(args.already)
    refuse_inputs([out / PLAN, out / ERRORS] + [out / f for f in files], inputs)
    _refuse_existing([out / PLAN, out / ERRORS])
    created = not out.exists()
    prepare_directory(out)

    try:
        design = jaxmr.design_experiments(
            model,
            tests,
            args.k,
            parameters=args.parameters,
            criterion=args.criterion,
            already=already,
            weighting=args.weighting,
            noise=args.noise,  # each test with its own discard and smoothing
        )
    except (ValueError, TypeError) as e:
        # Nothing written: the folder made for the plan goes too (it was left empty).
        if created and not any(out.iterdir()):
            out.rmdir()
        raise CLIError(str(e)) from e
    print(design, flush=True)
    print(
        f"(standard errors for a weighted residual of standard deviation --noise "
        f"{args.noise:g}, white: scale them to your rig's noise; correlated noise "
        "widens them. The ranking of the tests does not depend on it.)",
        flush=True,
    )

    chosen = [out / files[k] for k in design.indices]
    _refuse_existing([out / PLAN, out / ERRORS] + chosen)
    rows = design.plan_table()
    write_text(out / PLAN, lambda f: _write_plan(f, design, rows, chosen))
    write_text(out / ERRORS, lambda f: _write_errors(f, design, args.noise))
    for k, path in zip(design.indices, chosen):
        # The motion and input only: a measured candidate's force is not the plan's.
        # Its discard and smoothing are written (when not 0) for the fit to come.
        planned = dataclasses.replace(tests[k], force=None)
        write_atomically(
            path,
            lambda target, e=planned: jaxmr.data.write_csv(
                e, target, comment="planned by jaxmr design"
            ),
        )
    print(f"{len(chosen)} test(s), {PLAN} and {ERRORS} in {out}")
    # A few tests at the ends of the menu can leave a model's parameters two minima
    # apart: on simulated dampers a one-start fit of a 4-test plan stalled in the
    # wrong one on 4 of 10 noise draws, and 4 starts found the right one
    # (benchmarks/README.md, design_criterion_choice.py).
    print(
        f"next: run these tests on the rig, then fit them from several starts "
        f"(jaxmr fit --starts {ADVISED_STARTS} ...): a small plan can leave the "
        "parameters two minima apart"
    )
    return 0


def _refuse_existing(paths) -> None:
    existing = [p for p in paths if p.exists() or p.is_symlink()]
    if existing:
        listed = ", ".join(repr(str(p)) for p in existing[:3])
        more = f" and {len(existing) - 3} more" if len(existing) > 3 else ""
        raise CLIError(
            f"{listed}{more} already exist{'s' if len(existing) == 1 else ''}: "
            "`jaxmr design` never replaces a file; choose another --out (nothing "
            "was written)"
        )


def _write_errors(f, design, noise: float) -> None:
    """The fitted parameters with their predicted standard errors: with the plan
    (and any --already tests), and with every candidate."""
    f.write(
        f"# jaxmr experiment plan: predicted standard errors ({design.criterion_text}), "
        f"each in its parameter's unit, for a weighted residual of standard "
        f"deviation --noise {noise:g} (white): scale them to your rig's noise\n"
    )
    writer = csv.writer(f, lineterminator="\n")
    writer.writerow(ERROR_COLUMNS)
    for name, value, se, se_all in zip(
        design.names, design.values, design.std_errors, design.std_errors_all
    ):
        writer.writerow([name] + [f"{x:.10g}" for x in (value, se, se_all)])


def _write_plan(f, design, rows, paths) -> None:
    unit = "rad" if design.plan[0].rotary else "m"
    current = "V" if getattr(design.plan[0], "drive", "current") == "voltage" else "A"
    f.write(
        f"# jaxmr experiment plan: {design.criterion_text}, {len(rows)} of "
        f"{len(design.candidate_names)} candidate tests\n"
        f"# units: amplitude [{unit}] (half the peak-to-peak motion), frequency [Hz], "
        f"current [{current}] (empty if it varies), duration [s]\n"
    )
    writer = csv.writer(f, lineterminator="\n")
    writer.writerow(PLAN_COLUMNS)
    for row, path in zip(rows, paths):
        writer.writerow(
            [row["name"], path.name]
            + [
                "" if not math.isfinite(row[key]) else f"{row[key]:.10g}"
                for key in PLAN_COLUMNS[2:]
            ]
        )
