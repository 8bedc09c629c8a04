"""`fit`: identify a damper model from measured experiments by least squares.

Levenberg–Marquardt (optimistix) with exact forward-mode Jacobians through the
simulation, driven step by step from Python so that the fit can show progress, stop on
stalled progress (solver noise can keep the optimiser's own convergence test from ever
firing), and keep the best parameters when it fails or is interrupted.
"""

import dataclasses
import time
import warnings
from collections.abc import Callable, Sequence

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ._damper import Damper, as_damper
from ._hysteresis import AbstractHysteresis
from ._integrate import AbstractAdaptiveIntegrator, AbstractIntegrator, FixedStep
from ._parameter import Fixed, free_filter, is_parameter, unwrap
from ._signal import Sampled, _is_uniform
from ._simulate import _run


class FitData(eqx.Module):
    """Experiments padded to a common length and stacked (axis 0: experiment).

    Padding repeats the last sample's motion at extrapolated times and is masked out of
    the residual, so experiments of different lengths and sample rates fit together.
    """

    t: jax.Array
    x: jax.Array
    v: jax.Array
    current: jax.Array
    force: jax.Array
    mask: jax.Array
    weight: jax.Array
    window: jax.Array
    t_end: jax.Array
    names: tuple[str, ...] = eqx.field(static=True)
    uniform: bool = eqx.field(static=True)


def _per_experiment(value, n: int, what: str, item: str = "experiment") -> np.ndarray:
    """A non-negative duration [s] per experiment (or record, `item`) from `None`, a
    number or a sequence."""
    array = np.asarray(0.0 if value is None else value, dtype=float)
    if array.ndim > 1 or (array.ndim == 1 and array.shape[0] != n):
        raise ValueError(
            f"`{what}` must be one number or one per {item} ({n}), got shape "
            f"{array.shape}."
        )
    array = np.broadcast_to(array, (n,))
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ValueError(f"`{what}` must be finite and >= 0 [s], got {value!r}.")
    return array


def smooth(force, t, t_end, width):
    """Centred moving average of `width` [s] (0: none) of samples at times `t`, the
    window shrinking at `t[0]` and `t_end` (as MATLAB's `movmean`); trapezoidal
    integral, so exact for piecewise-linear signals. Vmappable (traced `width`)."""
    increments = (force[1:] + force[:-1]) / 2 * jnp.diff(t)
    integral = jnp.concatenate([jnp.zeros(1, force.dtype), jnp.cumsum(increments)])
    lo = jnp.clip(t - width / 2, t[0], t_end)
    hi = jnp.clip(t + width / 2, t[0], t_end)
    span = jnp.where(hi > lo, hi - lo, 1.0)
    average = (jnp.interp(hi, t, integral) - jnp.interp(lo, t, integral)) / span
    return jnp.where(width > 0, average, force)


def stack_experiments(
    experiments, weighting: str = "nrmse", discard=None, smoothing=None
) -> FitData:
    """Pad and stack experiments (`jaxmr.data.Experiment` or anything with `t`, `x`,
    `v`, `current`, `force`, `name`) for `fit`; `discard` and `smoothing` as in
    `fit`."""
    experiments = list(experiments)
    if not experiments:
        raise ValueError("`experiments` is empty: give at least one experiment.")
    if weighting not in ("nrmse", "force"):
        raise ValueError(f"`weighting` must be 'nrmse' or 'force', got {weighting!r}.")
    for k, e in enumerate(experiments):
        if getattr(e, "force", None) is None:
            raise ValueError(
                f"experiment {k} ({getattr(e, 'name', '')!r}) has no measured force: "
                "fitting needs the `F` (or `T`) column."
            )
    length = max(len(np.asarray(e.t)) for e in experiments)
    discard = _per_experiment(discard, len(experiments), "discard")
    width = _per_experiment(smoothing, len(experiments), "smoothing")
    columns = {key: [] for key in ("t", "x", "v", "current", "force", "mask", "weight")}
    t_end = []
    for e, skip in zip(experiments, discard):
        t, x, v = (np.asarray(getattr(e, key), dtype=float) for key in ("t", "x", "v"))
        i = np.broadcast_to(np.asarray(e.current, dtype=float), t.shape)
        f = np.asarray(e.force, dtype=float)
        n, pad = len(t), length - len(t)
        dt = t[-1] - t[-2]
        columns["t"].append(np.concatenate([t, t[-1] + dt * np.arange(1, pad + 1)]))
        columns["x"].append(np.concatenate([x, np.full(pad, x[-1])]))
        columns["v"].append(np.concatenate([v, np.zeros(pad)]))
        columns["current"].append(np.concatenate([i, np.full(pad, i[-1])]))
        columns["force"].append(np.concatenate([f, np.zeros(pad)]))
        kept = t >= t[0] + skip
        if not np.any(kept):
            raise ValueError(
                f"`discard` = {skip:g} s leaves no sample of experiment {e.name!r}."
            )
        columns["mask"].append(np.concatenate([kept.astype(float), np.zeros(pad)]))
        t_end.append(t[-1])
        n = int(np.sum(kept))
        scale = np.std(f[kept]) if weighting == "nrmse" else 1.0
        if weighting == "nrmse" and not scale > 0:
            raise ValueError(
                f"experiment {e.name!r} has a constant force: NRMSE weighting needs a "
                "varying force (use weighting='force')."
            )
        columns["weight"].append(
            1.0 / (scale * np.sqrt(n)) if weighting == "nrmse" else 1.0
        )
    arrays = {k: jnp.asarray(np.stack(v)) for k, v in columns.items()}
    arrays["window"] = jnp.asarray(width)
    arrays["t_end"] = jnp.asarray(np.asarray(t_end))
    names = tuple(
        str(getattr(e, "name", f"experiment {k}")) for k, e in enumerate(experiments)
    )
    uniform = all(_is_uniform(np.asarray(e.t)) for e in experiments)
    return FitData(**arrays, names=names, uniform=uniform)


def _simulate_data(model, data: FitData, integrator) -> jax.Array:
    """Simulated force for every experiment (no checks raised: a fit must not abort)."""
    damper = as_damper(model)

    def one(t, x, v, i):
        u = data.uniform
        motion, current = Sampled(t, x, v, uniform=u), Sampled(t, i, uniform=u)
        sol = _run(damper, motion, current, t, integrator, None, checks=False)
        return sol.force

    force = jax.vmap(one)(data.t, data.x, data.v, data.current)
    # The data's own smoothing, applied to the model's force (compare like with like).
    return jax.vmap(smooth)(force, data.t, data.t_end, data.window)


def _residuals(free, static, data: FitData, integrator):
    model = unwrap(eqx.combine(free, static))
    force = _simulate_data(model, data, integrator)
    r = (force - data.force) * data.mask * data.weight[:, None]
    # A diverged simulation must not poison the least-squares step with nan: a large
    # finite residual makes the step be rejected instead.
    return jnp.where(jnp.isfinite(r), r, 1e6).ravel()


def _for_forward_mode(integrator: AbstractIntegrator) -> AbstractIntegrator:
    if isinstance(integrator, AbstractAdaptiveIntegrator) and not isinstance(
        integrator.adjoint, dfx.ForwardMode
    ):
        return eqx.tree_at(lambda i: i.adjoint, integrator, dfx.ForwardMode())
    return integrator


class FastLevenbergMarquardt(optx.AbstractGaussNewton):
    """optimistix's Levenberg–Marquardt with a bolder trust region: it grows 10x (not
    3.5x) after a step that achieves 75 % (not 99 %) of the predicted reduction.

    From starts far from the optimum (the published UTFSM model, a 12-parameter
    Spencer fit) the default crept for 30+ steps before its damping had relaxed: 47
    instead of 80+ steps to the same optimum. Pass it as `fit(..., solver=...)`.

    **Arguments:** `rtol`, `atol`: optimistix's convergence tolerances.
    """

    rtol: float
    atol: float
    norm: Callable
    descent: optx.DampedNewtonDescent
    search: optx.ClassicalTrustRegion
    verbose: Callable[..., None]

    def __init__(self, rtol: float = 1e-8, atol: float = 1e-10):
        self.rtol, self.atol, self.norm = rtol, atol, optx.max_norm
        self.descent = optx.DampedNewtonDescent(linear_solver=lx.QR())
        self.search = optx.ClassicalTrustRegion(high_cutoff=0.75, high_constant=10.0)
        self.verbose = lambda **kwargs: None  # fit reports progress itself


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """The outcome of `fit`.

    **Attributes:**

    - `model`: the fitted model, plain numbers (ready for `simulate`).
    - `constrained`: the fitted model with its constraint wrappers (to refit).
    - `names`: the fitted parameters' names (paths in the model, e.g. `.alpha.a`).
    - `values`, `std_errors`: their values and standard errors (same units), from the
      Jacobian at the optimum: cov = s² (JᵀJ)⁺, s² = RSS/(N − p).
    - `correlation`: the parameters' correlation matrix.
    - `singular_values`: of the Jacobian with columns scaled by the parameter values
      (relative sensitivities), largest first.
    - `unidentified`: descriptions of parameter combinations the data do not determine
      (empty when all are identified).
    - `rmse`, `nrmse`: per experiment [force unit] and RMSE/std(F) (from
      `fit_system`: per record, in the output's unit, and RMSE/std(output)).
    - `experiment_names`.
    - `loss`: ½ Σ (weighted residual)²; `history`: the best loss after every step.
    - `num_steps`, `reason` (why it stopped), `converged`.
    """

    model: eqx.Module
    constrained: eqx.Module
    names: tuple[str, ...]
    values: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    singular_values: np.ndarray
    unidentified: tuple[str, ...]
    rmse: np.ndarray
    nrmse: np.ndarray
    experiment_names: tuple[str, ...]
    loss: float
    history: tuple[float, ...]
    num_steps: int
    reason: str
    converged: bool

    def table(self) -> str:
        """The parameters with standard errors, as a text table."""
        rows = [f"{'parameter':<24} {'value':>14} {'std error':>12} {'rel':>8}"]
        for name, value, se in zip(self.names, self.values, self.std_errors):
            rel = abs(se / value) if value != 0 else np.inf
            rows.append(f"{name:<24} {value:>14.6g} {se:>12.3g} {rel:>8.2%}")
        return "\n".join(rows)

    def __str__(self):
        lines = [
            f"fit: {self.reason} after {self.num_steps} steps, loss {self.loss:.6g}",
            self.table(),
            "NRMSE per experiment: "
            + ", ".join(
                f"{n}: {e:.4f}" for n, e in zip(self.experiment_names, self.nrmse)
            ),
        ]
        lines += [f"WARNING: {u}" for u in self.unidentified]
        return "\n".join(lines)


def _parameter_names(free) -> list[str]:
    names = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(free)[0]:
        name = jax.tree_util.keystr(path)
        for suffix in (".log_value", ".raw"):
            if name.endswith(suffix):
                name = name[: -len(suffix)]
        if np.ndim(leaf) == 0:
            names.append(name)
        else:
            names += [f"{name}[{k}]" for k in range(np.size(leaf))]
    return names


def _values_and_scale(free, static):
    """Physical values of the free parameters and d(value)/d(free variable), flat."""

    def values(f):
        tree = eqx.combine(f, static)
        wrapped = jax.tree.map(
            lambda p: p.value() if is_parameter(p) else p, tree, is_leaf=is_parameter
        )
        # Keep only the free positions, in the order of `free`'s leaves.
        return [
            v
            for v, keep in zip(
                jax.tree.leaves(wrapped),
                jax.tree.leaves(_free_mask(tree)),
                strict=True,
            )
            if keep
        ]

    flat_free = jax.tree.leaves(free)
    ones = jax.tree.map(jnp.ones_like, free)
    value_list, derivative_list = jax.jvp(values, (free,), (ones,))
    del flat_free
    flatten = lambda xs: np.concatenate([np.ravel(np.asarray(x)) for x in xs])
    return flatten(value_list), flatten(derivative_list)


def _free_mask(tree):
    """Per unwrapped leaf: does it come from a free variable? (Fixed → False.)"""

    def mark(p):
        if is_parameter(p):
            return not isinstance(p, Fixed)
        return eqx.is_inexact_array(p)

    return jax.tree.map(mark, tree, is_leaf=is_parameter)


def _describe_null(vector, names, threshold=0.03) -> str:
    order = np.argsort(-np.abs(vector))
    terms = [
        f"{vector[k]:+.2f}·log({names[k]})" for k in order if abs(vector[k]) > threshold
    ]
    return " ".join(terms)


@eqx.filter_jit
def _residual_and_jacobian(free, static, data, integrator, residuals=_residuals):
    # `residuals` (module-level, static under jit): the damper's by default, a
    # system's for `fit_system`; `data` and `integrator` are whatever it takes.
    residual = lambda f: residuals(f, static, data, integrator)
    return residual(free), jax.jacfwd(residual)(free)


def _statistics(free, static, data, integrator, residuals=_residuals):
    """Standard errors, correlations and identifiability at the optimum."""
    r, jac_tree = _residual_and_jacobian(free, static, data, integrator, residuals)
    r = np.asarray(r)
    J_raw = np.concatenate(
        [
            np.reshape(np.asarray(j), (r.shape[0], -1))
            for j in jax.tree.leaves(jac_tree)
        ],
        axis=1,
    )
    values, dvalue = _values_and_scale(free, static)
    # Chain rule: d r / d value = (d r / d free) / (d value / d free), elementwise.
    J = J_raw / np.where(dvalue == 0, 1.0, dvalue)[None, :]
    n_obs = int(np.sum(np.asarray(data.mask)))
    p = J.shape[1]
    s2 = float(r @ r) / max(n_obs - p, 1)
    scale = np.where(values == 0, 1.0, np.abs(values))
    Js = J * scale[None, :]
    U, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    rcond = 1e-10
    inv_s2 = np.where(sv > rcond * sv[0], 1.0 / sv**2, 0.0)
    cov_scaled = (Vt.T * inv_s2) @ Vt * s2
    cov = cov_scaled * scale[:, None] * scale[None, :]
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    return values, std, corr, sv, Vt, s2


def fit(
    model: AbstractHysteresis | Damper,
    experiments: Sequence,
    *,
    integrator: AbstractIntegrator | None = None,
    starts: int | Sequence | None = None,
    spread: float = 3.0,
    key: jax.Array | None = None,
    weighting: str = "nrmse",
    max_steps: int = 200,
    patience: int = 8,
    ftol: float = 1e-4,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    progress: bool | Callable = True,
    discard=None,
    smoothing=None,
    identifiability_threshold: float = 1e-7,
    solver: optx.AbstractLeastSquaresSolver | None = None,
) -> FitResult:
    r"""Fit a damper model to measured experiments by least squares.

    Minimises $\tfrac12 \sum_e w_e^2 \sum_k (F_{e,k} - \hat F_{e,k})^2$ over the model's
    free parameters with optimistix's Levenberg–Marquardt and exact forward-mode
    Jacobians through the simulation. With `weighting="nrmse"` (default)
    $w_e = 1/(\mathrm{std}(F_e)\sqrt{N_e})$, i.e. the sum of squared NRMSEs, so each
    experiment counts equally whatever its length and force level; `"force"` uses
    $w_e = 1$ (the source studies' $J = \sum (F_e - F_p)^2$).

    Which parameters are fitted: every array in `model`, including current laws
    (`LinearLaw` shares a law over all currents, `TableLaw` gives one value per
    current), except those wrapped in `jaxmr.Fixed`. Wrap a parameter in
    `jaxmr.Positive` or `jaxmr.Bounded` to constrain it.

    Stopping: LM's own test (`rtol`, `atol`), or stalled progress — the best loss has
    not improved by a relative `ftol` in `patience` steps — or `max_steps`. The default
    `ftol = 1e-4` is far below what noise makes significant (the loss of N residuals at
    the noise floor fluctuates by ~sqrt(2/N), 1.4 % for N = 10 000). An
    exception (including Ctrl-C) inside the loop stops the fit with the best parameters
    so far and the reason.

    **Arguments:**

    - `model`: a hysteresis model or `Damper`, its values the initial guess.
    - `experiments`: `jaxmr.data.Experiment`s (with force), any lengths and rates.
    - `integrator`: default `FixedStep` with steps of at most 0.5 ms (fast; its error
      of ~1e-4 of the peak force is far below measurement noise). An adaptive
      integrator is switched to forward-mode adjoints automatically.
    - `starts`: `None` (one start), an int $n$ (the model plus $n-1$ random starts,
      each free variable perturbed by a log-uniform factor within `spread`), or a
      sequence of models. All starts run as one batch; the best is kept.
    - `progress`: print a line every few seconds (True), nothing (False), or a
      callable `progress(step, loss)`.
    - `discard`: the start [s] of each experiment left out of the residual (one number
      or one per experiment), e.g. the first cycle of a sine test: the simulation
      still starts at the first sample, so the state is right where scoring begins.
    - `smoothing`: the width [s] of a centred moving average the data's force went
      through (one number or one per experiment, 0: none); the simulated force goes
      through the same before it is compared (e.g. the UTFSM tests, smoothed over a
      tenth of the period: `jaxmr.utfsm_smoothing`). `rmse` and `nrmse` are of the
      smoothed force too.

    **Returns:** a `FitResult`.
    """
    if jnp.result_type(float) != jnp.float64:
        warnings.warn(
            "jaxmr.fit is running in float32: identification needs float64 (solver "
            "tolerances, Jacobian conditioning). Call "
            "jax.config.update('jax_enable_x64', True) before creating arrays.",
            UserWarning,
            stacklevel=2,
        )
    data, integrator, free, static = _setup(
        model, experiments, weighting, integrator, discard, smoothing
    )
    _check_current_laws(model, data)
    start_frees = _starts(free, static, starts, spread, key)

    if solver is None:
        solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    scale = _column_scale(free, static, data, integrator)
    best_y, best_loss, history, steps, reasons = _iterate(
        solver,
        _divide(start_frees, scale),
        (_scaled_residuals, (static, scale), data, integrator),
        None,
        max_steps,
        patience,
        ftol,
        _progress_printer(progress),
    )
    best = int(np.argmin(best_loss))
    free_best = jax.tree.map(lambda a: a[best], _multiply(best_y, scale))
    return _result(
        free_best,
        static,
        data,
        integrator,
        float(best_loss[best]),
        tuple(history),
        steps,
        reasons[best],
        identifiability_threshold,
    )


def _setup(model, experiments, weighting, integrator, discard=None, smoothing=None):
    """Stacked data, the integrator (default: fixed steps of at most 0.5 ms, forward
    mode) and the model split into free variables and the rest."""
    data = stack_experiments(experiments, weighting, discard, smoothing)
    if integrator is None:
        steps = np.diff(np.asarray(data.t), axis=1)
        integrator = FixedStep(substeps=max(1, int(np.ceil(steps.max() / 5e-4))))
    integrator = _for_forward_mode(integrator)
    free, static = eqx.partition(model, free_filter(model))
    if not jax.tree.leaves(free):
        raise ValueError("nothing to fit: every parameter of `model` is Fixed.")
    return data, integrator, free, static


def _column_scale(free, static, data, integrator, residuals=_residuals):
    """Per free variable, 1/(norm of its Jacobian column) at the start.

    optimistix's Levenberg–Marquardt damps with λ·I, which suits unit-norm columns;
    a model's sensitivities span decades (log C0a against log α for the brake), and
    unscaled it crept along the valley for ~3x more steps. Rescaling the variables once
    (Moré's scaling, frozen at the start) fixes that.
    """
    _, jac = _residual_and_jacobian(free, static, data, integrator, residuals)
    norms = jax.tree.map(lambda j: jnp.sqrt(jnp.sum(j**2, axis=0)), jac)
    largest = max(float(jnp.max(n)) for n in jax.tree.leaves(norms))
    # A variable the data barely see (an effect below the noise) is not magnified more
    # than 100x: unbounded, its huge steps sent such a parameter to zero.
    floor = max(1e-2 * largest, 1e-300)
    return jax.tree.map(lambda n: 1.0 / jnp.maximum(n, floor), norms)


def _divide(ys, scale):
    return jax.tree.map(lambda y, s: y / s, ys, scale)


def _multiply(ys, scale):
    return jax.tree.map(lambda y, s: y * s, ys, scale)


def _scaled_residuals(y, static_and_scale, data, integrator):
    static, scale = static_and_scale
    return _residuals(_multiply(y, scale), static, data, integrator)


def _check_current_laws(model, data: FitData) -> None:
    """A current law with free slope or shape needs experiments at several currents."""
    from ._current_law import ConstantLaw, is_law

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
    currents = np.asarray(data.current)[np.asarray(data.mask) > 0]
    if np.ptp(currents) <= 1e-9 * max(1.0, float(np.max(np.abs(currents)))):
        names = sorted({type(law).__name__ for law in free_laws})
        raise ValueError(
            f"the model has free current laws ({', '.join(names)}) but every experiment "
            f"is at the same current ({float(currents[0]):g}): a law's dependence on "
            "current cannot be identified from one current. Give experiments at "
            "several currents, or replace the laws by plain parameters (or "
            "jaxmr.Fixed laws) for a single-current fit."
        )


def _iterate(solver, ys, args, data_axis, max_steps, patience, ftol, report):
    """Levenberg–Marquardt on a batch of problems, stepped from Python.

    Axis 0 of `ys` is the batch (starts, or independent problems when `data_axis` is
    0 and the data in `args` are batched too). Keeps each member's best parameters,
    stops each on its own convergence or stall, and stops all on an exception.
    Returns (best ys, best losses, history of the batch's best loss, steps, reasons).
    """
    dynamic, static_state = eqx.partition(
        _lm_init(solver, ys, args, data_axis), eqx.is_array
    )
    n = jax.tree.leaves(ys)[0].shape[0]
    best_loss = np.full(n, np.inf)
    best_y = ys
    history, last_improvement = [], np.zeros(n, dtype=int)
    reference = np.full(n, np.inf)
    converged = np.zeros(n, dtype=bool)
    stalled = np.zeros(n, dtype=bool)
    failure, k = None, 0
    try:
        for k in range(1, max_steps + 1):
            ys, dynamic, loss, terminate = _lm_step(
                solver, ys, dynamic, static_state, args, data_axis
            )
            loss = np.asarray(loss)
            # The first step only evaluates the start (its loss is that of the start).
            better = np.isfinite(loss) & (loss < best_loss)
            best_y = jax.tree.map(
                lambda new, old, b=better: jnp.where(
                    jnp.reshape(b, (-1,) + (1,) * (new.ndim - 1)), new, old
                ),
                ys,
                best_y,
            )
            best_loss = np.where(better, loss, best_loss)
            improved = best_loss < reference * (1 - ftol)
            reference = np.where(improved, best_loss, reference)
            last_improvement = np.where(improved, k, last_improvement)
            history.append(float(np.min(best_loss)))
            report(k, float(np.min(best_loss)))
            converged |= np.asarray(terminate)
            stalled |= (k - last_improvement) >= patience
            if np.all(converged | stalled):
                break
    except KeyboardInterrupt:
        failure = f"interrupted at step {k}; the best parameters so far are kept"
    except Exception as e:  # a runtime error of the simulation
        failure = f"failed at step {k}: {type(e).__name__}: {e}; best parameters kept"
    reasons = []
    for j in range(n):
        if failure is not None:
            reasons.append(failure)
        elif converged[j]:
            reasons.append("converged (Levenberg–Marquardt's tolerance met)")
        elif stalled[j]:
            reasons.append(
                f"stalled: no relative improvement above {ftol:g} in {patience} "
                "steps (the noise floor)"
            )
        else:
            reasons.append(f"reached max_steps = {max_steps}")
    return best_y, best_loss, history, k, reasons


def _lm_fn(y, args):
    # `residuals` is a module-level function (static under jit): the damper residual
    # here, a system's elsewhere; the engine below is shared.
    residuals, static, data, integrator = args

    # The residual carries its own materialised Jacobian: optimistix linearises the
    # residual and lineax then materialises that linearisation column by column, which
    # measured 10x slower than one `jacfwd` (all columns in one vectorised forward
    # pass). With this rule its linearisation is a matrix product.
    @jax.custom_jvp
    def residual(y):
        return residuals(y, static, data, integrator)

    @residual.defjvp
    def residual_jvp(primals, tangents):
        (y,), (ty,) = primals, tangents
        jac = jax.jacfwd(residual.fun)(y)
        r = residual.fun(y)
        out = sum(
            jnp.tensordot(j, t, axes=t.ndim)
            for j, t in zip(jax.tree.leaves(jac), jax.tree.leaves(ty), strict=True)
        )
        return r, out

    return residual(y), None


_LM_OPTIONS = {"jac": "fwd"}


# Module-level and jitted on their arguments. The solver state holds a jaxpr (static,
# compared by identity): only its arrays cross the jit boundary, with the static part
# from `_lm_init` passed unchanged each step, so the compiled step is reused.
@eqx.filter_jit
def _lm_init(solver, ys, args, data_axis):
    def one(y, args):
        f_struct = jax.eval_shape(lambda: _lm_fn(y, args)[0])
        return solver.init(_lm_fn, y, args, _LM_OPTIONS, f_struct, None, frozenset())

    return eqx.filter_vmap(one, in_axes=(0, (None, None, data_axis, None)))(ys, args)


@eqx.filter_jit
def _lm_step(solver, ys, dynamic, static_state, args, data_axis):
    def one(y, dyn, args):
        state = eqx.combine(dyn, static_state)
        y, state, _ = solver.step(_lm_fn, y, args, _LM_OPTIONS, state, frozenset())
        loss = 0.5 * jnp.sum(state.f_info.residual**2)
        return y, eqx.filter(state, eqx.is_array), loss, state.terminate

    in_axes = (0, 0, (None, None, data_axis, None))
    return eqx.filter_vmap(one, in_axes=in_axes)(ys, dynamic, args)


def _starts(free, static, starts, spread, key):
    if starts is None:
        return jax.tree.map(lambda a: a[None], free)
    if isinstance(starts, int):
        if starts < 1:
            raise ValueError(f"`starts` must be >= 1, got {starts}.")
        key = jax.random.key(0) if key is None else key
        leaves, treedef = jax.tree.flatten(free)
        keys = jax.random.split(key, len(leaves))
        log_spread = np.log(spread)
        batched = []
        for k_, leaf in zip(keys, leaves):
            u = jax.random.uniform(k_, (starts - 1,) + leaf.shape, leaf.dtype, -1, 1)
            factor = jnp.exp(u * log_spread)
            # A log-parametrised leaf is perturbed additively in log space.
            perturbed = leaf[None] * factor
            batched.append(jnp.concatenate([leaf[None], perturbed]))
        return jax.tree.unflatten(treedef, batched)
    models = list(starts)
    frees = [eqx.partition(m, free_filter(m))[0] for m in models]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *frees)


def _progress_printer(progress):
    if callable(progress):
        return progress
    if not progress:
        return lambda step, loss: None
    last = [time.monotonic()]

    def report(step, loss):
        now = time.monotonic()
        if now - last[0] >= 2.0:
            print(f"  fit step {step:4d}: loss {loss:.6g}", flush=True)
            last[0] = now

    return report


_simulate_data_jit = eqx.filter_jit(_simulate_data)


def _result(
    free, static, data, integrator, loss, history, steps, reason, threshold
) -> FitResult:
    model = unwrap(eqx.combine(free, static))
    force = np.asarray(_simulate_data_jit(model, data, integrator))
    statistics = _statistics(free, static, data, integrator)
    return _assemble_result(
        free, static, force, data, statistics, loss, history, steps, reason, threshold
    )


def _assemble_result(
    free, static, simulated, data, statistics, loss, history, steps, reason, threshold
) -> FitResult:
    """A `FitResult` from the best free variables, the simulated outputs (padded like
    the data: `data.force` or `data.measured`, `data.mask`) and `_statistics`."""
    constrained = eqx.combine(free, static)
    measured = np.asarray(data.force if hasattr(data, "force") else data.measured)
    mask = np.asarray(data.mask)
    rmse, nrmse = [], []
    for k in range(measured.shape[0]):
        keep = mask[k] > 0
        err = simulated[k][keep] - measured[k][keep]
        rmse.append(float(np.sqrt(np.mean(err**2))))
        nrmse.append(rmse[-1] / float(np.std(measured[k][keep])))
    values, std, corr, sv, Vt, _ = statistics
    names = _parameter_names(free)
    unidentified = _unidentified(sv, Vt, names, threshold)
    converged = reason.startswith(("converged", "stalled"))
    return FitResult(
        model=unwrap(constrained),
        constrained=constrained,
        names=tuple(names),
        values=values,
        std_errors=std,
        correlation=corr,
        singular_values=sv,
        unidentified=tuple(unidentified),
        rmse=np.asarray(rmse),
        nrmse=np.asarray(nrmse),
        experiment_names=data.names,
        loss=loss,
        history=history,
        num_steps=steps,
        reason=reason,
        converged=converged and not unidentified,
    )


def _unidentified(sv, Vt, names, threshold) -> list[str]:
    """A message per parameter combination whose relative singular value is below
    `threshold` (shared by `fit` and `fit_system`)."""
    messages = []
    for j in range(len(sv)):
        if sv[j] < threshold * sv[0]:
            messages.append(
                "not identified: the data do not determine the combination "
                + _describe_null(Vt[j], names)
                + f" (relative singular value {sv[j] / sv[0]:.1e}); fix one of these "
                "parameters (jaxmr.Fixed) or use a normalised model."
            )
    return messages


def fit_each(
    model: AbstractHysteresis | Damper,
    experiments: Sequence,
    *,
    integrator: AbstractIntegrator | None = None,
    weighting: str = "nrmse",
    max_steps: int = 200,
    patience: int = 8,
    ftol: float = 1e-4,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    progress: bool | Callable = True,
    discard=None,
    smoothing=None,
    identifiability_threshold: float = 1e-7,
    solver: optx.AbstractLeastSquaresSolver | None = None,
    shard: bool = True,
) -> list[FitResult]:
    """Fit `model` to each experiment separately, all in one batched solve.

    The independent problems (one per experiment: e.g. one run per specimen or per
    test condition) run as one vmapped Levenberg–Marquardt loop; each stops on its own
    and keeps its own best parameters. With several local devices and `shard=True` the
    batch is split across them with `jax.sharding` (a `NamedSharding` over a 1-D mesh of
    `jax.local_devices()`) when the number of experiments divides evenly; XLA then runs
    the shards in parallel.

    Several hosts: start every process with `jax.distributed.initialize()` and build
    the mesh over `jax.devices()` (all hosts' devices) in your own script, placing each
    host's share of the experiments with `jax.make_array_from_process_local_data`; the
    same jitted step then runs across hosts. jaxmr itself never schedules work.

    **Arguments:** as `fit` (no `starts`), plus `shard`.

    **Returns:** one `FitResult` per experiment, in order.
    """
    experiments = list(experiments)
    data, integrator, free, static = _setup(
        model, experiments, weighting, integrator, discard, smoothing
    )
    n = len(experiments)
    # One experiment per problem: axis 0 indexes problems, axis 1 the (single) run.
    arrays, data_static = eqx.partition(data, eqx.is_array)
    batched = eqx.combine(jax.tree.map(lambda a: a[:, None], arrays), data_static)
    ys = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), free)
    devices = jax.local_devices()
    if shard and len(devices) > 1 and n % len(devices) == 0:
        mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
        sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
        ys = jax.device_put(ys, sharding)
        batched = eqx.combine(
            jax.device_put(eqx.filter(batched, eqx.is_array), sharding), data_static
        )
    if solver is None:
        solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    first = eqx.combine(jax.tree.map(lambda a: a[:1], arrays), data_static)
    scale = _column_scale(free, static, first, integrator)
    best_y, best_loss, history, steps, reasons = _iterate(
        solver,
        _divide(ys, scale),
        (_scaled_residuals, (static, scale), batched, integrator),
        0,
        max_steps,
        patience,
        ftol,
        _progress_printer(progress),
    )
    results = []
    for p in range(n):
        data_p = eqx.combine(
            jax.tree.map(lambda a, p=p: a[p : p + 1], arrays), data_static
        )
        data_p = dataclasses.replace(data_p, names=(data.names[p],))
        results.append(
            _result(
                jax.tree.map(lambda a, p=p: a[p], _multiply(best_y, scale)),
                static,
                data_p,
                integrator,
                float(best_loss[p]),
                tuple(history),
                steps,
                reasons[p],
                identifiability_threshold,
            )
        )
    return results
