"""A controller run on recorded readings (`replay`): the commands it gives to a log of
its sensors, as on the machine, to compare with a hardware log or an export."""

from collections.abc import Mapping

import equinox as eqx
import jax
import numpy as np

from .._custom_types import Array, PyTree
from .._misc import to_device
from .base import AbstractController
from .observer_based import _NoPlant
from .sensors import readings

_NO_DEVICE = (
    "replay runs a controller on recorded readings, with no device to read: a law "
    "that inverts the damper needs an ObserverBasedController with an "
    "`observer=jaxmr.DamperObserver(nominal_damper)`."
)


@eqx.filter_jit
def _replay(controller, names: tuple[str, ...], table):
    plant = _NoPlant(why=_NO_DEVICE)

    def measurement(row):
        return readings({n: row[k] for k, n in enumerate(names)})

    def one(state, row):
        command, state = controller(measurement(row), state, plant)
        return state, (command, state)

    _, (commands, states) = jax.lax.scan(
        one, controller.init(measurement(table[0])), table
    )
    return commands, states


def replay(
    controller: AbstractController, measurements: Mapping[str, object]
) -> tuple[Array, PyTree]:
    """The commands a controller gives to recorded readings, sample by sample, as
    `simulate_system` steps it: its `init` at the first sample, then one step per
    sample (the first included). For a hardware log, a `SystemSolution`'s
    `measured` readings, or to check an exported controller (`export_c`,
    `export_stablehlo`) against the JAX one.

    **Arguments:**

    - `controller`: a controller (an `ObserverBasedController` for a law that
      inverts the damper: there is no device to read).
    - `measurements`: the readings by name, each a 1-D array over the samples, one
      per controller sample period (SI units: m/s², m, N, ...; `"time"` [s] for a
      law that reads the clock).

    **Returns:** `(commands, states)`: the commands [A], one per sample, and the
    controller's state after each sample (stacked on a leading axis).

    **Raises:** `ValueError` for readings of different lengths, none, or not 1-D;
    `KeyError` naming a reading the controller needs that is not given.
    """
    if not isinstance(controller, AbstractController):
        raise TypeError(
            "replay: `controller` must be a jaxmr controller, got "
            f"{type(controller).__name__}."
        )
    if not isinstance(measurements, Mapping) or not measurements:
        raise ValueError(
            "replay: `measurements` must be a non-empty dict of readings by name."
        )
    names = tuple(str(n) for n in measurements)
    # Stacked on the host and moved once (`to_device`): eager `jnp` conversions and
    # a `jnp.stack` each compiled per shape, before the replay's own program.
    columns = [np.asarray(v, dtype=float) for v in measurements.values()]
    shapes = {n: c.shape for n, c in zip(names, columns)}
    if any(c.ndim != 1 for c in columns) or len({c.shape for c in columns}) != 1:
        raise ValueError(
            f"replay: every reading must be a 1-D array of one length, got {shapes}."
        )
    if columns[0].shape[0] < 1:
        raise ValueError("replay: the readings hold no sample.")
    return _replay(controller, names, to_device(np.stack(columns, axis=1)))
