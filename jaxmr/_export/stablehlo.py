"""`export_stablehlo`: a controller as a serialized `jax.export` program (StableHLO),
for users with an XLA runtime."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._control import ObserverBasedController
from .._control.observer_based import _NoPlant
from .._control.sensors import readings
from .._misc import warn_if_float32
from .plan import plan
from .write import write_outputs

_NO_DEVICE = (
    "export_stablehlo: the exported controller has no simulated device to read; "
    "its law must invert the observer's damper (give the ObserverBasedController "
    "an `observer=jaxmr.DamperObserver(nominal)`)."
)


def stablehlo_function(controller: ObserverBasedController, measurements=None):
    """`(step, state_size, names)`: the pure function the export holds,
    `step(state, inputs, reset) -> (command, next_state)`, over the flat state
    vector (`state_size` entries) and the measurements `names` in order."""
    if not isinstance(controller, ObserverBasedController):
        raise NotImplementedError(
            f"export_stablehlo: a {type(controller).__name__} cannot be exported; wrap "
            "the law in a jaxmr.ObserverBasedController, which states what it "
            "measures, its damper model and its sample time."
        )
    names = plan(controller, measurements).inputs
    dtype = jnp.result_type(float)

    def measurement(inputs):
        return readings({n: inputs[i] for i, n in enumerate(names)})

    template = controller.init(measurement(jnp.zeros(len(names), dtype)))
    leaves, tree = jax.tree.flatten(template)
    sizes = [int(np.size(leaf)) for leaf in leaves]

    # The state as one vector of `dtype` (flags as 0 or 1), and back; explicit casts,
    # since jaxmr's users may run with strict dtype promotion.
    def ravel(state):
        parts = [jnp.ravel(leaf).astype(dtype) for leaf in jax.tree.leaves(state)]
        return jnp.concatenate(parts) if parts else jnp.zeros(0, dtype)

    def unravel(flat):
        out, start = [], 0
        for leaf, size in zip(leaves, sizes):
            part = flat[start : start + size].reshape(np.shape(leaf))
            start += size
            kind = jnp.asarray(leaf).dtype
            out.append(part != 0 if kind == jnp.bool_ else part.astype(kind))
        return jax.tree.unflatten(tree, out)

    def step(state, inputs, reset):
        m = measurement(inputs)
        state = unravel(jnp.where(reset, ravel(controller.init(m)), state))
        command, state = controller(m, state, _NoPlant(why=_NO_DEVICE))
        return jnp.asarray(command, dtype), ravel(state)

    return step, sum(sizes), names


def export_stablehlo(
    controller,
    path,
    *,
    measurements=None,
    platforms=("cpu",),
    force: bool = False,
) -> jax.export.Exported:
    """Write `controller` as a serialized `jax.export` program (StableHLO with its
    calling convention), for an XLA runtime; read it back with
    `jax.export.deserialize(open(path, "rb").read())` and call it with `.call`.

    The program is `step(state, inputs, reset) -> (command, next_state)`: `state` a
    flat vector [the controller's state, `ravel_pytree` order], `inputs` the
    measurements in the order of `measurements` (as `export_c`'s), `reset` a
    boolean: True at the first sample, where the state is the controller's `init` at
    these inputs (the `state` passed is then ignored: zeros will do). `command` [A]
    as `controller(measurement, state, plant)` gives it; call it every
    `controller.sampling.dt` seconds. In the default float dtype (float64 with
    `jax_enable_x64`).

    **Arguments:**

    - `controller`: an `ObserverBasedController` (any law; not `oracle`).
    - `path`: the file to write.
    - `measurements`: as for `export_c`.
    - `platforms`: what the program is lowered for, e.g. `("cpu", "cuda")`; default
      `("cpu",)`.
    - `force`: replace an existing file (default False: an error).

    **Returns:** the `jax.export.Exported` written.
    """
    warn_if_float32(
        "jaxmr.export_stablehlo",
        needs="the program computes in the default float dtype, and its commands "
        "then differ from the float64 controller's by float32 rounding, which the "
        "estimator's integrators and the observer's RK4 accumulate",
    )
    step, size, names = stablehlo_function(controller, measurements)
    dtype = jnp.result_type(float)
    exported = jax.export.export(jax.jit(step), platforms=tuple(platforms))(
        jax.ShapeDtypeStruct((size,), dtype),
        jax.ShapeDtypeStruct((len(names),), dtype),
        jax.ShapeDtypeStruct((), jnp.bool_),
    )
    data = bytes(exported.serialize())
    path = Path(path)
    write_outputs(
        path.parent, {path.name: lambda p: Path(p).write_bytes(data)}, force=force
    )
    return exported
