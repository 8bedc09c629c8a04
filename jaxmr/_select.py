"""Model selection: fit candidate models on training experiments, rank them by their
error on held-out experiments, and refit the best on everything.

Held-out error, not training error, decides: a model with more parameters always fits
its training data at least as well, and only data it has not seen show whether the
extra parameters describe the device or the noise.
"""

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from types import SimpleNamespace

import equinox as eqx
import numpy as np

from ._identify import FitResult, _simulate_data, fit, stack_experiments
from ._integrate import AbstractIntegrator, FixedStep
from ._model_library import MODEL_TEMPLATES
from ._parameter import unwrap

# The fixed step `fit` uses by default: at most 0.5 ms (see `fit`'s `integrator`).
MAX_STEP = 5e-4  # s

_simulate = eqx.filter_jit(_simulate_data)


def default_integrator(experiments: Sequence) -> FixedStep:
    """`fit`'s default integrator for these experiments: RK4 with steps of at most
    0.5 ms (an integer number of substeps per sample interval)."""
    longest = max(float(np.max(np.diff(np.asarray(e.t)))) for e in experiments)
    return FixedStep(substeps=max(1, int(np.ceil(longest / MAX_STEP))))


def predict_all(
    model, experiments: Sequence, *, integrator: AbstractIntegrator | None = None
) -> list[np.ndarray]:
    """The force (torque) `model` predicts for each experiment, in one batched run.

    Each experiment is simulated from the virgin state at its first sample, driven by
    its measured motion and input (a measured force is not needed).

    **Arguments:**

    - `model`: a hysteresis model or `Damper` (constraint wrappers are resolved).
    - `experiments`: `jaxmr.data.Experiment`s (or anything with `t`, `x`, `v`,
      `current`, `name`).
    - `integrator`: default `fit`'s: `FixedStep` with steps of at most 0.5 ms.

    **Returns:** one NumPy array of forces [N] (torques [N·m]) per experiment, at its
    samples; NaN where a simulation diverged.
    """
    experiments = list(experiments)
    if not experiments:
        return []
    if integrator is None:
        integrator = default_integrator(experiments)
    # `stack_experiments` pads and stacks; the force it needs is only a placeholder here.
    stand_ins = [
        SimpleNamespace(
            t=e.t,
            x=e.x,
            v=e.v,
            current=e.current,
            force=np.zeros(np.shape(e.t)),
            name=getattr(e, "name", ""),
        )
        for e in experiments
    ]
    data = stack_experiments(stand_ins, weighting="force")
    force = np.asarray(_simulate(unwrap(model), data, integrator))
    return [force[k, : len(np.asarray(e.t))] for k, e in enumerate(experiments)]


def predict(
    model, experiment, *, integrator: AbstractIntegrator | None = None
) -> np.ndarray:
    """The force [N] (torque [N·m]) `model` predicts at `experiment`'s samples, from the
    virgin state, under its measured motion and input. See `predict_all`."""
    return predict_all(model, [experiment], integrator=integrator)[0]


def prediction_errors(
    predicted: np.ndarray, measured: np.ndarray, keep: np.ndarray | None = None
) -> tuple[float, float]:
    """RMSE [force unit] and NRMSE = RMSE/std(measured) [1] over the samples `keep`
    (all by default); `inf` for a prediction that is not finite."""
    predicted, measured = np.asarray(predicted), np.asarray(measured)
    if keep is not None:
        predicted, measured = predicted[keep], measured[keep]
    if not np.all(np.isfinite(predicted)):
        return np.inf, np.inf
    rmse = float(np.sqrt(np.mean((predicted - measured) ** 2)))
    return rmse, rmse / float(np.std(measured))


@dataclasses.dataclass(frozen=True, eq=False)
class ModelScore:
    """One candidate of `compare_models`: its fit and its held-out error.

    **Attributes:**

    - `name`: the template name, or the model's class name.
    - `result`: the `FitResult` on the training experiments (`None` if it failed).
    - `test_names`, `test_rmse`, `test_nrmse`: per held-out experiment.
    - `fit_time`: wall time of the fit [s], compilation included.
    - `num_parameters`: the number of fitted (free) parameters.
    - `error`: why the candidate failed, or `None`.
    """

    name: str
    result: FitResult | None
    test_names: tuple[str, ...]
    test_rmse: np.ndarray
    test_nrmse: np.ndarray
    fit_time: float
    num_parameters: int
    error: str | None = None

    @property
    def model(self):
        """The fitted model (plain numbers), or `None`."""
        return None if self.result is None else self.result.model

    @property
    def median_test_nrmse(self) -> float:
        """The ranking criterion: the median held-out NRMSE (inf when failed)."""
        if self.error is not None or self.test_nrmse.size == 0:
            return np.inf
        value = float(np.median(self.test_nrmse))
        return value if np.isfinite(value) else np.inf

    @property
    def median_train_nrmse(self) -> float:
        """The median NRMSE on the training experiments (inf when failed)."""
        if self.result is None:
            return np.inf
        return float(np.median(self.result.nrmse))


def score_table(scores: Sequence[ModelScore]) -> str:
    """The ranking as a text table: rank, name, parameters, fit time, median NRMSE on
    the training and held-out experiments, and the fit's outcome."""
    rows = [
        f"{'rank':>4}  {'model':<20} {'params':>6} {'fit [s]':>8} {'train':>8} "
        f"{'held-out':>9}  outcome"
    ]
    for k, s in enumerate(scores, start=1):
        if s.error is not None:
            outcome = f"failed: {s.error}"
        elif not np.isfinite(s.median_test_nrmse):
            outcome = "held-out simulation diverged"
        elif s.result.unidentified:
            outcome = f"not identified ({len(s.result.unidentified)} combination(s))"
        else:
            outcome = s.result.reason.split(":")[0].split(" (")[0]
        rows.append(
            f"{k:>4}  {s.name:<20} {s.num_parameters:>6} {s.fit_time:>8.1f} "
            f"{s.median_train_nrmse:>8.4f} {s.median_test_nrmse:>9.4f}  {outcome}"
        )
    return "\n".join(rows)


def _candidates(names_or_models, train) -> list[tuple[str, Callable]]:
    """(name, build) pairs; `build()` gives the initial model."""
    if isinstance(names_or_models, (str, eqx.Module)):
        names_or_models = [names_or_models]
    if isinstance(names_or_models, Mapping):
        items = list(names_or_models.items())
    else:
        items = []
        for c in names_or_models:
            items.append((c, c) if isinstance(c, str) else (type(c).__name__, c))
    if not items:
        raise ValueError("`names_or_models` is empty: give at least one candidate.")
    out, seen = [], {}
    for name, c in items:
        if isinstance(c, str):
            if c not in MODEL_TEMPLATES:
                raise ValueError(
                    f"unknown model template {c!r}; the templates are "
                    f"{', '.join(MODEL_TEMPLATES)}."
                )
            build = lambda t=MODEL_TEMPLATES[c]: t(train)
        elif isinstance(c, eqx.Module):
            build = lambda m=c: m
        elif callable(c):
            build = lambda f=c: f(train)
        else:
            raise TypeError(
                f"candidate {name!r}: expected a template name, a model or a function "
                f"of the experiments, got {type(c).__name__}."
            )
        seen[name] = seen.get(name, 0) + 1
        label = name if seen[name] == 1 else f"{name} ({seen[name]})"
        out.append((str(label), build))
    return out


def _score_masks(test, score_from) -> list[np.ndarray]:
    if score_from is None:
        return [np.ones(np.shape(e.t), dtype=bool) for e in test]
    starts = np.broadcast_to(np.asarray(score_from, dtype=float), (len(test),))
    masks = [np.asarray(e.t) >= s for e, s in zip(test, starts)]
    for e, s, m in zip(test, starts, masks):
        if m.sum() < 2:
            raise ValueError(
                f"`score_from` = {s} s leaves fewer than 2 samples of the held-out "
                f"experiment {getattr(e, 'name', '')!r} to score."
            )
    return masks


def compare_models(
    names_or_models,
    train: Sequence,
    test: Sequence,
    *,
    score_from: float | Sequence[float] | None = None,
    log: Callable[[str], None] | None = None,
    **fit_kwargs,
) -> list[ModelScore]:
    r"""Fit each candidate on `train` and rank them by their error on `test`.

    Each candidate is fitted with `jaxmr.fit` (silently: `progress=False` unless given)
    and then predicts every held-out experiment from the virgin state; the score is
    $\mathrm{NRMSE} = \mathrm{RMSE}/\mathrm{std}(F)$ per held-out experiment, and the
    ranking is by its median (robust to one odd test). A candidate that fails (its
    template cannot scale to the data, or its fit raises) is ranked last with the
    reason.

    **Arguments:**

    - `names_or_models`: template names (keys of `jaxmr.MODEL_TEMPLATES`), models to
      fit from (their values the initial guess), or a mapping from names to models or
      to functions `experiments -> model`.
    - `train`: the experiments to fit on (`jaxmr.data.Experiment`s with force).
    - `test`: the held-out experiments (with force).
    - `score_from`: a time [s] (or one per test experiment) before which held-out
      samples are simulated, to bring the hysteretic state from its virgin value to
      the test's, but not scored (e.g. the first cycle). Default: all samples.
    - `log`: called with a line of text before and after each fit (e.g. `print`).
    - `fit_kwargs`: passed to `jaxmr.fit` (`max_steps`, `starts`, `integrator`, ...).

    **Returns:** the `ModelScore`s, best (lowest median held-out NRMSE) first.
    """
    train, test = list(train), list(test)
    if not train:
        raise ValueError("`train` is empty: give the experiments to fit on.")
    if not test:
        raise ValueError(
            "`test` is empty: give held-out experiments (or use `select_model`, which "
            "holds out part of the data itself)."
        )
    for e in test:
        if getattr(e, "force", None) is None:
            raise ValueError(
                f"held-out experiment {getattr(e, 'name', '')!r} has no measured force "
                "to score against."
            )
    masks = _score_masks(test, score_from)
    fit_kwargs.setdefault("progress", False)
    # Predictions take steps of at most 0.5 ms on the held-out data too, whose sample
    # interval may be longer than the training data's.
    integrator = fit_kwargs.get("integrator")
    if integrator is None:
        integrator = default_integrator(train + test)
    say = log or (lambda line: None)
    test_names = tuple(str(getattr(e, "name", "")) for e in test)
    scores = []
    for name, build in _candidates(names_or_models, train):
        say(f"{name}: fitting on {len(train)} experiment(s)...")
        start = time.perf_counter()
        try:
            result = fit(build(), train, **fit_kwargs)
            predicted = predict_all(result.model, test, integrator=integrator)
        except Exception as e:  # one candidate's failure must not end the comparison
            elapsed = time.perf_counter() - start
            message = f"{type(e).__name__}: {e}"
            say(f"{name}: failed after {elapsed:.1f} s: {message}")
            nan = np.full(len(test), np.nan)
            scores.append(
                ModelScore(name, None, test_names, nan, nan, elapsed, 0, message)
            )
            continue
        elapsed = time.perf_counter() - start
        errors = [
            prediction_errors(p, np.asarray(e.force), m)
            for p, e, m in zip(predicted, test, masks)
        ]
        score = ModelScore(
            name=name,
            result=result,
            test_names=test_names,
            test_rmse=np.array([r for r, _ in errors]),
            test_nrmse=np.array([n for _, n in errors]),
            fit_time=elapsed,
            num_parameters=len(result.names),
        )
        say(
            f"{name}: {elapsed:.1f} s, {result.num_steps} steps, {len(result.names)} "
            f"parameters; median NRMSE train {score.median_train_nrmse:.4f}, held-out "
            f"{score.median_test_nrmse:.4f}"
        )
        scores.append(score)
    # Stable: ties (e.g. two failures) keep the order given.
    return sorted(scores, key=lambda s: s.median_test_nrmse)


@dataclasses.dataclass(frozen=True, eq=False)
class Selection:
    """The outcome of `select_model`.

    **Attributes:**

    - `name`: the selected candidate.
    - `result`: its `FitResult` refitted on all the experiments (training and
      held-out), started from its training fit.
    - `scores`: the ranking (`compare_models`' output).
    - `holdout`: how the held-out data were chosen, in words.
    """

    name: str
    result: FitResult
    scores: list[ModelScore]
    holdout: str

    @property
    def model(self):
        """The selected, refitted model."""
        return self.result.model


def _experiment_window(e, start=None, end=None):
    if hasattr(e, "window"):
        return e.window(start, end)
    t = np.asarray(e.t)
    keep = np.ones(t.shape, dtype=bool)
    if start is not None:
        keep &= t >= start
    if end is not None:
        keep &= t <= end
    current = np.broadcast_to(np.asarray(e.current), t.shape)
    return SimpleNamespace(
        t=t[keep],
        x=np.asarray(e.x)[keep],
        v=np.asarray(e.v)[keep],
        current=current[keep],
        force=np.asarray(e.force)[keep],
        name=getattr(e, "name", ""),
    )


HOLDOUT_FRACTION = 1 / 3


def holdout_split(experiments: Sequence):
    """Choose held-out data from `experiments` alone.

    - With 3 or more input levels (mean current or voltage of an experiment): every
      experiment at every other interior level (the 2nd, 4th, ... of the sorted
      levels, never the largest) is held out, e.g. 0.25 and 0.75 A of 0, 0.25, ...,
      1 A. The held-out tests lie inside the training range of inputs, so that a
      current law is tested on interpolation, which is what it is fitted for, and
      every test condition is seen at the training levels.
    - Else, with 3 or more experiments: every third (ordered by input, then name),
      from the second on and never the last.
    - Else (1 or 2 experiments) each is split in time: the fit sees the first two
      thirds, and the score is the last third, simulated from the start so that its
      hysteretic state is the one the first two thirds leave.

    **Returns:** `(train, test, score_from, description)`: `score_from` for
    `compare_models` (`None`, or the split times [s]), and the choice in words.
    """
    experiments = list(experiments)
    levels = [float(np.mean(np.asarray(e.current))) for e in experiments]
    distinct = sorted(set(np.round(levels, 9)))
    if len(distinct) >= 3:
        held_levels = {distinct[j] for j in range(1, len(distinct) - 1, 2)}
        held = {k for k, level in enumerate(levels) if round(level, 9) in held_levels}
        what = "input level(s) " + ", ".join(
            f"{level:g}" for level in sorted(held_levels)
        )
    elif len(experiments) >= 3:
        order = sorted(
            range(len(experiments)),
            key=lambda k: (levels[k], str(getattr(experiments[k], "name", ""))),
        )
        held = {order[j] for j in range(1, len(order) - 1, 3)}
        what = "every third experiment"
    else:
        splits = []
        for e in experiments:
            t = np.asarray(e.t)
            splits.append(float(t[0] + (1 - HOLDOUT_FRACTION) * (t[-1] - t[0])))
        train = [_experiment_window(e, end=s) for e, s in zip(experiments, splits)]
        description = (
            f"held out the last {HOLDOUT_FRACTION:.0%} of each experiment's duration "
            "(fewer than 3 experiments)"
        )
        return train, experiments, splits, description
    train = [e for k, e in enumerate(experiments) if k not in held]
    test = [e for k, e in enumerate(experiments) if k in held]
    names = ", ".join(str(getattr(e, "name", "")) for e in test)
    description = f"held out {len(test)} of {len(experiments)} ({what}): {names}"
    return train, test, None, description


def select_model(
    names_or_models,
    train: Sequence,
    test: Sequence | None = None,
    *,
    score_from: float | Sequence[float] | None = None,
    log: Callable[[str], None] | None = None,
    **fit_kwargs,
) -> Selection:
    """Select a model by held-out error, then refit it on everything.

    **Arguments:**

    - `names_or_models`, `score_from`, `log`, `fit_kwargs`: as `compare_models`.
    - `train`: the experiments to fit on; with `test=None`, all the experiments, of
      which `holdout_split` holds out a part.
    - `test`: held-out experiments, or `None` to hold out part of `train`.

    **Returns:** a `Selection`: the best candidate refitted on the training and
    held-out experiments together (starting from its training fit), and the ranking.

    **Raises:** `RuntimeError` when every candidate failed.
    """
    train = list(train)
    if test is None:
        if score_from is not None:
            raise ValueError("`score_from` needs `test`: give both or neither.")
        fit_on, test, score_from, holdout = holdout_split(train)
        everything = train
    else:
        test = list(test)
        fit_on, everything = train, train + test
        holdout = f"{len(test)} held-out experiment(s) given"
    scores = compare_models(
        names_or_models, fit_on, test, score_from=score_from, log=log, **fit_kwargs
    )
    best = scores[0]
    if best.error is not None:
        raise RuntimeError(
            "every candidate failed:\n"
            + "\n".join(f"  {s.name}: {s.error}" for s in scores)
        )
    say = log or (lambda line: None)
    say(f"selected {best.name}; refitting on all {len(everything)} experiment(s)...")
    kwargs = dict(fit_kwargs)
    kwargs.setdefault("progress", False)
    # Started from the training fit (one start: `starts` served the first search).
    kwargs.pop("starts", None)
    result = fit(best.result.constrained, everything, **kwargs)
    return Selection(best.name, result, scores, holdout)
