r"""Optimal experiment design: which tests identify a model best, chosen from the exact
Jacobian of the fit's own residual.

A test $e$ (a motion and an input; never its force) informs the free parameters
$\theta$ of a model through its Fisher information $M_e = J_e^\top J_e/\sigma_e^2$:
$J_e$ is the Jacobian of the model's force at the test's scored samples with respect
to $\theta$, computed by the engine `fit` uses (`pack` lays the tests out in lanes,
`residual.residuals` simulates them, one forward-mode pass gives the Jacobian;
`result.jacobian_matrix`), and $\sigma_e$ is the force noise per sample. Informations
add: after tests $P$ (and tests already run, $M_0$), the fitted parameters'
covariance is, to first order, $(M_0 + \sum_{e \in P} M_e)^{-1}$ — what
`FitResult.std_errors` reports after fitting those tests' data. The design chooses
$P$: the largest $\log\det$ (D-optimal), or the smallest sum of the named parameters'
squared relative standard errors (A-optimal on a subset), greedily and then by
Fedorov exchanges (the best swap of a chosen test for an unchosen one, repeated until
none improves).

Coordinates: $\theta$ are the fit's own variables, as `jaxmr.fit` steps them and
`FitResult` differentiates them: the logarithm of a `Positive` parameter, the logistic
variable of a `Bounded` one, a plain parameter itself (in its unit). So $\log\det M$
has the unit of $-\sum \log$(plain parameters' units) and of the noise, but its
differences (a test's contribution, one plan against another) do not depend on units,
and the D-optimal plan does not depend on the coordinates at all. Standard errors are
reported like `FitResult`'s, in each parameter's own unit.

Local design: the information depends on the parameters' values, so a plan is as good
as the model it starts from (a template scaled to the device, a published model, or an
earlier fit: sequential design with `already=`).
"""

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import numpy as np

from .._integrate import FixedStep
from .._misc import warn_if_float32
from .._signal import AbstractSignal, Sine
from ..data._experiment import Experiment
from .data import StepPolicy, as_step_policy, pack, pad_all, per_experiment
from .fitting import _split_model, broken_constraints
from .residual import DIVERGED, residuals
from .result import (
    FitResult,
    _parameter_names,
    _values_and_scale,
    covariance,
    jacobian_matrix,
)

# Added to the information (in coordinates where all candidates together have unit
# diagonal) while choosing: a plan that does not yet determine every parameter still
# has a finite log det, which rises by about -log(RIDGE) ≈ 21 per newly determined
# direction, so the greedy steps first cover every parameter. Far below any
# determined direction's eigenvalue (one test of a menu of n has about 1/n).
RIDGE = 1e-9
# Directions of a plan's information below this fraction of its largest eigenvalue
# (unit-diagonal coordinates; 1e-6 in singular values of the Jacobian) are not
# determined: the parameters with a weight above `result.NULL_WEIGHT` in them get an
# infinite standard error (`result.covariance`).
RCOND = 1e-12
# An exchange must improve the criterion by more than this (relative, at least 1e-9
# absolute), so that rounding cannot make the exchanges cycle.
TOLERANCE = 1e-9
# Exchanges per chosen test at most (each strictly improves the criterion, so this
# only bounds a pathological case).
MAX_SWAPS_PER_TEST = 50


class _Motion(NamedTuple):
    """A test as the design sees it: its motion and input, never a force (`pack`
    reads `force = None` as zeros, so the residual is the model's force itself)."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    current: np.ndarray
    name: str
    rotary: bool
    force: None = None


def _motion(experiment, k: int) -> _Motion:
    t = np.asarray(experiment.t, dtype=float)
    return _Motion(
        t=t,
        x=np.asarray(experiment.x, dtype=float),
        v=np.asarray(experiment.v, dtype=float),
        current=np.broadcast_to(np.asarray(experiment.current, dtype=float), t.shape),
        name=str(getattr(experiment, "name", "") or f"test {k}"),
        rotary=bool(getattr(experiment, "rotary", False)),
    )


class Conditions(NamedTuple):
    """What a test asks of a rig, read from its motion and input."""

    amplitude: float
    """Half the peak-to-peak displacement [m] (angle [rad])."""
    frequency: float
    """Half the mean rate at which the motion crosses its mid-range [Hz] (a sine's
    frequency; NaN with fewer than two crossings)."""
    current: float
    """The constant input [A] (or [V]); NaN when it varies within the test."""
    duration: float
    """[s]."""


def conditions(experiment) -> Conditions:
    """The amplitude, frequency, current and duration of a test (see
    `Conditions`), from its motion and input only."""
    t = np.asarray(experiment.t, dtype=float)
    x = np.asarray(experiment.x, dtype=float)
    current = np.ravel(np.asarray(experiment.current, dtype=float))
    y = x - 0.5 * (np.max(x) + np.min(x))
    above = y >= 0
    k = np.flatnonzero(above[:-1] != above[1:])
    # Each crossing's time by linear interpolation between its two samples; two
    # crossings per period.
    crossings = t[k] - y[k] * (t[k + 1] - t[k]) / (y[k + 1] - y[k])
    frequency = (
        (len(crossings) - 1) / (2 * (crossings[-1] - crossings[0]))
        if len(crossings) >= 2
        else math.nan
    )
    constant = bool(np.all(current == current[0]))
    return Conditions(
        amplitude=float(0.5 * np.ptp(x)),
        frequency=float(frequency),
        current=float(current[0]) if constant else math.nan,
        duration=float(t[-1] - t[0]),
    )


def planned_test(
    motion: AbstractSignal,
    duration: float,
    current: float | AbstractSignal = 0.0,
    *,
    sample_rate: float = 1000.0,
    name: str = "",
    rotary: bool = False,
    drive: str = "current",
) -> Experiment:
    """A test to run, as an `Experiment` without force: `motion` (any signal: `Sine`,
    `Multisine`, `Chirp`, `Triangle`, ...) and `current` sampled from $t = 0$ to
    `duration`, the velocity from the signal's own derivative.

    **Arguments:**

    - `motion`: the displacement [m] (angle [rad] for a brake) as a signal.
    - `duration`: [s].
    - `current`: the input [A] (or [V], `drive="voltage"`): a number or a signal.
    - `sample_rate`: [Hz], the rate the rig records at.
    - `name`, `rotary`, `drive`: as `Experiment`.

    **Returns:** an `Experiment` with `force=None`.
    """
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"`duration` must be > 0 s, got {duration}.")
    if not (math.isfinite(sample_rate) and sample_rate > 0):
        raise ValueError(f"`sample_rate` must be > 0 Hz, got {sample_rate}.")
    count = int(round(duration * sample_rate)) + 1
    t = np.arange(count) / sample_rate
    times = jax.numpy.asarray(t)
    x = np.asarray(jax.vmap(motion)(times))
    v = np.asarray(jax.vmap(motion.derivative)(times))
    if isinstance(current, AbstractSignal):
        current = np.asarray(jax.vmap(current)(times))  # pyright: ignore[reportAssignmentType]  # the signal, sampled
    return Experiment(
        t,
        x,
        v,
        current,  # pyright: ignore[reportArgumentType]  # a number or the samples
        None,
        name=name,
        rotary=rotary,
        drive=drive,
        velocity_source="planned: the derivative of the motion signal",
    )


def sine_grid(
    amplitudes: Sequence[float],
    frequencies: Sequence[float],
    currents: Sequence[float],
    *,
    cycles: float = 3.0,
    sample_rate: float = 1000.0,
    rotary: bool = False,
    drive: str = "current",
) -> list[Experiment]:
    r"""A menu of sine tests: every amplitude × frequency × current,
    $x(t) = a \sin(2\pi f t)$ at a constant input, `cycles` periods long, sampled at
    `sample_rate` [Hz] (`planned_test`).

    **Arguments:** `amplitudes` [m] ([rad] with `rotary=True`), `frequencies` [Hz],
    `currents` [A] ([V] with `drive="voltage"`), `cycles`, `sample_rate`.

    **Returns:** the `Experiment`s (no force), named like `sine_10mm_1Hz_0.5A`
    (`sine_2deg_1Hz_0.5A` for a brake), amplitude first, then frequency, then current.
    """
    if not (math.isfinite(cycles) and cycles > 0):
        raise ValueError(f"`cycles` must be > 0, got {cycles}.")
    unit = "V" if drive == "voltage" else "A"
    tests = []
    for a in amplitudes:
        size = f"{np.degrees(a):g}deg" if rotary else f"{1e3 * a:g}mm"
        for f in frequencies:
            for i in currents:
                tests.append(
                    planned_test(
                        Sine(a, f),
                        cycles / f,
                        float(i),
                        sample_rate=sample_rate,
                        name=f"sine_{size}_{f:g}Hz_{i:g}{unit}",
                        rotary=rotary,
                        drive=drive,
                    )
                )
    return tests


def _check_one_per_test(value, n: int, candidates: int, what: str) -> None:
    """One value per candidate when tests are also `already` run is ambiguous."""
    if (
        not callable(value)
        and np.ndim(value) == 1
        and n > candidates
        and len(value) == candidates
    ):
        raise ValueError(
            f"`{what}`: one value per candidate ({candidates}) but tests are also "
            f"`already` run: give one per test ({n}: the candidates', then those "
            "of `already`), one number, or a function of a list of experiments "
            "(e.g. jaxmr.data.utfsm_first_cycle)."
        )


def _information(free, static, motions, policy, discard, smoothing, batch_size):
    """Per test: JᵀJ in the fit's coordinates (force unit² per coordinate²), the
    spread (standard deviation) of the model's force over its scored samples, and
    their number."""
    n = len(motions)
    size = n if batch_size is None else batch_size
    groups = [np.arange(a, min(a + size, n)) for a in range(0, n, size)]
    datas = [
        pack(
            [motions[k] for k in group],
            policy,
            weighting="force",
            discard=discard[group],
            smoothing=smoothing[group],
            need_force=False,
        )
        for group in groups
    ]
    runs = datas
    if len(datas) > 1:
        # One shape and one set of static fields for every batch, so that the
        # Jacobian compiles once: the simulation reads no static field but the
        # number of experiments, which the first batch has the most of.
        padded = pad_all(datas)
        common = jax.tree.structure(padded[0])
        runs = [jax.tree.unflatten(common, jax.tree.leaves(d)) for d in padded]
    information, spread, count = [], [], []
    for data, run in zip(datas, runs):
        r, J = jacobian_matrix(residuals, free, static, run, None)
        bounds = np.cumsum((0,) + data.kept_counts)
        for j, name in enumerate(data.names):
            r_e, J_e = r[bounds[j] : bounds[j + 1]], J[bounds[j] : bounds[j + 1]]
            if not (np.all(np.abs(r_e) < DIVERGED) and np.all(np.isfinite(J_e))):
                raise ValueError(
                    f"the model's simulation of test {name!r} diverges or its "
                    "Jacobian is not finite: remove the test from the menu, or check "
                    "the model's parameters (jaxmr.predict shows its force there)."
                )
            information.append(J_e.T @ J_e)
            spread.append(float(np.std(r_e)))
            count.append(len(r_e))
    return np.stack(information), np.asarray(spread), np.asarray(count)


def _objective(p: int, weights: np.ndarray | None) -> Callable:
    r"""The criterion to maximise over stacks of information matrices (unit-diagonal
    coordinates, `RIDGE` added): log det (D), or minus the weighted trace of the
    inverse, $-\mathrm{tr}(W M^{-1})$, with `weights` the diagonal of W (A) or W
    itself (I)."""
    ridge = RIDGE * np.eye(p)
    if weights is not None and weights.ndim == 1:
        weights = np.diag(weights)

    def value(M):
        M = M + ridge
        if weights is None:
            return np.linalg.slogdet(M)[1]
        return -np.einsum("...ij,ji->...", np.linalg.inv(M), weights)

    return value


def _choose(information, prior, k: int, value) -> tuple[list[int], list[int], int]:
    """Greedy choice of `k` tests, then Fedorov exchanges until none improves.

    **Returns:** the plan (sorted), the greedy plan (sorted), the number of
    exchanges."""
    n = information.shape[0]
    chosen: list[int] = []
    M = prior.copy()
    for _ in range(k):
        free = np.setdiff1d(np.arange(n), chosen)
        best = int(free[np.argmax(value(M[None] + information[free]))])
        chosen.append(best)
        M = M + information[best]
    greedy = sorted(chosen)
    current = float(value(M))
    swaps = 0
    while swaps < MAX_SWAPS_PER_TEST * k:
        free = np.setdiff1d(np.arange(n), chosen)
        if free.size == 0:
            break
        # Every plan with one chosen test (axis 0) swapped for an unchosen one (axis 1).
        trial = (
            M[None, None] - information[chosen][:, None] + information[free][None, :]
        )
        values = value(trial)
        a, c = np.unravel_index(int(np.argmax(values)), values.shape)
        if not values[a, c] > current + TOLERANCE * max(1.0, abs(current)):
            break
        chosen[a] = int(free[c])
        # Summed afresh, not updated, so that rounding does not accumulate.
        M = prior + information[chosen].sum(axis=0)
        current = float(value(M))
        swaps += 1
    return sorted(chosen), greedy, swaps


def _log_det(M) -> float:
    sign, log_det = np.linalg.slogdet(M)
    return float(log_det) if sign > 0 else -math.inf


def _std_errors(M, value_scale) -> np.ndarray:
    """Standard errors in the parameters' units from the information `M` in the fit's
    coordinates (infinite for those in a direction `M` does not determine)."""
    d = np.sqrt(np.diag(M))
    d = np.where(d > 0, d, 1.0)
    cov, loose = covariance(*np.linalg.eigh(M / np.outer(d, d)), RCOND)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0)) / d
    se = np.where(loose | (np.sqrt(np.diag(M)) == 0), math.inf, se)
    return se * np.abs(value_scale)


@dataclasses.dataclass(frozen=True, eq=False)
class Design:
    """The outcome of `design_experiments`.

    **Attributes:**

    - `indices`: the chosen candidates' positions in the menu, ascending.
    - `plan`: the chosen candidates themselves (the objects given), in that order.
    - `criterion`: `"D"` (largest log det of the information), `"A"` (smallest sum
      of squared relative standard errors of `parameters`) or `"I"` (smallest
      predicted variance of the fitted force, summed over every candidate test).
    - `parameters`: the parameters A-optimality is about (empty for D and I).
    - `names`, `values`: all free parameters (named as `FitResult.names`) and their
      values at the model the design was computed for.
    - `information`: per candidate, its Fisher information JᵀJ/σ² in the
      fit's coordinates (see the module docstring), shape (candidates, p, p).
    - `prior_information`: the information of the tests already run (`already`;
      zeros without).
    - `noise`: per candidate, the force noise σ per sample [N] (N·m) assumed
      (`weighting` and `noise` of `design_experiments`).
    - `log_det`, `log_det_all`: log det of the information with the plan and with every
      candidate (the tests already run included in both).
    - `contributions`: per chosen test, how much the plan's log det drops when it is
      left out (inf: the others alone leave a parameter undetermined).
    - `std_errors`, `std_errors_all`: predicted standard errors with the plan and with
      every candidate, in the parameters' units, like `FitResult.std_errors`.
    - `greedy_indices`: the greedy plan before the exchanges; `swaps`: how many
      exchanges improved it.
    - `candidate_names`: the names of all candidates.
    - `value_scale`: d(value)/d(fit coordinate) per parameter (the value for a
      `Positive`, 1 for a plain parameter).
    """

    indices: tuple[int, ...]
    plan: tuple
    criterion: str
    parameters: tuple[str, ...]
    names: tuple[str, ...]
    values: np.ndarray
    information: np.ndarray
    prior_information: np.ndarray
    noise: np.ndarray
    log_det: float
    log_det_all: float
    contributions: np.ndarray
    std_errors: np.ndarray
    std_errors_all: np.ndarray
    greedy_indices: tuple[int, ...]
    swaps: int
    candidate_names: tuple[str, ...]
    value_scale: np.ndarray

    def information_of(self, indices: Sequence[int]) -> np.ndarray:
        """The information (fit coordinates) of the tests already run plus the
        candidates `indices` (repeats count twice)."""
        indices = np.asarray(indices, dtype=int)  # pyright: ignore[reportAssignmentType]  # as an index array
        return self.prior_information + self.information[indices].sum(axis=0)

    def log_det_of(self, indices: Sequence[int]) -> float:
        """log det of `information_of(indices)` (-inf when singular)."""
        return _log_det(self.information_of(indices))

    def std_errors_of(self, indices: Sequence[int]) -> np.ndarray:
        """Predicted standard errors [parameters' units] of a fit to the tests
        already run plus the candidates `indices`."""
        return _std_errors(self.information_of(indices), self.value_scale)

    @property
    def relative_std_errors(self) -> np.ndarray:
        """`std_errors / |values|` with the plan."""
        with np.errstate(divide="ignore"):
            return self.std_errors / np.abs(self.values)

    def plan_table(self) -> list[dict]:
        """One row per chosen test: `name`, `amplitude` [m] ([rad]), `frequency`
        [Hz], `current` [A] ([V]), `duration` [s] (`conditions`) and `contribution`
        (log det drop without it)."""
        rows = []
        for index, test, drop in zip(self.indices, self.plan, self.contributions):
            row = {"index": index, "name": self.candidate_names[index]}
            row.update(conditions(test)._asdict())
            row["contribution"] = float(drop)
            rows.append(row)
        return rows

    def table(self) -> str:
        """The plan and the predicted standard errors, as text."""
        lines = [
            f"{'test':<24} {'amplitude':>10} {'freq [Hz]':>9} {'current':>8} "
            f"{'duration':>9} {'log det drop':>12}"
        ]
        for row in self.plan_table():
            lines.append(
                f"{row['name']:<24} {row['amplitude']:>10.4g} {row['frequency']:>9.4g} "
                f"{row['current']:>8.4g} {row['duration']:>9.4g} "
                f"{row['contribution']:>12.3f}"
            )
        n = len(self.candidate_names)
        lines.append(
            f"{'parameter':<24} {'value':>12} {'std error':>11} {'rel':>8} "
            f"{f'all {n}':>11} {'rel':>8}"
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            for name, value, se, se_all in zip(
                self.names, self.values, self.std_errors, self.std_errors_all
            ):
                lines.append(
                    f"{name:<24} {value:>12.5g} {se:>11.3g} {se / abs(value):>8.2%} "
                    f"{se_all:>11.3g} {se_all / abs(value):>8.2%}"
                )
        return "\n".join(lines)

    @property
    def criterion_text(self) -> str:
        """The criterion in words, e.g. "D-optimal"."""
        return {
            "D": "D-optimal",
            "I": "I-optimal (prediction over the menu)",
            "A": f"A-optimal for {', '.join(self.parameters)}",
        }[self.criterion]

    def __str__(self):
        head = (
            f"design ({self.criterion_text}): {len(self.indices)} of "
            f"{len(self.candidate_names)} tests, {self.swaps} exchange(s) after the "
            "greedy choice; log det "
            f"{self.log_det:.3f} (all candidates {self.log_det_all:.3f})"
        )
        return head + "\n" + self.table()


def design_experiments(
    model,
    candidates: Sequence,
    k: int,
    *,
    parameters: str | Sequence[str] | None = None,
    criterion: str | None = None,
    already: Sequence = (),
    weighting: str = "nrmse",
    noise: float = 1.0,
    discard=None,
    smoothing=None,
    integrator: StepPolicy | FixedStep | None = None,
    batch_size: int | None = None,
) -> Design:
    r"""Choose `k` of the `candidates` tests that identify `model`'s free parameters
    best: D-optimal (largest $\log\det M$); with `parameters`, A-optimal for them
    (smallest $\sum_j (\mathrm{se}_j/|\theta_j|)^2$ over the named ones); or
    I-optimal for prediction (smallest $\mathrm{tr}(M_\text{all} M^{-1})$, the
    predicted variance of the fitted model's weighted force summed over every
    candidate test, $M_\text{all}$ their information).

    $M = M_0 + \sum_{e \in \text{plan}} J_e^\top J_e/\sigma_e^2$ is the Fisher
    information in the fit's coordinates (log of `Positive` parameters, the logistic
    variable of `Bounded` ones, plain parameters in their unit), $J_e$ the exact
    Jacobian of the model's force at test $e$'s scored samples (the engine of
    `jaxmr.fit`: same steps, discard and smoothing), $\sigma_e$ the force noise,
    $M_0$ the information of the tests `already` run. The plan starts greedy (each step
    adds the test that improves the criterion most) and is improved by exchanges of a
    chosen test for an unchosen one until none improves (Fedorov). The design reads
    the candidates' motions and inputs only: a force column is never read (it may be
    missing or NaN).

    **Arguments:**

    - `model`: a hysteresis model or `Damper` whose free parameters (those not
      `jaxmr.Fixed`; wrapped in `Positive`/`Bounded` as for `fit`) are to be
      identified, at its values (e.g. a `jaxmr.templates.MODEL_TEMPLATES` start, a published
      model, `result.constrained` of an earlier fit), or a `FitResult` (its
      `constrained` model).
    - `candidates`: the menu: `jaxmr.data.Experiment`s (or anything with `t`, `x`,
      `v`, `current`), e.g. `sine_grid(...)`, `planned_test(...)`, or measured
      records.
    - `k`: how many to choose (distinct candidates).
    - `parameters`: names (as `FitResult.names`, e.g. `".alpha.b"`) for A-optimality;
      `None`: D-optimality over all free parameters.
    - `criterion`: `"D"`, `"A"` or `"I"` (default: `"A"` with `parameters`, else
      `"D"`). I-optimality spreads the plan over the conditions the menu covers,
      where D-optimality goes to its extremes: on the UTFSM damper (6 of 30 tests)
      it is the one that predicted the other 24 tests better, while on five simulated
      dampers neither criterion predicted clearly better from one start per fit,
      and D did from four (benchmarks/README). Fit a small plan from several
      starts (`fit(..., starts=4)`): a few tests at the extremes can leave a
      model's parameters two minima apart.
    - `already`: tests already run (sequential design): their information is added
      before choosing.
    - `weighting`: how the fit to come weighs the tests, as `fit`'s `weighting`:
      `"nrmse"` (default) weighs test $e$ by $1/(\mathrm{std}(\hat F_e)\sqrt{N_e})$,
      with the spread of the *model's* force $\hat F_e$ over its $N_e$ scored samples
      in place of the measured one's, so that every test counts alike whatever its
      length ($\sigma_e = s\,\mathrm{std}(\hat F_e)\sqrt{N_e}$); `"force"`: unweighted,
      $\sigma_e = s$ for every sample (white force noise: a test informs in proportion
      to its length).
    - `noise`: $s$, the standard deviation of a weighted residual: with `"force"` the
      force noise per sample [N] (N·m for a brake); with `"nrmse"` dimensionless,
      `FitResult`'s $s^2 = 2\,\mathrm{loss}/(N - p)$ (a fit whose $n$ tests of $N$
      scored samples in all each leave an NRMSE $\rho$ has $s \approx
      \rho\sqrt{n/N}$). The standard errors scale with it; the plan does not depend
      on it.
    - `discard`, `smoothing`: [s] as for `fit`: `None` (default: each test's own,
      `Experiment.discard` and `.smoothing`), a number for all tests, one per test
      (the candidates', then those of `already`), or a function of a list of
      experiments giving one per experiment (e.g. `jaxmr.data.utfsm_first_cycle`).
    - `integrator`: the `StepPolicy` (as `fit`).
    - `batch_size`: simulate this many tests at a time (`None`: all at once, fastest;
      a number bounds the memory, every batch padded to one shape so that the
      Jacobian compiles once).

    **Returns:** a `Design`.
    """
    warn_if_float32("jaxmr.design_experiments")
    if isinstance(model, FitResult):
        model = model.constrained
    _, free, static = _split_model(model)
    candidates, already = list(candidates), list(already)
    n = len(candidates)
    if n == 0:
        raise ValueError(
            "`candidates` is empty: give the menu of tests to choose from."
        )
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n:
        raise ValueError(
            f"`k` must be an integer from 1 to the number of candidates ({n}), got {k!r}."
        )
    if weighting not in ("nrmse", "force"):
        raise ValueError(f"`weighting` must be 'nrmse' or 'force', got {weighting!r}.")
    # A test the model cannot run (a current law negative there) would be planned,
    # its information computed from an unphysical model.
    broken = broken_constraints(model, candidates + already)
    if broken:
        raise ValueError(
            "the model breaks its own constraints at the inputs of the tests: "
            + "; ".join(broken)
            + ". Give tests within the inputs the model holds for (e.g. currents >= "
            "0), or a model valid there."
        )
    if not (math.isfinite(noise) and noise > 0):
        raise ValueError(f"`noise` must be > 0, got {noise}.")
    if batch_size is not None and (not isinstance(batch_size, int) or batch_size < 1):
        raise ValueError(
            f"`batch_size` must be a positive integer or None, got {batch_size!r}."
        )
    names = _parameter_names(free)
    if isinstance(parameters, str):
        parameters = (parameters,)
    parameters = () if parameters is None else tuple(parameters)
    if criterion is None:
        criterion = "A" if parameters else "D"
    if criterion not in ("D", "A", "I"):
        raise ValueError(f"`criterion` must be 'D', 'A' or 'I', got {criterion!r}.")
    if (criterion == "A") != bool(parameters):
        raise ValueError(
            "A-optimality needs `parameters` (the names it is about), and only it "
            f"reads them; got criterion {criterion!r} with parameters {parameters}."
        )
    unknown = [name for name in parameters if name not in names]
    if unknown:
        raise ValueError(
            f"`parameters`: {', '.join(map(repr, unknown))} not among the model's free "
            f"parameters: {', '.join(names)}."
        )

    tests = candidates + already
    item = "test (candidates, then `already`)"
    _check_one_per_test(discard, len(tests), n, "discard")
    _check_one_per_test(smoothing, len(tests), n, "smoothing")
    discard = per_experiment(discard, tests, "discard", item)
    smoothing = per_experiment(smoothing, tests, "smoothing", item)
    motions = [_motion(e, j) for j, e in enumerate(tests)]
    information, spread, count = _information(
        free,
        static,
        motions,
        as_step_policy(integrator),
        discard,
        smoothing,
        batch_size,
    )
    if weighting == "nrmse":
        flat = [m.name for m, s in zip(motions, spread) if not s > 0]
        if flat:
            raise ValueError(
                f"the model's force does not vary in test {flat[0]!r}: NRMSE "
                "weighting needs a varying force (use weighting='force')."
            )
        sigma = noise * spread * np.sqrt(count)
    else:
        sigma = np.full(len(tests), float(noise))
    information = information / (sigma**2)[:, None, None]
    prior = information[n:].sum(axis=0)
    information = information[:n]

    # Choose in coordinates where all candidates together have unit diagonal, so that
    # RIDGE and the tolerances mean the same for every model and unit.
    total = prior + information.sum(axis=0)
    d = np.sqrt(np.diag(total))
    d = np.where(d > 0, d, 1.0)
    unit = np.outer(d, d)
    values, value_scale = _values_and_scale(free, static)
    weights = None
    if criterion == "I":
        # Prediction over the menu: tr(M_all M^-1), M_all every candidate's information.
        weights = information.sum(axis=0) / unit
    if parameters:
        # A-optimality on relative standard errors, se/|value| (for a Positive its
        # log's standard error), so that parameters of different units add; a
        # parameter at 0 counts in its own coordinate.
        relative = np.where(
            values != 0, value_scale / np.where(values != 0, values, 1.0), 1.0
        )
        named = np.isin(names, parameters)
        weights = np.where(named, relative**2, 0.0) / d**2
    p = len(names)
    chosen, greedy, swaps = _choose(
        information / unit, prior / unit, k, _objective(p, weights)
    )
    M = prior + information[chosen].sum(axis=0)
    log_det = _log_det(M)
    contributions = np.array(
        [log_det - _log_det(M - information[c]) for c in chosen], dtype=float
    )
    std_errors_all = _std_errors(total, value_scale)
    unseen = [n for n, e in zip(names, std_errors_all) if not np.isfinite(e)]
    if unseen:
        # Every plan is then singular (log det -inf, each test's drop nan): the
        # plan was written and the command exited 0 without a word.
        warnings.warn(
            f"design_experiments: no candidate test (nor all of them together) "
            f"determines {', '.join(unseen)}: every plan leaves them unknown (an "
            "infinite standard error). Add candidates that excite them (another "
            "current, amplitude or frequency), or fix them (jaxmr.Fixed).",
            UserWarning,
            stacklevel=2,
        )
    return Design(
        indices=tuple(chosen),
        plan=tuple(candidates[c] for c in chosen),
        criterion=criterion,
        parameters=parameters,
        names=tuple(names),
        values=values,
        information=information,
        prior_information=prior,
        noise=sigma[:n],
        log_det=log_det,
        log_det_all=_log_det(total),
        contributions=contributions,
        std_errors=_std_errors(M, value_scale),
        std_errors_all=std_errors_all,
        greedy_indices=tuple(greedy),
        swaps=swaps,
        candidate_names=tuple(m.name for m in motions[:n]),
        value_scale=value_scale,
    )
