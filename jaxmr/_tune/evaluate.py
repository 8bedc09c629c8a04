"""`evaluate`: every metric of every held-out road."""

from collections.abc import Callable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._closed_loop import (
    Sampling,
    SystemSolution,
    _damper_stiffness,
    choose_substeps,
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
from .batch import road_count
from .common import chooses_steps, own_sampling, sensor_noise
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

    **Arguments:** as `tune` (`duration` [s] of each run; `sensors`, `sensor_key`, `sampling`, `integrator`:
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
    if metrics is not None and not isinstance(metrics, Mapping):
        raise TypeError(
            "evaluate: `metrics` must map names to functions of a solution, e.g. "
            f"{{'comfort': jaxmr.metrics.comfort}}, got {type(metrics).__name__}."
        )
    metrics = {"comfort": comfort} if metrics is None else dict(metrics)
    # The roads, each with its index (its noise), spread over every device of every
    # process (padded to a whole number per device); every process gets every
    # road's values.
    n = road_count(roads)
    mesh = batch_mesh()
    runs = spread(pad((roads, jnp.arange(n)), n, padded_size(n, mesh)), mesh)

    def run(integrator):
        out = _evaluate(
            system,
            controller,
            runs,
            duration,
            tuple(metrics.items()),
            sampling,
            integrator,
            noise,
            chosen,
        )
        return jax.tree.map(lambda a: np.asarray(to_host(a))[:n], out)

    if chosen:
        # The substeps `simulate_system` with no `integrator` chooses, for the
        # stiffest road, from the batch's own runs (read off the vmapped runs
        # rather than each road run again alone first).
        values, result, seen = choose_substeps(
            run,
            lambda out: bool(np.any(out[1] == RESULTS.nonfinite)),
            lambda out: float(np.max(out[2]["stiffness"], initial=0.0)),
            sampling.dt,
            integrator,
            run(integrator),
        )[0]
        fitted_range = system.damper.hysteresis.fitted_range
        if fitted_range is not None:
            fitted_range.warn(
                "evaluate",
                np.ravel(seen["damper_displacement"]),
                np.ravel(seen["damper_velocity"]),
                np.ravel(seen["current"]),
            )
    else:
        values, result, _ = run(integrator)
    failed = np.flatnonzero(~np.asarray(result == RESULTS.successful))
    if failed.size:
        k = int(failed[0])
        first = jax.tree.map(lambda code: jnp.asarray(code[k]), result)
        if bool(first == RESULTS.nonfinite):
            raise eqx.EquinoxRuntimeError(
                f"evaluate: the run on road {k} diverged (inf or nan): "
                f"{step_advice(sampling, integrator, chosen, 'evaluate')}."
            )
        # Any other failure (a command outside the controller's range) raises its
        # own message, as the run would alone.
        first.error_if(jnp.zeros(()), jnp.asarray(True))
    return values


@eqx.filter_jit
def _evaluate(
    system,
    controller,
    runs,
    duration,
    metrics: Sequence,
    sampling,
    integrator,
    noise,
    steps: bool,
):
    """Every metric of every run, the runs' results and (`steps`, when the
    substeps are being chosen) what choosing them reads: each run's damper
    stiffness [1/s] and the extremes of the damper's motion and input (for the
    fitted-range warning)."""

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
        seen = {}
        if steps:
            seen["stiffness"] = _damper_stiffness(system, road, sol)
            for name, value in (
                ("damper_displacement", sol.outputs["damper_displacement"]),
                ("damper_velocity", sol.outputs["damper_velocity"]),
                ("current", sol.current),
            ):
                # The extremes of the finite samples (a diverged run's tail is nan).
                seen[name] = jnp.stack([jnp.nanmin(value), jnp.nanmax(value)])
        return {name: fn(sol) for name, fn in metrics}, sol.result, seen

    return eqx.filter_vmap(one)(runs)
