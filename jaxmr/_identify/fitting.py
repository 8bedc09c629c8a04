"""`fit` and `fit_each`: identify a damper model from measured experiments by least
squares — the entry points that tie the stages together (data → residual → solver →
result)."""

import contextlib
import re
import warnings
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._channel import ChannelDelay
from .._current_law import ConstantLaw, is_law
from .._damper import Damper, with_fitted_range
from .._distribute import batch_mesh, gather, replicate, spread, to_host
from .._hysteresis import AbstractHysteresis
from .._integrate import FixedStep
from .._misc import to_device, warn_if_float32
from .._parameter import fitted_form, free_filter, unwrap
from .data import (
    FitData,
    StepPolicy,
    as_step_policy,
    experiment_list,
    pack,
    pad_all,
    per_experiment,
    stack,
)
from .interrupts import finishing
from .residual import (
    guarded_residuals,
    residuals,
    simulate,
    simulate_jit,
    traced_once,
    value_and_jacobian,
)
from .result import FitResult, assemble, kept_groups, statistics, statistics_from
from .solver import (
    FastLevenbergMarquardt,
    check_budget,
    column_mesh,
    column_scale,
    column_scales,
    divide,
    iterate,
    multiply,
    placed_like_data,
    progress_printer,
    scale_and_first_step,
    spread_starts,
    unscaled_member,
)


def _scaled_residuals(y, static, data, scale):
    # Through `traced_once` on the unscaled residual, which the statistics
    # differentiate at the optimum: with `statistics_refinement=1` (the same data)
    # one trace of the model serves both; refined, the statistics' data have
    # another shape and are traced apart.
    return traced_once(residuals, multiply(y, scale), static, data, None)


def _guarded_scaled_residuals(y, static, data, scale):
    return traced_once(guarded_residuals, multiply(y, scale), static, data, None)


def _each_scaled_residuals(y, static, data_and_scale, extra):
    # `fit_each`'s: each problem carries its own column scale beside its data (both
    # batched on axis 0), where `extra` is shared by the batch.
    data, scale = data_and_scale
    return _scaled_residuals(y, static, data, scale)


def _each_guarded_scaled_residuals(y, static, data_and_scale, extra):
    data, scale = data_and_scale
    return _guarded_scaled_residuals(y, static, data, scale)


def _fit_residuals(inside: bool):
    """The scaled residual a fit runs on: guarded (`guarded_residuals`: a point whose
    state leaves its bounds is rejected) when every start's state stays inside
    them, so that the fit ends where its report finds a sound simulation; else
    unguarded, as a start already outside would have no finite residual to descend
    from (the NEES notebook's voltage-driven start overshoots its bound and fits
    inside it). With the unscaled residual it scales."""
    if inside:
        return _guarded_scaled_residuals, guarded_residuals
    return _scaled_residuals, residuals


def _starts_inside(ys, static, data) -> bool:
    """Whether the guarded simulation of every start (axis 0 of `ys`, unscaled free
    values) is finite: no experiment's state leaves its bounds (the report's
    compiled simulation, reused: the start placed as the report's parameters are)."""
    n = jax.tree.leaves(ys)[0].shape[0]
    return all(
        bool(
            np.all(
                np.isfinite(
                    simulate_jit(
                        eqx.combine(
                            placed_like_data(
                                jax.tree.map(lambda a, k=k: a[k], ys), data
                            ),
                            static,
                        ),
                        data,
                        True,
                    )
                )
            )
        )
        for k in range(n)
    )


def _check_current_laws(model, experiments) -> None:
    """A current law with free slope or shape needs experiments at several currents."""
    laws = [
        law
        for law in jax.tree.leaves(model, is_leaf=is_law)
        if is_law(law) and not isinstance(law, ConstantLaw)
    ]
    free_laws = [
        law for law in laws if jax.tree.leaves(eqx.filter(law, free_filter(law)))
    ]
    if not free_laws:
        return
    currents = np.concatenate(
        [np.ravel(np.asarray(e.current, dtype=float)) for e in experiments]
    )
    if np.ptp(currents) <= 1e-9 * max(1.0, float(np.max(np.abs(currents)))):
        names = sorted({type(law).__name__ for law in free_laws})
        raise ValueError(
            f"the model has free current laws ({', '.join(names)}) but every experiment "
            f"is at the same current ({float(currents[0]):g}): a law's dependence on "
            "current cannot be identified from one current. Give experiments at "
            "several currents, or replace the laws by plain parameters (or "
            "jaxmr.Fixed laws) for a single-current fit."
        )


def _check_enough_data(free, data, where: str = "") -> None:
    """More scored samples than free parameters, or the fit is underdetermined: its
    standard errors divide by n − p (a 3-sample file fitted with 5 parameters reported
    a 6e7 % standard error as if it were a result)."""
    p = sum(int(np.size(leaf)) for leaf in jax.tree.leaves(free))
    n = sum(data.kept_counts)
    if n <= p:
        raise ValueError(
            f"{where}{n} scored sample(s) for {p} free parameter(s): a least-squares "
            "fit needs more samples than parameters. Give longer experiments (or a "
            "smaller `discard`), or fix parameters with jaxmr.Fixed."
        )
    check_record_lengths(data.names, data.kept_counts, p, "experiment", where)


def check_record_lengths(names, counts, p: int, what: str, where: str = "") -> None:
    """Every record (experiment) scored on more samples than the `p` free
    parameters. Each counts as much as any other in the fit (its normalised
    error), so a record of a few samples (a cut gone wrong) weighs like a whole
    test: a 3-sample record beside a 1500-sample one pulled `fit_system`'s
    estimates 4-6 standard errors off, with the fit "converged"."""
    short = [(name, c) for name, c in zip(names, counts) if c <= p]
    if short:
        listed = ", ".join(f"{name!r} ({c})" for name, c in short)
        raise ValueError(
            f"{where}{what}(s) scored on no more samples than the {p} free "
            f"parameter(s): {listed}. Each {what} counts as much as any other in the "
            f"fit, so one this short would weigh like a whole test: drop it, or give "
            "it more samples (or a smaller `discard`)."
        )


def _split_model(model):
    """`model` as a fit takes it (`fitted_form`), and its free and static parts."""
    if not isinstance(model, (AbstractHysteresis, Damper, ChannelDelay)):
        raise TypeError(
            "`model` must be a jaxmr hysteresis model, Damper or ChannelDelay (its "
            f"values the initial guess), got {type(model).__name__}."
        )
    model = fitted_form(model)
    free, static = eqx.partition(model, free_filter(model))
    if not jax.tree.leaves(free):
        raise ValueError(
            "nothing to fit: every parameter of `model` is Fixed (a parameter at a "
            "mode of its model, e.g. Bingham's `velocity_scale` of 0 for the exact "
            "sign, counts as fixed: give it a positive value to fit it)."
        )
    return model, free, static


def _lanes_on_devices(data: FitData) -> FitData:
    """The lanes split over the process's devices (GPUs, or CPU cores as devices with
    `XLA_FLAGS=--xla_force_host_platform_device_count=N`), each device scanning its
    own lanes, when they divide evenly; else, or across processes, as they are."""
    mesh = batch_mesh(local=True)
    lanes = data.step.shape[0]
    if jax.process_count() > 1 or mesh is None or lanes % mesh.size:
        return data
    where = lambda d: (d.inputs, d.step, d.reset)
    return eqx.tree_at(where, data, spread(where(data), mesh))


def broken_constraints(model, experiments) -> list[str]:
    """The messages of the physical constraints (a negative dashpot, ...) that
    `model` (its values: constraint wrappers resolved) breaks over the inputs of
    `experiments` (a current law is checked across their range), or []."""
    if not experiments:
        return []
    inputs = _inputs(experiments)
    return _broken_over(model, inputs.min(), inputs.max())


def _inputs(experiments) -> np.ndarray:
    """Every input sample [A or V] of `experiments`, in one flat array."""
    return np.concatenate([np.ravel(np.asarray(e.current, float)) for e in experiments])


def _broken_over(model, lo: float, hi: float) -> list[str]:
    """`broken_constraints` over the inputs from `lo` to `hi` [A or V]."""
    device = model.model if isinstance(model, ChannelDelay) else model
    hysteresis = device.hysteresis if isinstance(device, Damper) else device
    if not isinstance(hysteresis, AbstractHysteresis):
        return []
    # Off the model (a static field), as `predict_all` does: one program per structure.
    hysteresis = with_fitted_range(hysteresis, None)
    checks = _checks_over(hysteresis, jnp.asarray(lo), jnp.asarray(hi))
    return [c.message().rstrip(".") for c in checks if not np.asarray(c.ok).all()]


@eqx.filter_jit
def _checks_over(hysteresis, lo, hi):
    # One program: run eagerly, the checks' few dozen operations (each parameter
    # finite, each rule at each input of the grid) compiled one by one, 0.75 s of
    # the 2 s of compilation of a second `jaxmr fit` of the 30 UTFSM files.
    return unwrap(hysteresis).checks_over(lo, hi)


# How a broken-constraint warning starts (`constraints_unwarned` matches it).
BROKEN_CONSTRAINTS = "the fitted model breaks its own constraints"


def warn_broken_constraints(model, experiments) -> list[str]:
    """Warn (and return the messages) where a fitted model breaks its own physical
    constraints over the inputs of `experiments`: a plain parameter is fitted
    without bounds, and on poor data it can leave them; its simulations
    (`simulate`, `load_model`) would then refuse the model. Where it breaks them
    only at inputs below zero (an amplifier's offset or noise on a current or
    command channel), the warning says so: there the advice is to clip the input,
    not to constrain the parameters."""
    if not experiments:
        return []
    inputs = _inputs(experiments)
    broken = _broken_over(model, inputs.min(), inputs.max())
    if not broken:
        return broken
    if inputs.min() < 0 <= inputs.max():
        if not _broken_over(model, 0.0, inputs.max()):
            below = int(np.sum(inputs < 0))
            warnings.warn(
                f"{BROKEN_CONSTRAINTS} only where the input is below zero (down to "
                f"{inputs.min():.4g} A or V, {below} of {inputs.size} samples): "
                + "; ".join(broken)
                + ". Its current laws are fitted for inputs at or above zero and "
                "turn negative below it; `simulate` refuses it over such inputs "
                "(`predict_all` runs it). If the negative values are an offset or "
                "noise, clip the input at zero before fitting (numpy.maximum(i, 0)).",
                UserWarning,
                stacklevel=3,
            )
            return broken
    warnings.warn(
        f"{BROKEN_CONSTRAINTS}: "
        + "; ".join(broken)
        + ". Its simulations will refuse it: constrain those parameters "
        "(jaxmr.Positive, jaxmr.Bounded) or their law, or check the data.",
        UserWarning,
        stacklevel=3,
    )
    return broken


@contextlib.contextmanager
def constraints_unwarned():
    """Within it, `fit` does not warn of broken constraints (`select_model`'s
    screening and cross-validation fits: it warns once, for the model it returns)."""
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message=re.escape(BROKEN_CONSTRAINTS), category=UserWarning
        )
        yield


def _report(free, static, data, outcome, stats_data, threshold, residuals_fn):
    """The `FitResult` at the best parameters, its statistics from `residuals_fn` on
    `stats_data` (the data with shorter steps: the fixed step's derivative converges
    more slowly than its force, d/dγ of the brake was 16 % off at 0.5 ms steps for
    n < 1)."""
    # Guarded: an experiment whose state left its bounds scores NaN (rmse, nrmse inf),
    # a failure rather than the finite absurd forces of a diverged fixed step.
    simulated = np.asarray(simulate_jit(eqx.combine(free, static), data, True))
    # Each experiment's residual rows (refinement shortens steps, not samples).
    groups = kept_groups(data.kept_counts)
    stats = statistics(residuals_fn, free, static, stats_data, None, groups)
    return assemble(
        free,
        static,
        data.split(simulated),
        data.split(np.asarray(data.force)),
        data.split(data.kept_mask()),
        data.names,
        stats,
        outcome,
        threshold,
        times=data.split(np.asarray(data.t)),
    )


def fit(
    model: AbstractHysteresis | Damper | ChannelDelay,
    experiments: Sequence,
    *,
    integrator: StepPolicy | FixedStep | None = None,
    starts: int | Sequence | None = None,
    spread: float = 3.0,
    key: jax.Array | None = None,
    weighting: str = "nrmse",
    max_steps: int = 200,
    patience: int = 8,
    ftol: float = 1e-4,
    progress: bool | Callable = True,
    discard=None,
    smoothing=None,
    identifiability_threshold: float = 1e-7,
    solver: optx.AbstractLeastSquaresSolver | None = None,
    lanes: int | None = None,
    statistics_refinement: int = 4,
    stop=None,
) -> FitResult:
    r"""Fit a damper model to measured experiments by least squares.

    Minimises $\tfrac12 \sum_e w_e^2 \sum_k (F_{e,k} - \hat F_{e,k})^2$ over the model's
    free parameters with Levenberg–Marquardt (optimistix) and exact forward-mode
    Jacobians through the simulation. With `weighting="nrmse"` (default)
    $w_e = 1/(\mathrm{std}(F_e)\sqrt{N_e})$, i.e. the sum of squared NRMSEs, so each
    experiment counts equally whatever its length and force level; `"force"` uses
    $w_e = 1$ (the source studies' $J = \sum (F_e - F_p)^2$).

    Cost: every experiment is simulated with its own fixed RK4 step (`integrator`,
    a `StepPolicy`) and no experiment is padded to another's length (they are packed
    end to end, `lanes` scans side by side); the residual and its Jacobian cost about
    p + 1 simulations for p free parameters.

    Divergence: where every start keeps each experiment's state inside its bounds
    (the check `simulate` and the report make, e.g. Bouc–Wen's $|z| \le z_0$), a
    point whose state leaves them is rejected, so the fit ends on a simulation its
    report accepts rather than past the fixed step's stability limit; a start
    already outside fits unguarded.

    Which parameters are fitted: every array in `model`, including current laws
    (`LinearLaw` shares a law over all currents, `TableLaw` gives one value per
    current), except those wrapped in `jaxmr.Fixed`. Wrap a parameter in
    `jaxmr.Positive` or `jaxmr.Bounded` to constrain it.

    Stopping (`result.stop`, a `jaxmr.StopReason`): LM's own test (the `solver`'s
    `rtol`, `atol`), or stalled progress — the best loss has not improved by a
    relative `ftol` in `patience` steps, or in 3 accepted steps (steps that lowered
    it) while the Gauss–Newton model at the best point promises no more (the undamped
    step's predicted reduction; solvers other than `FastLevenbergMarquardt` do not
    say) — or `max_steps`, or a failed solve (reported as failed). The default
    `ftol = 1e-4` is far below what noise makes significant (the loss of N residuals
    at the noise floor fluctuates by ~sqrt(2/N), 1.4 % for N = 10 000). Ctrl-C, or
    the caller's `stop` flag, stops the fit with the best parameters so far
    (`result.interrupted`).

    **Arguments:**

    - `model`: a hysteresis model or `Damper`, its values the initial guess.
    - `experiments`: `jaxmr.data.Experiment`s (with force), any lengths and rates.
    - `integrator`: a `StepPolicy` (default `StepPolicy()`: each experiment's steps
      within the limits of its kind of device, given there) or `FixedStep(k)` (k
      steps per sample interval for every experiment).
    - `starts`: `None` (one start), an int $n$ (the model plus $n-1$ random starts,
      each free parameter's value multiplied by a log-uniform factor within
      `spread`), or a sequence of models. All starts run as one batch; the best is
      kept.
    - `progress`: print a line every few seconds (True), nothing (False), or a
      callable `progress(step, loss)`.
    - `discard`: the start [s] of each experiment left out of the residual (one number
      or one per experiment; `None`, the default: each experiment's own
      `Experiment.discard`), e.g. the first cycle of a sine test: the simulation
      still starts at the first sample, so the state is right where scoring begins.
    - `smoothing`: the width [s] of a centred moving average the data's force went
      through (one number or one per experiment, 0: none; `None`, the default: each
      experiment's own `Experiment.smoothing`); the simulated force goes through the
      same before it is compared (e.g. the UTFSM tests, smoothed over a tenth of the
      period: `jaxmr.data.utfsm_smoothing`, which `load_utfsm` sets). `rmse` and
      `nrmse` are of the smoothed force too.
    - `solver`: an optimistix least-squares solver (default
      `FastLevenbergMarquardt()`; its `rtol`, `atol` are LM's convergence test).
    - `lanes`: how many scans the experiments are packed into (default: up to 8).
      With several devices the lanes are spread over them where their count divides
      evenly; a fit from one start whose lanes are not splits its Jacobian's columns
      over the devices instead.
    - `statistics_refinement`: the standard errors come from a Jacobian with steps
      this many times shorter than the fit's (1: the fit's own).
    - `stop`: a `threading.Event` (anything with `is_set()`), e.g. set from another
      thread or a signal handler: checked after every step, it stops the fit as
      Ctrl-C does.

    **Returns:** a `FitResult`.
    """
    warn_if_float32("jaxmr.fit")
    check_budget(max_steps, patience)
    # A start read from a file holds the range of the data it was fitted on, not
    # of these: the fitted model holds none (`with_fitted_range` gives it one).
    model, free, static = _split_model(with_fitted_range(model, None))
    experiments = experiment_list(experiments)
    policy = as_step_policy(integrator)
    options = dict(
        weighting=weighting, discard=discard, smoothing=smoothing, lanes=lanes
    )
    data = pack(experiments, policy, **options)  # pyright: ignore[reportArgumentType]  # keywords of mixed types
    data = _lanes_on_devices(data)
    _check_enough_data(free, data)
    _check_current_laws(model, experiments)
    if solver is None:
        solver = FastLevenbergMarquardt()
    # One start: the column scale from the solver's own first step, whose compiled
    # Jacobian the fit then reuses, and from the model itself that step is the fit's
    # first (`scale_and_first_step`).
    one_start = starts is None or (
        starts == 1 if isinstance(starts, int) else len(starts) == 1
    )
    # A fit from one start whose lanes stay on one device (too few, or a count the
    # devices do not divide: `_lanes_on_devices`) splits its Jacobian's columns over
    # them instead (`column_mesh`), its data whole on each.
    columns = column_mesh(solver, free, data) if one_start else None
    data = replicate(data, columns)
    first = None
    starts_are_model = starts is None or isinstance(starts, int)
    if isinstance(starts, int) and starts != 1:
        # Random starts are spread in units of the column scale.
        scale = column_scale(residuals, free, static, data, None)
        ys = spread_starts(model, starts, spread, key, scale)
        fit_residuals, unscaled = _fit_residuals(_starts_inside(ys, static, data))
    else:
        if starts is None or isinstance(starts, int):
            ys = jax.tree.map(lambda a: to_host(a)[None], free)  # no eager program
        else:
            models = [fitted_form(with_fitted_range(m, None)) for m in starts]
            frees = [eqx.filter(m, free_filter(m)) for m in models]
            ys = jax.tree.map(lambda *xs: jnp.stack(xs), *frees)
        fit_residuals, unscaled = _fit_residuals(_starts_inside(ys, static, data))
        if one_start:
            scale, first = scale_and_first_step(
                solver, residuals, fit_residuals, free, static, data, columns
            )
            if not starts_are_model:
                first = None  # made from the model, not from the start given
        else:
            scale = column_scale(residuals, free, static, data, None)
    best_y, outcomes = iterate(
        solver,
        divide(ys, scale),
        (fit_residuals, static, data, scale),
        None,
        max_steps,
        patience,
        ftol,
        progress_printer(progress),
        stop=stop,
        first=first,
        columns=columns,
    )
    losses = [o.loss if np.isfinite(o.loss) else np.inf for o in outcomes]
    best = int(np.argmin(losses))
    outcome = outcomes[best]
    # An interrupted fit reports at once, from the fit's own Jacobian.
    refine = statistics_refinement > 1 and not outcome.interrupted
    stats_data = (
        pack(experiments, policy.refined(statistics_refinement), **options)  # pyright: ignore[reportArgumentType]  # keywords of mixed types
        if refine
        else data
    )
    stats_data = _lanes_on_devices(stats_data)
    with finishing("jaxmr.fit"):
        result = _report(
            unscaled_member(best_y, scale, best),
            static,
            data,
            outcome,
            stats_data,
            identifiability_threshold,
            # On the fit's own data, its own residual and trace: a guarded fit's
            # best point is inside the bounds there (its start was, and it accepts
            # no point outside), where both residuals are the same. Refined steps
            # are judged anew, so they are not guarded.
            residuals if refine else unscaled,
        )
    warn_broken_constraints(result.model, experiments)
    return result


# `fit_each` runs its problems this many at a time (`solver.iterate`'s `chunk`): the
# same compiled shapes in every layout, so a problem's result does not depend on how
# many others share its call or its devices. 256 brake fits on 2 cores: 91 s in chunks
# of 16, 99 s in chunks of 8 or 32, 113 s as one vmap of 256.
FIT_EACH_CHUNK = 16


def fit_each(
    model: AbstractHysteresis
    | Damper
    | ChannelDelay
    | Sequence[AbstractHysteresis | Damper | ChannelDelay],
    experiments: Sequence,
    *,
    integrator: StepPolicy | FixedStep | None = None,
    weighting: str = "nrmse",
    max_steps: int = 200,
    patience: int = 8,
    ftol: float = 1e-4,
    progress: bool | Callable = True,
    discard=None,
    smoothing=None,
    identifiability_threshold: float = 1e-7,
    solver: optx.AbstractLeastSquaresSolver | None = None,
    shard: bool = True,
    statistics_refinement: int = 4,
    stop=None,
) -> list[FitResult]:
    """Fit `model` to each experiment separately, all in one batched solve.

    The independent problems (one per experiment: e.g. one run per specimen or per
    test condition) run as one vmapped Levenberg–Marquardt loop; each stops on its own
    and keeps its own best parameters. Problems of different lengths are padded to
    the longest (padding adds no residual). With several devices and `shard=True`
    the batch is split across them with `jax.sharding` (a 1-D mesh of
    `jax.devices()`), padded with copies of its last problem to a multiple of the
    device count and trimmed after (CPU cores too, as host devices: see
    `jaxmr.devices.configure_cpu`). The problems run
    16 at a time on each device, so each one's result is the same bits whatever the
    number of problems, devices or processes (with at least 16 problems per device).
    Each problem's variables are scaled by its own Jacobian at its start, as `fit`
    scales them, so problems whose forces differ by orders of magnitude share a
    batch.

    Several processes (hosts, or one process per GPU): start each with
    `jax.distributed.initialize()` and make the same call with the same experiments
    in every process. The mesh then spans every process's devices, each process
    simulates and fits its own slice of the batch, and every process gets all the
    results (docs/scale-out.md). jaxmr itself never schedules work.

    **Arguments:** as `fit` (no `starts`), plus `shard`; `model` may also be a
    sequence of models of one structure, one start per experiment (their free
    values; `Fixed` values are the first model's). Each problem is one experiment,
    at one input level where its current is constant: a model with current laws
    (a template built on experiments at several levels) then has a slope no problem
    determines. Build the start from each experiment alone, e.g.
    `[MODEL_TEMPLATES[name]([e]) for e in experiments]`.

    **Returns:** one `FitResult` per experiment, in order; each `history` is that
    problem's own best loss up to its own stop.

    **Raises:** `ValueError` for the whole call, naming the experiment, where one
    cannot be fitted at all (no force to fit: all zero or constant; no more scored
    samples than free parameters): drop it and call again.
    """
    warn_if_float32("jaxmr.fit_each")
    check_budget(max_steps, patience)
    experiments = experiment_list(experiments)
    if not experiments:
        raise ValueError("`experiments` is empty: give at least one experiment.")
    own_starts = None
    model = with_fitted_range(model, None)  # as in `fit`
    if isinstance(model, (list, tuple)):
        if len(model) != len(experiments):
            raise ValueError(
                f"`model` is a sequence of {len(model)} starts for "
                f"{len(experiments)} experiments: give one per experiment (or one "
                "model for all)."
            )
        own_starts = [_split_model(m) for m in model]
        if len({jax.tree.structure(s) for _, _, s in own_starts}) != 1:
            raise ValueError(
                "the starting models in `model` must have one structure (the same "
                "class, laws and Fixed parameters), differing only in values."
            )
        model = model[0]
    _, free, static = _split_model(model)
    policy = as_step_policy(integrator)
    n = len(experiments)
    discards = per_experiment(discard, experiments, "discard")
    widths = per_experiment(smoothing, experiments, "smoothing")
    options = [
        dict(weighting=weighting, discard=float(d), smoothing=float(w), lanes=1)
        for d, w in zip(discards, widths)
    ]
    problems = [pack([e], policy, **o) for e, o in zip(experiments, options)]  # pyright: ignore[reportArgumentType]  # keywords of mixed types
    for problem in problems:
        _check_enough_data(free, problem, f"experiment {problem.names[0]!r}: ")
    mesh = batch_mesh() if shard else None
    devices = 1 if mesh is None else mesh.size
    chunk = min(FIT_EACH_CHUNK, -(-n // devices))
    # Padded to whole chunks on every device.
    count = -(-n // (chunk * devices)) * chunk * devices
    batched = spread(stack(problems + [problems[-1]] * (count - n)), mesh)
    if own_starts is None:
        ys = jax.tree.map(lambda a: jnp.broadcast_to(a, (count,) + a.shape), free)
    else:
        frees = [f for _, f, _ in own_starts]
        frees += [frees[-1]] * (count - n)
        ys = jax.tree.map(lambda *a: jnp.stack(a), *frees)
    ys = spread(ys, mesh)
    if solver is None:
        solver = FastLevenbergMarquardt()
    scale = column_scales(residuals, ys, static, batched, chunk, mesh)
    scale = spread(jax.tree.map(to_device, scale), mesh)
    inside = bool(np.all(to_host(_batched_inside(ys, static, batched))))
    each = _each_guarded_scaled_residuals if inside else _each_scaled_residuals
    best_y, outcomes = iterate(
        solver,
        divide(ys, scale),
        (each, static, (batched, scale), None),
        0,
        max_steps,
        patience,
        ftol,
        progress_printer(progress),
        chunk=chunk,
        mesh=mesh,
        stop=stop,
    )
    # A Ctrl-C from here on is set aside once (`finishing`): the fits are done.
    with finishing("jaxmr.fit_each"):
        # Every problem padded to one shape (and its refined data to another): the
        # reports then share one compiled simulation and one Jacobian, not one each.
        padded = pad_all(problems)
        stats_data = padded
        if statistics_refinement > 1 and not outcomes[0].interrupted:
            refined = policy.refined(statistics_refinement)
            stats_data = pad_all(
                [pack([e], refined, **o) for e, o in zip(experiments, options)]  # pyright: ignore[reportArgumentType]  # keywords of mixed types
            )
        best = jax.tree.map(lambda a: a[:n], gather(multiply(best_y, scale)))
        # One batched simulation and one batched Jacobian for every problem (a loop of
        # `_report`s dispatched 2 calls per problem: 256 fits spent longer reporting than
        # fitting).
        simulated, r, jac = _batched_statistics(
            best, static, stack(padded), stack(stats_data)
        )
        simulated, r = np.asarray(simulated), np.asarray(r)
        jac = [
            np.reshape(np.asarray(j), r.shape[:2] + (-1,)) for j in jax.tree.leaves(jac)
        ]
        J = np.concatenate(jac, axis=2)
        results = []
        for p in range(n):
            free_p = jax.tree.map(lambda a, p=p: a[p], best)
            data = padded[p]
            stats = statistics_from(
                r[p], J[p], free_p, static, kept_groups(data.kept_counts)
            )
            results.append(
                assemble(
                    free_p,
                    static,
                    data.split(simulated[p]),
                    data.split(np.asarray(data.force)),
                    data.split(data.kept_mask()),
                    data.names,
                    stats,
                    outcomes[p],
                    identifiability_threshold,
                    times=data.split(np.asarray(data.t)),
                )
            )
        return results


@eqx.filter_jit
def _batched_inside(ys, static, data):
    """`_starts_inside` for a batch of problems (axis 0 of `ys` and `data`), per
    problem."""

    def one(y, d):
        return jnp.all(jnp.isfinite(simulate(eqx.combine(y, static), d, True)))

    return jax.vmap(one)(ys, data)


@eqx.filter_jit
def _batched_statistics(free, static, data, stats_data):
    """The simulated force on `data` and the residual with its Jacobian on
    `stats_data`, for a batch of problems (axis 0)."""

    def one(f, d, sd):
        r, jac = value_and_jacobian(residuals, f, static, sd, None)
        # Guarded, as `_report`'s: a state that left its bounds is a failure (NaN,
        # `FitResult.diverged_at`), not a force.
        return simulate(eqx.combine(f, static), d, True), r, jac

    return jax.vmap(one)(free, data, stats_data)
