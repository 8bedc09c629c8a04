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

from .fitting import fit
from .result import FitResult
from .score import nrmse, predict_all, rmse
from .templates import MODEL_TEMPLATES


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
    - `stage`: `"full"` (fitted on all the training data, scored on whole held-out
      experiments) or `"screened"` (on their starts only, see `compare_models`).
    """

    name: str
    result: FitResult | None
    test_names: tuple[str, ...]
    test_rmse: np.ndarray
    test_nrmse: np.ndarray
    fit_time: float
    num_parameters: int
    error: str | None = None
    stage: str = "full"

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
        f"{'rank':>4}  {'model':<28} {'params':>6} {'fit [s]':>8} {'train':>8} "
        f"{'held-out':>9}  outcome"
    ]
    for k, s in enumerate(scores, start=1):
        if s.error is not None:
            outcome = f"failed: {s.error}"
        elif not np.isfinite(s.median_test_nrmse):
            outcome = "held-out simulation diverged"
        elif s.result.unidentified:  # pyright: ignore[reportOptionalMemberAccess]  # no error: a result
            outcome = f"not identified ({len(s.result.unidentified)} combination(s))"  # pyright: ignore[reportOptionalMemberAccess]  # no error: a result
        else:
            outcome = s.result.reason.split(":")[0].split(" (")[0]  # pyright: ignore[reportOptionalMemberAccess]  # no error: a result
        if s.stage != "full" and s.error is None:
            outcome += " (screening only)"
        rows.append(
            f"{k:>4}  {s.name:<28} {s.num_parameters:>6} {s.fit_time:>8.1f} "
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


# Screening: each candidate is first fitted on the start of every training experiment
# (up to SCREEN_CROSSINGS crossings of the displacement's ±20 % band after the discarded
# start, i.e. one cycle of a sine test, and at least SCREEN_DURATION seconds) for at
# most SCREEN_STEPS steps; only the best `finalists` are fitted on all the data.
SCREEN_CROSSINGS = 2
SCREEN_DURATION = 1.0  # s
SCREEN_STEPS = 25


def screening_end(e, discard: float = 0.0) -> float:
    """The time [s] up to which `e` is used for screening (see `SCREEN_CROSSINGS`)."""
    t, x = np.asarray(e.t, float), np.asarray(e.x, float)
    start = t[0] + discard
    centre, band = 0.5 * (np.max(x) + np.min(x)), 0.1 * np.ptp(x)
    after = t >= start
    side = np.where(x > centre + band, 1, np.where(x < centre - band, -1, 0))[after]
    outside = np.flatnonzero(side)  # samples beyond the band, on either side
    crossings = outside[1:][np.diff(side[outside]) != 0]
    end = (
        t[after][crossings[SCREEN_CROSSINGS - 1]]
        if len(crossings) >= SCREEN_CROSSINGS
        else t[-1]
    )
    return float(min(t[-1], max(end, start + SCREEN_DURATION)))


def _per(value, n: int):
    """One value (or None) per experiment, from None, a number or a sequence."""
    if value is None:
        return [None] * n
    array = np.asarray(value, dtype=float)
    return [float(a) for a in np.broadcast_to(array, (n,))]


def _score(model, test, masks, smoothing, integrator):
    predicted = predict_all(model, test, integrator=integrator, smoothing=smoothing)
    errors = [
        (rmse(p, e.force, m), nrmse(p, e.force, m))
        for p, e, m in zip(predicted, test, masks)
    ]
    return np.array([r for r, _ in errors]), np.array([n for _, n in errors])


def compare_models(
    names_or_models,
    train: Sequence,
    test: Sequence,
    *,
    score_from: float | Sequence[float] | None = None,
    log: Callable[[str], None] | None = None,
    finalists: int | None = 2,
    screen_steps: int = SCREEN_STEPS,
    discard=None,
    smoothing=None,
    test_smoothing=None,
    **fit_kwargs,
) -> list[ModelScore]:
    r"""Fit each candidate on `train` and rank them by their error on `test`.

    Time goes where it matters: every candidate is first *screened* — fitted for at
    most `screen_steps` steps on the start of each training experiment (about one
    cycle past `discard`, see `screening_end`) and scored on the same stretch of the
    held-out ones — and only the best `finalists` are fitted on all the training data
    (from their screening fit) and scored on whole held-out experiments. The score is
    $\mathrm{NRMSE} = \mathrm{RMSE}/\mathrm{std}(F)$ per held-out experiment, the
    ranking by its median (robust to one odd test): finalists first, then the
    screened rest. A candidate that fails (its template cannot scale to the data, or
    its fit raises) is ranked last with the reason. The results' standard errors are
    from each fit's own Jacobian (`statistics_refinement=1` unless given): rank here,
    refit the chosen model (`select_model` does) for its statistics.

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
    - `finalists`: how many screened candidates are fitted on all the data (`None`:
      no screening, every candidate fitted on all the data).
    - `screen_steps`: the most Levenberg–Marquardt steps of a screening fit.
    - `discard`, `smoothing`: per training experiment (or one for all), as `fit`'s.
    - `test_smoothing`: the smoothing [s] of the held-out experiments' force (one for
      all or one each; default: `smoothing` when it is one number).
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
    if finalists is not None and finalists < 1:
        raise ValueError(f"`finalists` must be >= 1 or None, got {finalists}.")
    masks = _score_masks(test, score_from)
    if test_smoothing is None and smoothing is not None and np.ndim(smoothing) == 0:
        test_smoothing = smoothing
    fit_kwargs.setdefault("progress", False)
    integrator = fit_kwargs.get("integrator")
    say = log or (lambda line: None)
    test_names = tuple(str(getattr(e, "name", "")) for e in test)
    train_discard = _per(discard, len(train))
    # The screening stretch of each experiment: its start up to `screening_end`.
    cut_train = [
        _experiment_window(e, None, screening_end(e, d or 0.0))
        for e, d in zip(train, train_discard)
    ]
    test_discard = [
        float(np.asarray(e.t)[np.argmax(m)] - np.asarray(e.t)[0])
        for e, m in zip(test, masks)
    ]
    cut_test = [
        _experiment_window(e, None, screening_end(e, d))
        for e, d in zip(test, test_discard)
    ]
    cut_masks = [m[: len(np.asarray(c.t))] for m, c in zip(masks, cut_test)]
    failed, scores = [], []
    for name, build in _candidates(names_or_models, train):
        stage = "screened" if finalists is not None else "full"
        fit_on = cut_train if finalists is not None else train
        scored_on, scored_masks = (
            (cut_test, cut_masks) if finalists is not None else (test, masks)
        )
        say(f"{name}: {stage} fit on {len(train)} experiment(s)...")
        start = time.perf_counter()
        try:
            kwargs = dict(fit_kwargs)
            if finalists is not None:
                kwargs["max_steps"] = min(screen_steps, kwargs.get("max_steps", 200))
                kwargs.setdefault("statistics_refinement", 1)
            result = fit(
                build(), fit_on, discard=discard, smoothing=smoothing, **kwargs
            )
            test_rmse, test_nrmse = _score(
                result.model, scored_on, scored_masks, test_smoothing, integrator
            )
        except (ValueError, TypeError, RuntimeError, FloatingPointError) as e:
            elapsed = time.perf_counter() - start
            message = f"{type(e).__name__}: {e}"
            say(f"{name}: failed after {elapsed:.1f} s: {message}")
            nan = np.full(len(test), np.nan)
            failed.append(
                ModelScore(name, None, test_names, nan, nan, elapsed, 0, message)
            )
            continue
        elapsed = time.perf_counter() - start
        score = ModelScore(
            name=name,
            result=result,
            test_names=test_names,
            test_rmse=test_rmse,
            test_nrmse=test_nrmse,
            fit_time=elapsed,
            num_parameters=len(result.names),
            stage=stage,
        )
        say(
            f"{name}: {elapsed:.1f} s, {result.num_steps} steps, {len(result.names)} "
            f"parameters; median NRMSE train {score.median_train_nrmse:.4f}, held-out "
            f"{score.median_test_nrmse:.4f} ({stage})"
        )
        scores.append(score)
        if result.interrupted:
            say("interrupted: the comparison stops here")
            return sorted(scores, key=lambda s: s.median_test_nrmse) + failed
    scores.sort(key=lambda s: s.median_test_nrmse)
    if finalists is None:
        return scores + failed
    final = []
    for screened in scores[:finalists]:
        name = screened.name
        say(
            f"{name}: full fit on {len(train)} experiment(s), from its screening fit..."
        )
        start = time.perf_counter()
        try:
            # The finalists' standard errors are not reported (`select_model` refits
            # the winner): their own Jacobian serves, not a refined one.
            kwargs = dict(fit_kwargs)
            kwargs.setdefault("statistics_refinement", 1)
            result = fit(
                screened.result.constrained,
                train,
                discard=discard,
                smoothing=smoothing,
                **kwargs,
            )
            test_rmse, test_nrmse = _score(
                result.model, test, masks, test_smoothing, integrator
            )
        except (ValueError, TypeError, RuntimeError, FloatingPointError) as e:
            say(f"{name}: full fit failed: {type(e).__name__}: {e}")
            final.append(screened)
            continue
        elapsed = time.perf_counter() - start + screened.fit_time
        score = ModelScore(
            name,
            result,
            test_names,
            test_rmse,
            test_nrmse,
            elapsed,
            len(result.names),
            stage="full",
        )
        say(
            f"{name}: {elapsed:.1f} s in all, {result.num_steps} steps; median NRMSE "
            f"train {score.median_train_nrmse:.4f}, held-out "
            f"{score.median_test_nrmse:.4f} (full)"
        )
        final.append(score)
        if result.interrupted:
            break
    final.sort(key=lambda s: (s.stage != "full", s.median_test_nrmse))
    return final + scores[finalists:] + failed


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


def holdout_split(experiments: Sequence, *, indices: bool = False):
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
    `compare_models` (`None`, or the split times [s]), and the choice in words; with
    `indices=True` also the positions in `experiments` of the training and held-out
    experiments.
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
        everyone = list(range(len(experiments)))
        if indices:
            return train, experiments, splits, description, everyone, everyone
        return train, experiments, splits, description
    train = [e for k, e in enumerate(experiments) if k not in held]
    test = [e for k, e in enumerate(experiments) if k in held]
    names = ", ".join(str(getattr(e, "name", "")) for e in test)
    description = f"held out {len(test)} of {len(experiments)} ({what}): {names}"
    if indices:
        train_index = [k for k in range(len(experiments)) if k not in held]
        return train, test, None, description, train_index, sorted(held)
    return train, test, None, description


def select_model(
    names_or_models,
    train: Sequence,
    test: Sequence | None = None,
    *,
    score_from: float | Sequence[float] | None = None,
    log: Callable[[str], None] | None = None,
    discard=None,
    smoothing=None,
    **fit_kwargs,
) -> Selection:
    """Select a model by held-out error, then refit it on everything.

    **Arguments:**

    - `names_or_models`, `score_from`, `log`, `fit_kwargs` (`finalists`, ...): as
      `compare_models`.
    - `train`: the experiments to fit on; with `test=None`, all the experiments, of
      which `holdout_split` holds out a part.
    - `test`: held-out experiments, or `None` to hold out part of `train`.
    - `discard`, `smoothing`: [s], one number or one per experiment of `train` (and
      then of `test`, in that order), as `fit`'s.

    **Returns:** a `Selection`: the best candidate refitted on the training and
    held-out experiments together (starting from its training fit), and the ranking.

    **Raises:** `RuntimeError` when every candidate failed.
    """
    train = list(train)
    if test is None:
        if score_from is not None:
            raise ValueError("`score_from` needs `test`: give both or neither.")
        n = len(train)
        discards, widths = _per(discard, n), _per(smoothing, n)
        fit_on, test, score_from, holdout, train_index, test_index = holdout_split(  # pyright: ignore[reportAssignmentType]  # indices=True: six items
            train, indices=True
        )
        everything = train
        all_discard, all_smoothing = discards, widths
        if score_from is not None:  # split in time: the discard still applies
            score_from = [
                max(s, float(np.asarray(e.t)[0]) + (d or 0.0))
                for s, e, d in zip(score_from, test, discards)
            ]
        else:
            score_from = [
                float(np.asarray(test[k].t)[0]) + (discards[j] or 0.0)
                for k, j in enumerate(test_index)
            ]
        train_discard = [discards[j] for j in train_index]
        train_smoothing = [widths[j] for j in train_index]
        test_smoothing = [widths[j] for j in test_index]
    else:
        test = list(test)
        fit_on, everything = train, train + test
        holdout = f"{len(test)} held-out experiment(s) given"
        n = len(everything)
        all_discard, all_smoothing = _per(discard, n), _per(smoothing, n)
        train_discard, train_smoothing = (
            all_discard[: len(train)],
            all_smoothing[: len(train)],
        )
        test_smoothing = all_smoothing[len(train) :]
        if score_from is None and discard is not None:
            score_from = [
                float(np.asarray(e.t)[0]) + (d or 0.0)
                for e, d in zip(test, all_discard[len(train) :])
            ]
    zero = lambda values: (
        None if all(v is None for v in values) else [v or 0.0 for v in values]
    )
    scores = compare_models(
        names_or_models,
        fit_on,
        test,
        score_from=score_from,
        log=log,
        discard=zero(train_discard),
        smoothing=zero(train_smoothing),
        test_smoothing=zero(test_smoothing),
        **fit_kwargs,
    )
    best = scores[0]
    if best.error is not None:
        raise RuntimeError(
            "every candidate failed:\n"
            + "\n".join(f"  {s.name}: {s.error}" for s in scores)
        )
    say = log or (lambda line: None)
    if best.result.interrupted:  # pyright: ignore[reportOptionalMemberAccess]  # no error: a result
        return Selection(best.name, best.result, scores, holdout)  # pyright: ignore[reportArgumentType]  # no error: a result
    say(f"selected {best.name}; refitting on all {len(everything)} experiment(s)...")
    kwargs = dict(fit_kwargs)
    kwargs.pop("finalists", None)
    kwargs.pop("screen_steps", None)
    kwargs.setdefault("progress", False)
    # Started from the training fit (one start: `starts` served the first search).
    kwargs.pop("starts", None)
    result = fit(
        best.result.constrained,  # pyright: ignore[reportArgumentType, reportOptionalMemberAccess]  # no error: a result
        everything,
        discard=zero(all_discard),
        smoothing=zero(all_smoothing),
        **kwargs,
    )
    return Selection(best.name, result, scores, holdout)
