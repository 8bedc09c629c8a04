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
    step_advice,
)
from .._control.base import AbstractController
from .._control.sensors import Sensors
from .._distribute import batch_mesh, pad, padded_size, spread, to_host
from .._integrate import FixedStep
from .._solution import RESULTS
from .._systems.base import AbstractSystem
from .batch import ROADS_EXAMPLE, batch_size
from .common import choose_integrator, chooses_steps, own_sampling, sensor_noise
from .loss import comfort, sensing


def evaluate(
    system: AbstractSystem,
    controller: AbstractController,
    roads,
    duration: float,
    metrics: dict[str, Callable[[SystemSolution], jax.Array]] | None = None,
    *,
    sensors: Sensors | str | None = None,
    sensor_key: jax.Array | None = None,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    **deprecated,
) -> dict[str, np.ndarray]:
    """Every metric of every road (a batch, one leading axis), e.g. on held-out seeds.

    **Arguments:** as `tune` (`sensors`, `sensor_key`, `sampling`, `integrator`:
    with none given, the substeps are chosen from the damper's stiffness on these
    roads, as `tune` chooses them; give a `TuneResult.integrator` to run a tuned
    pair at its tuning's steps); `metrics` maps names to per-run functions of a
    `SystemSolution` (default: `{"comfort": comfort}`). With `sensors`, road $i$ reads the noise of
    `jax.random.fold_in(sensor_key, i)` (`simulate_system(..., key=...)` with that
    key runs it alone): the same key gives every controller the same noise, so that
    comparisons are paired, and it is the draw `tune` judges on.

    **Returns:** `{name: array of one value per road}`.
    """
    sampling = own_sampling(controller, sampling, deprecated)
    chosen = chooses_steps(integrator, deprecated)
    sampling, integrator = loop_settings("evaluate", sampling, integrator, deprecated)
    noise = sensor_noise(sensors, sensor_key, "evaluate")
    metrics = {"comfort": comfort} if metrics is None else dict(metrics)
    integrator = choose_integrator(
        "evaluate", integrator, chosen, (system, controller), None, roads, duration,
        sampling, noise,
    )  # fmt: skip
    # The roads, each with its index (its noise), spread over every device of every
    # process (padded to a whole number per device); every process gets every
    # road's values.
    n = batch_size(roads, "roads", ROADS_EXAMPLE)
    mesh = batch_mesh()
    runs = spread(pad((roads, jnp.arange(n)), n, padded_size(n, mesh)), mesh)
    values, result = _evaluate(
        system,
        controller,
        runs,
        duration,
        tuple(metrics.items()),
        sampling,
        integrator,
        noise,
    )
    result = jax.tree.map(lambda code: jnp.asarray(to_host(code)[:n]), result)
    failed = np.flatnonzero(~np.asarray(result == RESULTS.successful))
    if failed.size:
        k = int(failed[0])
        first = jax.tree.map(lambda code: code[k], result)
        if bool(first == RESULTS.nonfinite):
            raise eqx.EquinoxRuntimeError(
                f"evaluate: the run on road {k} diverged (inf or nan): "
                f"{step_advice(sampling, integrator, chosen, 'evaluate')}."
            )
        # Any other failure (a command outside the controller's range) raises its
        # own message, as the run would alone.
        first.error_if(jnp.zeros(()), jnp.asarray(True))
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
            throw=False,  # `evaluate` raises, saying what to change
            **sensing(noise, index),
        )
        return {name: fn(sol) for name, fn in metrics}, sol.result

    return eqx.filter_vmap(one)(runs)
