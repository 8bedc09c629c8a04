"""`evaluate`: every metric of every held-out road."""

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._closed_loop import (
    Sampling,
    SystemSolution,
    loop_settings,
    simulate_system,
)
from .._control.base import AbstractController
from .._control.sensors import Sensors
from .._distribute import batch_mesh, pad, padded_size, spread, to_host
from .._integrate import FixedStep
from .._systems.base import AbstractSystem
from .batch import ROADS_EXAMPLE, batch_size
from .common import own_sampling, sensor_noise
from .loss import comfort, sensing


def evaluate(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    metrics: dict[str, Callable[[SystemSolution], jax.Array]] | None = None,
    *,
    sensors: Sensors | str = "oracle",
    sensor_key: jax.Array | None = None,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    **deprecated,
) -> dict[str, np.ndarray]:
    """Every metric of every road (a batch, one leading axis), e.g. on held-out seeds.

    **Arguments:** as `tune` (`sensors`, `sensor_key`, `sampling`, `integrator`);
    `metrics` maps names to per-run functions of a `SystemSolution` (default:
    `{"comfort": comfort}`). With `sensors`, road $i$ reads the noise of
    `jax.random.fold_in(sensor_key, i)` (`simulate_system(..., key=...)` with that
    key runs it alone): the same key gives every controller the same noise, so that
    comparisons are paired, and it is the draw `tune` judges on.

    **Returns:** `{name: array of one value per road}`.
    """
    sampling = own_sampling(controller, sampling, deprecated)
    sampling, integrator = loop_settings("evaluate", sampling, integrator, deprecated)
    noise = sensor_noise(sensors, sensor_key, "evaluate")
    metrics = {"comfort": comfort} if metrics is None else dict(metrics)
    # The roads, each with its index (its noise), spread over every device of every
    # process (padded to a whole number per device); every process gets every
    # road's values.
    n = batch_size(roads, "roads", ROADS_EXAMPLE)
    mesh = batch_mesh()
    runs = spread(pad((roads, jnp.arange(n)), n, padded_size(n, mesh)), mesh)
    values = _evaluate(
        system,
        controller,
        runs,
        duration,
        tuple(metrics.items()),
        sampling,
        integrator,
        noise,
    )
    return {name: to_host(value)[:n] for name, value in values.items()}


@eqx.filter_jit
def _evaluate(
    system, controller, runs, duration, metrics: Sequence, sampling, integrator, noise
):
    def one(run):
        road, index = run
        sol = simulate_system(
            system,
            road,
            controller,
            duration,
            sampling=sampling,
            integrator=integrator,
            **sensing(noise, index),
        )
        return {name: fn(sol) for name, fn in metrics}

    return eqx.filter_vmap(one)(runs)
