"""Derivative-free baselines for `tune`: random search and CMA-ES, on the same loss."""

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .._closed_loop import Sampling, SystemSolution, loop_settings
from .._control.base import AbstractController
from .._control.sensors import Sensors
from .._distribute import to_host
from .._integrate import FixedStep
from .._systems.base import AbstractSystem
from .common import (
    chooses_steps,
    finite_min,
    own_sampling,
    prepare,
    printer,
    sensor_noise,
    tune_result,
)
from .loss import comfort, population_losses
from .result import TuneResult
from .space import as_space, per_leaf


def _prepare(who, simulations, *args, **options):
    runs, setup, pair, u0, batch = prepare(who, *args, **options)
    if not isinstance(simulations, int) or simulations < runs:
        raise ValueError(
            f"{who}: `simulations` must be an integer >= the runs of one evaluation "
            f"({runs}), got {simulations!r}."
        )
    return runs, setup, pair, u0, batch


def random_search(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    *,
    parameters: Callable,
    simulations: int,
    objective: Callable[[SystemSolution], jax.Array] = comfort,
    spread: float = 10.0,
    population: int = 8,
    log_space: bool | Sequence[bool] = True,
    bounds: Sequence[tuple[float, float] | None] | None = None,
    validation=None,
    samples: AbstractSystem | None = None,
    worst_share: float = 1.0,
    key: jax.Array | None = None,
    sensors: Sensors | str | None = None,
    sensor_key: jax.Array | None = None,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    progress: bool | Callable = False,
    **deprecated,
) -> TuneResult:
    """The simplest derivative-free baseline for `tune`: random parameter sets around
    the start (the start included), scored with the hard law on the same training
    roads, until `simulations` road simulations are spent; keeps the best.

    Candidates are uniform within a factor `spread` of the start in log space
    (clipped to `bounds` when given), or within ± `spread` of it with
    `log_space=False` (per parameter, when `log_space` gives one bool per
    parameter); `population` of them are simulated together under `vmap`.

    **Arguments:** as `tune` (`duration` [s] of each run; `worst_share`, `sensors`
    and `sensor_key` included: every candidate reads the same fixed noise, `tune`'s
    judging draw), plus
    `simulations` (the budget: give `tune`'s `TuneResult.simulations` for an
    equal-budget comparison), `spread`, `population`,
    `key` (the candidates' draw, not the noise).
    """
    who = "random_search"
    if not (np.isfinite(spread) and spread > 0):
        raise ValueError(f"{who}: `spread` must be > 0, got {spread!r}.")
    if log_space is True and spread <= 1:
        raise ValueError(
            f"{who}: `spread` is a factor in log space, so it must be > 1 (a factor "
            f"{spread!r} spans nothing around the start), got {spread!r}."
        )
    if (
        isinstance(population, bool)
        or not isinstance(population, int)
        or population < 1
    ):
        raise ValueError(
            f"{who}: `population` must be an integer >= 1, got {population!r}."
        )
    sampling = own_sampling(controller, sampling, deprecated)
    chosen = chooses_steps(integrator, deprecated)
    sampling, integrator = loop_settings(who, sampling, integrator, deprecated)
    noise = sensor_noise(sensors, sensor_key, who)
    as_space(log_space, bounds, who)  # checks the bounds
    # Candidates are drawn and clipped in log values (or values): no sigmoid here.
    runs, setup, pair, u0, batch = _prepare(
        who,
        simulations,
        system,
        controller,
        roads,
        samples,
        parameters,
        log_space,
        None,
        objective,
        duration,
        sampling,
        integrator,
        worst_share,
        chosen=chosen,
        noise=noise,
    )
    trials = simulations // runs
    flat0, unravel = ravel_pytree(u0)
    # Per leaf: a factor `spread` in log space, ± `spread` in values, and the bounds'
    # logarithms (inf where unbounded) to clip to.
    leaves = per_leaf(as_space(log_space, bounds, who), len(u0))
    if len(leaves) != len(u0):
        raise ValueError(
            f"{who}: `bounds` give {len(leaves)} entries, but `parameters` selected "
            f"{len(u0)} arrays: give one per array."
        )
    width, _ = ravel_pytree(
        tuple(
            jnp.full_like(u, spread if entry is False else np.log(spread))
            for u, entry in zip(u0, leaves, strict=True)
        )
    )
    key = jax.random.key(0) if key is None else key
    draws = flat0 + width * jax.random.uniform(
        key, (trials, flat0.size), flat0.dtype, -1.0, 1.0
    )
    draws = draws.at[0].set(flat0)
    bounded = [isinstance(entry, tuple) for entry in leaves]
    if any(bounded):
        lo, _ = ravel_pytree(
            tuple(
                jnp.full_like(u, np.log(e[0]) if b else -np.inf)
                for u, e, b in zip(u0, leaves, bounded, strict=True)
            )
        )
        hi, _ = ravel_pytree(
            tuple(
                jnp.full_like(u, np.log(e[1]) if b else np.inf)
                for u, e, b in zip(u0, leaves, bounded, strict=True)
            )
        )
        draws = jnp.clip(draws, lo, hi)
    report = printer(progress, "random search candidate")
    start = time.perf_counter()
    history, scores = [], []
    reason = f"budget of {trials * runs} simulations spent"
    # Every chunk has one size (the last padded with the start, scored but not
    # counted), so the population's loss compiles once.
    size = min(population, trials)
    padded = jnp.concatenate(
        [draws, jnp.broadcast_to(flat0, ((-trials) % size, flat0.size))]
    )
    try:
        for j in range(0, trials, size):
            us = jax.vmap(unravel)(padded[j : j + size])
            chunk = to_host(population_losses(us, pair, samples, batch, setup, noise))
            scores.extend(chunk[: trials - j])
            best = finite_min(scores)[1]
            history.extend([best] * len(chunk[: trials - j]))
            report(len(scores), best)
    except KeyboardInterrupt:
        if not scores:
            raise
        reason = f"interrupted after {len(scores)} candidates; the best is kept"
    k, best = finite_min(scores)
    return tune_result(
        setup,
        pair,
        unravel(draws[k]),
        loss=best,
        initial=float(scores[0]),
        history=history,
        samples=samples,
        validation=validation,
        noise=noise,
        simulations=len(scores) * runs,
        start=start,
        reason=reason,
        who=who,
        chosen=chosen,
    )


@functools.lru_cache(maxsize=16)
def _cma_strategy(cma_class, size: int, dimension: int, dtype: str):
    """One evosax CMA-ES strategy per (population, dimension, dtype). evosax jits
    `init`, `ask` and `tell` with the strategy as a static argument (hashed by
    identity), so a new strategy per call compiled all three again on every
    `cma_es` call (2–7 s each): a reused one compiles once. The strategy keeps only
    the solution's structure, not its values."""
    return cma_class(population_size=size, solution=jnp.zeros((dimension,), dtype))


def cma_es(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    *,
    parameters: Callable,
    simulations: int,
    objective: Callable[[SystemSolution], jax.Array] = comfort,
    sigma: float = 0.5,
    population: int | None = None,
    target: float | None = None,
    log_space: bool | Sequence[bool] = True,
    bounds: Sequence[tuple[float, float] | None] | None = None,
    validation=None,
    samples: AbstractSystem | None = None,
    worst_share: float = 1.0,
    key: jax.Array | None = None,
    sensors: Sensors | str | None = None,
    sensor_key: jax.Array | None = None,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    progress: bool | Callable = False,
    **deprecated,
) -> TuneResult:
    """CMA-ES (Hansen's covariance matrix adaptation evolution strategy, as
    implemented by `evosax`), the strong derivative-free baseline for `tune`: each
    generation's candidates are scored with the hard law on the same training roads,
    simulated together under `vmap`, until `simulations` road simulations are spent
    or the best loss reaches `target`.

    Works in `tune`'s variables: log values (or values with `log_space=False`, or the
    sigmoid variables of `bounds`), started at the given parameters with step size
    `sigma` in those variables (0.5 in log space: a factor 1.6).

    **Arguments:** as `tune` (`duration` [s] of each run; `worst_share`, `sensors`
    and `sensor_key` included: every candidate reads the same fixed noise, `tune`'s
    judging draw, so that a
    generation is ranked on paired runs), plus `simulations` (the budget), `sigma`,
    `population` (default: CMA-ES's own 4 + 3 ln(dimension)), `target` (stop once the
    best training loss is at or below it: how many simulations a given loss costs),
    `key` (the strategy's draws, not the noise).

    Needs the optional dependency `evosax` (`pip install "jaxmr[search]"`).
    """
    try:
        from evosax.algorithms import CMA_ES
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise ImportError(
            'cma_es needs evosax: pip install "jaxmr[search]" (or evosax).'
        ) from error
    who = "cma_es"
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(
            f"{who}: `sigma` must be > 0 (the search's step size), got {sigma!r}."
        )
    if population is not None and (
        isinstance(population, bool)
        or not isinstance(population, int)
        or population < 2
    ):
        raise ValueError(
            f"{who}: `population` must be an integer >= 2 (or None: CMA-ES's own "
            f"4 + 3 ln(dimension)), got {population!r}."
        )
    sampling = own_sampling(controller, sampling, deprecated)
    chosen = chooses_steps(integrator, deprecated)
    sampling, integrator = loop_settings(who, sampling, integrator, deprecated)
    noise = sensor_noise(sensors, sensor_key, who)
    runs, setup, pair, u0, batch = _prepare(
        who,
        simulations,
        system,
        controller,
        roads,
        samples,
        parameters,
        log_space,
        bounds,
        objective,
        duration,
        sampling,
        integrator,
        worst_share,
        chosen=chosen,
        noise=noise,
    )
    flat0, unravel = ravel_pytree(u0)
    size = population or 4 + int(3 * np.log(flat0.size))
    if (1 + size) * runs > simulations:
        # The start is simulated first: a budget without room for one generation
        # after it returned the start unchanged.
        raise ValueError(
            f"cma_es: the start and one generation of {size} candidates on {runs} runs "
            f"need {(1 + size) * runs} simulations, more than the budget of "
            f"{simulations}."
        )
    # evosax relies on numpy-style dtype promotion (float times bool): give it that
    # whatever the user's `jax_numpy_dtype_promotion` setting.
    standard = functools.partial(jax.numpy_dtype_promotion, "standard")
    with standard():
        strategy = _cma_strategy(CMA_ES, size, flat0.size, str(flat0.dtype))
        params = dataclasses.replace(
            strategy.default_params, std_init=jnp.asarray(sigma, flat0.dtype)
        )
        key = jax.random.key(0) if key is None else key
        key, init_key = jax.random.split(key)
        state = strategy.init(init_key, flat0, params)
    # `init` leaves some of the state weakly typed and `tell` does not: without
    # this, `ask` and `tell` each compile twice (about 1 s of a first `cma_es`).
    state = jax.tree.map(lambda x: jnp.asarray(x, x.dtype), state)
    report = printer(progress, "cma_es generation")
    start = time.perf_counter()
    initial = float(
        to_host(
            population_losses(
                jax.vmap(unravel)(flat0[None]), pair, samples, batch, setup, noise
            )
        )[0]
    )
    spent = runs
    best_flat, best, history = flat0, initial, [initial]
    reason = f"budget of {simulations} simulations spent"
    try:
        while spent + size * runs <= simulations:
            if target is not None and best <= target:
                reason = f"reached the target loss {target:.6g}"
                break
            # An unpacked Array is Any, which pyright reads as `key`'s declared type.
            key, ask_key, tell_key = jax.random.split(key, 3)  # pyright: ignore[reportArgumentType]
            with standard():
                candidates, state = strategy.ask(ask_key, state, params)
            scores = to_host(
                population_losses(
                    jax.vmap(unravel)(candidates), pair, samples, batch, setup, noise
                )
            )
            spent += size * runs
            k, value = finite_min(scores)
            if value < best:
                best_flat, best = candidates[k], value
            # evosax ranks the scores: a failed candidate is simply the worst.
            ranked = jnp.where(
                jnp.isfinite(scores), scores, jnp.finfo(scores.dtype).max
            )
            with standard():
                state, _ = strategy.tell(tell_key, candidates, ranked, state, params)
            history.append(best)
            report(len(history) - 1, best)
    except KeyboardInterrupt:
        reason = f"interrupted after {len(history) - 1} generations; the best is kept"
    return tune_result(
        setup,
        pair,
        unravel(best_flat),
        loss=best,
        initial=initial,
        history=history,
        samples=samples,
        validation=validation,
        noise=noise,
        simulations=spent,
        start=start,
        reason=reason,
        who=who,
        chosen=chosen,
    )
