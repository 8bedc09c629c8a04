r"""The prediction band: where a fitted model is unsure of the force it predicts.

The band propagates the fit's parameter covariance (`FitResult.covariance`) to the
predicted force to first order: at each sample $k$,
$\operatorname{var}\hat F_k = g_k^\top \Sigma\, g_k$ with $g_k = \partial \hat F_k /
\partial\theta$ from one forward-mode pass through the simulation `fit` uses, and the
band is $\hat F_k \pm z\,\operatorname{std}\hat F_k$ ($z$ = 1.96 for 95 %). It is the
uncertainty of the model's force (the mean a repeat of the test would give), not of
a measurement: it holds the noise-free force, and measurement noise lies outside it.
"""

import dataclasses
from collections.abc import Sequence
from statistics import NormalDist

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._channel import ChannelDelay
from .._damper import Damper
from .._hysteresis import AbstractHysteresis
from .._integrate import FixedStep
from .data import (
    StepPolicy,
    as_step_policy,
    experiment_list,
    experiment_name,
    pack,
    per_experiment,
)
from .residual import residuals
from .result import FitResult, jacobian_matrix
from .score import with_finer_steps


@dataclasses.dataclass(frozen=True, eq=False)
class PredictionBand:
    """The band of one experiment's predicted force (`prediction_band`).

    **Attributes** (arrays at the experiment's samples, in the force's unit, [N] or
    [N·m]):

    - `name`: the experiment's name; `t`: its sample times [s].
    - `force`: the fitted model's prediction (as `jaxmr.predict`).
    - `std`: the prediction's standard error from the parameters' uncertainty.
    - `lower`, `upper`: `force ∓ z·std`, z the normal quantile of `level`.
    - `level`: the band's nominal coverage (e.g. 0.95).
    """

    name: str
    t: np.ndarray
    force: np.ndarray
    std: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    level: float

    def columns(self) -> dict[str, np.ndarray]:
        """The band as named columns, for a table or CSV: `F_pred` (the prediction),
        `F_std` (its standard error), `F_lower` and `F_upper` (the band's edges),
        each in the force's unit."""
        return {
            "F_pred": self.force,
            "F_std": self.std,
            "F_lower": self.lower,
            "F_upper": self.upper,
        }


def prediction_band(
    result: FitResult,
    experiments: Sequence,
    *,
    level: float = 0.95,
    integrator: StepPolicy | FixedStep | None = None,
    smoothing=None,
) -> list[PredictionBand]:
    """The band of the force `result`'s model predicts for each experiment, from the
    fit's parameter uncertainty (see the module docstring).

    **Arguments:**

    - `result`: a `FitResult` of `jaxmr.fit` or `fit_each` (a damper model; not of
      `fit_system`).
    - `experiments`: `jaxmr.data.Experiment`s (or anything with `t`, `x`, `v`,
      `current`, `name`); a measured force is not needed. The band covers every
      sample, an experiment's discarded start included.
    - `level`: the nominal coverage of the band, in (0, 1) (default 0.95).
    - `integrator`, `smoothing`: as in `jaxmr.predict_all`.

    **Returns:** one `PredictionBand` per experiment, in order.

    **Raises:** `TypeError` for a result that is not a damper model's; `ValueError`
    where a parameter has no finite standard error (the band would be unbounded: fix
    that parameter and refit) or `level` is not in (0, 1).
    """
    return prediction_band_from_covariance(
        result.model,
        result.names,
        result.covariance,
        experiments,
        level=level,
        integrator=integrator,
        smoothing=smoothing,
    )


def prediction_band_from_covariance(
    model,
    names: Sequence[str],
    covariance,
    experiments: Sequence,
    *,
    level: float = 0.95,
    integrator: StepPolicy | FixedStep | None = None,
    smoothing=None,
) -> list[PredictionBand]:
    """`prediction_band` from a model and the covariance of its fitted parameters,
    without the `FitResult`: e.g. a model read back with `jaxmr.load_model` and the
    covariance saved beside it (`jaxmr fit` saves it in its report).

    **Arguments:**

    - `model`: a damper model (hysteresis model, `Damper` or `ChannelDelay`) with
      plain values, as `FitResult.model`.
    - `names`: the fitted parameters, named as `FitResult.names` names them (paths in
      the model, e.g. `.alpha.a`; `[k]` for an array's entries); the others are
      held at their values.
    - `covariance`: their covariance matrix, in `names`' order (as
      `FitResult.covariance`: in the product of the two parameters' units).
    - `experiments`, `level`, `integrator`, `smoothing`: as `prediction_band`'s.

    **Returns:** one `PredictionBand` per experiment, in order.

    **Raises:** `TypeError` for a model that is not a damper model; `ValueError`
    where `names` and `covariance` disagree, name a parameter `model` lacks (or part
    of an array), a variance is not finite (that parameter is not determined: fix it
    and refit), or `level` is not in (0, 1).
    """
    if not 0 < level < 1:
        raise ValueError(f"`level` must be in (0, 1), got {level!r}.")
    if not isinstance(model, (AbstractHysteresis, Damper, ChannelDelay)):
        raise TypeError(
            "`model` must be a jaxmr hysteresis model, Damper or ChannelDelay, got "
            f"{type(model).__name__}."
        )
    names = [str(n) for n in names]
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (len(names), len(names)):
        raise ValueError(
            f"`covariance` has shape {cov.shape}, but {len(names)} parameters are "
            "named: give one row and column per name."
        )
    loose = ~np.isfinite(np.diag(cov))
    if np.any(loose):
        listed = ", ".join(np.asarray(names)[loose])
        raise ValueError(
            f"prediction_band: {listed} ha{'ve' if loose.sum() > 1 else 's'} no finite "
            "standard error (the data do not determine them), so the band is "
            "unbounded: fix them (jaxmr.Fixed) and refit."
        )
    free, static, order = _named_leaves(model, names)
    experiments = experiment_list(experiments)
    if not experiments:
        return []
    cov = cov[np.ix_(order, order)]
    widths = per_experiment(smoothing, experiments, "smoothing")

    def run(indices: list[int], steps: StepPolicy) -> list[tuple]:
        # Every sample scored (`discard=0`): the band covers the discarded start as
        # well, where `predict` predicts too.
        data = pack(
            [experiments[k] for k in indices],
            steps,
            weighting="force",
            discard=0.0,
            smoothing=widths[indices],
            need_force=False,
        )
        # With no measured force (zeros, whatever the experiments hold) and unit
        # weights the residual is the predicted force itself, and its Jacobian (with
        # respect to the plain values, the covariance's coordinates) the force's
        # sensitivity to the parameters.
        data = eqx.tree_at(lambda d: d.force, data, jnp.zeros_like(data.force))
        force, J = jacobian_matrix(residuals, free, static, data, None)
        variance = np.einsum("ki,ij,kj->k", J, cov, J)
        std = np.sqrt(np.maximum(variance, 0.0))
        return list(zip(data.split(force), data.split(std)))

    # The steps `predict_all` takes, so that the band's centre is its prediction
    # where a simulation diverged with the policy's steps too.
    names = [experiment_name(e, k) for k, e in enumerate(experiments)]
    results = with_finer_steps(run, names, as_step_policy(integrator))
    z = NormalDist().inv_cdf(0.5 + level / 2)
    return [
        PredictionBand(name, np.asarray(e.t, float), f, s, f - z * s, f + z * s, level)
        for name, e, (f, s) in zip(names, experiments, results)
    ]


def _named_leaves(model, names: list[str]):
    """`model` split into the leaves `names` names (as JAX arrays: `free`) and the
    rest (`static`), and the position in `names` of each of `free`'s entries in
    order (the Jacobian's columns)."""
    where = {name: k for k, name in enumerate(names)}
    if len(where) != len(names):
        raise ValueError("`names` names a parameter twice.")
    mask, order = [], []
    paths, treedef = jax.tree_util.tree_flatten_with_path(model)
    for path, leaf in paths:
        name = jax.tree_util.keystr(path)
        numeric = isinstance(leaf, (float, int, np.ndarray, jax.Array)) and not (
            isinstance(leaf, bool)
        )
        own = (
            [name]
            if np.ndim(leaf) == 0
            else [f"{name}[{k}]" for k in range(np.size(leaf))]
        )
        named = [n in where for n in own] if numeric else [False]
        if any(named) and not all(named):
            raise ValueError(
                f"`names` names part of {name} (an array): name all of its entries "
                "or none."
            )
        mask.append(all(named))
        order += [where[n] for n in own] if all(named) else []
    missing = sorted(set(names) - {names[k] for k in order})
    if missing:
        raise ValueError(
            f"`names` names {', '.join(missing)}, which the model does not have "
            f"(a {type(model).__name__}): the covariance is another model's."
        )
    is_free = jax.tree.unflatten(treedef, mask)
    free, static = eqx.partition(model, is_free)
    free = jax.tree.map(lambda v: jnp.asarray(v, dtype=float), free)
    return free, static, np.asarray(order, dtype=int)
