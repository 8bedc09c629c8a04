"""The residual of a fit and its Jacobian: the packed experiments (`data.py`) simulated
in one vectorised scan per lane, smoothed like the data, compared with the force.

One simulation path serves `fit`, `fit_each`, `predict`, `compare_models` and
`record_nrmse`: `_simulated` below (`simulate`, and the residuals, on top of it).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jax.sharding import PartitionSpec

from .._channel import delayed, split_channel
from .._damper import as_damper
from .._distribute import BATCH
from .._misc import rk4_stages
from .._parameter import unwrap
from .._traced import cached
from .data import FitData

# What a residual that is not finite (a diverged simulation) is replaced by: large, so
# that Levenberg–Marquardt rejects the step, and finite, so that it can.
DIVERGED = 1e6


def _lane(damper, inputs, step, reset, experiments: int, guard: bool = False):
    """Force at the start of every step of one lane (RK4; state reset where `reset`,
    at most `experiments` times); with `guard`, also whether the state has left its
    bounds (`state_bounds`, the largest since its experiment began, 1 % slack, as
    `simulate`'s) or stopped being finite at or before that step of its
    experiment."""
    # The states to reset to, computed before the scan for the lane's experiments
    # only and read in it: evaluated inside (under `where`), `initial_state` ran on
    # every step, and a `MagneticStage` traces its virgin magnetisation curve (64 RK4
    # steps) for it, which made every step of a fit about 65 times dearer.
    starts = jnp.nonzero(reset, size=experiments, fill_value=0)[0]
    virgin = jax.vmap(lambda s: damper.initial_state(*s[0]))(inputs[starts])
    # Each step's experiment (padding lanes, reset at every step, read the last).
    which = jnp.clip(jnp.cumsum(reset) - 1, 0, experiments - 1)
    first = virgin[which]

    def outside(y, command, widest):
        """Whether `y` is out (not finite, or beyond the widest bound of its
        experiment so far), and that widest bound."""
        bounds = damper.state_bounds(y, command)
        bad = ~jnp.all(jnp.isfinite(y))
        if bounds is None:
            return bad, widest
        widest = jnp.maximum(widest, bounds)
        return bad | jnp.any(jnp.abs(y) > 1.01 * widest + 1e-12), widest

    def body(carry, xs):
        y, bad, widest = carry
        stage, h, start, y_start = xs
        # (x, v, i) at the step's start, midpoint and end.
        begin, middle, end = stage
        y = jnp.where(start, y_start.astype(y.dtype), y)
        force = damper.force(y, *begin)
        rates = lambda y, s: damper.rates(y, *s)
        y_next = rk4_stages(rates, y, h, begin, middle, end)
        if not guard:
            return (y_next, bad, widest), force
        # Once out, out for the rest of the experiment (a diverged state that comes
        # back inside its bounds is no valid state either). The bound is the widest
        # since the experiment began (`simulate`'s `_finish` says why).
        widest = jnp.where(start, 0.0, widest)
        out, widest = outside(y, begin[2], widest)
        bad = jnp.where(start, False, bad) | out
        return (y_next, bad, widest), (force, bad)

    (x0, v0, i0) = inputs[0, 0]
    y0 = damper.initial_state(x0, v0, i0)
    if y0.shape[0] == 0:  # a static model (Bingham): no state to integrate
        force = jax.vmap(lambda s: damper.force(y0, *s[0]))(inputs)
        return (force, jnp.zeros(force.shape, bool)) if guard else force
    y0 = y0.astype(inputs.dtype)
    carry = (y0, jnp.zeros((), bool), jnp.zeros_like(y0))
    _, out = jax.lax.scan(body, carry, (inputs, step, reset, first))
    return out


def _simulated(model, data: FitData, guard: bool):
    """The model's unsmoothed force at every sample of the packed experiments, with
    `guard` also whether the experiment's state has left its bounds at or before
    that sample (else None), and the force channel's delay (or None)."""
    device, delay = split_channel(unwrap(model))
    damper = as_damper(device)
    lane = functools.partial(_lane, experiments=len(data.offsets), guard=guard)
    lanes = jax.vmap(lane, in_axes=(None, 0, 0, 0))(
        damper, data.inputs, data.step, data.reset
    )
    at_samples = lambda a: jnp.reshape(a, -1)[data.sample_index]
    if guard:
        lane_force, lane_bad = lanes
        return at_samples(lane_force), at_samples(lane_bad), delay
    # Without `guard`, `_lane` gives the force alone.
    return at_samples(lanes), None, delay


def simulate(model, data: FitData, guard: bool = False) -> jax.Array:
    """The model's force [N] (torque [N·m]) at every sample of the packed experiments,
    smoothed like the data where `data` says so, read through the force channel's
    delay for a `ChannelDelay` (constraint wrappers resolved). With `guard`, NaN from
    the first sample at which an experiment's state has left its bounds or is not
    finite: a diverged fixed-step solve, whose finite forces would be absurd."""
    force, bad, delay = _simulated(model, data, guard)
    if bad is None:
        return _smoothed(force, data, delay)
    # Zeros in place of the diverged forces, so that the smoothing's running
    # integral does not carry them into later experiments; NaN put back below.
    force = _smoothed(jnp.where(bad, 0.0, force), data, delay)
    # `bad` holds from the first bad sample on: a window is clean where its last
    # sample is.
    last = data.hi_index + (data.hi_fraction > 0).astype(data.hi_index.dtype)
    return jnp.where(bad | (data.smooth & bad[last]), jnp.nan, force)


def _smoothed(force, data: FitData, delay) -> jax.Array:
    """The simulated force at the samples read through the channel's delay and
    smoothed like the data."""
    if delay is not None:
        sample = jnp.arange(force.shape[0], dtype=data.first_sample.dtype)
        force = delayed(
            force, delay, sample, data.first_sample, data.last_sample, data.interval
        )
    # The data's own smoothing (a centred moving average), applied to the simulated
    # force: the trapezoidal integral, zero across experiments, read at each window's
    # ends.
    dt = jnp.diff(data.t) * data.same_run
    increments = (force[1:] + force[:-1]) / 2 * dt
    integral = jnp.concatenate([jnp.zeros(1, force.dtype), jnp.cumsum(increments)])

    def at(index, fraction):
        return integral[index] + fraction * (integral[index + 1] - integral[index])

    average = at(data.hi_index, data.hi_fraction) - at(data.lo_index, data.lo_fraction)
    return jnp.where(data.smooth, average / data.span, force)


def residuals(free, static, data: FitData, _=None) -> jax.Array:
    """Weighted residuals (simulated − measured) at the scored samples."""
    force = simulate(eqx.combine(free, static), data)
    return _weighted(force, data)


def guarded_residuals(free, static, data: FitData, _=None) -> jax.Array:
    """`residuals`, or `DIVERGED` everywhere where any experiment's state has left its
    bounds (as `simulate(..., guard=True)` and so a fit's report judge it).

    A fit that starts inside the bounds runs on this residual, so that it never
    accepts a point whose report would call the simulation diverged. Without it a fit
    climbs to the fixed step's stability limit where that helps its loss: LuGre on
    simulated sine tests of Spencer et al.'s (1997) damper raised σ0 to 1.2e7 N/m,
    where one RK4 step of 25 µm travel (`StepPolicy`) puts σ0·|v|·h/g at 2.8, RK4's
    limit; the fit's unguarded simulation stayed finite, its state 1 % past the
    bound, and the report then scored that experiment as diverged (NRMSE inf) and
    the fit as not converged. Spencer's templates did the same there."""
    force, bad, delay = _simulated(eqx.combine(free, static), data, True)
    assert bad is not None  # guarded
    r = _weighted(_smoothed(force, data, delay), data)
    return jnp.where(jnp.any(bad), DIVERGED, r)


def _weighted(force, data: FitData) -> jax.Array:
    r = (force[data.kept] - data.force[data.kept]) * data.weight
    return jnp.where(jnp.isfinite(r), r, DIVERGED)


def value_and_jacobian(residuals_fn, free, static, data, extra, columns=None):
    """The residual and its Jacobian (a pytree like `free`, each leaf with the
    residual's axes first) in one forward-mode pass: the primal is computed once
    alongside the p tangents, so the pair costs about p + 1 residuals' work.

    `columns`: a mesh whose devices each push the primal and their share of the
    tangents, then gather the others' columns, so that each holds the whole pair
    (`solver.column_mesh`: a fit from one start, whose one simulation loop a single
    core runs). A forward-mode pass over 3 of the Bouc–Wen benchmark's 6 columns took
    0.070 s, over all 6 0.116 s, on 2 cores. Padded with zero tangents to a whole
    number per device."""
    if columns is not None:
        return _value_and_jacobian_by_columns(
            residuals_fn, free, static, data, extra, columns
        )

    def both(f):
        r = traced_once(residuals_fn, f, static, data, extra)
        return r, r

    jac, r = jax.jacfwd(both, has_aux=True)(free)
    return r, jac


def _value_and_jacobian_by_columns(residuals_fn, free, static, data, extra, mesh):
    flat, unravel = ravel_pytree(free)
    p = flat.size
    basis = jnp.eye(-(-p // mesh.size) * mesh.size, p, dtype=flat.dtype)
    # The point and the data cross into `shard_map` as its arguments, whole on each
    # device: closed over, arrays placed on the mesh outside failed its gathers.
    operands, rest = eqx.partition((flat, static, data, extra), eqx.is_array)

    def block(rows, operands):
        x, static, data, extra = eqx.combine(operands, rest)
        residual = lambda x: traced_once(residuals_fn, unravel(x), static, data, extra)
        push = lambda v: jax.jvp(residual, (x,), (v,))
        r, tangents = jax.vmap(push, out_axes=(None, 0))(rows)
        return r, jax.lax.all_gather(tangents, BATCH, tiled=True)[:p]

    r, columns = jax.shard_map(
        block,
        mesh=mesh,
        in_specs=(PartitionSpec(BATCH), PartitionSpec()),
        out_specs=PartitionSpec(),
        check_vma=False,
    )(basis, operands)
    # Row by row of the Jacobian (p numbers each), as jacfwd lays it out: each leaf
    # of `free` with the residual's axes first.
    rows = jnp.moveaxis(columns, 0, -1).reshape(-1, p)
    jac = jax.vmap(unravel)(rows)
    return r, jax.tree.map(lambda j: j.reshape(r.shape + j.shape[1:]), jac)


@eqx.filter_jit
def traced_once(residuals_fn, free, static, data, extra):
    """`residuals_fn(free, static, data, extra)` as a jitted call inside the fit's
    programs: JAX traces the model's Python once per argument shapes and then
    transforms that jaxpr (the Jacobian's forward mode, the batch's vmap) wherever
    the residual appears again (the solver's `_init`, its step's trial point and
    Jacobian, the statistics), instead of running the model's Python again in each;
    XLA inlines the call, so the compiled programs do the same work."""
    return residuals_fn(free, static, data, extra)


# Kept on disk where the command line says (`cached`): a second `jaxmr fit` of the same
# shapes reads the step, the reported simulation and the statistics' Jacobian back
# instead of tracing the model again. The simulation returns one array; the Jacobian
# the residual and a tree like `free`.
simulate_jit = cached(lambda *_: 0)(simulate)
residuals_jit = eqx.filter_jit(residuals)


@cached(lambda residuals_fn, free, *_: (0, free))
def value_and_jacobian_jit(residuals_fn, free, static, data, extra):
    return value_and_jacobian(residuals_fn, free, static, data, extra)
