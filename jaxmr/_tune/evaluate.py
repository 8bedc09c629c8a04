"""`evaluate`: every metric of every held-out road."""

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import numpy as np

from .._closed_loop import (
    Sampling,
    SystemSolution,
    loop_settings,
    simulate_system,
)
from .._control.base import AbstractController
from .._distribute import batch_mesh, pad, padded_size, spread, to_host
from .._integrate import FixedStep
from .._systems.base import AbstractSystem
from .batch import ROADS_EXAMPLE, batch_size
from .loss import comfort


def evaluate(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    metrics: dict[str, Callable[[SystemSolution], jax.Array]] | None = None,
    *,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    **deprecated,
) -> dict[str, np.ndarray]:
    """Every metric of every road (a batch, one leading axis), e.g. on held-out seeds.

    **Arguments:** as `tune` (`sampling`, `integrator`); `metrics` maps names to
    per-run functions of a `SystemSolution` (default: `{"comfort": comfort}`).

    **Returns:** `{name: array of one value per road}`.
    """
    sampling, integrator = loop_settings("evaluate", sampling, integrator, deprecated)
    metrics = {"comfort": comfort} if metrics is None else dict(metrics)
    # The roads spread over every device of every process (padded to a whole number
    # per device); every process gets every road's values.
    n = batch_size(roads, "roads", ROADS_EXAMPLE)
    mesh = batch_mesh()
    roads = spread(pad(roads, n, padded_size(n, mesh)), mesh)
    values = _evaluate(
        system,
        controller,
        roads,
        duration,
        tuple(metrics.items()),
        sampling,
        integrator,
    )
    return {name: to_host(value)[:n] for name, value in values.items()}


@eqx.filter_jit
def _evaluate(
    system, controller, roads, duration, metrics: Sequence, sampling, integrator
):
    def one(road):
        sol = simulate_system(
            system, road, controller, duration, sampling=sampling, integrator=integrator
        )
        return {name: fn(sol) for name, fn in metrics}

    return eqx.filter_vmap(one)(roads)
