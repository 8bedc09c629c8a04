"""A fit written to a parameter file: the model with its fit report (`fit_report`,
`save_fit`), the file `jaxmr fit` writes and `jaxmr predict`, `jaxmr report` and
`jaxmr.load_model` read."""

import math
import os
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from .._fitted_range import FittedRange
from .._serialize import save_model
from .._version import __version__
from ..data import experiment_digest, file_digest
from .data import experiment_list
from .result import FitResult
from .select import Selection


def units(experiment) -> tuple[str, str]:
    """(force unit, input unit) of an experiment's device."""
    force = "N·m" if experiment.rotary else "N"
    return force, "V" if experiment.drive == "voltage" else "A"


def _number(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _seconds(x):
    return None if x is None else round(x, 3)


def _diverged_times(result: FitResult) -> list[float]:
    """`FitResult.diverged_at`, NaN for each experiment where it is not known."""
    if result.diverged_at is None:
        return [math.nan] * len(result.experiment_names)
    return [float(t) for t in result.diverged_at]


def _parsimony(decision) -> dict | None:
    if decision is None:
        return None
    return {
        "best": decision.best,
        "chosen": decision.chosen,
        "reason": decision.reason,
        "num_records": decision.num_records,
        "tolerance": decision.tolerance,
        "candidates": [
            {"template": n, "median_test_nrmse": _number(m)}
            for n, m in zip(decision.names, decision.median_nrmse)
        ],
    }


def _selection(selection: Selection) -> dict:
    return {
        "holdout": selection.holdout,
        "folds": list(selection.folds),
        # The parsimony rule's decision (`Selection.parsimony`), as data.
        "parsimony": _parsimony(selection.parsimony),
        # Which fit on every file was kept (`Selection.kept`), and their times.
        "kept": selection.kept,
        "refit_time_s": _seconds(selection.refit_time),
        "template_time_s": _seconds(selection.template_time),
        "ranking": [
            {
                "template": s.name,
                "num_parameters": s.num_parameters,
                "fit_time_s": round(s.fit_time, 3),
                "screening_time_s": _seconds(s.screening_time),
                "full_time_s": _seconds(s.full_time),
                "cv_time_s": _seconds(s.cv_time),
                "mean_test_nrmse": _number(s.mean_test_nrmse),
                "outcome": s.outcome,
                "median_train_nrmse": _number(s.median_train_nrmse),
                "median_test_nrmse": _number(s.median_test_nrmse),
                "stage": s.stage,
                "error": s.error,
            }
            for s in selection.scores
        ],
    }


def _fitted_rows(fitted: FitResult, experiments, files):
    """The experiments (and files) `fitted` was fitted on, in its order."""
    experiments = experiment_list(experiments)
    if files is not None and len(files) != len(experiments):
        raise ValueError(
            f"fit_report: {len(files)} file(s) for {len(experiments)} experiment(s)."
        )
    names = list(fitted.experiment_names)
    if len(experiments) != len(names):
        # A selection interrupted before its fit on every experiment hands back its
        # training fit: its rows are those experiments, found by name.
        given = [str(getattr(e, "name", "")) for e in experiments]
        used = [given.index(n) for n in names if n in given]
        if len(used) != len(names) or len(set(used)) != len(used):
            raise ValueError(
                f"fit_report: {len(experiments)} experiment(s) for a fit of "
                f"{len(names)}: give the experiments it was fitted on."
            )
        experiments = [experiments[k] for k in used]
        files = None if files is None else [files[k] for k in used]
    return experiments, files


def _environment() -> dict:
    """What computed the fit: the versions and the devices (results may differ in
    the last bits between versions and device counts: docs/scale-out.md)."""
    import platform
    from importlib.metadata import version

    return {
        "jaxmr": __version__,
        "jax": jax.__version__,
        "jaxlib": version("jaxlib"),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "platform": jax.default_backend(),
        "devices": jax.device_count(),
        "processes": jax.process_count(),
    }


def fit_report(
    result: FitResult | Selection,
    experiments: Sequence,
    *,
    files: Sequence[str | os.PathLike] | None = None,
    template: str | None = None,
) -> dict:
    """The report of a fit, as data (JSON-able), the `report` entry of the parameter
    file that `jaxmr fit` and `save_fit` write (`jaxmr predict` draws the prediction
    band from its covariance; `jaxmr report` gives its verdict and knows the fitted
    files by it).

    **Arguments:**

    - `result`: a `FitResult`, or a `Selection` (`select_model`'s: its fit on every
      experiment, with the ranking and the parsimony rule's decision).
    - `experiments`: the experiments it was fitted on, in order.
    - `files`: the file each experiment was read from (`jaxmr report` knows a file by
      its bytes or its name), or None (it knows an experiment by its numbers).
    - `template`: the name of the model (default: the selection's choice, else the
      model's class).

    **Returns:** a dict: the template, the device and units (`force_unit`, `input`),
    `environment` (the versions of jaxmr, JAX, jaxlib, NumPy and Python, the
    platform and the device and process counts), the parameters with standard
    errors, the magnitude each is relative to in the warnings
    (`FitResult.magnitudes`) and their covariance (null where not finite), one row
    per experiment (`per_file`: file, its SHA-256, the numbers' SHA-256, experiment
    name, RMSE [force unit], NRMSE, where its simulation diverged [s]), the verdict
    (`reason`, `stop`, `outcome`, `converged`, `num_steps`, `loss`, `unidentified`,
    `poorly_determined`, `poor_fit`, `interrupted`), each experiment's
    `smoothing_s` and `discard_s`, and for a `Selection` its `selection` (folds,
    ranking, decision). `jaxmr fit` adds `settings` (its options), `warnings` (what
    it warned of) and `fit_time_s` (its wall time [s]); the parameter file holds
    the fitted range beside the report (`fitted_range`).
    """
    selection = result if isinstance(result, Selection) else None
    environment = _environment()
    fitted: FitResult = result.result if isinstance(result, Selection) else result
    experiments, files = _fitted_rows(fitted, experiments, files)
    if template is None:
        template = selection.name if selection else type(fitted.model).__name__
    paths = [None] * len(experiments) if files is None else [str(f) for f in files]
    force_unit, input_unit = units(experiments[0])
    report = {
        "environment": environment,
        "template": template,
        "device": "rotary" if experiments[0].rotary else "linear",
        "force_unit": force_unit,
        "input": f"{experiments[0].drive} [{input_unit}]",
        "files": paths,
        # `magnitude`: what the warnings take each error relative to (FitResult).
        "parameters": [
            {"name": n, "value": _number(v), "std_error": _number(se), "magnitude": m}
            for n, v, se, m in zip(
                fitted.names,
                fitted.values,
                fitted.std_errors,
                [None] * len(fitted.names)
                if fitted.magnitudes is None
                else [_number(m) for m in fitted.magnitudes],
            )
        ],
        # The parameters' covariance (in the product of their units; null where not
        # finite): `jaxmr predict` and `jaxmr report` draw the prediction band from it.
        "covariance": {
            "names": list(fitted.names),
            "matrix": [[_number(c) for c in row] for row in fitted.covariance],
        },
        "per_file": [
            {
                "file": f,
                "sha256": None if f is None else file_digest(f),
                "data_sha256": experiment_digest(e),
                "experiment": str(n),
                "rmse": _number(r),  # in `force_unit`
                "nrmse": _number(q),
                # Where its simulation diverged [s] (`FitResult.diverged_at`), or null.
                "diverged_at_s": _number(d),
            }
            for f, e, n, r, q, d in zip(
                paths,
                experiments,
                fitted.experiment_names,
                fitted.rmse,
                fitted.nrmse,
                _diverged_times(fitted),
            )
        ],
        "reason": fitted.reason,
        "stop": fitted.stop.name.lower(),
        "outcome": fitted.outcome,
        "converged": bool(fitted.converged),
        "num_steps": int(fitted.num_steps),
        "loss": _number(fitted.loss),
        "unidentified": list(fitted.unidentified),
        "poorly_determined": list(fitted.poorly_determined),
        "poor_fit": fitted.poor_fit,
        "interrupted": bool(fitted.interrupted),
    }
    if selection is not None:
        report["selection"] = _selection(selection)
    report["smoothing_s"] = [float(getattr(e, "smoothing", 0.0)) for e in experiments]
    report["discard_s"] = [float(getattr(e, "discard", 0.0)) for e in experiments]
    return report


def save_fit(
    result: FitResult | Selection,
    experiments: Sequence,
    path: str | os.PathLike,
    *,
    files: Sequence[str | os.PathLike] | None = None,
    template: str | None = None,
    overwrite: bool = False,
    **extra,
) -> None:
    """Write a fit to a parameter file as `jaxmr fit` writes it: the fitted model,
    the range of motion and input it was fitted on (`FittedRange.from_experiments`),
    and its report (`fit_report`), so that `jaxmr.load_model` reads the model back
    (warning beyond that range) and `jaxmr predict` and `jaxmr report` draw its
    prediction band and give its verdict (which `jaxmr.save_model` alone does not
    write).

    **Arguments:** `result`, `experiments`, `files`, `template`: as `fit_report`;
    `path`: the JSON file to write; `overwrite`: write over an existing file
    (default False: refused); `extra`: more JSON-able entries of the report.

    **Raises:** `FileExistsError` where `path` exists and `overwrite` is False.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"save_fit: {str(path)!r} exists; pass overwrite=True to replace it."
        )
    report = fit_report(result, experiments, files=files, template=template)
    report.update(extra)
    fitted = result.result if isinstance(result, Selection) else result
    fitted_on, _ = _fitted_rows(fitted, experiments, None)
    fitted_range = FittedRange.from_experiments(fitted_on)
    save_model(
        fitted.model,
        path,
        fitted_range=fitted_range,
        report=report,
        overwrite=overwrite,
    )
