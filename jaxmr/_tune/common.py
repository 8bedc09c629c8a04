"""Input checks and helpers shared by every tuner."""

import time
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import numpy as np

from .._closed_loop import Sampling, check_sensors, step_advice, steps_for_runs
from .._control.base import AbstractController
from .._control.observer_based import ObserverBasedController
from .._control.sensors import Sensors
from .._control.smooth import with_temperature
from .._distribute import to_host
from .._integrate import FixedStep
from .._systems.base import AbstractSystem
from .batch import batch_size, road_batch, road_count
from .loss import Setup, losses, sensing
from .result import TuneResult
from .space import as_space, as_tuple_where, from_values, initial_values, to_values


def check_inputs(system, controller, roads, samples) -> int:
    """The number of runs one evaluation of the loss simulates."""
    if not isinstance(system, AbstractSystem):
        raise TypeError(
            f"`system` must be a jaxmr system, got {type(system).__name__}."
        )
    if not isinstance(controller, AbstractController):
        raise TypeError(
            f"`controller` must be a jaxmr controller, got {type(controller).__name__}."
        )
    runs = road_count(roads)
    if samples is not None:
        if not isinstance(samples, AbstractSystem):
            raise TypeError(
                "`samples` must be a batch of systems (one leading axis), e.g. from "
                f"a fit's `FitResult.sample` placed in the system, got {type(samples).__name__}."
            )
        runs *= batch_size(samples, "samples", "`FitResult.sample(...)` (in a system)")
    return runs


def prepare(
    who: str,
    system,
    controller,
    roads,
    samples,
    parameters,
    log_space: bool | Sequence[bool],
    bounds,
    objective,
    duration,
    sampling: Sampling,
    integrator: FixedStep,
    worst_share: float = 1.0,
    *,
    chosen: bool = False,
    noise=None,
):
    """Every tuner's start: the checked inputs, the runs one evaluation simulates, the
    static `Setup` of the loss, the pair, the optimiser's starting variables and the
    `road_batch` of the roads. `sampling` and `integrator` come checked
    (`loop_settings`); with `chosen` the substeps are chosen for the starting pair
    (`choose_integrator`, its runs read through `noise`)."""
    runs = check_inputs(system, controller, roads, samples)
    share = check_worst_share(worst_share, samples, who)
    if not callable(parameters):
        raise TypeError(
            f"{who}: `parameters` must be a function of the (system, controller) pair "
            "selecting the tuned leaves, e.g. `lambda pair: (pair[1].c_sky,)`; got "
            f"{parameters!r}."
        )
    where = as_tuple_where(parameters)
    space = as_space(log_space, bounds, who)
    # Every tuner judges, keeps and returns the hard law (T = 0), whatever temperature
    # the controller was handed with: a relaxed law is a device for the gradient, not
    # what runs on the car.
    pair = (system, with_temperature(controller, 0.0))
    u0 = from_values(initial_values(pair, where, space, who), space, who)
    integrator = choose_integrator(
        who, integrator, chosen, pair, samples, roads, duration, sampling, noise
    )
    setup = Setup(space, where, objective, duration, sampling, integrator, share)
    return runs, setup, pair, u0, road_batch(roads)


def chooses_steps(integrator, deprecated: dict) -> bool:
    """Whether a tuner chooses its RK4 substeps (`choose_integrator`): no
    `integrator` given, nor the deprecated `substeps`."""
    return integrator is None and "substeps" not in deprecated


def _item(batch, k: int):
    """Element `k` of a batch (every array's leading axis)."""
    return jax.tree.map(lambda x: x[k] if eqx.is_array(x) else x, batch)


def choose_integrator(
    who: str,
    integrator: FixedStep,
    chosen: bool,
    pair,
    samples,
    roads,
    duration: float,
    sampling: Sampling,
    noise,
) -> FixedStep:
    """The RK4 substeps per sample of a tuner's runs: `integrator` as given, or
    (`chosen`) those `simulate_system` with no `integrator` chooses from the
    damper's stiffness, for the stiffest run of the starting `pair` over the
    `roads` (and every damper sample): `FixedStep()` where the damper is not stiff
    (the runs then as they always were). The runs of a batch go under `vmap`,
    where no run can choose for itself."""
    if not chosen:
        return integrator
    system, controller = pair
    n = road_count(roads)
    systems = [("", system)]
    if samples is not None:
        count = batch_size(samples, "samples", "`FitResult.sample(...)` (in a system)")
        systems = [(f"sample {s}, ", _item(samples, s)) for s in range(count)]
    runs = []
    for label, one in systems:
        for j in range(n):
            sensed = sensing(noise, j)
            runs.append(
                (
                    f"{label}road {j}",
                    one,
                    _item(roads, j),
                    controller,
                    sensed.get("sensors"),
                    sensed.get("key"),
                )
            )
    return steps_for_runs(who, runs, duration, sampling)


def own_sampling(controller, sampling, deprecated: dict):
    """`sampling`, or an `ObserverBasedController`'s own when none is given (its
    filters step at it; `simulate_system` refuses another)."""
    if (
        sampling is None
        and isinstance(controller, ObserverBasedController)
        and not {"dt", "delay"} & set(deprecated)
    ):
        return controller.sampling
    return sampling


def sensor_noise(sensors, sensor_key, who: str) -> tuple[Sensors, Any] | str | None:
    """What the losses' runs read (`loss.sensing`), `sensors` checked as
    `simulate_system` checks them (`check_sensors`): `None` (perfect readings, no
    device), `"oracle"` (perfect information) or `(sensors, sensor_key)`."""
    sensors = check_sensors(sensors, sensor_key, who, "sensor_key")
    return (sensors, sensor_key) if isinstance(sensors, Sensors) else sensors


def check_worst_share(worst_share, samples, who: str) -> float:
    """`worst_share` as a float in (0, 1], refused without `samples` unless 1."""
    if isinstance(worst_share, bool) or not isinstance(worst_share, (int, float)):
        raise TypeError(
            f"{who}: `worst_share` must be a number in (0, 1], got "
            f"{type(worst_share).__name__}."
        )
    share = float(worst_share)
    if not 0 < share <= 1:
        raise ValueError(
            f"{who}: `worst_share` must lie in (0, 1] (1: the mean over the damper "
            f"samples; 1/S: the worst of S samples), got {worst_share}."
        )
    if share < 1 and samples is None:
        raise ValueError(
            f"{who}: `worst_share` < 1 weighs the worst damper samples, so it needs "
            "`samples=` (a batch of systems, e.g. `FitResult.sample` placed in the system)."
        )
    return share


def set_temperature(controller, temperature):
    """The controller with every law's relaxation at `temperature` (None: as it is),
    wrapped laws included (`with_temperature`)."""
    if temperature is None:
        return controller
    return with_temperature(controller, float(temperature))


def held_out_loss(u, pair, samples, validation, setup: Setup, noise) -> float | None:
    """The hard pair's mean objective on the validation roads (their noise drawn as
    `evaluate` draws it)."""
    if validation is None:
        return None
    batch = road_batch(validation)
    return float(to_host(losses(u, pair, samples, batch, setup, noise)[1]))


def printer(progress, who: str):
    if callable(progress):
        return progress
    if not progress:
        return lambda step, loss: None

    def report(step, loss):
        print(f"  {who} {step:4d}: best loss {loss:.6g}", flush=True)

    return report


def finite_min(values) -> tuple[int, float]:
    values = np.asarray(values, dtype=float)
    values = np.where(np.isfinite(values), values, np.inf)
    k = int(np.argmin(values))
    return k, float(values[k])


def tune_result(
    setup: Setup,
    pair,
    best_u,
    *,
    loss,
    initial,
    history,
    samples,
    validation,
    noise=None,
    simulations: int,
    start: float,
    reason: str,
    who: str,
    chosen: bool,
) -> TuneResult:
    """A `TuneResult` for the best variables found (the hard pair); `ValueError`,
    saying what to change, when every parameter set tried failed (`who` the tuner,
    `chosen` whether it chose its substeps)."""
    if not np.isfinite(loss) and not reason.startswith("interrupted"):
        raise ValueError(_failed(who, setup, chosen))
    seconds = time.perf_counter() - start
    values = to_values(best_u, setup.space)
    tuned_system, tuned = eqx.tree_at(setup.where, pair, values)
    return TuneResult(
        system=tuned_system,
        controller=tuned,
        values=values,
        loss=float(loss),
        initial_loss=float(initial),
        held_out_loss=held_out_loss(best_u, pair, samples, validation, setup, noise),
        history=tuple(history),
        simulations=simulations,
        seconds=seconds,
        reason=reason,
        integrator=setup.integrator,
    )


def _failed(who: str, setup: Setup, chosen: bool) -> str:
    """What to change when no parameter set tried gave a finite loss."""
    if chosen:
        substeps, dt = setup.integrator.substeps, setup.sampling.dt
        return (
            f"{who}: every parameter set tried gave a non-finite loss, although the "
            f"starting parameters' runs were finite at the {substeps} RK4 substeps "
            f"per {dt:g} s sample chosen from the damper's stiffness: `objective` "
            "is not finite on them (it must give a finite number for every run)."
        )
    return (
        f"{who}: every parameter set tried gave a non-finite loss (a diverged run, "
        f"or an `objective` that is not finite): "
        f"{step_advice(setup.sampling, setup.integrator, False, who)}."
    )
