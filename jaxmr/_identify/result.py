"""The result of a fit and its statistics: standard errors, correlations,
identifiability, and warnings for what the data do not determine."""

import dataclasses
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._parameter import Fixed, is_parameter, unwrap
from .residual import value_and_jacobian_jit

# A parameter whose standard error exceeds this fraction of its value, or a pair whose
# correlation exceeds this in magnitude, is named as poorly determined.
MAX_RELATIVE_ERROR = 1.0
MAX_CORRELATION = 0.99


class Outcome(NamedTuple):
    """How the solver loop ended for one problem."""

    loss: float
    """The best loss, ½ Σ (weighted residual)²."""
    history: tuple[float, ...]
    """The batch's best loss after every step."""
    steps: int
    reason: str
    """Why it stopped, in words."""
    interrupted: bool
    """Whether Ctrl-C stopped it."""


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
    - `poorly_determined`: warnings naming each parameter whose relative standard
      error exceeds 100 % and each pair correlated beyond ±0.99 (empty when none).
    - `rmse`, `nrmse`: per experiment [force unit] and RMSE/std(F) (from
      `fit_system`: per record, in the output's unit, and RMSE/std(output)).
    - `experiment_names`.
    - `loss`: ½ Σ (weighted residual)²; `history`: the best loss after every step.
    - `num_steps`, `reason` (why it stopped), `converged` (stopped on the solver's
      test or on stalled progress, every combination identified, a finite loss
      above 0).
    - `interrupted`: whether Ctrl-C stopped it.
    """

    model: eqx.Module
    constrained: eqx.Module
    names: tuple[str, ...]
    values: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    singular_values: np.ndarray
    unidentified: tuple[str, ...]
    poorly_determined: tuple[str, ...]
    rmse: np.ndarray
    nrmse: np.ndarray
    experiment_names: tuple[str, ...]
    loss: float
    history: tuple[float, ...]
    num_steps: int
    reason: str
    converged: bool
    interrupted: bool = False

    def table(self) -> str:
        """The parameters with standard errors, as a text table."""
        rows = [f"{'parameter':<24} {'value':>14} {'std error':>12} {'rel':>8}"]
        for name, value, se in zip(self.names, self.values, self.std_errors):
            rel = abs(se / value) if value != 0 else np.inf
            rows.append(f"{name:<24} {value:>14.6g} {se:>12.3g} {rel:>8.2%}")
        return "\n".join(rows)

    def sample(self, n: int, key: jax.Array) -> eqx.Module:
        """`n` models drawn from the fit's uncertainty: the parameters jointly normal
        with the estimated covariance (log-normal, to first order the same, for those
        with a positive value, so that a positive parameter stays positive); every
        array of the returned model gains a leading axis of size `n` (a batch to
        `vmap` over, e.g. for `jaxmr.tune(..., samples=...)`).

        **Arguments:** `n`, the number of samples; `key`, a JAX random key.
        """
        if not isinstance(n, int) or n < 1:
            raise ValueError(
                f"FitResult.sample: `n` must be a positive integer, got {n!r}."
            )
        values = np.asarray(self.values, dtype=float)
        std = np.nan_to_num(np.asarray(self.std_errors, dtype=float))
        corr = np.nan_to_num(np.asarray(self.correlation, dtype=float))
        np.fill_diagonal(corr, 1.0)
        if not np.all(np.isfinite(values)):
            raise ValueError("FitResult.sample: the fitted values are not finite.")
        log = values > 0
        # In log variables, d log v = dv / v: the covariance scales by 1/v.
        scale = np.where(log, 1.0 / np.where(log, values, 1.0), 1.0)
        cov = corr * np.outer(std * scale, std * scale)
        w, V = np.linalg.eigh((cov + cov.T) / 2)
        root = V * np.sqrt(np.maximum(w, 0.0))
        normal = np.asarray(jax.random.normal(key, (n, values.size)))
        centre = np.where(log, np.log(np.where(log, values, 1.0)), values)
        t = centre + normal @ root.T
        draws = np.where(log, np.exp(t), t)
        # The free parameters are the model's leaves where `_free_mask` is True, in
        # order; every other leaf is repeated.
        leaves, treedef = jax.tree.flatten(self.model)
        mask = jax.tree.leaves(_free_mask(self.constrained))
        if len(mask) != len(leaves):  # pragma: no cover - a structural invariant
            raise RuntimeError("FitResult.sample: the model and its mask disagree.")
        out, k = [], 0
        for leaf, free in zip(leaves, mask, strict=True):
            leaf = jnp.asarray(leaf)
            if free:
                size = leaf.size
                block = draws[:, k : k + size].reshape((n,) + leaf.shape)
                out.append(jnp.asarray(block, dtype=leaf.dtype))
                k += size
            else:
                out.append(jnp.broadcast_to(leaf, (n,) + leaf.shape))
        return jax.tree.unflatten(treedef, out)

    def __str__(self):
        lines = [
            f"fit: {self.reason} after {self.num_steps} steps, loss {self.loss:.6g}",
            self.table(),
            "NRMSE per experiment: "
            + ", ".join(
                f"{n}: {e:.4f}" for n, e in zip(self.experiment_names, self.nrmse)
            ),
        ]
        lines += [f"WARNING: {u}" for u in self.unidentified + self.poorly_determined]
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

    ones = jax.tree.map(jnp.ones_like, free)
    value_list, derivative_list = jax.jvp(values, (free,), (ones,))
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


def poorly_determined(values, std, corr, names) -> list[str]:
    """A warning per parameter with relative standard error above
    `MAX_RELATIVE_ERROR` and per pair correlated beyond `MAX_CORRELATION`."""
    messages = []
    for name, value, se in zip(names, values, std):
        relative = abs(se / value) if value != 0 else np.inf
        if not np.isfinite(se):
            messages.append(
                f"poorly determined: {name} = {value:.4g} has no finite standard "
                "error: the data do not see a direction it moves along (with another "
                "parameter, or alone); fix it (jaxmr.Fixed) or add experiments that "
                "excite it."
            )
        elif relative > MAX_RELATIVE_ERROR:
            messages.append(
                f"poorly determined: {name} = {value:.4g} ± {se:.3g} (relative "
                f"standard error {relative:.0%}); the data barely constrain it: fix it "
                "(jaxmr.Fixed) or add experiments that excite it."
            )
    p = len(names)
    for a in range(p):
        for b in range(a + 1, p):
            c = corr[a, b]
            if np.isfinite(c) and abs(c) > MAX_CORRELATION:
                messages.append(
                    f"poorly determined: {names[a]} and {names[b]} are correlated "
                    f"{c:+.4f}; the data determine a combination of them, not each."
                )
    return messages


def jacobian_matrix(residuals_fn, free, static, data, extra):
    """The residual and its Jacobian with respect to the free variables (the fit's
    own coordinates: log of a `Positive`, the logistic variable of a `Bounded`) as one
    NumPy matrix, residuals × variables in the order of `_parameter_names(free)`."""
    r, jac_tree = value_and_jacobian_jit(residuals_fn, free, static, data, extra)
    r = np.asarray(r)
    J = np.concatenate(
        [
            np.reshape(np.asarray(j), (r.shape[0], -1))
            for j in jax.tree.leaves(jac_tree)
        ],
        axis=1,
    )
    return r, J


def statistics(residuals_fn, free, static, data, extra, n_obs: int):
    """Values, standard errors, correlations, singular values and right singular
    vectors of the (relative) Jacobian, and s², at the optimum: cov = s² (JᵀJ)⁺ with
    s² = RSS/(N − p)."""
    r, J_raw = jacobian_matrix(residuals_fn, free, static, data, extra)
    return statistics_from(r, J_raw, free, static, n_obs)


# A parameter whose weight in an undetermined direction exceeds this moves along it.
NULL_WEIGHT = 0.03


def covariance(eigenvalues, vectors, rcond: float):
    """The covariance (up to the noise variance) from the eigen-decomposition of an
    information matrix JᵀJ (`eigenvalues`, `vectors` as columns; the squared singular
    values and right singular vectors of J serve), and which parameters are loose.

    Directions with an eigenvalue at most `rcond` × the largest are not determined by
    the data. The pseudo-inverse gives them no variance at all, so that a parameter
    moving along one would look exact; such a parameter (weight above `NULL_WEIGHT`)
    is `loose`: its variance is infinite and the caller reports it so. Shared by the
    fit's report and the experiment design's predicted standard errors.
    """
    w = np.asarray(eigenvalues, dtype=float)
    determined = w > rcond * max(float(np.max(w)), 0.0)
    inverse = np.where(determined, 1.0 / np.where(determined, w, 1.0), 0.0)
    cov = (vectors * inverse) @ vectors.T
    loose = np.any(np.abs(vectors[:, ~determined]) > NULL_WEIGHT, axis=1)
    return cov, loose


def statistics_from(r, J_raw, free, static, n_obs: int):
    """`statistics` from the residual and its Jacobian (`jacobian_matrix`'s layout)."""
    values, dvalue = _values_and_scale(free, static)
    # Chain rule: d r / d value = (d r / d free) / (d value / d free), elementwise.
    J = J_raw / np.where(dvalue == 0, 1.0, dvalue)[None, :]
    p = J.shape[1]
    s2 = float(r @ r) / max(n_obs - p, 1)
    scale = np.where(values == 0, 1.0, np.abs(values))
    Js = J * scale[None, :]
    if not np.all(np.isfinite(Js)):
        nan = np.full(p, np.nan)
        return values, nan, np.full((p, p), np.nan), nan, np.eye(p), s2
    _, sv, Vt = np.linalg.svd(Js, full_matrices=False)
    # Undetermined: a singular value at most 1e-10 of the largest (eigenvalue 1e-20).
    cov_scaled, loose = covariance(sv**2, Vt.T, 1e-20)
    cov = cov_scaled * s2 * scale[:, None] * scale[None, :]
    std = np.where(loose, np.inf, np.sqrt(np.maximum(np.diag(cov), 0.0)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[loose, :] = np.nan
    corr[:, loose] = np.nan
    np.fill_diagonal(corr, 1.0)
    return values, std, corr, sv, Vt, s2


def assemble(
    free,
    static,
    simulated,
    measured,
    kept_masks,
    experiment_names,
    stats,
    outcome,
    threshold,
) -> "FitResult":
    """A `FitResult` from the best free variables, the simulated and measured outputs
    per experiment (lists of arrays), the samples scored, and `statistics`."""
    constrained = eqx.combine(free, static)
    rmse, nrmse = [], []
    for sim, meas, keep in zip(simulated, measured, kept_masks):
        err = np.asarray(sim)[keep] - np.asarray(meas)[keep]
        rmse.append(float(np.sqrt(np.mean(err**2))))
        spread = float(np.std(np.asarray(meas)[keep]))
        nrmse.append(rmse[-1] / spread if spread > 0 else np.inf)
    values, std, corr, sv, Vt, _ = stats
    names = _parameter_names(free)
    unidentified = (
        _unidentified(sv, Vt, names, threshold)
        if np.all(np.isfinite(sv))
        else [
            "the Jacobian at the optimum is not finite: the statistics are unavailable"
        ]
    )
    weak = poorly_determined(values, std, corr, names)
    loss, reason = outcome.loss, outcome.reason
    stopped_well = reason.startswith(("converged", "stalled"))
    sound = np.isfinite(loss) and loss > 0 and np.all(np.isfinite(rmse))
    if stopped_well and not sound:
        reason = (
            f"not converged: the loss is {loss:g} (a loss of exactly 0 or a non-finite "
            "one means degenerate data or a diverged model, not a fit)"
        )
    return FitResult(
        model=unwrap(constrained),
        constrained=constrained,
        names=tuple(names),
        values=values,
        std_errors=std,
        correlation=corr,
        singular_values=sv,
        unidentified=tuple(unidentified),
        poorly_determined=tuple(weak),
        rmse=np.asarray(rmse),
        nrmse=np.asarray(nrmse),
        experiment_names=tuple(experiment_names),
        loss=float(loss),
        history=outcome.history,
        num_steps=outcome.steps,
        reason=reason,
        converged=bool(stopped_well and sound and not unidentified),
        interrupted=outcome.interrupted,
    )
