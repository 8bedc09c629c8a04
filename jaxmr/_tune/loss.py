"""The tuning loss: a closed-loop objective averaged over roads (and damper samples),
its NaN-safe gradient, and the population form the derivative-free searches use."""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from .._closed_loop import Sampling, SystemSolution, simulate_system
from .._integrate import FixedStep
from .._metrics import wk_rms
from .space import to_values


def comfort(solution: SystemSolution) -> jax.Array:
    """ISO 2631-1 Wk-weighted RMS body acceleration $a_w$ [m/s²] of one run."""
    if not isinstance(solution, SystemSolution):
        raise TypeError(
            "comfort takes a closed-loop run of a vehicle (`simulate_system`), which "
            f"has a body acceleration; got a {type(solution).__name__}. For a "
            "measured or simulated acceleration [m/s²], use jaxmr.metrics.wk_rms."
        )
    return wk_rms(solution["body_acceleration"], solution.dt)


@dataclasses.dataclass(frozen=True)
class Setup:
    """Everything static about a tuning loss (hashable: a jit cache key)."""

    space: bool | tuple
    where: Callable
    objective: Callable
    duration: float
    sampling: Sampling
    integrator: FixedStep
    # The share of damper samples whose mean the loss is (1: every sample; see
    # `worst_share_weights`).
    worst_share: float = 1.0


def sensing(noise, index) -> dict:
    """`simulate_system`'s keywords for road `index` of a batch read through
    `noise = (sensors, key)`: the road's noise from `jax.random.fold_in(key, index)`;
    for perfect readings, `noise` None or `"oracle"` (`common.sensor_noise`), that
    value as `sensors`."""
    if not isinstance(noise, tuple):
        return {"sensors": noise}
    sensors, key = noise
    return {"sensors": sensors, "key": jax.random.fold_in(key, index)}


def _one_run(u, system, controller, run, setup: Setup, noise=None):
    """The objective of one road `run = (road, index)`, read through `noise`
    (`sensing`)."""
    road, index = run
    system, controller = eqx.tree_at(
        setup.where, (system, controller), to_values(u, setup.space)
    )
    solution = simulate_system(
        system,
        road,
        controller,
        setup.duration,
        sampling=setup.sampling,
        integrator=setup.integrator,
        throw=False,
        # Substeps not unrolled (`simulate_system`'s default): with the CPU flags of
        # `configure_cpu`, unrolling 4 compiled the gradient 1.7-2.3x longer and ran
        # it no faster (skyhook, 12 roads of 3 s: 0.14 s against 0.12 s) or 4x
        # slower (an observer-based controller on realistic sensors).
        **sensing(noise, index),
    )
    return setup.objective(solution)


def _over_runs(fn, system, samples, roads):
    """`fn(system, run)` for every run `(road, index)` of `roads`, and for every damper sample when `samples`
    (a batch of systems, one leading axis) is given: shape (roads,) or (samples,
    roads)."""

    def over_roads(one_system):
        return eqx.filter_vmap(lambda road: fn(one_system, road))(roads)

    if samples is None:
        return over_roads(system)
    return eqx.filter_vmap(over_roads)(samples)


def worst_share_weights(per_sample, share: float):
    r"""Weights $w_s$ (summing to 1) that make $\sum_s w_s J_s$ the mean of the worst
    `share` of the samples' losses $J_s$: the conditional value at risk (CVaR) of the
    uniform distribution over the samples. With $S$ samples and $k = \text{share}\,S$,
    the $j$-th worst ($j = 0, 1, \ldots$) weighs $\mathrm{clip}(k - j, 0, 1)/k$: `share`
    1 is the mean, $1/S$ the worst sample alone, and a fractional $k$ weighs the last
    sample it reaches in part. The ranking is held constant in the gradient (the CVaR's
    gradient wherever no two samples tie)."""
    count = per_sample.shape[0]
    k = share * count
    rank = jnp.argsort(jnp.argsort(-jax.lax.stop_gradient(per_sample)))
    return jnp.clip(k - rank.astype(per_sample.dtype), 0.0, 1.0) / k


def mean_or_inf(values, valid=None, share: float = 1.0):
    """The mean over the runs (the `valid` ones: roads on the last axis), or inf.

    For samples x roads with `share` < 1: the mean of the worst `share` of the
    samples' means over their roads (`worst_share_weights`)."""
    if valid is None:
        valid = jnp.ones(values.shape[-1:], bool)
    valid = jnp.broadcast_to(valid, values.shape)
    # A run that failed (diverged, left the current range) makes the whole parameter
    # set unacceptable: the mean is inf, never a finite number that hides it.
    finite = jnp.all(jnp.isfinite(values) | ~valid)
    if values.ndim == 2 and share < 1:
        per_sample = jnp.sum(jnp.where(valid, values, 0.0), axis=1) / jnp.sum(
            valid, axis=1
        ).astype(values.dtype)
        safe = jnp.where(jnp.isfinite(per_sample), per_sample, 0.0)
        value = jnp.sum(worst_share_weights(safe, share) * safe)
        return jnp.where(finite, value, jnp.inf)
    total = jnp.sum(jnp.where(valid, values, 0.0))
    return jnp.where(finite, total / jnp.sum(valid).astype(values.dtype), jnp.inf)


@eqx.filter_jit
def losses(u, pair, samples, batch, setup: Setup, noise=None):
    """The objective of every run of a `road_batch`, shape (roads,) or (samples,
    roads), padding included, and the batch's mean (`mean_or_inf`); `noise`: what
    the controller reads (`sensing`)."""
    system, controller = pair
    roads, valid = batch
    values = _over_runs(
        lambda s, road: _one_run(u, s, controller, road, setup, noise),
        system,
        samples,
        roads,
    )
    return values, mean_or_inf(values, valid, setup.worst_share)


@eqx.filter_jit
def population_losses(us, pair, samples, batch, setup: Setup, noise=None):
    """`mean_or_inf` of the runs of a `road_batch` for every candidate (the leading
    axis of each u), every candidate on the same `noise` (as `losses`)."""
    system, controller = pair
    roads, valid = batch

    def one(u):
        values = _over_runs(
            lambda s, road: _one_run(u, s, controller, road, setup, noise),
            system,
            samples,
            roads,
        )
        return mean_or_inf(values, valid, setup.worst_share)

    return jax.vmap(one)(us)


@eqx.filter_jit
def loss_and_grad(u, pair, samples, batch, setup: Setup, noise=None):
    """The mean objective and its gradient with respect to u, NaN-safe (`noise` as
    in `losses`: the gradient is taken through the sampled noise).

    Every run is differentiated on its own (under `vmap`): a run whose value or
    gradient is not finite (a diverged road) drops out of the gradient, which is the
    mean over the runs that succeeded, while the value becomes inf. Masking the value
    alone would not do: a `where` passes zero cotangent into the failed run, and zero
    times its infinite Jacobian is NaN in the gradient of every parameter.
    """
    system, controller = pair
    roads, valid = batch

    def one(s, road):
        return jax.value_and_grad(
            lambda u: _one_run(u, s, controller, road, setup, noise)
        )(u)

    values, grads = _over_runs(one, system, samples, roads)
    ok = jnp.isfinite(values) & jnp.broadcast_to(valid, values.shape)
    for g in grads:
        ok = ok & jnp.all(jnp.isfinite(g), axis=tuple(range(values.ndim, g.ndim)))
    value = mean_or_inf(values, valid, setup.worst_share)
    if values.ndim == 2 and setup.worst_share < 1:
        # Each sample's gradient is the mean over its own successful roads; the
        # samples are then weighted as the value weighs them (ranked by their mean
        # over the successful roads, a sample with a failed road counted worst).
        count = jnp.maximum(jnp.sum(ok, axis=1), 1).astype(values.dtype)
        per_sample = jnp.sum(jnp.where(ok, values, 0.0), axis=1) / count
        failed = jnp.any(~ok & jnp.broadcast_to(valid, values.shape), axis=1)
        ranked = jnp.where(failed, jnp.inf, per_sample)
        weight = worst_share_weights(ranked, setup.worst_share) / count

        def weighted(g):
            mask = ok.reshape(ok.shape + (1,) * (g.ndim - ok.ndim))
            # g: (samples, roads, *parameter shape)
            w = weight.reshape(weight.shape + (1,) * (g.ndim - 2))
            return jnp.sum(w * jnp.sum(jnp.where(mask, g, 0.0), axis=1), axis=0)

        return value, tuple(weighted(g) for g in grads), values
    count = jnp.maximum(jnp.sum(ok), 1).astype(values.dtype)

    def masked_mean(g):
        mask = ok.reshape(ok.shape + (1,) * (g.ndim - ok.ndim))
        return jnp.sum(jnp.where(mask, g, 0.0), axis=tuple(range(ok.ndim))) / count

    return value, tuple(masked_mean(g) for g in grads), values
