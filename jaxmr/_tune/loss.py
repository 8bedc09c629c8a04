"""The tuning loss: a closed-loop objective averaged over roads (and damper samples),
its NaN-safe gradient, and the population form the derivative-free searches use."""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from .._closed_loop import SystemSolution, simulate_system
from .._metrics import wk_rms
from .space import to_values


def comfort(solution: SystemSolution) -> jax.Array:
    """ISO 2631-1 Wk-weighted RMS body acceleration $a_w$ [m/s²] of one run."""
    return wk_rms(solution["body_acceleration"], solution.dt)


@dataclasses.dataclass(frozen=True)
class Setup:
    """Everything static about a tuning loss (hashable: a jit cache key)."""

    space: bool | tuple
    where: Callable
    objective: Callable
    duration: float
    dt: float
    substeps: int
    delay: int


def _one_run(u, system, controller, road, setup: Setup):
    system, controller = eqx.tree_at(
        setup.where, (system, controller), to_values(u, setup.space)
    )
    solution = simulate_system(
        system,
        road,
        controller,
        setup.duration,
        dt=setup.dt,
        substeps=setup.substeps,
        delay=setup.delay,
        throw=False,
        # Unrolled substeps: the reverse pass of tuning's gradient ran 1.5-2x faster
        # (`simulate_system`); past 8 the compile time is not worth it.
        unroll=min(setup.substeps, 8),
    )
    return setup.objective(solution)


def _over_runs(fn, system, samples, roads):
    """`fn(system, road)` for every road, and for every damper sample when `samples`
    (a batch of systems, one leading axis) is given: shape (roads,) or (samples,
    roads)."""

    def over_roads(one_system):
        return eqx.filter_vmap(lambda road: fn(one_system, road))(roads)

    if samples is None:
        return over_roads(system)
    return eqx.filter_vmap(over_roads)(samples)


def mean_or_inf(values, valid=None):
    """The mean over the runs (the `valid` ones: roads on the last axis), or inf."""
    if valid is None:
        valid = jnp.ones(values.shape[-1:], bool)
    valid = jnp.broadcast_to(valid, values.shape)
    # A run that failed (diverged, left the current range) makes the whole parameter
    # set unacceptable: the mean is inf, never a finite number that hides it.
    finite = jnp.all(jnp.isfinite(values) | ~valid)
    total = jnp.sum(jnp.where(valid, values, 0.0))
    return jnp.where(finite, total / jnp.sum(valid).astype(values.dtype), jnp.inf)


@eqx.filter_jit
def losses(u, pair, samples, batch, setup: Setup):
    """The objective of every run of a `road_batch`, shape (roads,) or (samples,
    roads), padding included, and the batch's mean (`mean_or_inf`)."""
    system, controller = pair
    roads, valid = batch
    values = _over_runs(
        lambda s, road: _one_run(u, s, controller, road, setup), system, samples, roads
    )
    return values, mean_or_inf(values, valid)


@eqx.filter_jit
def population_losses(us, pair, samples, batch, setup: Setup):
    """`mean_or_inf` of the runs of a `road_batch` for every candidate (the leading
    axis of each u)."""
    system, controller = pair
    roads, valid = batch

    def one(u):
        values = _over_runs(
            lambda s, road: _one_run(u, s, controller, road, setup),
            system,
            samples,
            roads,
        )
        return mean_or_inf(values, valid)

    return jax.vmap(one)(us)


@eqx.filter_jit
def loss_and_grad(u, pair, samples, batch, setup: Setup):
    """The mean objective and its gradient with respect to u, NaN-safe.

    Every run is differentiated on its own (under `vmap`): a run whose value or
    gradient is not finite (a diverged road) drops out of the gradient, which is the
    mean over the runs that succeeded, while the value becomes inf. Masking the value
    alone would not do: a `where` passes zero cotangent into the failed run, and zero
    times its infinite Jacobian is NaN in the gradient of every parameter.
    """
    system, controller = pair
    roads, valid = batch

    def one(s, road):
        return jax.value_and_grad(lambda u: _one_run(u, s, controller, road, setup))(u)

    values, grads = _over_runs(one, system, samples, roads)
    ok = jnp.isfinite(values) & jnp.broadcast_to(valid, values.shape)
    for g in grads:
        ok = ok & jnp.all(jnp.isfinite(g), axis=tuple(range(values.ndim, g.ndim)))
    count = jnp.maximum(jnp.sum(ok), 1).astype(values.dtype)

    def masked_mean(g):
        mask = ok.reshape(ok.shape + (1,) * (g.ndim - ok.ndim))
        return jnp.sum(jnp.where(mask, g, 0.0), axis=tuple(range(ok.ndim))) / count

    return mean_or_inf(values, valid), tuple(masked_mean(g) for g in grads), values
