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

from .data import per_experiment
from .fitting import fit
from .result import FitResult, StopReason
from .score import nrmse, predict_all, rmse
from .templates import MODEL_TEMPLATES


@dataclasses.dataclass(frozen=True)
class FitStarted:
    """An event of `compare_models` and `select_model` (their `callback`): a fit of
    candidate `name` starts.

    **Attributes:** `name`; `stage`: `"screening"` (on the start of each training
    experiment), `"full"` (on all the training data), `"refit"` (the selected
    model on every experiment, from its training fit) or `"template"` (the same
    from the candidate's own start, see `Selection`); `num_experiments`: how many
    it is fitted on.
    """

    name: str
    stage: str
    num_experiments: int


@dataclasses.dataclass(frozen=True)
class FitEnded:
    """An event of `compare_models` and `select_model` (their `callback`): a fit of
    candidate `name` ended (with its scoring on the held-out experiments).

    **Attributes:**

    - `name`, `stage`: as `FitStarted`'s.
    - `seconds`: the wall time [s] of this stage alone (fit and held-out scoring,
      compilation included).
    - `num_steps`, `loss`, `stop` (a `StopReason`), `converged`, `outcome` (the
      verdict in words): the fit's (`FitResult`'s); `num_parameters`: its free
      parameters.
    - `train_nrmse`, `test_nrmse`: the median NRMSE on the training and held-out
      experiments (`test_nrmse` NaN for the refit and the template's fit, which
      hold nothing out).
    - `error`: why the fit failed (`None` when it did not; the fit's fields are then
      0, NaN or `None`).
    """

    name: str
    stage: str
    seconds: float
    num_steps: int = 0
    loss: float = float("nan")
    stop: StopReason | None = None
    converged: bool = False
    num_parameters: int = 0
    train_nrmse: float = float("nan")
    test_nrmse: float = float("nan")
    error: str | None = None
    outcome: str = ""


# A candidate's fit that raises one of these has failed (it is ranked last, with the
# reason): a template that cannot scale to the data or data a fit refuses raise
# ValueError; XLA's runtime (e.g. out of memory for a large candidate) and equinox's
# checks raise RuntimeError subclasses; NumPy's checked arithmetic FloatingPointError.
# Anything else (a TypeError, AttributeError, ...) is a programming error and
# propagates; so do NotImplementedError and RecursionError, RuntimeErrors of code.
_FIT_FAILURES = (ValueError, RuntimeError, FloatingPointError)
_CODE_ERRORS = (NotImplementedError, RecursionError)


class _LogLines:
    """The events of `compare_models` and `select_model` as the lines of text their
    `log` is called with (each fit's own wall time, and its verdict in the words of
    `FitResult.outcome`)."""

    def __init__(self, log: Callable[[str], None]):
        self.log = log
        self.screening: dict[str, float] = {}  # name -> its screening time [s]

    def __call__(self, event) -> None:
        name, stage = event.name, event.stage
        screened = stage == "full" and name in self.screening
        if isinstance(event, FitStarted):
            n = event.num_experiments
            if stage == "refit":
                self.log(
                    f"selected {name}; refitting on all {n} experiment(s) from its "
                    "training fit..."
                )
            elif stage == "template":
                self.log(
                    f"{name}: fit on all {n} experiment(s) from its own start (the "
                    "lower loss of the two is kept)..."
                )
            elif screened:
                self.log(
                    f"{name}: full fit on {n} experiment(s), from its screening fit..."
                )
            else:
                what = "screened" if stage == "screening" else "full"
                self.log(f"{name}: {what} fit on {n} experiment(s)...")
            return
        if event.error is not None:
            if screened or stage == "template":
                self.log(f"{name}: {stage} fit failed: {event.error}")
            else:
                self.log(f"{name}: failed after {event.seconds:.1f} s: {event.error}")
            return
        if stage in ("refit", "template"):
            self.log(
                f"{name}: {event.seconds:.1f} s, {event.num_steps} steps, loss "
                f"{event.loss:.6g}, median NRMSE {event.train_nrmse:.4f} ({stage}); "
                f"{event.outcome}"
            )
            return
        errors = (
            f"median NRMSE train {event.train_nrmse:.4f}, held-out "
            f"{event.test_nrmse:.4f}"
        )
        if screened:
            total = self.screening[name] + event.seconds
            self.log(
                f"{name}: {event.seconds:.1f} s ({total:.1f} s with its screening), "
                f"{event.num_steps} steps; {errors} (full); {event.outcome}"
            )
        else:
            if stage == "screening":
                self.screening[name] = event.seconds
            what = "screened" if stage == "screening" else "full"
            self.log(
                f"{name}: {event.seconds:.1f} s, {event.num_steps} steps, "
                f"{event.num_parameters} parameters; {errors} ({what}); "
                f"{event.outcome}"
            )
        if event.stop is StopReason.INTERRUPTED:
            self.log("interrupted: the comparison stops here")


def _reporter(callback, log):
    """One `report(event)` for a `callback` of events and a `log` of lines."""
    lines = None if log is None else _LogLines(log)

    def report(event):
        if callback is not None:
            callback(event)
        if lines is not None:
            lines(event)

    return report


def _ended(name, stage, seconds, result, train_nrmse, test_nrmse) -> FitEnded:
    return FitEnded(
        name=name,
        stage=stage,
        seconds=seconds,
        num_steps=result.num_steps,
        loss=result.loss,
        stop=result.stop,
        converged=result.converged,
        num_parameters=len(result.names),
        train_nrmse=train_nrmse,
        test_nrmse=test_nrmse,
        outcome=result.outcome,
    )


@dataclasses.dataclass(frozen=True, eq=False)
class ModelScore:
    """One candidate of `compare_models`: its fit and its held-out error.

    **Attributes:**

    - `name`: the template name, or the model's class name.
    - `result`: the `FitResult` on the training experiments (`None` if it failed).
    - `test_names`, `test_rmse`, `test_nrmse`: per held-out experiment.
    - `fit_time`: wall time of the fit [s], compilation included (a finalist's:
      its screening and its full fit together).
    - `num_parameters`: the number of fitted (free) parameters.
    - `error`: why the candidate failed, or `None`.
    - `stage`: `"full"` (fitted on all the training data, scored on whole held-out
      experiments) or `"screened"` (on their starts only, see `compare_models`).
    - `screening_time`, `full_time`: the wall time [s] of each stage alone (fit and
      held-out scoring, compilation included), `None` for a stage not run.
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
    screening_time: float | None = None
    full_time: float | None = None

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

    @property
    def outcome(self) -> str:
        """The candidate's verdict in words: its fit's (`FitResult.outcome`, "converged"
        alone when it did), or why it failed; then whether its held-out simulation
        diverged and whether it was only screened."""
        result = self.result
        if self.error is not None or result is None:
            return f"failed: {self.error}"
        words = "converged" if result.converged else result.outcome
        if not np.isfinite(self.median_test_nrmse):
            words += "; held-out simulation diverged"
        if self.stage != "full":
            words += " (screening only)"
        return words


def score_table(scores: Sequence[ModelScore]) -> str:
    """The ranking as a text table: rank, name, parameters, the wall time [s] of the
    screening and of the full fit (`ModelScore.screening_time`, `full_time`:
    compilation included; "-" for a stage not run), median NRMSE on the training and
    held-out experiments, and the verdict (`ModelScore.outcome`)."""

    def seconds(value):
        return "-" if value is None else f"{value:.1f}"

    rows = [
        f"{'rank':>4}  {'model':<28} {'params':>6} {'screen [s]':>10} "
        f"{'full [s]':>8} {'train':>8} {'held-out':>9}  outcome"
    ]
    for k, s in enumerate(scores, start=1):
        rows.append(
            f"{k:>4}  {s.name:<28} {s.num_parameters:>6} "
            f"{seconds(s.screening_time):>10} {seconds(s.full_time):>8} "
            f"{s.median_train_nrmse:>8.4f} {s.median_test_nrmse:>9.4f}  {s.outcome}"
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
    callback: Callable[[FitStarted | FitEnded], None] | None = None,
    finalists: int | None = 2,
    screen_steps: int = SCREEN_STEPS,
    discard=None,
    smoothing=None,
    test_smoothing=None,
    stop=None,
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
    screened rest. A candidate whose fit fails (its template cannot scale to the
    data, the data are refused, the runtime fails: `ValueError`, `RuntimeError`,
    `FloatingPointError`) is ranked last with the reason; any other exception (a
    programming error) propagates. The results' standard errors are from each fit's
    own Jacobian (`statistics_refinement=1` unless given): rank here, refit the
    chosen model (`select_model` does) for its statistics.

    **Arguments:**

    - `names_or_models`: template names (keys of `jaxmr.templates.MODEL_TEMPLATES`), models to
      fit from (their values the initial guess), or a mapping from names to models or
      to functions `experiments -> model`.
    - `train`: the experiments to fit on (`jaxmr.data.Experiment`s with force).
    - `test`: the held-out experiments (with force).
    - `score_from`: a time [s] (or one per test experiment) before which held-out
      samples are simulated, to bring the hysteretic state from its virgin value to
      the test's, but not scored (e.g. the first cycle). Default: each test
      experiment's start plus its own `discard` (0 for anything without one).
    - `log`: called with a line of text before and after each fit (e.g. `print`).
    - `callback`: called with a `FitStarted` before and a `FitEnded` after each fit.
    - `finalists`: how many screened candidates are fitted on all the data (`None`:
      no screening, every candidate fitted on all the data).
    - `screen_steps`: the most Levenberg–Marquardt steps of a screening fit.
    - `discard`, `smoothing`: per training experiment (or one for all), as `fit`'s
      (`None`: each experiment's own).
    - `test_smoothing`: the smoothing [s] of the held-out experiments' force (one for
      all or one each; default: `smoothing` when it is one number, else each held-out
      experiment's own).
    - `stop`: a `threading.Event` (as `fit`'s): once set, the fit under way stops
      with its best parameters and the comparison ends there, as on Ctrl-C.
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
    if score_from is None:
        score_from = [
            float(np.asarray(e.t)[0]) + d
            for e, d in zip(test, per_experiment(None, test, "discard"))
        ]
    masks = _score_masks(test, score_from)
    if test_smoothing is None and smoothing is not None and np.ndim(smoothing) == 0:
        test_smoothing = smoothing
    fit_kwargs.setdefault("progress", False)
    fit_kwargs["stop"] = stop
    integrator = fit_kwargs.get("integrator")
    report = _reporter(callback, log)
    test_names = tuple(str(getattr(e, "name", "")) for e in test)
    train_discard = per_experiment(discard, train, "discard")
    # The screening stretch of each experiment: its start up to `screening_end`.
    cut_train = [
        _experiment_window(e, None, screening_end(e, d))
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

    def attempt(name, stage, build, fit_on, scored_on, scored_masks, kwargs):
        """((result, test rmse, test nrmse) or None, the failure's message or None,
        seconds) of one stage, with its `FitStarted` and `FitEnded` events (the
        latter, on success, is the caller's: it holds the score)."""
        report(FitStarted(name, stage, len(train)))
        start = time.perf_counter()
        try:
            result = fit(
                build(), fit_on, discard=discard, smoothing=smoothing, **kwargs
            )
            test_rmse, test_nrmse = _score(
                result.model, scored_on, scored_masks, test_smoothing, integrator
            )
        except _FIT_FAILURES as e:
            if isinstance(e, _CODE_ERRORS):
                raise
            seconds = time.perf_counter() - start
            message = f"{type(e).__name__}: {e}"
            report(FitEnded(name, stage, seconds, error=message))
            return None, message, seconds
        seconds = time.perf_counter() - start
        return (result, test_rmse, test_nrmse), None, seconds

    failed, scores = [], []
    screening = finalists is not None
    for name, build in _candidates(names_or_models, train):
        kwargs = dict(fit_kwargs)
        if screening:
            kwargs["max_steps"] = min(screen_steps, kwargs.get("max_steps", 200))
            kwargs.setdefault("statistics_refinement", 1)
        stage = "screening" if screening else "full"
        outcome, message, seconds = attempt(
            name,
            stage,
            build,
            cut_train if screening else train,
            cut_test if screening else test,
            cut_masks if screening else masks,
            kwargs,
        )
        if outcome is None:
            nan = np.full(len(test), np.nan)
            failed.append(
                ModelScore(
                    name,
                    None,
                    test_names,
                    nan,
                    nan,
                    seconds,
                    0,
                    message,
                    screening_time=seconds if screening else None,
                    full_time=None if screening else seconds,
                )
            )
            continue
        result, test_rmse, test_nrmse = outcome
        score = ModelScore(
            name=name,
            result=result,
            test_names=test_names,
            test_rmse=test_rmse,
            test_nrmse=test_nrmse,
            fit_time=seconds,
            num_parameters=len(result.names),
            stage="screened" if screening else "full",
            screening_time=seconds if screening else None,
            full_time=None if screening else seconds,
        )
        report(
            _ended(
                name,
                stage,
                seconds,
                result,
                score.median_train_nrmse,
                score.median_test_nrmse,
            )
        )
        scores.append(score)
        if result.interrupted:
            return sorted(scores, key=lambda s: s.median_test_nrmse) + failed
    scores.sort(key=lambda s: s.median_test_nrmse)
    if not screening:
        return scores + failed
    final = []
    for screened in scores[:finalists]:
        name = screened.name
        # The finalists' standard errors are not reported (`select_model` refits
        # the winner): their own Jacobian serves, not a refined one.
        kwargs = dict(fit_kwargs)
        kwargs.setdefault("statistics_refinement", 1)
        outcome, message, seconds = attempt(
            name,
            "full",
            lambda s=screened: s.result.constrained,  # pyright: ignore[reportOptionalMemberAccess]  # ranked: a result
            train,
            test,
            masks,
            kwargs,
        )
        if outcome is None:
            final.append(screened)
            continue
        result, test_rmse, test_nrmse = outcome
        score = ModelScore(
            name,
            result,
            test_names,
            test_rmse,
            test_nrmse,
            seconds + screened.fit_time,
            len(result.names),
            stage="full",
            screening_time=screened.screening_time,
            full_time=seconds,
        )
        report(
            _ended(
                name,
                "full",
                seconds,
                result,
                score.median_train_nrmse,
                score.median_test_nrmse,
            )
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
    - `result`: its `FitResult` on all the experiments (training and held-out): of
      two fits, the one with the lower loss, so never worse than the candidate fitted
      alone with `fit` and the same options: the refit from its training fit
      (`kept == "refit"`) and the fit from the candidate's own start, its template
      built on all the experiments (`kept == "template"`).
    - `scores`: the ranking (`compare_models`' output).
    - `holdout`: how the held-out data were chosen, in words.
    - `refit_time`, `template_time`: the wall time [s] of each of those two fits,
      compilation included (`None` for a fit not made: the comparison or the refit
      was interrupted, or the template's fit failed).
    - `kept`: which of the two `result` is, `"refit"` or `"template"` (the stages
      of their `FitEnded` events); `None` when the comparison was interrupted and
      `result` is the training fit.
    """

    name: str
    result: FitResult
    scores: list[ModelScore]
    holdout: str
    refit_time: float | None = None
    template_time: float | None = None
    kept: str | None = None

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
    callback: Callable[[FitStarted | FitEnded], None] | None = None,
    discard=None,
    smoothing=None,
    stop=None,
    **fit_kwargs,
) -> Selection:
    """Select a model by held-out error, then refit it on everything.

    **Arguments:**

    - `names_or_models`, `score_from`, `log`, `callback`, `stop`, `fit_kwargs`
      (`finalists`, ...): as `compare_models` (the two fits on every experiment
      have the stages `"refit"` and `"template"`).
    - `train`: the experiments to fit on; with `test=None`, all the experiments, of
      which `holdout_split` holds out a part.
    - `test`: held-out experiments, or `None` to hold out part of `train`.
    - `discard`, `smoothing`: [s], one number or one per experiment of `train` (and
      then of `test`, in that order), as `fit`'s (`None`: each experiment's own).

    **Returns:** a `Selection`: the best candidate fitted on the training and
    held-out experiments together, twice (from its training fit, and from its own
    start as `fit` alone would: the lower loss is kept), and the ranking.

    **Raises:** `RuntimeError` when every candidate failed.
    """
    train = list(train)
    if test is None:
        if score_from is not None:
            raise ValueError("`score_from` needs `test`: give both or neither.")
        everything = train
        discards = per_experiment(discard, everything, "discard")
        widths = per_experiment(smoothing, everything, "smoothing")
        fit_on, test, score_from, holdout, train_index, test_index = holdout_split(  # pyright: ignore[reportAssignmentType]  # indices=True: six items
            train, indices=True
        )
        starts = [float(np.asarray(e.t)[0]) for e in test]
        held_discard = [discards[j] for j in test_index]
        if score_from is not None:  # split in time: the discard still applies
            score_from = [
                max(s, t0 + d) for s, t0, d in zip(score_from, starts, held_discard)
            ]
        else:
            score_from = [t0 + d for t0, d in zip(starts, held_discard)]
        train_discard = discards[train_index]
        train_smoothing = widths[train_index]
        test_smoothing = widths[test_index]
    else:
        test = list(test)
        fit_on, everything = train, train + test
        holdout = f"{len(test)} held-out experiment(s) given"
        discards = per_experiment(discard, everything, "discard")
        widths = per_experiment(smoothing, everything, "smoothing")
        train_discard = discards[: len(train)]
        train_smoothing = widths[: len(train)]
        test_smoothing = widths[len(train) :]
        if score_from is None:
            score_from = [
                float(np.asarray(e.t)[0]) + d
                for e, d in zip(test, discards[len(train) :])
            ]
    scores = compare_models(
        names_or_models,
        fit_on,
        test,
        score_from=score_from,
        log=log,
        callback=callback,
        discard=train_discard,
        smoothing=train_smoothing,
        test_smoothing=test_smoothing,
        stop=stop,
        **fit_kwargs,
    )
    best = scores[0]
    if best.error is not None or best.result is None:
        raise RuntimeError(
            "every candidate failed:\n"
            + "\n".join(f"  {s.name}: {s.error}" for s in scores)
        )
    if best.result.interrupted:
        return Selection(best.name, best.result, scores, holdout)
    report = _reporter(callback, log)
    kwargs = dict(fit_kwargs)
    kwargs.pop("finalists", None)
    kwargs.pop("screen_steps", None)
    kwargs.setdefault("progress", False)
    options = dict(discard=discards, smoothing=widths, stop=stop)

    def refit(stage, model, **more):
        report(FitStarted(best.name, stage, len(everything)))
        start = time.perf_counter()
        result = fit(model, everything, **options, **kwargs, **more)
        seconds = time.perf_counter() - start
        median = float(np.median(result.nrmse))
        report(_ended(best.name, stage, seconds, result, median, float("nan")))
        return result, seconds

    # From the training fit (one start: `starts` served the first search) ...
    chained, refit_time = refit(
        "refit",
        best.result.constrained,  # pyright: ignore[reportArgumentType]  # a fitted model
        starts=None,
    )
    if chained.interrupted:
        return Selection(
            best.name, chained, scores, holdout, refit_time=refit_time, kept="refit"
        )
    # ... and from the template's own start on all the data, as `fit` alone runs it
    # (with the same options, `starts` included). A chained fit can end in another,
    # worse local minimum than the template's: on 5 UTFSM files (one per amplitude
    # and frequency, 0 to 1 A) Bouc–Wen's refit stopped after 13 steps at a loss
    # 25 % above its template's own 35-step fit; on three 2 mm / 5 Hz tests Spencer's
    # at 1.4 % above, with other parameters (α 534 against 274 N), and fits restarted
    # from its end (fresh trust region and scaling) gained 0.1 % in all: a minimum,
    # not a premature stop, so no stall rule would help. Keeping the lower loss of
    # the two makes the selected model never worse than its template fitted alone,
    # at the cost of that fit (it shares the refit's compiled shapes).
    build = dict(_candidates(names_or_models, everything))[best.name]
    start = time.perf_counter()
    try:
        template, template_time = refit("template", build())
    except _FIT_FAILURES as e:
        if isinstance(e, _CODE_ERRORS):
            raise
        seconds = time.perf_counter() - start
        message = f"{type(e).__name__}: {e}"
        report(FitEnded(best.name, "template", seconds, error=message))
        template, template_time = None, None
    kept = (
        "template"
        if template is not None and _lower_loss(template, chained)
        else "refit"
    )
    return Selection(
        best.name,
        template if kept == "template" else chained,  # pyright: ignore[reportArgumentType]  # not None when kept
        scores,
        holdout,
        refit_time=refit_time,
        template_time=template_time,
        kept=kept,
    )


def _lower_loss(a: FitResult, b: FitResult) -> bool:
    """Whether fit `a` reached a lower loss than `b` (a non-finite loss is none)."""
    loss = lambda r: r.loss if np.isfinite(r.loss) else np.inf
    return loss(a) < loss(b)
