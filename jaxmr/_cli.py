"""The `jaxmr` command line: `jaxmr demo`, `fit`, `predict`, `report` and `convert`.

Each subcommand is a `_add_<name>(subparsers)` that registers its arguments and a
`_<name>(args) -> int` that runs it; `main` parses, dispatches and turns a `CLIError`
into a message on stderr and exit status 1 (argparse's usage errors exit with 2), and
Ctrl-C into exit status 130.

Every file a command writes follows one rule (`_plan_outputs`, `_write_atomically`):
never over one of the command's inputs (not even with `--force`); over another existing
file only with `--force`, and then the command says what it replaced; through a
temporary file in the same directory and a rename, so that an error (a full disk) or an
interrupt never leaves half a file.
"""

import argparse
import csv
import hashlib
import json
import math
import os
import re
import secrets
import signal
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

# Light imports only: `jaxmr --help` and a usage error must not wait seconds for JAX.
# `jaxmr/__init__.py` imports its public names on first use, `jaxmr.plot` imports
# matplotlib when it draws, and JAX with jaxmr's models and identification (and
# `jaxmr.data`, which builds on them) are imported by the commands that use them.
import jaxmr
import jaxmr.plot

if TYPE_CHECKING:
    import jaxmr.data  # at run time `jaxmr.data` is imported on first use

# The candidates of `--model auto`: the richest structures first (their screening fits
# decide), each behind a fitted input lag when the input varies within a file.
AUTO_CANDIDATES = ("shear_thinning_spencer", "spencer", "bouc_wen")
# How `jaxmr fit --channel-delay` names a model seen through a fitted channel delay.
DELAY_SUFFIX = " + channel delay"
# The names of `jaxmr.MODEL_TEMPLATES` and `jaxmr.data.DATASETS`, for the help texts
# (both modules import JAX; tests/test_cli.py checks that the lists agree).
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
)
DATASET_NAMES = ("utfsm", "nees", "boucwen")
# The exit status of a command stopped by Ctrl-C (the shell's 128 + SIGINT).
INTERRUPTED = 130


class CLIError(Exception):
    """A failure the user can fix (a bad path, ...): printed without a traceback."""


def main(argv: Sequence[str | os.PathLike] | None = None) -> int:
    """Run the `jaxmr` command line with `argv` (default: `sys.argv[1:]`).

    **Returns:** the exit status: 0 on success, 1 on an error reported on stderr,
    130 when interrupted by Ctrl-C (argparse exits with 2 on a usage error). With
    `argv=None` (the `jaxmr` program) Ctrl-C is ignored once the command is done.
    """
    parser = _parser()
    args = parser.parse_args(None if argv is None else [os.fspath(a) for a in argv])
    try:
        # Only now, with a command to run: JAX takes seconds to import. jaxmr never
        # changes JAX's configuration on import; the command line is an application
        # and wants the accuracy of double precision (Adaptive's rtol 1e-8).
        # Simulation loops compiled as one kernel each; for `fit`, every core an XLA
        # device, over which it splits its lanes. Only as the program: `main()`
        # called from Python, after JAX, leaves its caller's settings alone.
        if "jax" not in sys.modules:
            from ._cpu import configure_cpu

            configure_cpu(devices=None if args.command == "fit" else 1)
        import jax

        jax.config.update("jax_enable_x64", True)
        with _Warnings(args.command) as args.warnings:
            return args.run(args)
    except CLIError as e:
        print(f"jaxmr {args.command}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        # Every file is written whole (through a rename) or not at all.
        print(f"\njaxmr {args.command}: interrupted", file=sys.stderr)
        return INTERRUPTED
    finally:
        if argv is None and threading.current_thread() is threading.main_thread():
            # The program ends here: a Ctrl-C in JAX's clean-up at exit would only
            # print a traceback.
            signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Warnings(list):
    """The `UserWarning`s raised while a command runs (a file's implausible units,
    float32, ...), as a context manager: each distinct message is printed once on
    stderr, `jaxmr <command>: warning: ...` (the file and line of the code that warned
    mean nothing to a user of the command line), and kept in this list for the
    command's report (`jaxmr fit` writes them into the JSON). Other warnings are left
    to Python's filters."""

    def __init__(self, command: str):
        super().__init__()
        self.command = command
        self._context = warnings.catch_warnings()

    def __enter__(self):
        self._context.__enter__()  # restores the filters and `showwarning` on exit
        warnings.simplefilter("always", UserWarning)
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if not issubclass(category, UserWarning):
                return shown(message, category, filename, lineno, file, line)
            text = str(message)
            if text not in self:
                self.append(text)
                print(f"jaxmr {self.command}: warning: {text}", file=sys.stderr)

        warnings.showwarning = show
        return self

    def __exit__(self, *exc_info):
        return self._context.__exit__(*exc_info)


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
    _add_convert(subparsers)
    from jaxmr import _design_cli  # `jaxmr design`, in its own module

    _design_cli.add_parser(subparsers)
    return parser


# ---------------------------------------------------------------------------------------
# Output files: one rule for every command

FORCE_HELP = "replace existing output files (never one of the inputs)"


def _same_file(a, b) -> bool:
    """Whether the paths `a` and `b` name one file (through links, `..`, or a
    case-insensitive file system when both exist)."""
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def _plan_outputs(targets: Sequence[Path], inputs, *, force: bool) -> set[Path]:
    """Check, before any work, the files a command will write: none may be one of its
    `inputs` (with or without `--force`), none a directory, and an existing one only
    with `force`.

    **Returns:** the targets that exist, which the command replaces (and says so).
    """
    for target in targets:
        for source in inputs:
            if _same_file(target, source):
                raise CLIError(
                    f"{str(target)!r} would write over the input file {str(source)!r}: "
                    "choose another --out (jaxmr never writes over its inputs, even "
                    "with --force)"
                )
    existing = [t for t in targets if t.exists() or t.is_symlink()]
    for target in existing:
        if target.is_dir():
            raise CLIError(f"the output path {str(target)!r} is a directory")
    if existing and not force:
        listed = ", ".join(repr(str(t)) for t in existing[:3])
        more = f" and {len(existing) - 3} more" if len(existing) > 3 else ""
        raise CLIError(
            f"{listed}{more} already exist{'s' if len(existing) == 1 else ''}: pass "
            "--force to replace, or choose another --out (nothing was written)"
        )
    return set(existing)


def _check_writable_file(path: Path) -> None:
    """Fail before a long fit rather than after it."""
    parent = path.parent
    if not parent.is_dir():
        raise CLIError(f"the directory of the output file {str(path)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise CLIError(f"cannot write to the directory of {str(path)!r}")


def _write_atomically(
    path: Path, write: Callable[[Path], None], *, replacing: bool = False
) -> None:
    """`write(temporary)` to a new file beside `path`, then rename it to `path`: `path`
    is then the whole new file or untouched, whatever fails or interrupts. An
    `OSError` becomes a `CLIError` naming `path`; `replacing` (a file `_plan_outputs`
    allowed to replace) is said in the message."""
    if not replacing and (path.exists() or path.is_symlink()):
        raise CLIError(  # appeared since `_plan_outputs`
            f"{str(path)!r} appeared while jaxmr was running: pass --force to "
            "replace it, or choose another --out"
        )
    # A new name in the same directory (os.replace is atomic on one file system),
    # created by an ordinary open so that the file gets the usual permissions.
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    try:
        try:
            write(temporary)
            os.replace(temporary, path)
        except BaseException:
            try:
                temporary.unlink(missing_ok=True)
            except OSError:
                pass
            raise
    except OSError as e:
        raise CLIError(
            f"cannot write {str(path)!r}: {e.strerror or e} "
            f"({'left unchanged' if replacing else 'not written'})"
        ) from e
    print(
        f"wrote {path}{' (replaced the existing file)' if replacing else ''}",
        flush=True,
    )


def _write_text(path: Path, write, *, replacing: bool = False) -> None:
    """`_write_atomically` for `write(f)` to a text file `f` (UTF-8)."""

    def to(temporary: Path) -> None:
        with open(temporary, "w", newline="", encoding="utf-8") as f:
            write(f)

    _write_atomically(path, to, replacing=replacing)


def _save_figure(plt, figure, path: Path, *, replacing: bool = False) -> None:
    try:
        _write_atomically(
            path,
            lambda temporary: figure.savefig(temporary, dpi=120, format="png"),
            replacing=replacing,
        )
    finally:
        plt.close(figure)


# ---------------------------------------------------------------------------------------
# jaxmr demo

# The SAS study's test: its brake under a 1 Hz sine of ±3.5°, currents 0 → 1 A.
DEMO_CURRENTS = (0.0, 0.25, 0.5, 0.75, 1.0)  # A
DEMO_AMPLITUDE_DEG = 3.5
DEMO_FREQUENCY = 1.0  # Hz
DEMO_DURATION = 3.0  # s: two cycles of transient from the virgin state, one kept
DEMO_RATE = 1000.0  # Hz, output samples
# Why the loops barely change with current (printed by the demo and in its --help).
DEMO_GROWTH_NOTE = (
    "The loops grow by only about 9 % from 0 to 1 A: that is the brake's published "
    "law (SAS study, Table 1), not a numerical effect. Its hysteretic torque "
    "alpha(i) z grows with alpha = 1 + 0.07 i N·m, 7 % per ampere, and its viscous "
    "torque (0.0015 + 0.07 i) N·m·s/rad times at most 0.38 rad/s at ±3.5°, 1 Hz adds "
    "about 2 % of the energy at 1 A. The energy axis starts at 0 so that the change "
    "is seen at its true scale."
)


def _add_demo(subparsers) -> None:
    demo = subparsers.add_parser(
        "demo",
        help="simulate the SAS rotary MR brake at five currents; write loops and a table",
        description=(
            "Simulate the SAS study's rotary MR brake (Bouc-Wen, its published "
            f"parameters) under a {DEMO_FREQUENCY:g} Hz sine of ±{DEMO_AMPLITUDE_DEG:g}° "
            f"at currents {', '.join(f'{c:g}' for c in DEMO_CURRENTS)} A, and write "
            "torque loops (last cycle), energy per cycle against current, and a table "
            "of peak torque and energy per cycle (summary.csv, summary.md). "
            + DEMO_GROWTH_NOTE
        ),
    )
    demo.add_argument(
        "--out",
        metavar="DIR",
        default="demo_out",
        help="directory for the figures and tables (created; default: demo_out)",
    )
    demo.add_argument("--force", action="store_true", help=FORCE_HELP)
    demo.set_defaults(run=_demo)


DEMO_FIGURES = (
    ("torque_angle.png", "displacement"),
    ("torque_velocity.png", "velocity"),
    ("torque_time.png", "time"),
)
DEMO_FILES = (
    *(name for name, _ in DEMO_FIGURES),
    "energy_vs_current.png",
    "summary.csv",
    "summary.md",
)


def _demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"the output path {str(out)!r} exists and is not a directory")
    replacing = _plan_outputs([out / n for n in DEMO_FILES], [], force=args.force)
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
    for name, against in DEMO_FIGURES:
        ax = jaxmr.plot.loop(
            solution,
            against,
            units="rotary",
            labels=labels,
            last_cycles_from=last_cycle_from,
        )
        ax.set_title(title, fontsize="medium")
        _save_figure(plt, ax.figure, out / name, replacing=out / name in replacing)
    growth = energy[-1] / energy[0] - 1
    ax = jaxmr.plot.energy_vs_current(currents, energy)
    ax.set_title(
        f"SAS MR brake, Bouc-Wen: energy per cycle\n{growth:+.0%} from "
        f"{currents[0]:g} to {currents[-1]:g} A (its published law)",
        fontsize="medium",
    )
    path = out / "energy_vs_current.png"
    _save_figure(plt, ax.figure, path, replacing=path in replacing)

    header = ("current [A]", "peak torque [N·m]", "energy per cycle [J]")
    rows = list(zip(currents, peak, energy))
    _write_text(
        out / "summary.csv",
        lambda f: _write_csv(f, ("current_A", "peak_torque_Nm", "energy_J"), rows),
        replacing=out / "summary.csv" in replacing,
    )
    table = _markdown_table(header, rows)
    _write_text(
        out / "summary.md",
        lambda f: f.write(table),
        replacing=out / "summary.md" in replacing,
    )
    print()
    print(table, end="")
    # The energy of a linear dashpot over a sine cycle is exactly π c ω X²: the rest is
    # the hysteretic part (α z).
    amplitude, omega = np.deg2rad(DEMO_AMPLITUDE_DEG), 2 * np.pi * DEMO_FREQUENCY
    at = [jaxmr.sas_brake_bouc_wen().at(c) for c in currents]
    c0 = np.array([float(m.c0) for m in at if isinstance(m, jaxmr.BoucWen)])
    viscous = np.pi * c0 * omega * amplitude**2
    print(
        f"\nenergy per cycle {energy[0]:.4f} J at {currents[0]:g} A, "
        f"{energy[-1]:.4f} J at {currents[-1]:g} A: {growth:+.1%}, of which the "
        f"hysteretic torque {(energy[-1] - viscous[-1]) / (energy[0] - viscous[0]) - 1:+.1%}"
        f" and the viscous torque {(viscous[-1] - viscous[0]) / energy[0]:+.1%} of the "
        f"energy at {currents[0]:g} A.\n{DEMO_GROWTH_NOTE}"
    )
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
    if not isinstance(
        model, (jaxmr.AbstractHysteresis, jaxmr.Damper, jaxmr.ChannelDelay)
    ):
        raise CLIError(
            f"{path}: holds a {type(model).__name__}, not a damper model "
            "(a hysteresis model, Damper or ChannelDelay)"
        )
    return model, data


def _json_number(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _json_seconds(x):
    return None if x is None else round(x, 3)


def _units(experiment) -> tuple[str, str]:
    """(force unit, input unit)."""
    force = "N·m" if experiment.rotary else "N"
    return force, "V" if experiment.drive == "voltage" else "A"


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


# ---------------------------------------------------------------------------------------
# jaxmr fit


def _add_fit(subparsers) -> None:
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
            "file, why the fit stopped, unidentified parameters)."
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
            + ", ".join(AUTO_CANDIDATES)
            + "; their _lag variants when the input varies within a file)"
        ),
    )
    command.add_argument(
        "--holdout",
        action="append",
        default=None,
        metavar="FILE",
        help=(
            "with --model auto: a file (one of FILE) held out to score the candidates "
            "on; repeat for several (default: every other interior current level, or "
            "the last third of each file when there are fewer than 3 files)"
        ),
    )
    command.add_argument(
        "--finalists",
        type=int,
        default=2,
        metavar="N",
        help="with --model auto: how many screened candidates get a full fit (default 2)",
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
        default=1,
        metavar="N",
        help="starts per fit: the data-scaled guess plus N-1 random ones (default 1)",
    )
    command.add_argument("files", nargs="+", metavar="FILE", help="CSV experiments")
    command.set_defaults(run=_fit)


def _processing(option: str, files, key: str, flag: str):
    """Per-file values [s] of --smoothing or --discard: a number, or 'file' (each
    file's own comment line, else 0)."""
    if option != "file":
        try:
            value = float(option)
        except ValueError:
            raise CLIError(
                f"{flag}: expected a number of seconds or 'file', got {option!r}"
            ) from None
        if not (math.isfinite(value) and value >= 0):
            raise CLIError(f"{flag}: must be a finite number >= 0 [s], got {option!r}")
        return [value] * len(files)
    values = []
    for path in files:
        try:
            found = jaxmr.data.read_processing(path).get(key)
        except ValueError as e:
            raise CLIError(str(e)) from e
        values.append(0.0 if found is None else float(found))
    return values


def _candidate_names(args, experiments) -> list[str]:
    from jaxmr._identify.templates import input_varies_in_time

    if args.candidates is None:
        lag = input_varies_in_time(experiments)
        return [f"{c}_lag" if lag else c for c in AUTO_CANDIDATES]
    candidates = [c.strip() for c in args.candidates.split(",") if c.strip()]
    unknown = [c for c in candidates if c not in TEMPLATE_NAMES]
    if unknown or not candidates:
        raise CLIError(
            f"--candidates: unknown model(s) {', '.join(map(repr, unknown))}; choose "
            f"from {', '.join(TEMPLATE_NAMES)}"
            if unknown
            else "--candidates names no model"
        )
    return candidates


def _where(frame) -> tuple[bool, bool]:
    """Whether the stack from `frame` down holds JAX's own code, and the solver's
    loop (`iterate`, which stops at a `KeyboardInterrupt` with the best model; found
    by its names, as a wrapper such as jaxtyping's shares its code object)."""
    in_jax = in_loop = False
    from jaxmr._identify.solver import iterate  # imported by the fit by now

    solver_loop = (iterate.__module__, iterate.__name__)
    while frame is not None:
        name = frame.f_globals.get("__name__", "")
        in_jax |= name in ("jax", "jaxlib") or name.startswith(("jax.", "jaxlib."))
        in_loop |= (name, frame.f_code.co_name) == solver_loop
        frame = frame.f_back
    return in_jax, in_loop


class _Interrupts:
    """Ctrl-C (SIGINT) while `jaxmr fit` runs, as a context manager.

    The first Ctrl-C stops the fit, which keeps its best model so far. It raises
    `KeyboardInterrupt` at once where that is safe: in the solver's loop (which
    catches it) or before the first step (nothing to lose). Elsewhere it is deferred
    to the fit's next step (`progress`) or, if none comes, to the end: within JAX
    (XLA's compiler polls for Ctrl-C, and an exception raised through it crashed the
    process later), and after a fit's loop (its report would be lost). Every later
    Ctrl-C, and any while the command is `finishing` (reporting and writing the
    model), is only counted and acknowledged: it cannot lose the model. `count` is
    how many came. Python allows signal handlers in the main thread only; elsewhere
    nothing changes.
    """

    def __init__(self):
        self.count = 0
        self.steps = 0
        self.pending = False
        self.finishing = False
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
        in_jax, in_loop = _where(frame)
        if self.count > 1 or self.finishing:
            _say("Ctrl-C again: ignored while the model is finished and written")
        elif in_jax or (self.steps and not in_loop):
            self.pending = True
            _say(
                "Ctrl-C: stopping at the fit's next step (after JAX's current "
                "computation or compilation); the best model so far will be written"
            )
        else:
            raise KeyboardInterrupt

    def progress(self, report: Callable[[int, float], None]):
        """A fit's `progress(step, loss)`: `report`, then a deferred Ctrl-C raised
        in the solver's loop, which stops there and keeps the best model."""

        def call(step, loss):
            self.steps += 1
            report(step, loss)
            if self.pending:
                self.pending = False
                raise KeyboardInterrupt

        return call


def _say(line: str) -> None:
    print(f"\njaxmr fit: {line}", file=sys.stderr, flush=True)


def _fit(args: argparse.Namespace) -> int:
    if args.model != AUTO and args.model not in TEMPLATE_NAMES:
        raise CLIError(
            f"unknown model {args.model!r}; choose one of "
            f"{', '.join(TEMPLATE_NAMES)}, or {AUTO}"
        )
    if args.max_steps < 1 or args.starts < 1 or args.finalists < 1:
        raise CLIError("--max-steps, --starts and --finalists must be at least 1")
    out = Path(args.out)
    replacing = _plan_outputs(
        [out], args.files + (args.holdout or []), force=args.force
    )
    _check_writable_file(out)
    experiments = _read_experiments(args.files, need_force=True, why="fitting")
    smoothing = _processing(args.smoothing, args.files, "smoothing", "--smoothing")
    discard = _processing(args.discard, args.files, "discard", "--discard")
    _, input_unit = _units(experiments[0])
    print(f"read {len(experiments)} file(s):", flush=True)
    for path, e, w, d in zip(args.files, experiments, smoothing, discard):
        i = np.asarray(e.current)
        level = f"{i[0]:g}" if e.is_constant_current else f"{i.min():g}..{i.max():g}"
        extra = "".join(
            [
                f", smoothed over {w:g} s" if w else "",
                f", first {d:g} s discarded" if d else "",
            ]
        )
        print(
            f"  {path}: {len(e)} samples, {e.duration:g} s, {level} {input_unit}{extra}",
            flush=True,
        )
    fit_kwargs = {"max_steps": args.max_steps}
    if args.starts > 1:
        fit_kwargs["starts"] = args.starts
    log = _FitLog(single=args.model != AUTO, terminal=sys.stdout.isatty())
    with _Interrupts() as interrupts:
        # The steps' progress (`log.step`), where a Ctrl-C deferred by `interrupts`
        # also stops the fit.
        fit_kwargs["progress"] = interrupts.progress(log.step)
        fitting = (args, experiments, smoothing, discard, fit_kwargs, log)
        return _fit_and_save(*fitting, out, out in replacing, interrupts)


# A line of progress every this many Levenberg–Marquardt steps when the output is not a
# terminal (a log file, a pipe): on a terminal a single fit prints every 2 s and
# `auto` only its candidates' lines, which left a log file silent for minutes.
PROGRESS_STEPS = 10
# The line `compare_models` prints when a candidate's fit ends: its time is replaced by
# that fit's own (for a finalist `compare_models` gives screening and full fit together).
_FIT_ENDED = re.compile(r"^(?P<name>[^:]+): (?P<seconds>\d+(?:\.\d*)?) s(?: in all)?, ")


class _FitLog:
    """What `jaxmr fit` prints while it fits, and each fit's own wall time.

    `step` is the fits' `progress(step, loss)`; `line` is the `log` of `select_model`
    (`--model auto`), whose lines say when a candidate's screening or full fit starts
    (they end with "...") and ends. `times[(name, stage)]` is the wall time [s] of
    each stage ("screening", "full", "refit"), compilation included.
    """

    def __init__(self, *, single: bool, terminal: bool, clock=time.perf_counter):
        self.single, self.terminal, self.clock = single, terminal, clock
        self.label = "fit"
        self.times: dict[tuple[str, str], float] = {}
        self._stage: tuple[str, str] | None = None
        self._started = clock()
        self._printed = time.monotonic()

    def step(self, step: int, loss: float) -> None:
        if self.terminal:
            now = time.monotonic()
            if not self.single or now - self._printed < 2.0:
                return
            self._printed = now
        elif step % PROGRESS_STEPS:
            return
        print(f"    {self.label} step {step:4d}: loss {loss:.6g}", flush=True)

    def line(self, line: str) -> None:
        now = self.clock()
        if line.endswith("..."):
            self.close()
            name, _, rest = line.partition(": ")
            refit = re.match(r"selected (?P<name>.+?); refitting", line)
            if refit:
                self._stage = (refit["name"], "refit")
            elif rest.startswith(("screened fit", "full fit")):
                self._stage = (name, "screening" if rest[0] == "s" else "full")
            if self._stage is not None:
                self.label = f"{self._stage[0]} ({self._stage[1]})"
                self._started = now
        elif self._stage is not None:
            own = now - self._started
            self.times[self._stage] = own
            self._stage = None
            line = _FIT_ENDED.sub(lambda m: f"{m['name']}: {own:.1f} s, ", line, 1)
        print(f"  {line}", flush=True)

    def close(self) -> None:
        """End the stage under way (the refit of `select_model` prints no end)."""
        if self._stage is not None:
            self.times[self._stage] = self.clock() - self._started
            self._stage = None


def _outcome(result) -> str:
    """Why the fit stopped, in the terms of its `converged` (which the JSON report
    writes): Levenberg–Marquardt's own test and progress stalled at the noise floor
    both count as converged, if every parameter combination is identified."""
    reason = result.reason
    if result.converged:
        if reason.startswith("stalled"):  # "stalled: no relative improvement ..."
            return f"converged: {reason.partition(': ')[2]}"
        return reason  # "converged (Levenberg–Marquardt's tolerance met)"
    if result.interrupted or reason.startswith("not converged"):
        return reason
    if reason.startswith(("converged", "stalled")):  # stopped well, not identified
        return (
            f"not converged: {len(result.unidentified)} parameter combination(s) "
            "not identified"
        )
    return f"not converged: {reason}"  # failed, or max_steps reached


def _fit_and_save(
    args, experiments, smoothing, discard, fit_kwargs, log, out, replacing, interrupts
) -> int:
    from jaxmr._identify.templates import MODEL_TEMPLATES, with_channel_delay

    start = time.perf_counter()
    selection = None
    try:
        if args.model == AUTO:
            candidates = _candidate_names(args, experiments)
            selection = _select(
                args, experiments, candidates, smoothing, discard, fit_kwargs, log
            )
            name, result = selection.name, selection.result
        else:
            name = args.model
            template = MODEL_TEMPLATES[name]
            if args.channel_delay:
                template = with_channel_delay(template)
                name = f"{name}{DELAY_SUFFIX}"
            try:
                model = template(experiments)
            except ValueError as e:
                raise CLIError(str(e)) from e
            print(f"fitting {name}...", flush=True)
            try:
                result = jaxmr.fit(
                    model,
                    experiments,
                    smoothing=smoothing,
                    discard=discard,
                    **fit_kwargs,
                )
            except ValueError as e:  # data `fit` refuses, e.g. a constant force
                raise CLIError(str(e)) from e
    except KeyboardInterrupt:
        print(
            "\njaxmr fit: interrupted before any model was fitted; nothing written",
            file=sys.stderr,
        )
        return INTERRUPTED
    # From here on a Ctrl-C is deferred: the model is reported and written first.
    interrupts.finishing = True
    elapsed = time.perf_counter() - start
    report = _fit_report(
        name, args.files, experiments, result, elapsed, selection, log.times
    )
    report["smoothing_s"] = smoothing
    report["discard_s"] = discard
    report["warnings"] = list(getattr(args, "warnings", []))
    print(f"\n{name}: {elapsed:.1f} s")
    # FitResult's own summary, its first line (the raw `reason`) in the words of
    # `converged`.
    summary = str(result).split("\n", 1)
    summary[0] = (
        f"fit: {_outcome(result)} after {result.num_steps} steps, "
        f"loss {result.loss:.6g}"
    )
    print("\n".join(summary))
    if _save_model(result.model, out, report, replacing=replacing):
        interrupts.count += 1
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


def _select(args, experiments, candidates, smoothing, discard, fit_kwargs, log):
    from jaxmr._identify.select import select_model
    from jaxmr._identify.templates import MODEL_TEMPLATES, with_channel_delay

    if args.channel_delay:
        candidates = {
            f"{c}{DELAY_SUFFIX}": with_channel_delay(MODEL_TEMPLATES[c])
            for c in candidates
        }

    kwargs = dict(fit_kwargs, finalists=args.finalists, log=log.line)
    if args.holdout:
        held = {os.path.abspath(p) for p in args.holdout}
        unknown = held - {os.path.abspath(p) for p in args.files}
        if unknown:
            raise CLIError(
                "--holdout: not among the input files: " + ", ".join(sorted(unknown))
            )
        keep = [os.path.abspath(p) not in held for p in args.files]
        if all(keep) or not any(keep):
            raise CLIError("--holdout must leave at least one file to fit on")
        order = [k for k in range(len(keep)) if keep[k]] + [
            k for k in range(len(keep)) if not keep[k]
        ]
        train = [experiments[k] for k in order if keep[k]]
        test = [experiments[k] for k in order if not keep[k]]
        kwargs.update(
            discard=[discard[k] for k in order], smoothing=[smoothing[k] for k in order]
        )
        print(
            f"selecting among {', '.join(candidates)} by held-out NRMSE...", flush=True
        )
        try:
            selection = select_model(candidates, train, test, **kwargs)
        except (RuntimeError, ValueError) as e:
            raise CLIError(str(e)) from e
    else:
        print(
            f"selecting among {', '.join(candidates)} by held-out NRMSE...", flush=True
        )
        try:
            selection = select_model(
                candidates, experiments, discard=discard, smoothing=smoothing, **kwargs
            )
        except (RuntimeError, ValueError) as e:  # every candidate failed, or bad data
            raise CLIError(str(e)) from e
    log.close()
    print(f"({selection.holdout})")
    print(_ranking_table(selection.scores, log.times))
    return selection


def _candidate_outcome(score) -> str:
    """A candidate's outcome for the ranking, in the words of `_outcome`."""
    if score.error is not None:
        return f"failed: {score.error}"
    if not np.isfinite(score.median_test_nrmse):
        outcome = "held-out simulation diverged"
    elif score.result.converged:
        outcome = "converged"
    else:
        outcome = _outcome(score.result).split(" (")[0]
    return outcome + (" (screening only)" if score.stage != "full" else "")


def _ranking_table(scores, times: dict) -> str:
    """The candidates, best first, with each one's screening and full fit times [s]
    (compilation included) and outcome."""

    def seconds(name, stage):
        value = times.get((name, stage))
        return "-" if value is None else f"{value:.1f}"

    rows = [
        f"{'rank':>4}  {'model':<28} {'params':>6} {'screen [s]':>10} "
        f"{'full [s]':>8} {'train':>8} {'held-out':>9}  outcome"
    ]
    for k, s in enumerate(scores, start=1):
        rows.append(
            f"{k:>4}  {s.name:<28} {s.num_parameters:>6} "
            f"{seconds(s.name, 'screening'):>10} {seconds(s.name, 'full'):>8} "
            f"{s.median_train_nrmse:>8.4f} {s.median_test_nrmse:>9.4f}  "
            f"{_candidate_outcome(s)}"
        )
    return "\n".join(rows)


def _save_model(model, out: Path, report: dict, *, replacing: bool) -> bool:
    """Write the parameter file atomically (`_write_atomically`). A write stopped by a
    `KeyboardInterrupt` (a Ctrl-C that came past `_Interrupts`) is made again. If the
    file cannot be written, the model goes to a new file in the temporary directory,
    which the error names.

    **Returns:** whether a `KeyboardInterrupt` came during the write.
    """

    def write(path):
        jaxmr.save_model(model, path, report=report)

    interrupted = False
    for _ in range(3):
        try:
            _write_atomically(out, write, replacing=replacing)
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


def _file_digest(path) -> str | None:
    """The SHA-256 of a file's bytes: `jaxmr report` knows a fitted file by it, under
    any name or directory (None when it cannot be read)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _fit_report(name, files, experiments, result, elapsed, selection, times) -> dict:
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
                "sha256": _file_digest(f),
                "experiment": str(n),
                "rmse": _json_number(r),  # in `force_unit`
                "nrmse": _json_number(e),
            }
            for f, n, r, e in zip(
                files, result.experiment_names, result.rmse, result.nrmse
            )
        ],
        "reason": result.reason,
        "outcome": _outcome(result),
        "converged": bool(result.converged),
        "num_steps": int(result.num_steps),
        "loss": _json_number(result.loss),
        "unidentified": list(result.unidentified),
        "poorly_determined": list(result.poorly_determined),
        "interrupted": bool(result.interrupted),
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
                    **{
                        f"{stage}_time_s": _json_seconds(times.get((s.name, stage)))
                        for stage in ("screening", "full")
                    },
                    "outcome": _candidate_outcome(s),
                    "median_train_nrmse": _json_number(s.median_train_nrmse),
                    "median_test_nrmse": _json_number(s.median_test_nrmse),
                    "stage": s.stage,
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
        "--out",
        required=True,
        metavar="PRED.csv",
        help="the CSV file to write (never FILE itself)",
    )
    command.add_argument("--force", action="store_true", help=FORCE_HELP)
    command.add_argument(
        "--smoothing",
        default="file",
        metavar="SECONDS",
        help=(
            "a moving average [s] applied to the prediction, as the measured force "
            "went through; 'file' (default): FILE's '# smoothing:' line, else 0"
        ),
    )
    command.add_argument(
        "--discard",
        default="file",
        metavar="SECONDS",
        help="the start [s] left out of the printed error ('file': FILE's line, else 0)",
    )
    command.set_defaults(run=_predict)


def _predict(args: argparse.Namespace) -> int:
    from jaxmr._identify.score import predict_all

    out = Path(args.out)
    replacing = _plan_outputs([out], [args.file, args.params], force=args.force)
    _check_writable_file(out)
    model, _ = _load_model(args.params)
    (experiment,) = _read_experiments([args.file], need_force=False, why="")
    (smoothing,) = _processing(args.smoothing, [args.file], "smoothing", "--smoothing")
    (discard,) = _processing(args.discard, [args.file], "discard", "--discard")
    (predicted,) = predict_all(model, [experiment], smoothing=smoothing)
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
    if experiment.force is not None:
        print(_prediction_error(args.file, experiment, predicted, discard), flush=True)
    _write_atomically(
        out,
        lambda path: jaxmr.data.write_csv(result, path, comment=comment),
        replacing=out in replacing,
    )
    return 0


def _prediction_error(path, experiment, predicted, discard: float) -> str:
    """The line that `predict` prints: RMSE and NRMSE against the measured force after
    the discarded start; the NRMSE (RMSE/std) is undefined for a constant force."""
    from jaxmr._identify.score import nrmse, rmse

    t = np.asarray(experiment.t)
    keep = t >= t[0] + discard
    if not np.any(keep):
        return f"{path}: no error: --discard {discard:g} s leaves no sample"
    force_unit, _ = _units(experiment)
    error = f"{path}: RMSE {rmse(predicted, experiment.force, keep):.6g} {force_unit}"
    if not np.std(np.asarray(experiment.force)[keep]) > 0:
        return (
            f"{error}; NRMSE undefined: the measured force is constant (its standard "
            "deviation, the NRMSE's denominator, is 0)"
        )
    return f"{error}, NRMSE {nrmse(predicted, experiment.force, keep):.4f}"


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
            "[N or N·m] and NRMSE per file with the model's parameters (report.csv, "
            "report.md). Each file is marked 'fitted' (the fit of PARAMS.json used "
            "it, whatever its name now) or 'unseen' (the model never saw it: a test of "
            "prediction). The start-up transient is left out of the errors and "
            "figures, as the fit left it out: a fitted file's discarded start is the "
            "fit's; an unseen file's is its '# discard:' line, else the fit's when it "
            "used one value for every file. Smoothing follows the same rule."
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


FITTED, UNSEEN, UNKNOWN = "fitted", "unseen", "unknown"


def _fitted_index(path, fit_report: dict) -> int | None:
    """The position of `path` among the fit's files: the same bytes (`sha256`, any
    name or directory), or the same file under the name the fit was given."""
    per_file = fit_report.get("per_file") or []
    digest = _file_digest(path)
    for k, row in enumerate(per_file):
        if isinstance(row, dict) and digest is not None and row.get("sha256") == digest:
            return k
    for k, row in enumerate(per_file):
        if isinstance(row, dict) and isinstance(row.get("file"), str):
            if _same_file(path, row["file"]):
                return k
    return None


def _fit_processing(files, fit_report: dict, key: str) -> tuple[list, list[str]]:
    """Per file, the value [s] of `key` ("smoothing" or "discard") as `jaxmr report`'s
    help says, and whether the fit used the file (fitted, unseen, or unknown for a
    parameter file without a fit report)."""
    own = _processing("file", files, key, f"# {key}:")
    if not fit_report:
        return own, [UNKNOWN] * len(files)
    used = fit_report.get(f"{key}_s")
    if not (isinstance(used, list) and all(isinstance(v, (int, float)) for v in used)):
        used = []
    common = float(used[0]) if used and all(v == used[0] for v in used) else None
    values, status = [], []
    for path, value in zip(files, own):
        k = _fitted_index(path, fit_report)
        if k is not None:
            status.append(FITTED)
            values.append(float(used[k]) if k < len(used) else value)
        else:
            status.append(UNSEEN)
            has_line = jaxmr.data.read_processing(path).get(key) is not None
            values.append(value if has_line or common is None else common)
    return values, status


def _report(args: argparse.Namespace) -> int:
    from jaxmr._identify.score import nrmse, predict_all, rmse

    model, data = _load_model(args.params)
    experiments = _read_experiments(
        args.files, need_force=True, why="the comparison with the model"
    )
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"the output path {str(out)!r} exists and is not a directory")
    figure_names = _figure_names(args.files)
    tables = [out / "report.csv", out / "report.md"]
    replacing = _plan_outputs(
        [out / n for n in figure_names] + tables,
        [args.params, *args.files],
        force=args.force,
    )
    _prepare_directory(out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fit_report = data.get("report") if isinstance(data.get("report"), dict) else {}
    smoothing, status = _fit_processing(args.files, fit_report, "smoothing")
    discard, _ = _fit_processing(args.files, fit_report, "discard")
    predicted = predict_all(model, experiments, smoothing=smoothing)
    force_unit, input_unit = _units(experiments[0])
    rows = []
    for path, e, p, figure_name, d, seen in zip(
        args.files, experiments, predicted, figure_names, discard, status
    ):
        t = np.asarray(e.t)
        keep = t >= t[0] + d
        if not np.any(keep):
            raise CLIError(f"{path}: the discarded start ({d:g} s) leaves no sample")
        error, relative = rmse(p, e.force, keep), nrmse(p, e.force, keep)
        level = float(np.mean(np.asarray(e.current)))
        rows.append((str(path), e.name, seen, level, d, error, relative))
        after = f", from {d:g} s" if d else ""
        figure = jaxmr.plot.measured_vs_predicted_loops(
            e.window(t[0] + d),
            np.asarray(p)[keep],
            title=(
                f"{e.name} ({seen}{after}): {type(model).__name__}, NRMSE "
                f"{relative:.4f}, RMSE {error:.4g} {force_unit}"
            ),
        )
        path = out / figure_name
        _save_figure(plt, figure, path, replacing=path in replacing)
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
            )
        )
        for path, name, seen, level, d, error, relative in rows:
            writer.writerow(
                (
                    path,
                    name,
                    seen,
                    f"{level:.6g}",
                    f"{d:.6g}",
                    f"{error:.10g}",
                    f"{relative:.10g}",
                )
            )

    _write_text(tables[0], write_table, replacing=tables[0] in replacing)
    markdown = _report_markdown(
        args.params, model, rows, parameters, fit_report, force_unit, args
    )
    _write_text(
        tables[1], lambda f: f.write(markdown), replacing=tables[1] in replacing
    )
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


def _report_markdown(
    params, model, rows, parameters, fit_report, force_unit, args
) -> str:
    lines = [f"# jaxmr report: {type(model).__name__} from {params}", ""]
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
        "| NRMSE |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for path, name, seen, level, d, error, e in rows:
        lines.append(
            f"| {path} | {name} | {seen} | {level:.4g} | {d:g} | {error:.4g} "
            f"| {e:.4f} |"
        )
    lines += [
        "",
        "| parameter | value | std error |",
        "|---|---:|---:|",
    ]
    for name, value, se in parameters:
        lines.append(f"| {name} | {value:.6g} | {se} |")
    if fit_report:
        outcome = fit_report.get("outcome", fit_report.get("reason", "unknown"))
        lines += ["", f"Fit: {outcome}."]
        for warning in fit_report.get("unidentified", []):
            lines.append(f"WARNING: {warning}")
        for warning in fit_report.get("warnings", []):
            lines.append(f"WARNING (while fitting): {warning}")
    for warning in getattr(args, "warnings", []):
        lines.append(f"WARNING (this report): {warning}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------
# jaxmr convert


def _add_convert(subparsers) -> None:
    command = subparsers.add_parser(
        "convert",
        help="turn a public dataset into jaxmr's canonical CSV files",
        description=(
            "Convert a public dataset that jaxmr's loaders know into canonical CSV "
            "files (one per experiment, with the dataset's own smoothing and discarded "
            "start as comment lines, which `jaxmr fit` reads): "
            + ", ".join(DATASET_NAMES)
            + ". Existing files are never replaced without --force."
        ),
    )
    command.add_argument("dataset", choices=DATASET_NAMES, help="the dataset")
    command.add_argument(
        "source", metavar="SOURCE", help="the dataset's directory or file as published"
    )
    command.add_argument("--out", required=True, metavar="DIR", help="output directory")
    command.add_argument(
        "--force", action="store_true", help="replace files that already exist"
    )
    command.set_defaults(run=_convert)


def _convert(args: argparse.Namespace) -> int:
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


if __name__ == "__main__":
    sys.exit(main())
