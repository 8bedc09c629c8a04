"""Prediction and scoring: a model simulated on measured records (the fit's own
simulation path and step policy, `residual.simulate`) and its error, NRMSE =
RMSE/std(F), the figure every dataset's authors quote.

NumPy in, NumPy out (not jit-able): the layer around the models, like `jaxmr.data`.
"""

import sys
import warnings
from collections.abc import Callable, Sequence

import numpy as np

from .._damper import with_fitted_range
from .._integrate import FixedStep
from .._misc import user_stacklevel
from .data import (
    StepPolicy,
    as_step_policy,
    check_one_device,
    experiment_list,
    experiment_name,
    pack,
    per_experiment,
    window,
)
from .residual import simulate_jit

# How many times shorter the steps are, in turn, when an experiment's simulation
# diverged with its step policy's own steps (`with_finer_steps`). A plain Bouc–Wen fit
# to simulated tests of Spencer et al.'s (1997) damper (n = 0.16: z crosses from one
# bound to the other within about 6 µm of travel) diverged on two of four held-out
# records with 25 µm steps; with 2, 4 and 16 times shorter steps its held-out NRMSEs
# agreed to 3 digits (0.117, 0.152, 0.151, 0.324) and its training NRMSEs moved by
# at most 0.002 (2026-11-28). 16 resolves a state that relaxes within 1.6 µm.
RETRY_REFINEMENTS = (4, 16)


class StepsRefined(UserWarning):
    """A simulation diverged with its step policy's steps (the model's state changes
    over less travel, or time, than one step) and was run again with shorter ones
    (`jaxmr.predict_all`): its prediction is finite, and its steps differ from the
    fit's. Filter it with `warnings.filterwarnings("ignore",
    category=jaxmr.StepsRefined)`."""


def with_finer_steps(
    run: Callable[[list[int], StepPolicy], list],
    names: Sequence[str],
    policy: StepPolicy,
) -> list:
    """`run(indices, policy)` (one result per experiment of `indices`: an array, or a
    tuple of arrays, NaN where its simulation diverged) for every experiment, each
    one whose result is not finite run again with steps `RETRY_REFINEMENTS` times
    shorter, in turn, until it is; one `StepsRefined` warning names the experiments
    rerun (`names`: every experiment's). What stays NaN diverged at every step."""
    results = list(run(list(range(len(names))), policy))
    rerun: dict[int, int] = {}
    for factor in RETRY_REFINEMENTS:
        diverged = [k for k, r in enumerate(results) if not _finite(r)]
        if not diverged:
            break
        for k, again in zip(diverged, run(diverged, policy.refined(factor))):
            if _finite(again):
                results[k], rerun[k] = again, factor
    if rerun:
        listed = ", ".join(f"{names[k]!r} ({f}x)" for k, f in rerun.items())
        warnings.warn(
            f"the simulation of {listed} diverged with the step policy's steps and "
            "was run again with steps shorter by the factor given: the model's state "
            "changes within less than a step (less travel, or for a brake less "
            "time); a fit with shorter steps (jaxmr.StepPolicy's `max_travel`, "
            "`max_step`) would resolve it throughout",
            StepsRefined,
            stacklevel=user_stacklevel(sys._getframe()),
        )
    return results


def _finite(result) -> bool:
    parts = result if isinstance(result, tuple) else (result,)
    return all(bool(np.all(np.isfinite(p))) for p in parts)


def predict_all(
    model,
    experiments: Sequence,
    *,
    integrator: StepPolicy | FixedStep | None = None,
    smoothing=None,
    refine_diverged: bool = True,
) -> list[np.ndarray]:
    """The force (torque) `model` predicts for each experiment, in one batched run.

    Each experiment is simulated from the virgin state at its first sample, driven by
    its measured motion and input (a measured force is not needed), with the steps
    `fit` uses (`integrator`: a `StepPolicy`, default `StepPolicy()`).

    **Arguments:**

    - `model`: a hysteresis model or `Damper` (constraint wrappers are resolved).
    - `experiments`: `jaxmr.data.Experiment`s (or anything with `t`, `x`, `v`,
      `current`, `name`).
    - `integrator`: the step policy.
    - `smoothing`: the width [s] of a centred moving average applied to the
      prediction (one for all or one per experiment; 0: none), as the data's authors
      applied to the measured force (`jaxmr.data.utfsm_smoothing`); `None` (default):
      each experiment's own `smoothing` (`jaxmr.data.Experiment.smoothing`, 0 for
      anything without one), so the prediction is comparable with its force.
    - `refine_diverged`: an experiment whose simulation diverged is run again with
      steps 4, then 16 times shorter (`RETRY_REFINEMENTS`), and a `StepsRefined`
      warning names it (default); `False`: its NaN is returned as is.

    **Returns:** one NumPy array of forces [N] (torques [N·m]) per experiment, at its
    samples; NaN where a simulation diverged (at every step tried): from the first
    sample at which the model's state is not finite or has left its theoretical
    bounds (`state_bounds`, e.g. Dahl's |z| <= 1, with 1 % slack), where a
    fixed-step solve would go on to give finite but absurd forces.
    """
    experiments = experiment_list(experiments)
    if not experiments:
        return []
    check_one_device(experiments, model)
    policy = as_step_policy(integrator)
    # Resolved once, so that a rerun subset keeps each experiment's own width.
    widths = per_experiment(smoothing, experiments, "smoothing")
    # Off the model (a static field): a loaded model shares the fit's compilation.
    plain = with_fitted_range(model, None)

    def run(indices: list[int], steps: StepPolicy) -> list[np.ndarray]:
        data = pack(
            [experiments[k] for k in indices],
            steps,
            weighting="force",
            smoothing=widths[indices],
            need_force=False,
        )
        return data.split(np.asarray(simulate_jit(plain, data, True)))

    if not refine_diverged:
        return run(list(range(len(experiments))), policy)
    return with_finer_steps(
        run, [experiment_name(e, k) for k, e in enumerate(experiments)], policy
    )


def predict(
    model,
    experiment,
    *,
    integrator: StepPolicy | FixedStep | None = None,
    smoothing=None,
    refine_diverged: bool = True,
) -> np.ndarray:
    """The force [N] (torque [N·m]) `model` predicts at `experiment`'s samples, from the
    virgin state, under its measured motion and input. See `predict_all`."""
    (force,) = predict_all(
        model,
        [experiment],
        integrator=integrator,
        smoothing=smoothing,
        refine_diverged=refine_diverged,
    )
    return force


def _same_shape(simulated, measured) -> tuple[np.ndarray, np.ndarray]:
    """Both as float arrays of one shape: NumPy would broadcast (n,) against (n, 1)
    to an (n, n) table and score it without a word."""
    simulated, measured = np.asarray(simulated, float), np.asarray(measured, float)
    if simulated.shape != measured.shape:
        raise ValueError(
            f"the simulated and measured forces must have one shape (one value per "
            f"sample), got {simulated.shape} and {measured.shape}."
        )
    return simulated, measured


def nrmse(simulated, measured, keep=None, *, remove_mean: bool = False) -> float:
    """RMSE/std(F) [1] over the samples `keep` (a boolean mask; all when `None`); with
    `remove_mean` both signals lose their means over those samples first. `inf` for a
    prediction that is not finite or a measured force that does not vary."""
    simulated, measured = _same_shape(simulated, measured)
    if keep is not None:
        simulated, measured = simulated[keep], measured[keep]
    if not np.all(np.isfinite(simulated)):
        return np.inf
    if remove_mean:
        simulated, measured = simulated - simulated.mean(), measured - measured.mean()
    spread = float(np.std(measured))
    if not spread > 0:
        return np.inf
    return float(np.sqrt(np.mean((simulated - measured) ** 2)) / spread)


def rmse(simulated, measured, keep=None) -> float:
    """RMSE [force unit] over the samples `keep`; `inf` if not finite."""
    simulated, measured = _same_shape(simulated, measured)
    if keep is not None:
        simulated, measured = simulated[keep], measured[keep]
    if not np.all(np.isfinite(simulated)):
        return np.inf
    return float(np.sqrt(np.mean((simulated - measured) ** 2)))


def scored_samples(experiments, start=None, until=None) -> list[np.ndarray]:
    """Per experiment, the samples with `t0 + start <= t <= t0 + until` [s] (`start`
    and `until` one for all or one per experiment; `start=None`: each experiment's
    own `discard`; `until=None`: the end)."""
    n = len(experiments)
    start = per_experiment(start, experiments, "discard")
    until = np.broadcast_to(np.asarray(np.inf if until is None else until, float), (n,))
    masks = []
    for e, a, b in zip(experiments, start, until):
        t = np.asarray(e.t, float)
        masks.append((t >= t[0] + a) & (t <= t[0] + b))
    return masks


def record_nrmse(
    model,
    experiments,
    *,
    discard=None,
    until=None,
    smoothing=None,
    remove_mean: bool = False,
    integrator: StepPolicy | FixedStep | None = None,
) -> np.ndarray:
    """NRMSE = RMSE/std(F) of a model on whole records (`predict_all`), scored on the
    samples with `t0 + discard <= t <= t0 + until` (the simulation always starts at
    the first sample, so the state there is right).

    **Arguments:**

    - `model`, `experiments`, `integrator`, `smoothing`: as `predict_all`.
    - `discard`: the start [s] left out of the score, per record or one for all
      (`jaxmr.data.utfsm_first_cycle` for the UTFSM protocol); `None` (default):
      each record's own `discard` (0 for anything without one).
    - `until`: the end [s] of the scored part, per record or one for all (`None`: the
      record's end).
    - `remove_mean`: score force fluctuations (the NEES protocol).

    **Returns:** one NRMSE per record.
    """
    experiments = experiment_list(experiments)
    for e in experiments:
        if getattr(e, "force", None) is None:
            raise ValueError(
                f"experiment {getattr(e, 'name', '')!r} has no measured force to score "
                "the model against."
            )
    forces = predict_all(model, experiments, integrator=integrator, smoothing=smoothing)
    masks = scored_samples(experiments, discard, until)
    return np.array(
        [
            nrmse(f, e.force, keep, remove_mean=remove_mean)
            for f, e, keep in zip(forces, experiments, masks)
        ]
    )


def moving_average(values, t, width: float) -> np.ndarray:
    """Centred moving average of `width` [s] of samples at times `t`: the
    trapezoidal integral of the piecewise-linear signal over [t − w/2, t + w/2]
    divided by the window's length, the window shrinking at the ends (the same
    window as `fit`'s `smoothing`); `width = 0` returns the values. Unlike MATLAB's
    `movmean`, whose window is a whole number of samples (off-centre for an even
    number), it is exactly centred for any width: the two differ where a window
    spans a few samples (a review measured up to a factor 2 in single files'
    NRMSE on the UTFSM 2 mm/5 Hz tests, 4-sample windows)."""
    values, t = np.asarray(values, float), np.asarray(t, float)
    if not (np.isfinite(width) and width >= 0):
        raise ValueError(
            f"`width` must be a finite number of seconds >= 0, got {width!r}."
        )
    if values.shape != t.shape or t.ndim != 1:
        raise ValueError(
            f"`values` and `t` must be 1-D of one length, got {values.shape} and {t.shape}."
        )
    if width > t[-1] - t[0]:
        # A width in samples given for seconds: the average of (nearly) everything.
        raise ValueError(
            f"`width` = {width:g} s is wider than the record ({t[-1] - t[0]:g} s): give "
            "the width in seconds."
        )
    if width == 0:
        return values
    integral = np.concatenate(
        [[0.0], np.cumsum((values[1:] + values[:-1]) / 2 * np.diff(t))]
    )
    (lo, lo_fraction), (hi, hi_fraction), span = window(t, width)
    at = lambda k, f: integral[k] + f * (integral[k + 1] - integral[k])
    return (at(hi, hi_fraction) - at(lo, lo_fraction)) / span
