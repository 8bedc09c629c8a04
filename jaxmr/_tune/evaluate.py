"""`evaluate`: every metric of every held-out road."""

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import numpy as np

from .._closed_loop import SystemSolution, simulate_system
from .._control.base import AbstractController
from .._systems.base import AbstractSystem
from .loss import comfort


def evaluate(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    metrics: dict[str, Callable[[SystemSolution], jax.Array]] | None = None,
    *,
    dt: float = 1e-3,
    substeps: int = 4,
    delay: int = 1,
) -> dict[str, np.ndarray]:
    """Every metric of every road (a batch, one leading axis), e.g. on held-out seeds.

    **Arguments:** as `tune`; `metrics` maps names to per-run functions of a
    `SystemSolution` (default: `{"comfort": comfort}`).

    **Returns:** `{name: array of one value per road}`.
    """
    metrics = {"comfort": comfort} if metrics is None else dict(metrics)
    return {
        name: np.asarray(value)
        for name, value in _evaluate(
            system,
            controller,
            roads,
            duration,
            tuple(metrics.items()),
            dt,
            substeps,
            delay,
        ).items()
    }


@eqx.filter_jit
def _evaluate(
    system, controller, roads, duration, metrics: Sequence, dt, substeps, delay
):
    def one(road):
        sol = simulate_system(
            system, road, controller, duration, dt=dt, substeps=substeps, delay=delay
        )
        return {name: fn(sol) for name, fn in metrics}

    return eqx.filter_vmap(one)(roads)
