"""Files for every command: reading experiments and parameter files, and writing.

Every file a command writes follows one rule (`plan_outputs`, `write_atomically`): never
over one of the command's inputs (not even with `--force`); over another existing file
only with `--force`, and then the command says what it replaced; through
`jaxmr.data.write_atomically` (a temporary file in the same directory and a rename), so
that an error (a full disk) or an interrupt never leaves half a file. Every problem
becomes a `CLIError` whose message names the file.
"""

import argparse
import dataclasses
import json
import math
import os
import tempfile
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import jaxmr

from .errors import CLIError

if TYPE_CHECKING:
    import jaxmr.data  # at run time `jaxmr.data` is imported on first use (it imports JAX)

FORCE_HELP = "replace existing output files (never one of the inputs)"


# ---------------------------------------------------------------------------------------
# Reading


ACCEPT_UNITS_HELP = (
    "go on with values that are implausible in their declared (or SI) units, e.g. a "
    "displacement amplitude above 0.5 m, or with a force whose sign would feed energy "
    "into the motion (by default the command stops there: such a file is almost always "
    "in other units, or read the other way round)"
)

# The data layer's `DataWarning` kinds that stop a command unless --accept-units, and
# how the refusal names each.
_REFUSED = {"unit": "implausible unit(s)", "sign": "a reversed sign"}


_Read = TypeVar("_Read")


def checking_units(
    read: Callable[[], _Read], *, accept: bool, fix: str, sign_fix: str
) -> _Read:
    """`read()`, refusing implausible data: the data layer's `DataWarning`s of kind
    "unit" (a column in other units) and "sign" (a force or velocity read the other
    way round) become a `CLIError` naming the column (and the unit its values look
    like), with `fix` (how to declare the unit) or `sign_fix` (how to negate it); with
    `accept` they stay warnings. The other warnings go on to the command's printer,
    once each."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = read()
    refused = [
        w.message
        for w in caught
        if isinstance(w.message, jaxmr.data.DataWarning) and w.message.kind in _REFUSED
    ]
    for w in caught:
        if accept or w.message not in refused:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if refused and not accept:
        lines = []
        for u in refused:
            looks = f", which look like {u.suggested}" if u.suggested else ""
            lines.append(f"{u} [column `{u.column}`{looks}]")
        kinds = [kind for kind in _REFUSED if any(u.kind == kind for u in refused)]
        fixes = {"unit": fix, "sign": sign_fix}
        raise CLIError(
            " and ".join(_REFUSED[kind] for kind in kinds)
            + ", nothing done:\n  "
            + "\n  ".join(lines)
            + f"\n{'; '.join(fixes[kind] for kind in kinds)}; or pass --accept-units "
            "if the values are right"
        )
    return result


def read_experiments(
    paths: Sequence[str],
    *,
    need_force: bool,
    why: str,
    accept_units: bool | None = None,
) -> list:
    """Read canonical CSV files; every problem becomes a `CLIError` with the data
    layer's message (which names the file, the line and the fix). With `accept_units`
    False an implausible unit is an error (`checking_units`); None or True: a
    warning. Every file is read before a refusal, which names each one in other
    units (not only the first)."""

    def read(path):
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
        return experiment

    if accept_units is None:
        experiments = [read(path) for path in paths]
    else:
        experiments = checking_units(
            lambda: [read(path) for path in paths],
            accept=accept_units,
            fix=(
                "write the file in SI units, e.g. with the column's unit "
                "declared: `jaxmr convert table RAW --columns t,x:mm,... --out "
                "DIR`"
            ),
            sign_fix=(
                "write the file with the column named above negated, e.g. "
                "with a minus sign before its unit: `jaxmr convert table RAW "
                "--columns t,x:mm,F:-kN ... --out DIR` (or v:-mm/s)"
            ),
        )
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


def seconds_option(option: str, flag: str) -> float | None:
    """The value [s] of a `--smoothing` or `--discard` option: a finite number >= 0,
    or `None` for 'file' (take it from each file, or the command's default)."""
    if option == "file":
        return None
    try:
        value = float(option)
    except ValueError:
        raise CLIError(
            f"{flag}: expected a number of seconds or 'file', got {option!r}"
        ) from None
    if not (math.isfinite(value) and value >= 0):
        raise CLIError(f"{flag}: must be a finite number >= 0 [s], got {option!r}")
    return value


def with_processing(experiments, option: str, key: str, flag: str) -> list:
    """The experiments with their `key` ("smoothing" or "discard", [s]) as the option
    `flag` says: one number for all, or 'file' (as read: each file's own comment
    line, else 0)."""
    value = seconds_option(option, flag)
    if value is None:
        return list(experiments)
    # Rebuilding an experiment checks its data again: its warnings, said once when
    # the file was read (naming the file), would come again naming the experiment.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", jaxmr.data.DataWarning)
        try:
            return [dataclasses.replace(e, **{key: value}) for e in experiments]
        except ValueError as e:  # e.g. a width or start longer than a record
            raise CLIError(f"{flag}: {e}") from e


def load_model(path: str):
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


def fitted_range(params, data: dict):
    """The `jaxmr.FittedRange` a parameter file holds (`jaxmr fit` saves it), or None
    for one without (an older `jaxmr fit`'s, a model saved from Python)."""
    saved = data.get("fitted_range")
    if saved is None:
        return None
    try:
        return jaxmr.FittedRange.from_dict(saved)
    except ValueError as e:
        raise CLIError(f"{params}: {e}") from e


def _device(rotary: bool, drive: str) -> str:
    return f"{'rotary' if rotary else 'linear'} device driven by {drive}"


def check_device(params, data: dict, paths: Sequence, experiments):
    """Refuse files of another kind of device than the model was fitted to (a brake's
    angle and torque against a damper's, a voltage against a current): their numbers
    would be read in the other units, and the answer would look plausible.

    **Returns:** the file's `jaxmr.FittedRange`, or None (nothing to check against).
    """
    fitted = fitted_range(params, data)
    if fitted is None:
        return None
    for path, e in zip(paths, experiments):
        if (e.rotary, e.drive) != (fitted.rotary, fitted.drive):
            raise CLIError(
                f"{path} is a {_device(e.rotary, e.drive)}, but the model of {params} "
                f"was fitted to a {_device(fitted.rotary, fitted.drive)}: give files "
                "of the device the model was fitted to (columns t, "
                + ("theta" if fitted.rotary else "x")
                + ", "
                + ("u" if fitted.drive == "voltage" else "i")
                + ", ...)"
            )
    return fitted


def beyond_range(fitted, path, experiment) -> str | None:
    """A sentence saying where `experiment` leaves the model's fitted range, or None
    (within it, or no range to check against)."""
    if fitted is None:
        return None
    found = fitted.exceeded(experiment.x, experiment.v, experiment.current)
    if not found:
        return None
    return (
        f"{path} lies beyond the range the model was fitted on: "
        + "; ".join(found)
        + ". The model's force there is extrapolation."
    )


def predicted_by_jaxmr(path) -> bool:
    """Whether a canonical CSV's force (torque) column is a prediction that `jaxmr
    predict` wrote (its `# F: predicted by jaxmr` comment line), not a measurement."""
    comments = jaxmr.data.read_comments(path)
    marks = (comments.get("F", ""), comments.get("T", ""))
    return any(mark.startswith("predicted by jaxmr") for mark in marks)


BAND_LEVEL_HELP = (
    "the nominal coverage of the prediction band, in (0, 1) (default 0.95: the "
    "model's force ± 1.96 standard errors)"
)


def band_level(text: str) -> float:
    """The value of `--band-level` (argparse's `type`)."""
    try:
        level = float(text)
    except ValueError:
        level = math.nan
    if not 0 < level < 1:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}")
    return level


def prediction_bands(model, data: dict, experiments, path, level: float):
    """The prediction band of each experiment (`jaxmr.prediction_band_from_covariance`)
    from the covariance of the fitted parameters that `jaxmr fit` saves in its report
    (`"covariance"`: their names and matrix).

    **Returns:** `(bands, None)`, the `jaxmr.PredictionBand`s; or `(None, reason)` for
    a parameter file without a usable covariance (an older `jaxmr fit`'s, a model
    saved from Python, a parameter without a finite standard error): then it has said
    why, once, and the command goes on without a band.
    """
    report = data.get("report")
    saved = report.get("covariance") if isinstance(report, dict) else None
    reason = None
    if not (
        isinstance(saved, dict)
        and isinstance(saved.get("names"), list)
        and isinstance(saved.get("matrix"), list)
    ):
        reason = (
            "it holds no covariance of the fitted parameters (a model saved by an "
            "older `jaxmr fit` or from Python): refit it with `jaxmr fit` to get one"
        )
    else:
        try:
            # JSON null: a covariance that is not finite (an undetermined parameter).
            matrix = [
                [math.nan if c is None else float(c) for c in row]
                for row in saved["matrix"]
            ]
            bands = jaxmr.prediction_band_from_covariance(
                model, saved["names"], matrix, experiments, level=level
            )
            return bands, None
        except (TypeError, ValueError) as e:
            reason = str(e)
    print(f"{path}: no prediction band: {reason}", flush=True)
    return None, reason


def units(experiment) -> tuple[str, str]:
    """(force unit, input unit) of an experiment's device."""
    force = "N·m" if experiment.rotary else "N"
    return force, "V" if experiment.drive == "voltage" else "A"


# ---------------------------------------------------------------------------------------
# Writing


def same_file(a, b) -> bool:
    """Whether the paths `a` and `b` name one file (through links, `..`, or a
    case-insensitive file system when both exist)."""
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def refuse_inputs(targets: Sequence[Path], inputs) -> None:
    """Fail if one of `targets` is one of the `inputs` (whatever the options)."""
    for target in targets:
        for source in inputs:
            if same_file(target, source):
                raise CLIError(
                    f"{str(target)!r} would write over the input file {str(source)!r}: "
                    "choose another --out (jaxmr never writes over its inputs, even "
                    "with --force)"
                )


def plan_outputs(targets: Sequence[Path], inputs, *, force: bool) -> set[Path]:
    """Check, before any work, the files a command will write: none may be one of its
    `inputs` (with or without `--force`), none a directory, and an existing one only
    with `force`.

    **Returns:** the targets that exist, which the command replaces (and says so).
    """
    refuse_inputs(targets, inputs)
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


def check_writable_file(path: Path) -> None:
    """Fail before a long fit rather than after it."""
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise CLIError(
            f"the output file {str(path)!r} would go in {str(parent)!r}, which is a "
            "file, not a directory"
        )
    if not parent.is_dir():
        raise CLIError(f"the directory of the output file {str(path)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise CLIError(f"cannot write to the directory of {str(path)!r}")


def prepare_directory(out: Path) -> None:
    """Create `out` and check that a file can be written there, before the work."""
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


def write_atomically(
    path: Path, write: Callable[[Path], object], *, replacing: bool = False
) -> None:
    """`jaxmr.data.write_atomically(path, write)`, then say so: `path` is the whole new
    file or untouched, whatever fails or interrupts. An `OSError` becomes a `CLIError`
    naming `path`; `replacing` (a file `plan_outputs` allowed to replace) is said in
    the messages."""
    if not replacing and (path.exists() or path.is_symlink()):
        raise CLIError(  # appeared since `plan_outputs`
            f"{str(path)!r} appeared while jaxmr was running: pass --force to "
            "replace it, or choose another --out"
        )
    try:
        jaxmr.data.write_atomically(path, write)
    except OSError as e:
        raise CLIError(
            f"cannot write {str(path)!r}: {e.strerror or e} "
            f"({'left unchanged' if replacing else 'not written'})"
        ) from e
    print(
        f"wrote {path}{' (replaced the existing file)' if replacing else ''}",
        flush=True,
    )


def write_text(path: Path, write, *, replacing: bool = False) -> None:
    """`write_atomically` for `write(f)` to a text file `f` (UTF-8)."""

    def to(temporary: Path) -> None:
        with open(temporary, "w", newline="", encoding="utf-8") as f:
            write(f)

    write_atomically(path, to, replacing=replacing)


def save_figure(plt, figure, path: Path, *, replacing: bool = False) -> None:
    """Write a matplotlib figure as a PNG (120 dpi) and close it."""
    try:
        write_atomically(
            path,
            lambda temporary: figure.savefig(temporary, dpi=120, format="png"),
            replacing=replacing,
        )
    finally:
        plt.close(figure)
