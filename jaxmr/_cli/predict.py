"""`jaxmr predict`: the force of a fitted model under a CSV experiment's motion and
input, written as a canonical CSV."""

import argparse
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

import jaxmr

from .errors import CLIError
from .files import (
    BAND_LEVEL_HELP,
    FORCE_HELP,
    band_level,
    beyond_range,
    check_device,
    check_writable_file,
    load_model,
    plan_outputs,
    predicted_by_jaxmr,
    prediction_bands,
    read_experiments,
    units,
    with_processing,
    write_atomically,
)

if TYPE_CHECKING:
    import jaxmr.data  # at run time `jaxmr.data` is imported on first use (it imports JAX)


def add_parser(subparsers) -> None:
    """Register `jaxmr predict`."""
    command = subparsers.add_parser(
        "predict",
        help="predict the force of a fitted model for a CSV experiment",
        description=(
            "Simulate the model of a parameter file (from `jaxmr fit`) under the motion "
            "and input of a CSV experiment and write the predicted force (or torque) "
            "in jaxmr's canonical CSV format: t, x, v, i (or theta, omega, u) as read, "
            "and F (T) predicted, followed by its prediction band from the fitted "
            "parameters' uncertainty: F_std (the prediction's standard error), "
            "F_lower and F_upper (the band's edges), in N (T_std, T_lower, T_upper "
            "in N·m for a brake); no band for a parameter file without the fit's "
            "covariance. A measured force in FILE is written beside the prediction, "
            "F_measured (T_measured), and its error printed."
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
        "--band-level",
        type=band_level,
        default=0.95,
        metavar="P",
        help=BAND_LEVEL_HELP,
    )
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
    command.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr predict` (see `add_parser`)."""
    out = Path(args.out)
    replacing = plan_outputs([out], [args.file, args.params], force=args.force)
    check_writable_file(out)
    model, data = load_model(args.params)
    read = read_experiments([args.file], need_force=False, why="")
    read = with_processing(read, args.smoothing, "smoothing", "--smoothing")
    (experiment,) = with_processing(read, args.discard, "discard", "--discard")
    fitted = check_device(args.params, data, [args.file], [experiment])
    beyond = beyond_range(fitted, args.file, experiment)
    if beyond is not None:
        warnings.warn(beyond, UserWarning, stacklevel=2)
    # Through the experiment's own smoothing (`Experiment.smoothing`). A rerun with
    # shorter steps (`jaxmr.StepsRefined`) is said, and written into the file.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        (predicted,) = jaxmr.predict_all(model, [experiment])
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    refined = [str(w.message) for w in caught if w.category is jaxmr.StepsRefined]
    if not np.all(np.isfinite(predicted)):
        raise CLIError(diverged_message(args.file, experiment, predicted))
    # Rebuilding checks the data again: its warnings were said, naming the file, when
    # it was read.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", jaxmr.data.DataWarning)
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
            # The prediction went through the measured force's moving average: the
            # file says so (its '# smoothing:' line), as a measured file would.
            smoothing=experiment.smoothing,
        )
    load = "T" if experiment.rotary else "F"
    comment = (
        f"{load}: predicted by jaxmr {jaxmr.__version__} with the "
        f"{type(model).__name__} model of {args.params}, from the motion and input of "
        f"{args.file}"
    )
    if experiment.smoothing > 0:
        smoothed = (
            f"through the {experiment.smoothing:g} s moving average the measured "
            f"{'torque' if experiment.rotary else 'force'} went through (--smoothing 0 "
            "for the model's own)"
        )
        comment += f", {smoothed}"
        print(f"{args.file}: the prediction is {smoothed}", flush=True)
    # The band's centre is the same simulation as `predicted` (`predict_all`'s).
    bands, _ = prediction_bands(model, data, [experiment], args.params, args.band_level)
    band = None if bands is None else bands[0]
    if band is not None:
        comment += (
            f"\n{load}_std, {load}_lower, {load}_upper: the prediction band of "
            f"nominal coverage {band.level:g}, {load} ∓ z·{load}_std (z the normal "
            "quantile), from the fitted parameters' covariance to first order: where "
            f"the model's {'torque' if experiment.rotary else 'force'} lies, not the "
            "measurement"
        )
    if beyond is not None:
        comment += f"\nwarning: {beyond}"
    for text in refined:
        comment += f"\nwarning: {text}"
    if experiment.force is not None:
        comment += (
            f"\n{load}_measured: the {'torque' if experiment.rotary else 'force'} "
            f"measured in {args.file}, as read"
        )
        if predicted_by_jaxmr(args.file):
            warnings.warn(
                f"the {load} column of {args.file} was predicted by jaxmr "
                f"(its '# {load}:' line), not measured: the printed error compares two "
                "predictions",
                UserWarning,
                stacklevel=2,
            )
        print(_prediction_error(args.file, experiment, predicted), flush=True)
        narrow = _band_narrower_than_error(experiment, predicted, band)
        if narrow is not None:
            print(f"{args.file}: note: {narrow}", flush=True)
            comment += f"\nnote: {narrow}"
    write_atomically(
        out,
        lambda path: jaxmr.data.write_csv(
            result, path, comment=comment, measured=experiment.force, band=band
        ),
        replacing=out in replacing,
    )
    return 0


def diverged_message(path, experiment, predicted) -> str:
    """What `predict` and `report` say of a prediction that is not finite (NaN from
    `jaxmr.predict_all` where the model's state left its bounds or the solve
    diverged): the experiment, the time, and what to try."""
    first = int(np.argmax(~np.isfinite(np.asarray(predicted))))
    t = float(np.asarray(experiment.t)[first])
    return (
        f"the simulation of {path} (experiment {experiment.name!r}) diverged at "
        f"t = {t:g} s, with the fit's steps and with shorter ones "
        "(`jaxmr.predict_all`): the model's state left its bounds or stopped being "
        "finite, so no force is written. Check that the displacement and velocity columns agree "
        "there (a step in one that the other does not show) and that the motion "
        "lies within the range the model was fitted on; else the model's parameters "
        "do not suit this input"
    )


# A band whose median half-width is below this share of the record's RMSE is said to
# be narrow: most of the error is then outside what the band describes.
NARROW_BAND = 0.5


def _band_narrower_than_error(experiment, predicted, band) -> str | None:
    """Words for a band much narrower than the record's error (after the discarded
    start), or None. A user trial read a ±28 N band beside an RMSE of 185 N in the
    CSV alone, and trusted its edges as bounds on the measurement."""
    from jaxmr.scores import rmse  # imports JAX: not at `jaxmr --help`

    keep = _scored(experiment)
    if band is None or not np.any(keep):
        return None
    error = rmse(predicted, experiment.force, keep)
    half = float(np.median((np.asarray(band.upper) - np.asarray(band.lower))[keep]) / 2)
    if not (np.isfinite(error) and error > 0 and half < NARROW_BAND * error):
        return None
    force_unit, _ = units(experiment)
    return (
        f"the band's median half-width ({half:.3g} {force_unit}) is "
        f"{error / max(half, 1e-300):.3g}x below this record's RMSE ({error:.3g} "
        f"{force_unit}): the band holds the parameters' uncertainty only, and the "
        "rest of the error (the model's structure, the noise) lies outside it; it is "
        "not a bound on the measurement"
    )


def _scored(experiment) -> np.ndarray:
    """The samples an error is scored on: after the discarded start."""
    t = np.asarray(experiment.t)
    return t >= t[0] + experiment.discard


def _prediction_error(path, experiment, predicted) -> str:
    """The line that `predict` prints: RMSE and NRMSE against the measured force after
    the discarded start (`experiment.discard`); the NRMSE (RMSE/std) is undefined for
    a constant force."""
    from jaxmr.scores import nrmse, rmse  # imports JAX: not at `jaxmr --help`

    keep = _scored(experiment)
    if not np.any(keep):
        return f"{path}: no error: --discard {experiment.discard:g} s leaves no sample"
    force_unit, _ = units(experiment)
    error = f"{path}: RMSE {rmse(predicted, experiment.force, keep):.6g} {force_unit}"
    if not np.std(np.asarray(experiment.force)[keep]) > 0:
        return (
            f"{error}; NRMSE undefined: the measured force is constant (its standard "
            "deviation, the NRMSE's denominator, is 0)"
        )
    return f"{error}, NRMSE {nrmse(predicted, experiment.force, keep):.4f}"
