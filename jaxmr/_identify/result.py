"""The result of a fit and its statistics: standard errors, correlations,
identifiability, and warnings for what the data do not determine."""

import dataclasses
import enum
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._parameter import Fixed, is_parameter, unwrap
from . import score
from .residual import value_and_jacobian_jit

# A parameter whose standard error exceeds this fraction of its value, or a pair whose
# correlation exceeds this in magnitude, is named as poorly determined.
MAX_RELATIVE_ERROR = 1.0
MAX_CORRELATION = 0.99
# A redundant group (`_redundant_groups`) is named only where one of its members'
# relative standard error exceeds this: correlation says the members trade off, their
# errors say by how much. The Bouc–Wen benchmark oscillator fitted to its training
# record has five parameters in one near-null direction, each known to 0.06 % or
# better: nothing a user should fix.
MAX_GROUP_RELATIVE_ERROR = 0.1
# A fit whose NRMSE on an experiment exceeds this explains under half of that force's
# variance (1 - 0.7² = 0.51): a converged fit of the wrong channel, a force in other
# units than the motion's, pure noise or a motion that is not the device's is
# "converged" all the same, and says so (`FitResult.poor_fit`). The UTFSM, NEES and
# simulated fits of every default candidate stay below 0.3.
POOR_FIT_NRMSE = 0.7
# A parameter whose whole effect on the force is small (an offset or an accumulator
# stiffness fitted to about 0 on data that need none) has errors large against its
# value and still leaves the force determined. Errors are judged relative to each
# parameter's magnitude: the larger of |value| and the value at which it would move
# the force by this fraction of the model's largest term (`magnitudes`).
EFFECT_FLOOR = 0.01


class StopReason(enum.Enum):
    """Why a fit's solver loop stopped (as optimistix's `RESULTS`: a member per
    reason, each with a `message` sentence).

    `converged` is the one verdict built on it: LM's own test and progress stalled at
    the noise floor count as convergence (solver noise can keep LM's test from ever
    firing at the optimum); `FitResult.converged` adds that every parameter
    combination is identified.
    """

    TOLERANCE = "converged (Levenberg–Marquardt's tolerance met)"
    STALLED = (
        "stalled: no relative improvement above `ftol` in `patience` steps, or in "
        "3 accepted steps with a Gauss–Newton model that promises no more (a "
        "minimum)"
    )
    MAX_STEPS = "reached max_steps"
    SOLVER_FAILED = (
        "failed: the Levenberg–Marquardt solve reported an error (e.g. a non-finite "
        "step); the best parameters so far are kept"
    )
    NONFINITE = "failed: every evaluated point gave a non-finite loss"
    DEGENERATE = (
        "not converged: the loss is 0 or not finite (degenerate data or a diverged "
        "model, not a fit)"
    )
    INTERRUPTED = "interrupted; the best parameters so far are kept"

    @property
    def message(self) -> str:
        """The reason in words."""
        return self.value

    @property
    def converged(self) -> bool:
        """Whether this stop counts as convergence (`TOLERANCE` or `STALLED`)."""
        return self in (StopReason.TOLERANCE, StopReason.STALLED)

    def sentence(self, steps: int) -> str:
        """`message` with the step it stopped at, where that is the point (an
        interruption, the step budget)."""
        if self is StopReason.INTERRUPTED:
            return f"interrupted at step {steps}; the best parameters so far are kept"
        if self is StopReason.MAX_STEPS:
            return f"reached max_steps = {steps}"
        return self.message


class Outcome(NamedTuple):
    """How the solver loop ended for one problem."""

    loss: float
    """The best loss, ½ Σ (weighted residual)²."""
    history: tuple[float, ...]
    """The batch's best loss after every step."""
    steps: int
    stop: StopReason
    """Why it stopped."""

    @property
    def interrupted(self) -> bool:
        """Whether Ctrl-C or the caller's stop flag stopped it."""
        return self.stop is StopReason.INTERRUPTED

    @property
    def reason(self) -> str:
        """Why it stopped, in words (`StopReason.sentence`)."""
        return self.stop.sentence(self.steps)


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """The outcome of `fit`.

    **Attributes:**

    - `model`: the fitted model, plain numbers (ready for `simulate`).
    - `constrained`: the fitted model with its constraint wrappers (to refit).
    - `names`: the fitted parameters' names (paths in the model, e.g. `.alpha.a`).
    - `values`, `std_errors`: their values and standard errors (same units).
      What an error means: the spread of the fitted value over repeats of the same
      tests (the same motions and currents, new noise), to first order. Each
      experiment's own residual tells its noise level and its autocorrelation, so
      that the errors hold for experiments of any lengths, weights and noise levels
      and for noise correlated from sample to sample (a sandwich (JᵀJ)⁺ M (JᵀJ)⁺ with
      an AR(1)-prewhitened Newey–West middle per experiment, `statistics_from`).
      value ± 1.96 std_error is a 95 % interval; `benchmarks/calibration.py`
      measures how often it holds the truth. A model error counts as noise (it is
      a correlated residual), so with a model that misses the data the errors are
      about the best-fitting values' spread, and on the wide side. They describe
      the minimum the fit landed in, never other minima (`starts` looks for those).
      `inf`: the parameter moves along a direction the data do not determine.
    - `correlation`, `covariance`: the parameters' correlation and covariance
      matrices (covariance in the product of the two parameters' units; NaN in the
      rows and columns of a parameter with an infinite error).
    - `singular_values`: of the Jacobian with columns scaled by the parameter values
      (relative sensitivities), largest first. A parameter of small effect (a force
      offset fitted to about 0) is scaled instead by the value at which it would
      move the force by 1 % of the model's largest term, where that is larger: it
      is then neither "not identified" nor "poorly determined" for being small.
    - `unidentified`: descriptions of parameter combinations the data do not determine
      (empty when all are identified).
    - `poorly_determined`: warnings from those errors, each named once: one per group
      of redundant parameters (correlated beyond ±0.99, pairwise or as a group),
      one for those with no finite error, one per other parameter whose relative
      standard error exceeds 100 % (of its magnitude, as above; empty for a
      well-determined fit).
    - `rmse`, `nrmse`: per experiment [force unit] and RMSE/std(F) (from
      `fit_system`: per record, in the output's unit, and RMSE/std(output)).
    - `experiment_names`.
    - `loss`: ½ Σ (weighted residual)²; `history`: the best loss after every step.
    - `num_steps`; `stop`, why it stopped (a `StopReason`; `reason`: the same in
      words); `converged`: `stop.converged` (the solver's test or stalled progress,
      with a finite loss above 0) and every combination identified; `outcome`: that
      verdict in words, followed by `poor_fit` where that is not None.
    - `poor_fit`: the experiments whose NRMSE exceeds 0.7 (the model explains under
      half of their force's variance), named with what to check, or None.
    - `interrupted`: whether Ctrl-C or the caller's `stop` flag stopped it.
    - `magnitudes`: what each standard error is relative to in the warnings and
      the table's `rel` column (same units as `values`): |value|, or the size at
      which the parameter would move the force by 1 % of the model's largest term
      where that is larger.
    - `diverged_at`: per experiment, the time [s] (on the experiment's own `t`) from
      which its simulation at the fitted parameters diverged: the model's state left
      its bounds (`state_bounds`, e.g. Dahl's |z| <= 1) or stopped being finite, so
      its forces from there on are no prediction (NaN where it held; `None` from
      `fit_system`). Such an experiment's `rmse` is inf, the fit is a failure, and
      `outcome` (`divergence`) names the experiment and the time, as `jaxmr
      predict` and `jaxmr report` do.
    """

    model: eqx.Module
    constrained: eqx.Module
    names: tuple[str, ...]
    values: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    covariance: np.ndarray
    singular_values: np.ndarray
    unidentified: tuple[str, ...]
    poorly_determined: tuple[str, ...]
    rmse: np.ndarray
    nrmse: np.ndarray
    experiment_names: tuple[str, ...]
    loss: float
    history: tuple[float, ...]
    num_steps: int
    stop: StopReason
    diverged_at: np.ndarray | None = None
    magnitudes: np.ndarray | None = None

    @property
    def divergence(self) -> str | None:
        """Where the fitted model's simulation diverged, in words (each experiment
        and its time [s], from `diverged_at`), or None where none did."""
        if self.diverged_at is None:
            return None
        where = [
            f"experiment {name!r} at t = {float(t):g} s"
            for name, t in zip(self.experiment_names, self.diverged_at)
            if np.isfinite(t)
        ]
        if not where:
            return None
        return (
            f"the fitted model's simulation diverged on {', '.join(where)} (its state "
            "left its bounds or stopped being finite)"
        )

    @property
    def poor_fit(self) -> str | None:
        """The experiments the fitted model explains little of, in words (NRMSE above
        `POOR_FIT_NRMSE`, 0.7: under half of the force's variance), with what to
        check; None where it explains every one. A converged fit can be a poor one:
        converged says the fit is at a minimum, not that the model fits."""
        nrmse = np.asarray(self.nrmse, float)
        poor = [
            f"{name} (NRMSE {e:.3g})"
            for name, e in zip(self.experiment_names, nrmse)
            if np.isfinite(e) and e > POOR_FIT_NRMSE
        ]
        if not poor:
            return None
        return (
            f"the model explains little of the force on {', '.join(poor)}: check "
            "that force, motion and input are the device's channels, in SI units, "
            "with one sign convention, and that the record is not noise"
        )

    @property
    def reason(self) -> str:
        """Why the fit stopped, in words (`StopReason.sentence`)."""
        return self.stop.sentence(self.num_steps)

    @property
    def converged(self) -> bool:
        """The fit's verdict: `stop.converged` and every combination identified."""
        return self.stop.converged and not self.unidentified

    @property
    def outcome(self) -> str:
        """The verdict in words, starting with "converged" exactly when `converged`
        (the one wording: the summary, `score_table`, `select_model`'s log and
        `jaxmr fit`'s report use it). Progress stalled at a minimum counts as
        converged, so its words are not "stalled". Converged means at a minimum, the
        one the start led to: other starts may find a lower one, and it need not fit:
        where the model explains little of an experiment's force, `poor_fit` follows
        the verdict."""
        stop = self.stop
        if self.converged:
            if stop is StopReason.STALLED:
                # "a minimum", not "the noise floor": users read that as the
                # measurement's, which a fit at NRMSE 0.2 is far above.
                verdict = "converged: no relative improvement left (a minimum)"
            else:  # "converged (Levenberg–Marquardt's tolerance met)"
                verdict = stop.message
            return self._poorly(verdict)
        if stop in (StopReason.INTERRUPTED, StopReason.DEGENERATE):
            verdict = self.reason  # "interrupted at step ...", "not converged: ..."
        elif stop.converged:  # stopped well, not identified
            verdict = (
                f"not converged: {len(self.unidentified)} parameter combination(s) "
                "not identified"
            )
        else:
            verdict = f"not converged: {self.reason}"  # failed, or max_steps reached
        # A diverged experiment is never converged (its rmse is inf): say where.
        divergence = self.divergence
        if divergence is not None:
            return f"{verdict}; {divergence}"
        return self._poorly(verdict)

    def _poorly(self, verdict: str) -> str:
        poor = self.poor_fit
        return verdict if poor is None else f"{verdict}; {poor}"

    @property
    def interrupted(self) -> bool:
        """Whether Ctrl-C or the caller's `stop` flag stopped the fit."""
        return self.stop is StopReason.INTERRUPTED

    def table(self) -> str:
        """The parameters with standard errors, as a text table."""
        rows = [f"{'parameter':<24} {'value':>14} {'std error':>12} {'rel':>9}"]
        magnitudes = np.abs(self.values) if self.magnitudes is None else self.magnitudes
        floored = False
        for name, value, se, size in zip(
            self.names, self.values, self.std_errors, magnitudes
        ):
            # Relative to the magnitude the warnings use: a force offset fitted to
            # ~0 showed "rel 5916660%" beside "well determined".
            rel = abs(se / size) if size != 0 else np.inf
            mark = "*" if size != abs(value) else " "
            floored |= mark == "*"
            rows.append(f"{name:<24} {value:>14.6g} {se:>12.3g} {rel:>8.2%}{mark}")
        if floored:
            rows.append(
                f"* relative to the size at which it would move the force by "
                f"{EFFECT_FLOOR:.0%} of the model's largest term (its value is "
                "smaller: a small effect, not a poorly determined one)"
            )
        return "\n".join(rows)

    def sample(self, n: int, key: jax.Array) -> eqx.Module:
        """`n` models drawn from the fit's uncertainty: the parameters jointly normal
        with `covariance` (log-normal with the fitted value as median and the same
        covariance for those with a positive value, so that a positive parameter
        stays positive); every array of
        the returned model gains a leading axis of size `n` (a batch to `vmap` over,
        e.g. for `jaxmr.tune(..., samples=...)`).

        **Arguments:** `n`, the number of samples; `key`, a JAX random key.

        **Raises:** `ValueError` where a parameter has no finite standard error
        (the data do not bound it, so no draw of it means anything: fix it).
        """
        if not isinstance(n, int) or n < 1:
            raise ValueError(
                f"FitResult.sample: `n` must be a positive integer, got {n!r}."
            )
        values = np.asarray(self.values, dtype=float)
        if not np.all(np.isfinite(values)):
            raise ValueError("FitResult.sample: the fitted values are not finite.")
        loose = ~np.isfinite(np.asarray(self.std_errors, dtype=float))
        if np.any(loose):
            names = ", ".join(np.asarray(self.names)[loose])
            raise ValueError(
                f"FitResult.sample: {names} ha{'ve' if loose.sum() > 1 else 's'} no "
                "finite standard error (the data do not determine them): fix them "
                "(jaxmr.Fixed) and refit before sampling."
            )
        log = values > 0
        # Log variables whose medians are the fitted values and whose draws have
        # the fit's covariance (a multivariate log-normal's moments): with
        # R = C / (a b) and d the log variances, d solves e^d (e^d - 1) = R_aa,
        # cov(log a, log b) = log(1 + R_ab e^{-(d_a + d_b)/2}) and cov(log a, b) =
        # C_ab e^{-d_a/2} / a. For a small relative error that is the linearised
        # C_ab / (a b); for a large one (a positive parameter fitted to about 0,
        # whose error is far beyond its value) the linearisation gave log-normals
        # of absurd spread (exp of ±1e6).
        scale = np.where(log, 1.0 / np.where(log, values, 1.0), 1.0)
        relative = np.asarray(self.covariance, dtype=float) * np.outer(scale, scale)
        d = np.where(
            log,
            np.log((1 + np.sqrt(1 + 4 * np.maximum(np.diag(relative), 0.0))) / 2),
            0.0,
        )
        shrink = np.where(log, np.exp(-d / 2), 1.0)
        cov = relative * np.outer(shrink, shrink)
        both = np.outer(log, log)
        cov = np.where(both, np.log1p(np.maximum(cov, -1 + 1e-12)), cov)
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
            # In parentheses: the outcome may end in a sentence of advice, which
            # "after 5 steps" had continued ("... is not noise after 5 steps").
            f"fit: {self.outcome} ({self.num_steps} steps, loss {self.loss:.6g})",
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
    value_list, derivative_list = _values_and_derivatives(free, static)
    flatten = lambda xs: np.concatenate([np.ravel(np.asarray(x)) for x in xs])
    return flatten(value_list), flatten(derivative_list)


# Jitted: eagerly, each of the wrappers' operations compiled apart in a fresh process.
@eqx.filter_jit
def _values_and_derivatives(free, static):
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
    return jax.jvp(values, (free,), (ones,))


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


# A parameter with a weight above this in a near-null direction of the correlation
# matrix belongs to that direction's redundant group (its standardised share; a
# redundant pair has 0.71 each, an even group of 10 about 0.3).
GROUP_WEIGHT = 0.1


def _redundant_groups(corr, finite) -> list[list[int]]:
    """Groups of parameters (indices) the data determine only in combination: joined
    by a correlation beyond `MAX_CORRELATION` or by a direction of the correlation
    matrix with an eigenvalue below 1 − `MAX_CORRELATION` (the smallest eigenvalue of
    a pair correlated c is 1 − |c|, so both tests agree on pairs; the eigenvalue also
    finds a group of three or more that no single pair reveals)."""
    index = np.flatnonzero(finite)
    parent = list(range(len(corr)))

    def root(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    def join(members):
        for a in members[1:]:
            parent[root(a)] = root(members[0])

    if index.size >= 2:
        block = corr[np.ix_(index, index)]
        if np.all(np.isfinite(block)):
            w, V = np.linalg.eigh((block + block.T) / 2)
            for j in np.flatnonzero(w < 1 - MAX_CORRELATION):
                members = index[np.abs(V[:, j]) > GROUP_WEIGHT]
                if members.size >= 2:
                    join(list(members))
        for a, b in zip(*np.nonzero(np.abs(np.nan_to_num(block)) > MAX_CORRELATION)):
            if a < b:
                join([int(index[a]), int(index[b])])
    groups: dict[int, list[int]] = {}
    for k in index:
        groups.setdefault(root(int(k)), []).append(int(k))
    return [g for g in groups.values() if len(g) >= 2]


def poorly_determined(values, std, corr, names, magnitude=None) -> list[str]:
    """Warnings for what the data barely determine, each named once: one message per
    group of redundant parameters (`_redundant_groups`: the data determine a
    combination of them, not each) where a member's relative standard error exceeds
    `MAX_GROUP_RELATIVE_ERROR`, one for the parameters with no finite standard
    error, and one per other parameter whose relative standard error exceeds
    `MAX_RELATIVE_ERROR`. A well-determined fit gets none, however correlated its
    parameters. Errors are relative to `magnitude` (`Statistics.magnitude`; default
    |value|)."""
    values, std = np.asarray(values, float), np.asarray(std, float)
    magnitude = np.abs(values) if magnitude is None else np.asarray(magnitude, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.where(magnitude != 0, np.abs(std / magnitude), np.inf)
    messages = []
    loose = ~np.isfinite(std)
    if np.any(loose):
        listed = ", ".join(
            f"{names[k]} = {values[k]:.4g}" for k in np.flatnonzero(loose)
        )
        messages.append(
            f"poorly determined: {listed} ha{'ve' if loose.sum() > 1 else 's'} no "
            "finite standard error: the data do not see a direction they move along "
            "(together, or alone); fix them (jaxmr.Fixed) or add experiments that "
            "excite them."
        )
    grouped = np.zeros(len(names), dtype=bool)
    for group in _redundant_groups(np.asarray(corr, float), ~loose):
        if not np.max(relative[group]) > MAX_GROUP_RELATIVE_ERROR:
            continue  # each member pinned down: correlated, yet determined
        grouped[group] = True
        block = np.abs(np.asarray(corr, float)[np.ix_(group, group)])
        np.fill_diagonal(block, 0.0)
        members = ", ".join(
            f"{names[k]} = {values[k]:.4g} ± {std[k]:.3g} ({relative[k]:.0%})"
            for k in group
        )
        # Which to fix first: the least determined (well-determined members were
        # named beside it, and "fix all but one" had advised fixing them too).
        weakest = group[int(np.argmax(relative[group]))]
        of = (
            ""
            if np.all(magnitude[group] == np.abs(values[group]))
            else " (each error relative to its magnitude: its value, or the size at "
            f"which it would move the force by {EFFECT_FLOOR:.0%} of the model's "
            "largest term)"
        )
        messages.append(
            f"poorly determined: {len(group)} parameters are redundant, the data "
            f"determine a combination of them, not each (correlations up to "
            f"{np.max(block):.4f}): {members}{of}; fix the least determined, "
            f"{names[weakest]} (jaxmr.Fixed), then all but one of them if the others "
            "stay so, or add experiments that tell them apart."
        )
    for k in np.flatnonzero(~loose & ~grouped & (relative > MAX_RELATIVE_ERROR)):
        of = (
            ""
            if magnitude[k] == abs(values[k])
            else f" of {magnitude[k]:.3g}, the size at which it would move the force "
            f"by {EFFECT_FLOOR:.0%} of the model's largest term"
        )
        messages.append(
            f"poorly determined: {names[k]} = {values[k]:.4g} ± {std[k]:.3g} "
            f"(relative standard error {relative[k]:.0%}{of}); the data barely constrain "
            "it: fix it (jaxmr.Fixed) or add experiments that excite it."
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


class Statistics(NamedTuple):
    """A fit's statistics at its optimum (`statistics_from`), in the parameters'
    units."""

    values: np.ndarray
    std: np.ndarray
    """Standard errors; `inf` for a parameter moving along an undetermined direction."""
    corr: np.ndarray
    cov: np.ndarray
    """The covariance; NaN in the rows and columns of parameters with `std` inf."""
    sv: np.ndarray
    """Singular values of the Jacobian with columns scaled by the parameters'
    `magnitude`, largest first."""
    Vt: np.ndarray
    """Its right singular vectors (rows)."""
    magnitude: np.ndarray
    """The larger of |value| and the value at which the parameter would move the
    force by `EFFECT_FLOOR` of the model's largest term (`magnitudes`): what its
    errors are relative to."""


def statistics(residuals_fn, free, static, data, extra, groups, errors=None):
    """`statistics_from` the residual and Jacobian of `residuals_fn` at `free`."""
    r, J_raw = jacobian_matrix(residuals_fn, free, static, data, extra)
    return statistics_from(r, J_raw, free, static, groups, errors)


def kept_groups(counts) -> list[np.ndarray]:
    """The residual rows of each experiment when they lie end to end, `counts[e]` of
    experiment e (`FitData.kept_counts`; rows after them, padding, belong to none)."""
    ends = np.cumsum(counts)
    return [np.arange(end - count, end) for count, end in zip(counts, ends)]


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


# How `FitResult` estimates its covariance (see `statistics_from`); the others are
# kept for `benchmarks/calibration.py`, which measures them all.
ERRORS = "prewhitened"
ERROR_METHODS = ("pooled", "experiment", "hac", "prewhitened")
# The largest lag-1 autocorrelation the prewhitening filter takes (and the bandwidth
# rule sees): beyond it, residuals are a smooth model error more than noise, and a
# filter 1/(1 − ρ) would amplify it without bound.
RHO_MAX = 0.99
# The most a residual's share of the parameters' absorbed variance may inflate one
# experiment's middle (`_correction`): at this the experiment's residual has given
# nine tenths of its variance to the parameters, and its error is unknowable anyway.
MAX_CORRECTION = 10.0


def lag1(r) -> float:
    """The lag-1 autocorrelation of a residual series (about 0, not its mean: a fit
    without an offset leaves a mean in the residual, and it is correlation too)."""
    return autocorrelation(r, 1)


def autocorrelation(r, lag: int) -> float:
    """The lag-`lag` autocorrelation of a residual series (about 0, as `lag1`)."""
    r = np.asarray(r, float)
    energy = float(r @ r)
    if r.size <= lag or not energy > 0:
        return 0.0
    return float(r[lag:] @ r[:-lag]) / energy


def ar_coefficient(r) -> float:
    """The prewhitening filter's coefficient of a residual series: its lag-1
    autocorrelation ρ₁, or, where ρ₁ is clearly above 0 (beyond 2/√n) and the ratio
    ρ₂/ρ₁ is larger, that ratio: white noise beside an AR(1) disturbance (an
    ARMA(1,1) series) has ρ_k = ρ₁ φ^(k−1), so the ratio is the disturbance's own φ
    where ρ₁ is only φ times its share of the variance (2 % white + 2 % AR(1) at 0.9
    gave ρ₁ = 0.45, and prewhitened with it, 95 % intervals covered 81 %). For AR(1)
    noise both are φ."""
    r = np.asarray(r, float)
    rho1 = lag1(r)
    if r.size < 3 or not rho1 > 2 / np.sqrt(r.size):
        return rho1
    return max(rho1, autocorrelation(r, 2) / rho1)


def _backward_filter(J, rho: float):
    """Y_t = J_t + ρ Y_{t+1} (Y_{n−1} = J_{n−1}) for every column, by recursive
    doubling: log₂ n vectorised passes instead of n Python steps."""
    Y = np.array(J, dtype=float, copy=True)
    n, shift, power = Y.shape[0], 1, rho
    while shift < n and abs(power) > 1e-18:
        Y[:-shift] += power * Y[shift:]
        shift, power = 2 * shift, power * power
    return Y


def bartlett_bandwidth(rho: float, n: int) -> float:
    """Andrews' (1991) plug-in bandwidth of the Bartlett kernel for a series whose
    approximating AR(1) coefficient is `rho`, `n` samples: 1.1447 (α n)^(1/3), α =
    4ρ²/((1 − ρ)²(1 + ρ)²); lags below it get weight 1 − lag/bandwidth."""
    rho = float(np.clip(rho, -RHO_MAX, RHO_MAX))
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    return float(min(1.1447 * (alpha * n) ** (1 / 3), n - 1))


def _long_run(r, J, prewhiten: bool, kernel: bool):
    """Σ_t Σ_s J_tᵀ cov(r_t, r_s) J_s estimated from one experiment's residual `r`
    and Jacobian rows `J` (time order).

    Prewhitened (Andrews & Monahan 1992): the residual's AR(1) coefficient ρ
    (`ar_coefficient`, at most `RHO_MAX` in size) splits r = A⁻¹u into innovations u
    (u_0 = √(1−ρ²) r_0, u_t = r_t − ρ r_{t−1}), and Jᵀ cov(r) J = Xᵀ cov(u) X with
    X = A⁻ᵀJ (X_t = J_t + ρ X_{t+1}, X_0 divided by √(1−ρ²)): exact for AR(1) noise
    and no assumption beyond it, since cov(u) is estimated next. `kernel`: cov(u)
    by Newey–West (Bartlett kernel) on the scores X_t u_t with `bartlett_bandwidth`
    of u's own lag-1 autocorrelation; else the scores taken as independent."""
    r = np.asarray(r, float)
    J = np.asarray(J, float)
    u, X = r, J
    if prewhiten:
        # A fitted residual's lag-1 autocorrelation is low by about (1 + 3ρ)/n
        # (Kendall's bias of an AR(1) estimate with a fitted mean): 0.016 at ρ =
        # 0.98, n = 250, where 1/(1 − ρ) is then off by 45 %.
        rho = ar_coefficient(r)
        rho = float(np.clip(rho + (1 + 3 * rho) / len(r), -RHO_MAX, RHO_MAX))
        a0 = np.sqrt(1 - rho**2)
        u = np.concatenate([[a0 * r[0]], r[1:] - rho * r[:-1]])
        X = _backward_filter(J, rho)
        X[0] /= a0
    h = X * u[:, None]
    S = h.T @ h
    if kernel:
        G = _bartlett_lags(h, bartlett_bandwidth(lag1(u), len(u)))
        S += G + G.T
    return S


def _bartlett_lags(h, bandwidth: float):
    """Σ_{l ≥ 1} w_l G_l with G_l = Σ_t h_{t+l} h_tᵀ and the Bartlett weights w_l = 1 −
    l/bandwidth (lags below the bandwidth), as K̃ᵀh with K̃_t = Σ_l w_l h_{t+l}: one
    FFT correlation of each column with the weights. The same sum as a loop over the
    lags, O(n p log n) instead of O(n p² L): a loop of `h[l:].T @ h[:-l]` over
    the several hundred lags of a strongly correlated residual took 4 s of a 5-file
    Spencer fit's 19 s (2026-11-27)."""
    n, p = h.shape
    lags = np.arange(1, min(int(np.ceil(bandwidth)), n))
    if lags.size == 0:
        return np.zeros((p, p))
    # Zero-padded beyond n + L, so that the circular correlation never wraps.
    size = 1 << int(np.ceil(np.log2(n + lags[-1] + 1)))
    kernel = np.zeros(size)
    kernel[size - lags] = 1 - lags / bandwidth  # circular: kernel[−l] = w_l
    spectrum = np.fft.rfft(h, size, axis=0) * np.fft.rfft(kernel)[:, None]
    weighted = np.fft.irfft(spectrum, size, axis=0)[:n]
    return weighted.T @ h


def _middle(r, Js, groups, bread, errors: str):
    """The sandwich's middle Σ_e J_eᵀ cov(r_e) J_e (relative coordinates), each
    experiment's residual `r[groups[e]]` estimating its own noise."""
    if errors == "pooled":
        # The former estimate: one variance s² = RSS/(N − p) over every residual.
        rows = np.concatenate(list(groups))
        s2 = float(r[rows] @ r[rows]) / max(rows.size - Js.shape[1], 1)
        return s2 * Js[rows].T @ Js[rows]
    middle = np.zeros((Js.shape[1],) * 2)
    for rows in groups:
        if errors == "experiment":
            S = float(r[rows] @ r[rows]) / len(rows) * Js[rows].T @ Js[rows]
        else:
            S = _long_run(r[rows], Js[rows], errors == "prewhitened", True)
        # A fitted residual is shorter than the noise: the parameters absorb its
        # part along the Jacobian, tr(B S) of the energy a = Σ r² (N − p of N for
        # independent noise, more for correlated). Each experiment's middle is
        # scaled back by a / (a − tr(B S)), the correction n/(n − p) generalised.
        energy = float(r[rows] @ r[rows])
        absorbed = float(np.trace(bread @ S))
        if energy > 0:
            S = S * min(energy / max(energy - absorbed, 1e-300), MAX_CORRECTION)
        middle += S
    return middle


def magnitudes(values, J) -> np.ndarray:
    """What each parameter's errors are relative to: the larger of |value| and
    `EFFECT_FLOOR` × E / ‖J_k‖, the value at which it would move the (weighted)
    force by that fraction of E, the largest whole effect ‖value_j J_j‖ among the
    parameters. `J`: d residual / d value, columns in `values`' order."""
    values = np.asarray(values, float)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        norms = np.linalg.norm(J, axis=0)
        whole = np.abs(values) * norms
        finite = whole[np.isfinite(whole)]
        largest = float(np.max(finite)) if finite.size else 0.0
        floor = np.where(norms > 0, EFFECT_FLOOR * largest / norms, 0.0)
    floor = np.where(np.isfinite(floor), floor, 0.0)
    return np.maximum(np.abs(values), floor)


def statistics_from(r, J_raw, free, static, groups, errors=None) -> Statistics:
    r"""`Statistics` from the residual `r` and its Jacobian (`jacobian_matrix`'s
    layout; `groups`: each experiment's rows of `r`, in time order).

    The covariance is a sandwich, $B\,M\,B$ with $B = (J^\top J)^+$ and the middle
    $M = \sum_e J_e^\top \operatorname{cov}(r_e) J_e$ estimated from each experiment's
    own residual: its own noise level (whatever its weight, length or noise), and
    its autocorrelation (`errors`, default `ERRORS`):

    - `"prewhitened"`: an AR(1) filter per experiment, then Newey–West on what
      remains (`_long_run`);
    - `"hac"`: Newey–West on the raw scores with Andrews' bandwidth;
    - `"experiment"`: independent samples, one variance per experiment;
    - `"pooled"`: the former s² (JᵀJ)⁺, one variance over all residuals — right only
      when each weight is 1/σ of independent noise.

    First order in the noise, for residuals correlated over a span much shorter than
    each experiment.
    """
    errors = ERRORS if errors is None else errors
    if errors not in ERROR_METHODS:
        raise ValueError(f"`errors` must be one of {ERROR_METHODS}, got {errors!r}.")
    r = np.asarray(r, float)
    values, dvalue = _values_and_scale(free, static)
    # Chain rule: d r / d value = (d r / d free) / (d value / d free), elementwise.
    J = J_raw / np.where(dvalue == 0, 1.0, dvalue)[None, :]
    p = J.shape[1]
    magnitude = magnitudes(values, J)
    scale = np.where(magnitude == 0, 1.0, magnitude)
    Js = J * scale[None, :]
    if not np.all(np.isfinite(Js)) or not np.all(np.isfinite(r)):
        nan = np.full(p, np.nan)
        square = np.full((p, p), np.nan)
        return Statistics(values, nan, square, square, nan, np.eye(p), magnitude)
    # A diverged model (absurd but finite forces) overflows these products: its
    # errors come out inf or NaN, which the result reports, with no NumPy warning.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        _, sv, Vt = np.linalg.svd(Js, full_matrices=False)
        # Undetermined: a singular value at most 1e-10 of the largest (eigenvalue
        # 1e-20).
        bread, loose = covariance(sv**2, Vt.T, 1e-20)
        cov_scaled = bread @ _middle(r, Js, groups, bread, errors) @ bread
        cov = cov_scaled * scale[:, None] * scale[None, :]
        cov = (cov + cov.T) / 2
        std = np.where(loose, np.inf, np.sqrt(np.maximum(np.diag(cov), 0.0)))
        corr = cov / np.outer(std, std)
    for matrix in (corr, cov):
        matrix[loose, :] = np.nan
        matrix[:, loose] = np.nan
    np.fill_diagonal(corr, 1.0)
    cov[loose, loose] = np.inf
    return Statistics(values, std, corr, cov, sv, Vt, magnitude)


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
    times=None,
) -> "FitResult":
    """A `FitResult` from the best free variables, the simulated and measured outputs
    per experiment (lists of arrays), the samples scored, and `statistics`; `times`
    [s] (a list of arrays like `simulated`, or None): where a simulation that is NaN
    from some sample on (the guarded simulation of a diverged state) diverged."""
    constrained = eqx.combine(free, static)
    scored = list(zip(simulated, measured, kept_masks))
    rmse = [score.rmse(*s) for s in scored]
    nrmse = [score.nrmse(*s) for s in scored]
    values, std, corr, cov, sv, Vt, magnitude = stats
    names = _parameter_names(free)
    unidentified = (
        _unidentified(sv, Vt, names, threshold)
        if np.all(np.isfinite(sv))
        else [
            "the Jacobian at the optimum is not finite: the statistics are unavailable"
        ]
    )
    weak = poorly_determined(values, std, corr, names, magnitude)
    loss, stop = outcome.loss, outcome.stop
    sound = np.isfinite(loss) and loss > 0 and np.all(np.isfinite(rmse))
    if stop.converged and not sound:
        # A loss of exactly 0 or a non-finite one: degenerate data or a diverged
        # model, not a fit.
        stop = StopReason.DEGENERATE
    return FitResult(
        model=unwrap(constrained),
        constrained=constrained,
        names=tuple(names),
        values=values,
        std_errors=std,
        correlation=corr,
        covariance=cov,
        singular_values=sv,
        unidentified=tuple(unidentified),
        poorly_determined=tuple(weak),
        rmse=np.asarray(rmse),
        nrmse=np.asarray(nrmse),
        experiment_names=tuple(experiment_names),
        loss=float(loss),
        history=outcome.history,
        num_steps=outcome.steps,
        stop=stop,
        diverged_at=None if times is None else _diverged_at(simulated, times),
        magnitudes=np.asarray(magnitude, float),
    )


def _diverged_at(simulated, times) -> np.ndarray:
    """Per experiment, the time [s] of its first simulated sample that is not finite
    (NaN where all are)."""
    at = []
    for force, t in zip(simulated, times):
        bad = ~np.isfinite(np.asarray(force))
        at.append(float(np.asarray(t)[np.argmax(bad)]) if bad.any() else np.nan)
    return np.asarray(at, dtype=float)
