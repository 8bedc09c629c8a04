"""A batch spread over every device of every process, with JAX's own sharding.

`sweep`, `fit_each` and `evaluate` (and the tuning losses' roads) split their batch
axis over a 1-D mesh of `jax.devices()`: the local devices of a single process (GPUs,
or host devices from `XLA_FLAGS=--xla_force_host_platform_device_count=N`), or every
process's devices after `jax.distributed.initialize()`. Every process runs the same
call with the same inputs; each builds only the shards its own devices hold
(`jax.make_array_from_callback`), the compiled program runs on all of them, and
`gather` brings the results back to every process. A batch that does not divide
evenly is padded with copies of its last member and trimmed after. Nothing here
schedules work: placement is data, the partitioning is XLA's.
"""

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

BATCH = "batch"


def batch_mesh(local: bool = False) -> Mesh | None:
    """jaxmr's one device mesh: 1-D (axis `"batch"`) over every device of every
    process (`local=True`: of this process only, e.g. `fit`'s lanes, which every
    process scans whole), or None when there is only one device (nothing to
    spread)."""
    devices = jax.local_devices() if local else jax.devices()
    if len(devices) == 1:
        return None
    return Mesh(np.array(devices), (BATCH,))


def padded_size(n: int, mesh: Mesh | None) -> int:
    """`n` rounded up to a whole number of members per device."""
    if mesh is None:
        return n
    return -(-n // mesh.size) * mesh.size


def pad(tree, n: int, count: int):
    """Every array leaf's axis 0 (length `n`) grown to `count` with copies of its last
    member (a real member: it simulates and fits like the others, and is trimmed)."""
    if count == n:
        return tree
    arrays, static = eqx.partition(tree, eqx.is_array)
    grow = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], count - n, axis=0)])
    return eqx.combine(jax.tree.map(grow, arrays), static)


def spread(tree, mesh: Mesh | None):
    """Every array leaf placed on `mesh`, axis 0 split over its devices (the batch's
    size must divide evenly: `pad` first). Each process builds only its own shards,
    from the same host values."""
    if mesh is None:
        return tree
    return _place(tree, NamedSharding(mesh, PartitionSpec(BATCH)))


def replicate(tree, mesh: Mesh | None):
    """Every array leaf whole on every device of `mesh` (unchanged without one).

    A jitted function is traced and compiled again for every new placement of its
    inputs: a tuner's parameters start on one device and come back from the first
    step replicated over the mesh. Placed so from the start, every step calls the one
    compiled program (two devices: two compilations of the loss and its gradient
    before, 6 s of a 16 s first `tune`)."""
    if mesh is None:
        return tree
    return _place(tree, NamedSharding(mesh, PartitionSpec()))


def _place(tree, sharding: NamedSharding):
    """Every array leaf of `tree` placed by `sharding`. Each process builds only its
    own shards, from the same host values; a leaf already so placed is left alone."""

    def place(a):
        if isinstance(a, jax.core.Tracer):
            # Inside the caller's `jit`, `grad` or `vmap`: ask the compiler for the
            # placement (a value in a trace has no host copy to split).
            return jax.lax.with_sharding_constraint(a, sharding)
        if isinstance(a, jax.Array) and a.sharding == sharding:
            return a
        host = np.asarray(a)
        return jax.make_array_from_callback(host.shape, sharding, lambda i: host[i])

    arrays, static = eqx.partition(tree, eqx.is_array)
    return eqx.combine(jax.tree.map(place, arrays), static)


def gather(tree):
    """Every array of `tree` whole on every process.

    An array spread over several processes' devices (the outputs of `jaxmr.sweep`,
    `fit_each`, ... after `jax.distributed.initialize()`) cannot be read by one
    process alone; this all-gathers it (a collective: every process must call it with
    the same tree). Arrays a process can already read whole are returned unchanged, so
    the call is harmless in a single process.
    """
    arrays, static = eqx.partition(tree, eqx.is_array)

    def whole(a):
        # A tracer (`sweep` under `grad`, `jit` or `vmap`) is a value inside the
        # caller's trace, not a spread array: the caller's program places it.
        if isinstance(a, jax.core.Tracer):
            return a
        if not isinstance(a, jax.Array) or a.is_fully_addressable:
            return a
        if a.is_fully_replicated:  # a reduction's result: every process holds it
            return jnp.asarray(a.addressable_data(0))
        return jnp.asarray(multihost_utils.process_allgather(a, tiled=True))

    return eqx.combine(jax.tree.map(whole, arrays), static)


def to_host(a) -> np.ndarray:
    """A numpy copy of `a`, gathered from every process first where it is spread."""
    return np.asarray(gather(a))
