"""The batch a tuning loss runs over: roads (and damper samples), checked, and spread
over every device of every process."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._distribute import batch_mesh, pad, padded_size, spread
from .._road import RandomRoad

ROADS_EXAMPLE = "`jax.vmap(lambda k: jaxmr.iso8608_road('C', 20.0, 10.0, k))(keys)`"


def batch_size(tree, what: str, example: str) -> int:
    """The one leading size of the arrays of a batch (clear error otherwise)."""
    sizes = {x.shape[0] for x in jax.tree.leaves(tree) if eqx.is_array(x) and x.ndim}
    if len(sizes) != 1:
        raise ValueError(
            f"`{what}` must be a batch with one leading axis (e.g. {example}), got "
            f"leading sizes {sorted(sizes) or 'none'}."
        )
    return sizes.pop()


def road_count(roads) -> int:
    """The number of roads in a batch (`batch_size`), a single road given alone named
    as such: its scalars have no leading axis, and its samples' time axis would be
    read as the batch."""
    single = isinstance(roads, RandomRoad) and roads.values.ndim == 1
    if single or any(eqx.is_array(x) and x.ndim == 0 for x in jax.tree.leaves(roads)):
        raise ValueError(
            "`roads` must be a batch with one leading axis, one road per row (e.g. "
            f"{ROADS_EXAMPLE}); this looks like one road (its arrays have no batch "
            "axis). For one road give `jax.tree.map(lambda x: x[None], road)`."
        )
    return batch_size(roads, "roads", ROADS_EXAMPLE)


def road_batch(roads):
    """`((roads, index), valid)`: the roads, each with its index in the batch (which
    picks its sensors' noise, `loss.sensing`), spread over every device of every
    process, padded to a whole number per device with copies of the last (`valid`
    False), which the losses' means leave out (`loss.mean_or_inf`)."""
    n = road_count(roads)
    mesh = batch_mesh()
    count = padded_size(n, mesh)
    valid = jnp.arange(count) < n
    runs = (roads, jnp.arange(n))
    return spread((pad(runs, n, count), valid), mesh)
