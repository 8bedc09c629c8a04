"""`jaxmr convert`: a public dataset as canonical CSV files
(`jaxmr.data.convert_dataset`), or a user's own tables (`jaxmr convert table`,
`jaxmr.data.read_table`)."""

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

import jaxmr

from .errors import CLIError
from .files import (
    ACCEPT_UNITS_HELP,
    checking_units,
    plan_outputs,
    prepare_directory,
    write_atomically,
)

if TYPE_CHECKING:
    import jaxmr.data  # at run time `jaxmr.data` is imported on first use (it imports JAX)

# The names of `jaxmr.data.DATASETS`, for the help (`jaxmr.data` imports JAX;
# tests/test_cli.py checks that the lists agree).
DATASET_NAMES = ("utfsm", "nees", "boucwen")
TABLE = "table"  # a user's own tables


def add_parser(subparsers) -> None:
    """Register `jaxmr convert`."""
    command = subparsers.add_parser(
        "convert",
        help="turn your own tables or a public dataset into jaxmr's canonical CSV files",
        description=(
            "`jaxmr convert table FILE... --columns t,x:mm,v:mm/s,F:kN --current 0.5 "
            "--out DIR` converts your own measurement tables (any of tabs, semicolons, "
            "commas or whitespace between columns, '.' or ',' as the decimal mark, "
            "detected; header lines before the numbers skipped; units as declared) "
            "into canonical CSV files in SI units, one per table, named after it "
            "(jaxmr.data.read_table). `jaxmr convert DATASET SOURCE --out DIR` "
            "converts a public dataset that jaxmr's loaders know ("
            + ", ".join(DATASET_NAMES)
            + ") into canonical CSV files (one per experiment, with the dataset's own "
            "smoothing and discarded start as comment lines, which `jaxmr fit` reads). "
            "Existing files are never replaced without --force."
        ),
    )
    command.add_argument(
        "dataset",
        choices=(TABLE, *DATASET_NAMES),
        help="'table' for your own files, or a public dataset",
    )
    command.add_argument(
        "source",
        nargs="+",
        metavar="SOURCE",
        help="the tables (with 'table'), or the dataset's directory or file as published",
    )
    command.add_argument("--out", required=True, metavar="DIR", help="output directory")
    command.add_argument(
        "--force", action="store_true", help="replace files that already exist"
    )
    table = command.add_argument_group("tables (`jaxmr convert table`)")
    table.add_argument(
        "--columns",
        metavar="SPEC",
        help=(
            "the tables' columns in order, each a name with an optional unit after a "
            "colon (default SI), e.g. t,x:mm,v:mm/s,F:kN. Names: t [s, ms, us, min]; "
            "x [m, cm, mm, um, in], v [m/s, cm/s, mm/s, in/s] (optional: computed from "
            "x), F [N, kN, daN, lbf] for a damper; theta [rad, mrad, deg], omega "
            "[rad/s, deg/s, rpm], T [N·m, Nm, N·mm, kN·m] for a brake; the input i "
            "[A, mA] or u [V, mV]; _ to leave a column out. A minus sign before a "
            "unit negates a motion or force column (F:-kN): for a load cell read the "
            "other way round"
        ),
    )
    level = table.add_mutually_exclusive_group()
    level.add_argument(
        "--current",
        metavar="A",
        help=(
            "the constant coil current [A] of tables without an i column: one value "
            "for all, or one per table, comma-separated (e.g. 0,0.5,1)"
        ),
    )
    level.add_argument(
        "--voltage",
        metavar="V",
        help="the constant command voltage [V] instead, as --current",
    )
    for flag, what in (
        ("--smoothing", "the width [s] of the moving average the force went through"),
        ("--discard", "the start [s] to leave out of every score"),
    ):
        table.add_argument(
            flag,
            type=float,
            default=0.0,
            metavar="SECONDS",
            help=f"{what}, written into the files for `jaxmr fit` (default 0: none)",
        )
    table.add_argument("--accept-units", action="store_true", help=ACCEPT_UNITS_HELP)
    command.set_defaults(run=run)


def _levels(text: str, flag: str, count: int) -> list[float]:
    """The values of --current or --voltage: one for every table, or one each."""
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        raise CLIError(
            f"{flag}: expected a number or comma-separated numbers, got {text!r}"
        ) from None
    if len(values) == 1:
        return values * count
    if len(values) != count:
        raise CLIError(
            f"{flag}: {len(values)} values for {count} table(s); give one for all or "
            "one per table"
        )
    return values


def run_table(args: argparse.Namespace) -> int:
    """Run `jaxmr convert table`: every table read (and refused) before any file is
    written."""
    if not args.columns:
        raise CLIError("convert table: --columns is required (e.g. t,x:mm,v:mm/s,F:kN)")
    sources = [Path(s) for s in args.source]
    for source in sources:
        if not source.is_file():
            raise CLIError(
                f"{source}: {'is a directory' if source.is_dir() else 'no such file'}"
            )
    out = Path(args.out)
    targets = [out / f"{jaxmr.data.experiment_name(s)}.csv" for s in sources]
    stems = [t.name for t in targets]
    repeated = sorted({n for n in stems if stems.count(n) > 1})
    if repeated:
        raise CLIError(
            f"two tables would be written to the same file(s) {repeated}: convert "
            "tables with the same name into different --out folders"
        )
    replacing = plan_outputs(targets, sources, force=args.force)
    n = len(sources)
    named = {c.split(":")[0].strip() for c in args.columns.split(",")}
    if not ({"i", "u"} & named or args.current or args.voltage):
        # Said here in the command line's words (the library names its arguments).
        raise CLIError(
            "no input: give --current LEVELS [A] or --voltage LEVELS [V] (one per "
            "table), or an `i` [A] or `u` [V] column in --columns"
        )
    currents = _levels(args.current, "--current", n) if args.current else [None] * n
    voltages = _levels(args.voltage, "--voltage", n) if args.voltage else [None] * n

    def read(source, current, voltage):
        try:
            return jaxmr.data.read_table(
                source,
                args.columns,
                current=current,
                voltage=voltage,
                smoothing=args.smoothing,
                discard=args.discard,
            )
        except ValueError as e:
            raise CLIError(str(e)) from e
        except OSError as e:
            raise CLIError(f"cannot read {source}: {e.strerror or e}") from e

    # Every table read before a refusal, which then names each one in other units.
    experiments = checking_units(
        lambda: [read(*a) for a in zip(sources, currents, voltages)],
        accept=args.accept_units,
        fix="declare the unit in --columns (e.g. x:mm, t:ms, i:mA)",
        sign_fix="negate the column named above in --columns: a minus "
        "sign before its unit (e.g. F:-kN, v:-mm/s, or F:- in SI)",
    )
    prepare_directory(out)
    for source, experiment, target in zip(sources, experiments, targets):
        comment = (
            f"converted by jaxmr {jaxmr.__version__} (jaxmr convert table) from "
            f"{source} with --columns {args.columns}"
        )
        write_atomically(
            target,
            lambda p, e=experiment, c=comment: jaxmr.data.write_csv(e, p, comment=c),
            replacing=target in replacing,
        )
        # The input each table was given, so that a list of levels paired with files
        # in another order than meant (a shell glob sorts 0.5A before 0A) shows.
        print(f"{source} -> {target} ({_input_words(experiment)})")
    print(f"{len(targets)} file(s) in {out}")
    return 0


def _input_words(experiment) -> str:
    """The experiment's input in words: its constant level, or its range."""
    unit = "V" if experiment.drive == "voltage" else "A"
    values = np.asarray(experiment.current, float)
    low, high = float(np.min(values)), float(np.max(values))
    if low == high:
        return f"{experiment.drive} {low:g} {unit}"
    return f"{experiment.drive} {low:g} to {high:g} {unit}"


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr convert` (see `add_parser`)."""
    if args.dataset == TABLE:
        return run_table(args)
    table_options = [
        flag
        for flag, value in (
            ("--columns", args.columns),
            ("--current", args.current),
            ("--voltage", args.voltage),
            ("--accept-units", args.accept_units),
            ("--smoothing", args.smoothing),
            ("--discard", args.discard),
        )
        if value
    ]
    if table_options:
        raise CLIError(
            f"{', '.join(table_options)}: for `jaxmr convert table` only (a public "
            "dataset's units are known)"
        )
    if len(args.source) != 1:
        raise CLIError(
            f"convert {args.dataset}: give one SOURCE, got {len(args.source)}"
        )
    args.source = args.source[0]
    # convert_dataset applies the rule of every command itself (never over the
    # source, an existing file only with force, each file through a rename).
    out = Path(args.out)
    existed = set(out.iterdir()) if args.force and out.is_dir() else set()
    try:
        written = jaxmr.data.convert_dataset(
            args.dataset, args.source, args.out, force=args.force
        )
    except (ValueError, FileExistsError, OSError) as e:
        raise CLIError(str(e)) from e
    for path in written:
        replaced = " (replaced the existing file)" if Path(path) in existed else ""
        print(f"wrote {path}{replaced}")
    print(f"{len(written)} file(s) in {args.out}")
    return 0
