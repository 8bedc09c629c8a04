"""What an exported controller reads: its measurements, in the order of the exported
function's inputs, and the readings its law may read."""

import dataclasses
from collections.abc import Sequence

from .._control import ObserverBasedController, Sensors
from .._control.sensors import ESTIMATOR_READS
from .._control.state_space import POSITIONS
from .syntax import check_identifier

# The quarter car's realistic sensors (`realistic_sensors(QuarterCar)`), the default
# with an estimator, in their `Sensors.names` order (sorted), the order a user lays
# out `SystemSolution.measured`'s readings in (another default order had fed the
# exported controller a deflection as an acceleration without a word).
CAR = ("body_acceleration", "damper_displacement", "wheel_acceleration")
ESTIMATES = (
    "body_velocity",
    "wheel_velocity",
    "damper_velocity",
    "damper_displacement",
    "body_acceleration",
)


@dataclasses.dataclass(frozen=True)
class Plan:
    """`inputs`: the measurements, in order; `readings`: every name the law may read
    (measurements, estimates and the observer's force), sorted."""

    inputs: tuple[str, ...]
    readings: tuple[str, ...]


def measurement_names(controller: ObserverBasedController, measurements) -> tuple:
    """The measurement names, checked: `measurements` (names or a `Sensors` set) or
    the default (`export_c`)."""
    if isinstance(measurements, Sensors):
        names = tuple(measurements.names)
    elif measurements is None:
        if controller.estimator is not None:
            names = CAR
        else:
            # A law says what it reads: its `features`, or the clock alone for a law
            # that runs open loop (`reads_time`, e.g. `CurrentSchedule`); any other
            # reads the velocities the common laws use.
            law_reads = getattr(controller.law, "features", None) or (
                ("time",)
                if getattr(controller.law, "reads_time", False)
                else ("body_velocity", "damper_velocity")
            )
            names = tuple(law_reads)
            if controller.observer is not None:
                names += tuple(
                    n
                    for n in ("damper_displacement", "damper_velocity")
                    if n not in names
                )
    elif isinstance(measurements, Sequence) and not isinstance(measurements, str):
        names = tuple(measurements)
    else:
        raise TypeError(
            "`measurements` must be a sequence of measurement names or a "
            f"jaxmr.Sensors set, got {measurements!r}."
        )
    for n in names:
        check_identifier(n, "a measurement name")
    if len(set(names)) != len(names):
        raise ValueError(f"`measurements` names one more than once: {names}.")
    return names


def plan(controller: ObserverBasedController, measurements) -> Plan:
    """The `Plan` of `controller` on `measurements`; `ValueError` where the
    estimator or the observer lacks a measurement it needs."""
    inputs = measurement_names(controller, measurements)
    readings = set(inputs)
    if controller.oracle:
        raise ValueError(
            "export: this controller reads the simulated device's true state "
            "(`oracle=True`), which no real controller has; export one with a "
            "`DamperObserver`."
        )
    if controller.estimator is not None:
        missing = [n for n in ESTIMATOR_READS if n not in inputs]
        if missing:
            raise ValueError(
                f"export: the VelocityEstimator needs the measurements {missing}; "
                f"`measurements` has {inputs}."
            )
        readings |= set(ESTIMATES)
        if controller.estimates_positions:
            readings |= set(POSITIONS)
        if "wheel_acceleration" in inputs:
            readings.add("wheel_acceleration")
    if controller.observer is not None:
        missing = [
            n for n in ("damper_displacement", "damper_velocity") if n not in readings
        ]
        if missing:
            raise ValueError(
                f"export: the DamperObserver integrates on {missing}, which neither "
                f"the measurements {inputs} nor an estimator give."
            )
        readings.add("damper_force")
    return Plan(inputs, tuple(sorted(readings)))
