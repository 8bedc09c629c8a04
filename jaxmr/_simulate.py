"""`simulate` and `sweep`: a damper under prescribed motion and current."""

import contextlib
from collections.abc import Sequence
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import Literal as JaxprLiteral
from jax.sharding import PartitionSpec

from ._channel import ChannelDelay
from ._current_law import is_law, ranged_laws
from ._custom_types import ArrayLike, Float, ScalarLike
from ._damper import Damper, as_damper, fitted_range_in, with_fitted_range
from ._distribute import batch_mesh, gather, pad, padded_size, spread
from ._fitted_range import FittedRange, check_fitted_range
from ._hysteresis import AbstractHysteresis
from ._integrate import AbstractIntegrator, Adaptive, FixedStep
from ._misc import Check, as_float_array, guarded, is_concrete, warn_if_float32
from ._parameter import numbers_as_arrays
from ._signal import AbstractSignal, Constant, as_signal
from ._solution import RESULTS, Solution


def _check_times(ts) -> jax.Array:
    with jax.ensure_compile_time_eval():
        return _check_times_now(ts)


def _check_times_now(ts) -> jax.Array:
    ts = as_float_array(ts)
    if ts.ndim != 1 or ts.shape[0] < 2:
        raise ValueError(
            "`ts` must be a 1-D array of at least two output times [s], got shape "
            f"{ts.shape}."
        )
    if is_concrete(ts):
        # numpy, not jnp: inside a caller's jit, jnp on a closed-over concrete array
        # gives a tracer, which cannot be tested here.
        values = np.asarray(ts)
        if not np.all(np.isfinite(values)):
            k = int(np.argmin(np.isfinite(values)))
            raise ValueError(
                f"`ts` contains NaN or inf (ts[{k}] = {values[k]}); give finite "
                "output times."
            )
        steps = np.diff(values)
        if not np.all(steps > 0):
            k = int(np.argmin(steps > 0))
            raise ValueError(
                f"`ts` must be strictly increasing, but ts[{k}] = {values[k]} >= "
                f"ts[{k + 1}] = {values[k + 1]}; sort the times and drop duplicates."
            )
    return ts


def _runtime_checks(damper: Damper, motion, current, ts, table_errors: bool = True):
    """Checks of values only known under jit: they raise with these messages.

    Returns `ts` (guarded by the checks) and whether the current stays inside the range
    of every TableLaw in the model. With `table_errors=False` leaving a range is not an
    error but the result code `current_outside_table` (`throw=False`: one current
    beyond a table must not stop a whole sweep).
    """
    checks = [
        Check(
            jnp.all(jnp.isfinite(ts)),
            "`ts` contains NaN or inf; give finite output times",
        ),
        Check(
            jnp.all(jnp.diff(ts) > 0),
            "`ts` must be strictly increasing; sort the times and drop duplicates",
        ),
    ]
    checks += [check.named("`motion`") for check in motion.checks()]
    checks += [check.named("`current`") for check in current.checks()]
    lo, hi = current.bounds()
    in_tables = jnp.array(True)
    model = type(damper.hysteresis).__name__
    for path, law in ranged_laws(damper.hysteresis):
        # `ranged_laws` yields only laws whose range is not None.
        law_lo, law_hi = law.range()  # pyright: ignore[reportGeneralTypeIssues]
        ok = (lo >= law_lo) & (hi <= law_hi)
        if table_errors:
            # The ranges are traced here: `simulate` and `sweep` quote them when the
            # inputs are concrete (`_check_tables_now`).
            checks.append(
                Check(
                    ok,
                    "`current` leaves the current range of a TableLaw in the model "
                    f"(`{model}{path}`; laws are not extrapolated); extend the table "
                    "or keep the current inside it",
                )
            )
        else:
            in_tables = in_tables & ok
    checks += damper.hysteresis.checks_over(lo, hi)
    if damper.dynamics is not None:
        dynamics = damper.dynamics
        name = type(dynamics).__name__
        checks += [check.named(name) for check in dynamics.constraints()]
    # The message quotes a value only where it is concrete (`Check.message`).
    return guarded(ts, checks), in_tables


def _check_tables_now(damper: Damper, bounds, device: str = "", current: str = ""):
    """Raise now, quoting the numbers, when concrete current `bounds` (lo, hi) [A] leave
    the range of a concrete TableLaw in `damper`. The runtime check cannot quote them:
    under jit they are traced. Raised as the runtime check's exception type, so the
    same mistake raises the same error with concrete or traced inputs."""
    if bounds is None:
        return
    lo, hi = bounds
    model = type(damper.hysteresis).__name__
    for path, law in ranged_laws(damper.hysteresis):
        if not is_concrete(law):
            continue
        with jax.ensure_compile_time_eval():
            # `ranged_laws` yields only laws whose range is not None.
            law_lo, law_hi = (float(x) for x in law.range())  # pyright: ignore[reportOptionalIterable]
        if lo < law_lo or hi > law_hi:
            spans = f"is {lo:g} A" if lo == hi else f"spans [{lo:g}, {hi:g}] A"
            raise eqx.EquinoxRuntimeError(
                f"`current{current}` leaves the current range of a TableLaw in the "
                f"model{device}: it {spans}, the TableLaw for `{model}{path}` covers "
                f"[{law_lo:g}, {law_hi:g}] A (laws are not extrapolated); extend the "
                "table or keep the current inside it."
            )


# The runtime law check's words (`AbstractHysteresis.checks_over`).
_LAW_CHECK = "its current laws checked over the input's range"


@contextlib.contextmanager
def _laws_explained(runs):
    """Where the runtime check of the current laws fails inside, raise instead the
    message of `_check_laws_now` for the first of `runs()` ((damper, bounds, device
    name, current name)) that breaks them: it quotes the input. Only after a
    failure: the eager check costs some 10 ms per run (a 16-current sweep of the
    brake: 130 ms before its 95 ms solve)."""
    try:
        yield
    except eqx.EquinoxRuntimeError as error:
        if _LAW_CHECK in str(error):
            for run in runs():
                _check_laws_now(*run, cause=error)
        raise


def _check_laws_now(
    damper: Damper, bounds, device: str = "", current: str = "", cause=None
):
    """Raise, quoting the input, when a concrete model's current laws break a
    physical constraint somewhere in concrete current `bounds` (lo, hi) [A or V] (a
    negative dashpot at -0.5 A, a quadratic law turning negative at 2 A): the
    runtime check (`checks_over`, traced under jit) can name neither. `cause`: the
    runtime error this explains."""
    hysteresis = damper.hysteresis
    if bounds is None or not is_concrete(hysteresis):
        return
    if not any(is_law(p) for p in jax.tree.leaves(hysteresis, is_leaf=is_law)):
        return  # plain numbers were checked at construction
    lo, hi = bounds
    with jax.ensure_compile_time_eval():
        checks = hysteresis.checks_over(jnp.asarray(lo), jnp.asarray(hi))
        failed = [c for c in checks if not bool(c.ok)]
    if failed:
        check = failed[0]
        # The input where it fails (`checks_over` quotes it as its one value).
        (at,) = check.value.values() if isinstance(check.value, dict) else (lo,)
        spans = f"is {lo:g}" if lo == hi else f"spans [{lo:g}, {hi:g}]"
        raise eqx.EquinoxRuntimeError(
            f"{check.rule}, at an input of {float(at):g} A (or V): `current{current}` "
            f"{spans} for the model{device}; keep it where the model holds (e.g. the "
            "range it was fitted on)."
        ) from cause


def _concrete_bounds(current: AbstractSignal) -> tuple[float, float] | None:
    """A concrete current signal's (lo, hi) [A], or None when traced."""
    if not is_concrete(current):
        return None
    with jax.ensure_compile_time_eval():
        lo, hi = current.bounds()
        return float(lo), float(hi)


def _field(t, y, args):
    damper, motion, current = args
    return damper.rates(y, motion(t), motion.derivative(t), current(t))


def _run(
    damper,
    motion,
    current,
    ts,
    integrator,
    initial_state,
    checks: bool = True,
    throw: bool = True,
) -> Solution:
    """One simulation, traced (no jit of its own: it is vmapped and mapped).

    `checks=False` skips the runtime input checks: `fit` validates its data once, and
    under vmap every `eqx.error_if` becomes a host callback on each evaluation.
    `throw=False` makes a current outside a TableLaw's range a result code, not an
    error.
    """
    in_tables = jnp.array(True)
    if checks:
        ts, in_tables = _runtime_checks(damper, motion, current, ts, throw)
    x, v, ys, result, num_steps = _solve(
        damper, motion, current, ts, integrator, initial_state
    )
    return _finish(damper, current, ts, x, v, ys, result, num_steps, in_tables)


def _solve(damper, motion, current, ts, integrator, initial_state):
    """The motion at `ts` and the states integrated under it: `(x, v, ys, result,
    num_steps)`."""
    x = jax.vmap(motion)(ts)
    v = jax.vmap(motion.derivative)(ts)
    if initial_state is None:
        y0 = damper.initial_state(x[0], v[0], current(ts[0]))
    else:
        y0 = as_float_array(initial_state)
    if y0.shape[0] == 0:  # a static model (Bingham): nothing to integrate
        ys = jnp.zeros((ts.shape[0], 0), dtype=ts.dtype)
        return x, v, ys, RESULTS.successful, jnp.array(0)
    jumps = [
        jnp.ravel(j).astype(ts.dtype)
        for j in (motion.jump_times(), current.jump_times())
        if j is not None
    ]
    # Passed only when there are jumps: an integrator written for the
    # four-argument `integrate` keeps working with smooth signals.
    extra = {"jump_ts": jnp.concatenate(jumps)} if jumps else {}
    ys, result, num_steps = integrator.integrate(
        _field, y0, ts, (damper, motion, current), **extra
    )
    return x, v, ys, result, num_steps


def _finish(damper, current, ts, x, v, ys, result, num_steps, in_tables) -> Solution:
    """The solution of one run from its solved states: the force, the effective
    current and the result code at this run's `current`."""
    i = jax.vmap(current)(ts)
    force = jax.vmap(damper.force)(ys, x, v, i)
    effective = jax.vmap(damper.effective_current)(ys, i)
    force_ok = jnp.all(jnp.isfinite(force))
    result = RESULTS.where(
        (result == RESULTS.successful) & ~force_ok, RESULTS.nonfinite_force, result
    )
    if ys.shape[1] > 0 and damper.state_bounds(ys[0], i[0]) is not None:
        # A fixed-step solve can diverge to large finite values; 1 % slack covers the
        # integrator's own overshoot of a saturating state. The bound is the widest
        # so far, not the present one: a bound that shrinks with the input (LuGre's
        # max(F_c, F_s)/σ0 under a falling current) leaves a state saturated at the
        # higher input outside it while the state relaxes to the new one, which is no
        # divergence (the NEES record's voltage fell from 2.26 to 0.15 V in one
        # sample: LuGre's state was 19 % over the new bound and back within 4
        # samples, and every LuGre fit there read as diverged). A state that does
        # diverge leaves the widest bound too.
        bounds = jax.lax.cummax(jax.vmap(damper.state_bounds)(ys, i), axis=0)
        inside = jnp.all(jnp.abs(ys) <= 1.01 * bounds + 1e-12)
        result = RESULTS.where(
            (result == RESULTS.successful) & ~inside,
            RESULTS.state_out_of_bounds,
            result,
        )
    # The input's fault comes first: whatever the solve did, it ran a current the model
    # is not valid for.
    result = RESULTS.where(in_tables, result, RESULTS.current_outside_table)
    return Solution(
        ts=ts,
        displacement=x,
        velocity=v,
        current=i,
        effective_current=effective,
        force=force,
        states=ys,
        result=result,
        num_steps=num_steps,
        state_names=damper.state_names,
    )


def _run_shared(
    damper, motion, currents, ts, integrator, throw: bool = True, keep=None
):
    """The runs of one damper and motion at every constant current of the batch
    `currents` (leading axis), for a damper whose state equation does not depend on the
    current (`_state_ignores_current`): the states are solved once and the force is
    evaluated at each current. The same solutions as `_run` per current, stacked;
    `keep` as in `_sweep_flat`."""
    # Every run's input checks, as `_run` does them; the solve uses the times guarded
    # by the first current's (the motion's checks are in all of them).
    ts_each, in_tables = jax.vmap(
        lambda c: _runtime_checks(damper, motion, c, ts, throw)
    )(currents)
    first = jax.tree.map(lambda a: a[0], currents)
    x, v, ys, result, num_steps = _solve(
        damper, motion, first, ts_each[0], integrator, None
    )

    def at_current(k):
        c, t, ok = jax.tree.map(lambda a: a[k], (currents, ts_each, in_tables))
        sol = _finish(damper, c, t, x, v, ys, result, num_steps, ok)
        return sol if keep is None else sol.only(keep)

    # A loop over the currents, not a vmap: vmapped, XLA fused the motion (its sin and
    # cos at every output time) into each current's force and again into its
    # finiteness check, so it ran twice per current (an optimization barrier does not
    # survive XLA's CPU pipeline). Out of a loop the motion is computed once, before
    # it. Each current's solution is written in place into the stacked one (under the
    # sweep's vmap, already in its (pair, current, ...) order: a `lax.map` stacked
    # the currents first and cost a transposed copy of the whole output). The brake
    # sweep of benchmarks/simulate_sweep.py (64 motions x 16 currents, torque only)
    # took half the CPU time; the results are the same to the bit.
    n = in_tables.shape[0]
    template, static = eqx.partition(
        eqx.filter_eval_shape(at_current, 0),
        lambda a: isinstance(a, jax.ShapeDtypeStruct),
    )

    def write(k, out):
        sol = eqx.filter(at_current(k), eqx.is_array)
        return jax.tree.map(lambda o, a: o.at[k].set(a), out, sol)

    out = jax.tree.map(lambda a: jnp.zeros((n, *a.shape), a.dtype), template)
    return eqx.combine(jax.lax.fori_loop(0, n, write, out), static)


def _state_ignores_current(damper: Damper, dtype) -> bool:
    """Whether the damper's state equation (its rates and initial state) is the same at
    every commanded current, decided from its structure at trace time: no output of the
    jaxpr of `i -> (rates(s, x, v, i), initial_state(x, v, i))` depends on `i`.

    Conservative: an equation with any input that depends on `i` makes all its outputs
    depend on it (sub-jaxprs of control flow included). A current law acting only on
    the force's gains (the SAS brake's alpha and c0) leaves the state alone; a law on
    `beta`, or current dynamics (`FirstOrderLag`), do not.
    """
    arrays, static = eqx.partition(damper, eqx.is_array)
    # The answer depends only on what the jaxpr is traced from: the structure, the
    # static fields and the arrays' shapes and types. Remembered by those (tracing
    # took ~5 ms of every `sweep` call); a model with unhashable static fields is
    # traced each time.
    leaves, tree = jax.tree.flatten(arrays)
    key = (tree, static, tuple((a.shape, a.dtype) for a in leaves), jnp.dtype(dtype))
    try:
        return _IGNORES_CURRENT[key]
    except TypeError:  # unhashable
        return _trace_ignores_current(damper, dtype)
    except KeyError:
        pass
    if len(_IGNORES_CURRENT) >= 256:
        _IGNORES_CURRENT.clear()
    _IGNORES_CURRENT[key] = answer = _trace_ignores_current(damper, dtype)
    return answer


# `_state_ignores_current`'s answers, by the model's structure and array types.
_IGNORES_CURRENT: dict = {}


def _trace_ignores_current(damper: Damper, dtype) -> bool:
    """`_state_ignores_current`, from the model's jaxpr."""
    arrays, static = eqx.partition(damper, eqx.is_array)
    scalar = jnp.zeros((), dtype)
    state = jnp.zeros(len(damper.state_names), dtype)

    def equation(i, arrays, s, x, v):
        d = eqx.combine(arrays, static)
        return d.rates(s, x, v, i), d.initial_state(x, v, i)

    jaxpr = jax.make_jaxpr(equation)(scalar, arrays, state, scalar, scalar).jaxpr
    dependent = {jaxpr.invars[0]}

    def depends(var) -> bool:
        return not isinstance(var, JaxprLiteral) and var in dependent

    for eqn in jaxpr.eqns:
        if any(depends(var) for var in eqn.invars):
            dependent.update(eqn.outvars)
    return not any(depends(var) for var in jaxpr.outvars)


@eqx.filter_jit
def _simulate(damper, motion, current, ts, integrator, initial_state, throw):
    sol = _run(damper, motion, current, ts, integrator, initial_state, throw=throw)
    return sol.result.error_if(sol, sol.result != RESULTS.successful) if throw else sol


# Why `simulate` and `sweep` warn in float32 (`warn_if_float32`).
_FLOAT64_NEEDED = (
    "simulations need float64 (Adaptive's default rtol 1e-8 is below what float32 "
    "resolves, and rounding accumulates with time; FixedStep runs, at float32's "
    "accuracy)"
)


def _prepare(device, motion, current, integrator):
    if isinstance(device, ChannelDelay):
        as_damper(device)  # its own message: simulate the device, `.model`
    if not isinstance(device, (Damper, AbstractHysteresis)):
        raise TypeError(
            "`device` must be a jaxmr Damper or hysteresis model, e.g. "
            f"BoucWen(...) or Damper(BoucWen(...), FirstOrderLag(rate)); got "
            f"{type(device).__name__}."
        )
    damper = as_damper(device)
    if not isinstance(motion, AbstractSignal):
        raise TypeError(
            "`motion` must be a jaxmr signal of displacement [m] or angle [rad], e.g. "
            f"Sine(amplitude, frequency) or Sampled(t, x); got {type(motion).__name__}."
        )
    current = as_signal(current, "current")
    integrator = Adaptive() if integrator is None else integrator
    if not isinstance(integrator, AbstractIntegrator):
        raise TypeError(
            "`integrator` must be jaxmr.Adaptive(), Stiff() or FixedStep(), got "
            f"{type(integrator).__name__}."
        )
    return damper, motion, current, integrator


def simulate(
    device: Damper | AbstractHysteresis,
    motion: AbstractSignal,
    current: AbstractSignal | ScalarLike = 0.0,
    ts: Float[ArrayLike, " times"] | None = None,
    *,
    integrator: AbstractIntegrator | None = None,
    initial_state: Float[ArrayLike, " states"] | None = None,
    throw: bool = True,
    fitted_range: FittedRange | None = None,
) -> Solution:
    r"""Simulate a damper (or brake) under a prescribed motion and current.

    Integrates the damper's internal state from `ts[0]` with the motion $x(t)$,
    $v(t) = \dot x(t)$ and commanded current $i(t)$ prescribed, and returns the force
    and states at `ts`. Jit-compiled (one compilation per model type, signal type and
    array shapes) and differentiable with respect to every array in its arguments.

    **Arguments:**

    - `device`: a `Damper`, or a bare hysteresis model (no current dynamics).
    - `motion`: the relative displacement [m] (angle [rad] for a brake) as a signal:
      `Sine`, `Triangle`, `Multisine`, `Chirp`, `Sampled`, ...
    - `current`: commanded current [A] (voltage [V] for voltage-driven models): a number
      or a signal (`Constant`, `Steps`, `Sampled`, `Sine`).
    - `ts`: output times [s], 1-D, strictly increasing, at least two.
    - `integrator`: `Adaptive()` (default: Dopri8, rtol 1e-8), `Stiff()` or
      `FixedStep(substeps)`.
    - `initial_state`: the state at `ts[0]`; default: a virgin device (z = 0) with the
      current dynamics settled at the initial command.
    - `throw`: raise if the solve fails (default); with `False` inspect
      `solution.result` instead (a current outside a `TableLaw`'s range is then the
      code `RESULTS.current_outside_table`; other invalid inputs still raise).
    - `fitted_range`: the range the model was fitted on (`jaxmr.FittedRange`);
      default: the model's own (its `fitted_range`, which `load_model` sets from
      the file), if it has one. When the motion's displacement or velocity, or the
      current, at `ts` leaves it, warn once (`OutsideFittedRange`), before the
      solve, naming each interval exceeded and by how much. Skipped when the inputs
      are traced (under jit, vmap or grad).

    **Returns:** a `Solution` (force [N] or torque [N·m], states, inputs, result).
    """
    if ts is None:
        raise ValueError(
            "`ts` is required: the output times [s], e.g. jnp.linspace(0, 2, 2001)."
        )
    warn_if_float32("jaxmr.simulate", needs=_FLOAT64_NEEDED)
    damper, motion, current, integrator = _prepare(device, motion, current, integrator)
    ts = _check_times(ts)
    if throw and ranged_laws(damper.hysteresis):
        _check_tables_now(damper, _concrete_bounds(current))
    if initial_state is not None:
        initial_state = as_float_array(initial_state)
        expected = len(damper.state_names)
        if initial_state.shape != (expected,):
            raise ValueError(
                f"`initial_state` must have shape ({expected},) for states "
                f"{damper.state_names}, got {initial_state.shape}."
            )
    fitted_range = check_fitted_range(fitted_range)
    if fitted_range is None:
        fitted_range = damper.fitted_range
    # The range is read here, outside the jit: off the model, a loaded model shares
    # the compilation of the same model built in code.
    damper = with_fitted_range(damper, None)
    if fitted_range is not None and is_concrete(motion, current, ts):
        # Before the solve: a run that fails far outside the range is told why first.
        fitted_range.warn(
            "jaxmr.simulate",
            jax.vmap(motion)(ts),
            jax.vmap(motion.derivative)(ts),
            jax.vmap(current)(ts),
        )
    explained = lambda: [(damper, _concrete_bounds(current), "", "")]  # noqa: E731
    with _laws_explained(explained if throw else list):
        return _simulate(damper, motion, current, ts, integrator, initial_state, throw)


# ---------------------------------------------------------------------------------------
# Sweeps


def _kind(module) -> str:
    """A module's type for a message; a damper's with its model's (every device of a
    sweep is wrapped in a `Damper` before it is stacked)."""
    inner = getattr(module, "hysteresis", None)
    if isinstance(module, Damper) and inner is not None:
        return f"{type(inner).__name__} (in a Damper)"
    return type(module).__name__


def _stack(items, what: str):
    """A batched module from a sequence of modules of the same structure."""
    items = list(items)
    if not items:
        raise ValueError(f"`{what}` is an empty sequence.")
    arrays = [eqx.filter(m, eqx.is_array) for m in items]
    structures = {jax.tree.structure(a) for a in arrays}
    if len(structures) != 1:
        # A number set by `eqx.tree_at(..., 300.0)` is a Python float, not an array:
        # as an array it stacks with the other members' (only done here, off the
        # common path: a sweep's members are many).
        items = [numbers_as_arrays(m) for m in items]
        arrays = [eqx.filter(m, eqx.is_array) for m in items]
        structures = {jax.tree.structure(a) for a in arrays}
    if len(structures) != 1:
        raise ValueError(
            f"every element of `{what}` must be of the same type with the same "
            "structure (e.g. all Sine, or all BoucWen with the same parameters given as "
            f"laws); got {sorted({_kind(m) for m in items})}."
        )
    static = eqx.filter(items[0], eqx.is_array, inverse=True)

    def stack(*xs):
        # On the host where every member has a value of a fixed (not weak) type: one
        # numpy copy, not an XLA call over every member (a sweep's members are many
        # scalars: ~5 ms of `sweep`'s ~15 ms of Python per call on 64 motions x 16
        # currents went here). Traced or weakly typed members keep `jnp.stack`.
        if is_concrete(xs) and not any(getattr(x, "weak_type", False) for x in xs):
            return np.stack([np.asarray(x) for x in xs])
        return jnp.stack(xs)

    try:
        stacked = jax.tree.map(stack, *arrays)
    except ValueError as e:
        raise ValueError(
            f"the elements of `{what}` have arrays of different shapes: {e}"
        ) from e
    return eqx.combine(stacked, static), len(items)


def _items(value, convert, what: str) -> tuple[list, bool]:
    """The converted elements of a sweep argument, and whether it is a batch (a
    sequence, or a 1-D array of currents)."""
    if isinstance(value, (list, tuple)):
        return [convert(v) for v in value], True
    if what == "current" and not isinstance(value, AbstractSignal):
        array = as_float_array(value)
        if array.ndim == 1:
            return [as_signal(c) for c in array], True
        if array.ndim > 1:
            raise ValueError(
                "`current` as an array must be 1-D, one constant current per run (a "
                "grid over the motions comes from `grid=True`; a current that varies "
                f"in time is a signal such as jaxmr.Sampled), got shape {array.shape}."
            )
    return [convert(value)], False


def _as_batch(items: list, batched: bool, what: str):
    """(module, size or None): the elements of a batch stacked, or the single one."""
    return _stack(items, what) if batched else (items[0], None)


def _sweep_runs(devices, device_batched, currents, current_batched, grid) -> list:
    """(damper, current bounds, device name, current name) for every (device,
    current) pair the sweep runs."""
    bounds = [_concrete_bounds(c) for c in currents]
    zipped = not grid and len(devices) > 1 and len(bounds) > 1
    return [
        (
            device,
            b,
            f" device[{j}]" if device_batched else "",
            f"[{k}]" if current_batched else "",
        )
        for j, device in enumerate(devices)
        for k, b in enumerate(bounds)
        if not (zipped and j != k)
    ]


def _check_sweep_tables(runs):
    """`_check_tables_now` for every run of `_sweep_runs`."""
    for device, b, *names in runs:
        if ranged_laws(device.hysteresis):
            _check_tables_now(device, b, *names)


def _index(batched, size, indices):
    if size is None:
        return batched, None
    arrays, static = eqx.partition(batched, eqx.is_array)
    return eqx.combine(jax.tree.map(lambda a: a[indices], arrays), static), 0


def _auto_batching(integrator) -> Literal["vmap", "map"]:
    # Measured on a 2-core CPU, one XLA device (benchmarks/simulate_sweep.py and the same
    # runs at other sizes: SAS brake, 10 s at 1 kHz, 2026-11-21), simulated s per wall s:
    # - FixedStep(3), 1024 runs: vmap 1580-3240 over 3 calls, map with batch_size 64:
    #   1950, 256: 2220, None (one run at a time): 1470; 128 runs: vmap 2530, map 64
    #   2270. Scans vectorise.
    # - Adaptive(), 128 runs: vmap 590, map None 965, map 64 680, map 8 260; 512 runs:
    #   vmap 410, map None 850, map 64 660. A vmapped adaptive solve runs every member as
    #   long as the slowest, and each step of a vmapped while loop costs more (even
    #   batch_size=1 took 2-3x the CPU time of None), so adaptive runs are mapped one at
    #   a time (the default batch_size=None). GPUs: not measured.
    return "vmap" if isinstance(integrator, FixedStep) else "map"


@eqx.filter_jit
def _sweep(
    damper,
    motion,
    current,
    axes,
    ts,
    integrator,
    batching,
    batch_size,
    shape,
    throw,
    shared=False,
    keep=None,
):
    # The throw and the reshape to the sweep's axes happen inside the same compiled call:
    # done outside, each copied the whole solution (~15 % of a large sweep's time).
    sol = _sweep_flat(
        damper,
        motion,
        current,
        axes,
        ts,
        integrator,
        batching,
        batch_size,
        throw,
        shared,
        keep,
    )
    # The batch may have been padded to a whole number of runs per device.
    runs = int(np.prod(shape[:-1] if shared else shape))
    sol = jax.tree.map(lambda a: a[:runs], sol)
    if throw:
        # Only the result codes go through the check: guarding the whole solution
        # put it through the check's conditional, which gathered a batch split over
        # several devices onto the first (the brake sweep on 2 CPU devices: ~40 % more
        # CPU time, and its output no longer split). The call still raises, as the
        # guarded codes are one of its outputs.
        result = sol.result.error_if(
            sol.result, jnp.any(sol.result != RESULTS.successful)
        )
        sol = eqx.tree_at(lambda s: s.result, sol, result)
    # Shared: each (device, motion) pair carries all the currents, on a second axis.
    lead = 2 if shared else 1
    return jax.tree.map(lambda a: a.reshape(shape + a.shape[lead:]), sol)


def _sweep_flat(
    damper,
    motion,
    current,
    axes,
    ts,
    integrator,
    batching,
    batch_size,
    throw=True,
    shared=False,
    keep=None,
):
    """The flat batch of runs. With `shared` the batch is of (device, motion) pairs and
    `current` (unbatched, axis None) holds every current: `_run_shared`. `keep`: the
    `Solution` fields each run returns (None: all)."""

    def one(d, m, c):
        # throw=False: a current outside a table is this run's result code, not an
        # error that stops every run.
        if shared:
            sol = _run_shared(d, m, c, ts, integrator, throw=throw, keep=keep)
        else:
            sol = _run(d, m, c, ts, integrator, None, throw=throw)
        # Dropped here, per run, so that XLA never writes them: in a large shared
        # sweep, writing states and motion again for every current cost more than
        # solving.
        return sol if keep is None else sol.only(keep)

    def local(d, m, c):
        if batching == "vmap":
            return jax.vmap(one, in_axes=axes)(d, m, c)
        # lax.map needs every input batched: broadcast the unbatched ones cheaply.
        n = _batch_length(d, m, c, axes)
        args = [x if ax == 0 else _broadcast(x, n) for x, ax in zip((d, m, c), axes)]
        return jax.lax.map(lambda a: one(*a), tuple(args), batch_size=batch_size)

    mesh = batch_mesh()
    n = _batch_length(damper, motion, current, axes)
    if mesh is not None and n % mesh.size == 0:
        # One shard of the batch per device (`sweep` padded it to a whole number of
        # runs per device), each mapped/vmapped locally.
        specs = tuple(
            PartitionSpec("batch") if ax == 0 else PartitionSpec() for ax in axes
        )
        in_specs = tuple(
            jax.tree.map(lambda _, s=spec: s, eqx.filter(x, eqx.is_array))
            for x, spec in zip((damper, motion, current), specs)
        )
        arrays = [eqx.partition(x, eqx.is_array) for x in (damper, motion, current)]

        def sharded(da, ma, ca):
            d, m, c = (eqx.combine(a, s) for a, (_, s) in zip((da, ma, ca), arrays))
            out = local(d, m, c)
            return eqx.filter(out, eqx.is_array)

        out_static = eqx.filter(
            jax.eval_shape(local, damper, motion, current), eqx.is_array, inverse=True
        )
        out_arrays = jax.shard_map(
            sharded,
            mesh=mesh,
            in_specs=in_specs,
            out_specs=PartitionSpec("batch"),
            check_vma=False,
        )(*(a for a, _ in arrays))
        return eqx.combine(out_arrays, out_static)
    return local(damper, motion, current)


def _batch_length(d, m, c, axes):
    for x, ax in zip((d, m, c), axes):
        if ax == 0:
            return jax.tree.leaves(eqx.filter(x, eqx.is_array))[0].shape[0]
    raise AssertionError("no batched argument")


def _broadcast(x, n):
    arrays, static = eqx.partition(x, eqx.is_array)
    arrays = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), arrays)
    return eqx.combine(arrays, static)


def sweep(
    device: Damper | AbstractHysteresis | Sequence[Damper | AbstractHysteresis],
    motion: AbstractSignal | Sequence[AbstractSignal],
    current: AbstractSignal | ScalarLike | Sequence | Float[ArrayLike, " currents"],
    ts: Float[ArrayLike, " times"],
    *,
    grid: bool = True,
    integrator: AbstractIntegrator | None = None,
    batching: Literal["auto", "vmap", "map"] = "auto",
    batch_size: int | None = None,  # None: one run at a time, see _auto_batching
    throw: bool = True,
    keep: str | Sequence[str] | None = None,
    fitted_range: FittedRange | None = None,
) -> Solution:
    r"""Simulate many runs in one call: over currents, motions and parameter sets.

    Any of `device`, `motion` and `current` may be a list (or tuple) of objects of the
    same type; `current` may also be a 1-D array of constant currents [A]. With
    `grid=True` (default) every combination runs and the solution's leading axes are the
    lengths of the sequences, in the order device, motion, current (single objects add no
    axis). With `grid=False` the sequences are zipped: they must have equal lengths and
    give one leading axis.

    Runs are batched the way that measured fastest on CPU: fixed-step integration under
    `vmap`; adaptive integration with `lax.map`, one run at a time by default (a
    vmapped adaptive batch runs as long as its slowest member, and measured 1.6–2x
    slower than mapping on CPU). With several
    local devices (GPUs, or host devices from
    `XLA_FLAGS=--xla_force_host_platform_device_count=N`) the batch is split across them
    (padded to a whole number of runs per device with copies of its last run, which
    are dropped from the result).

    Over constant currents (a 1-D array, or a list of numbers or `Constant`s) with a
    model whose state equation does not depend on the current (the current laws act
    only on the force, as in `sas_brake_bouc_wen()`; no current dynamics), the states
    are solved once per (device, motion) and the force is evaluated at every current:
    decided at trace time from the model's structure, with the same `Solution` as one
    solve per run.

    **Arguments:** as `simulate`, plus

    - `grid`: outer product (True) or zip (False) of the sequences.
    - `batching`: `"auto"`, `"vmap"` or `"map"`.
    - `batch_size`: runs vmapped together inside each `lax.map` step (default `None`:
      one at a time; ignored by `"vmap"`).
    - `keep`: the `Solution` fields to compute and return, e.g. `("force",)`; the others
      are `None` (`result` and `num_steps` are always kept). Default: all. A large sweep
      spends much of its time writing its outputs: on 1024 brake runs of 10 s, keeping
      only the torque ran 2.3x faster (benchmarks/simulate_sweep.py).
    - `fitted_range`: as in `simulate`, checked after the runs over every run's
      displacement, velocity and current that `keep` kept: one warning for the sweep.
      Default: the devices' own, when they hold one and the same (devices fitted
      on different ranges are checked only against a range given here).

    **Returns:** a `Solution` whose arrays have the sweep's leading axes; with
    `throw=False` each run has its own `result` (a current outside a `TableLaw`'s range
    gives `RESULTS.current_outside_table` for the runs with that current).
    """
    warn_if_float32("jaxmr.sweep", needs=_FLOAT64_NEEDED)
    keep = Solution.check_fields(keep)
    fitted_range = check_fitted_range(fitted_range)
    damper_in = device
    if isinstance(device, (list, tuple)):
        damper_in = [as_damper(d) for d in device]
    _, _, _, integrator = _prepare(
        damper_in[0] if isinstance(damper_in, list) else damper_in,
        motion[0] if isinstance(motion, (list, tuple)) else motion,
        0.0,
        integrator,
    )
    ts = _check_times(ts)
    if batching not in ("auto", "vmap", "map"):
        raise ValueError(
            f"`batching` must be 'auto', 'vmap' or 'map', got {batching!r}."
        )
    if batching == "auto":
        batching = _auto_batching(integrator)

    def as_motion(m):
        if not isinstance(m, AbstractSignal):
            raise TypeError(f"`motion` must be jaxmr signals, got {type(m).__name__}.")
        return m

    devices = _items(damper_in, as_damper, "device")
    if fitted_range is None:
        fitted_range = fitted_range_in(devices[0], strict=False)
    # Off the models before they are stacked and jitted (as in `simulate`).
    devices = ([with_fitted_range(d, None) for d in devices[0]], devices[1])
    currents = _items(current, as_signal, "current")
    batches = [
        _as_batch(*devices, "device"),
        _as_batch(*_items(motion, as_motion, "motion"), "motion"),
        _as_batch(*currents, "current"),
    ]
    sizes = [size for _, size in batches]
    batched = [k for k, s in enumerate(sizes) if s is not None]
    if not batched:
        raise ValueError(
            "sweep needs at least one sequence (of devices, motions or currents); for "
            "a single run use `simulate`."
        )
    if grid:
        shape = tuple(s for s in sizes if s is not None)  # the batched ones
        grids = np.indices(shape).reshape(len(shape), -1)
        index = {k: grids[j] for j, k in enumerate(batched)}
    else:
        lengths = {s for s in sizes if s is not None}
        if len(lengths) != 1:
            raise ValueError(
                "with grid=False the sequences are zipped and must have equal lengths, "
                f"got lengths {[sizes[k] for k in batched]}."
            )
        shape = (lengths.pop(),)
        index = {k: np.arange(shape[0]) for k in batched}
    runs = lambda: _sweep_runs(*devices, *currents, grid) if throw else []  # noqa: E731
    if throw and any(ranged_laws(d.hysteresis) for d in devices[0]):
        _check_sweep_tables(runs())
    shared = _shares_states(devices[0][0], currents, batched, grid, ts.dtype)
    if shared:
        # Solve each (device, motion) pair once; every current rides along whole. With
        # neither batched, one pair: a batch of one keeps the batching machinery.
        pairs = shape[:-1]  # the current is the last axis of a grid, or the only one
        if pairs:
            grids = np.indices(pairs).reshape(len(pairs), -1)
            index = {k: grids[j] for j, k in enumerate(batched[:-1])}
        else:
            batches[1] = _stack([batches[1][0]], "motion")
            index = {1: np.zeros(1, dtype=int)}
    args, axes = [], []
    for k, (module, size) in enumerate(batches):
        if shared and k == 2:  # the whole batch of currents goes to every pair
            module, axis = module, None
        else:
            module, axis = _index(module, size, index.get(k))
        args.append(module)
        axes.append(axis)
    # Spread over every device of every process (padded to a whole number of runs
    # per device, trimmed inside `_sweep`); every process gets the whole solution.
    mesh = batch_mesh()
    n = _batch_length(*args, axes)  # pyright: ignore[reportCallIssue]  # 3 args
    count = padded_size(n, mesh)
    args = [
        spread(pad(a, n, count), mesh) if ax == 0 else a for a, ax in zip(args, axes)
    ]
    d, m, c = args  # device, motion, current
    with _laws_explained(runs):
        solution = _sweep(
            d, m, c, tuple(axes), ts, integrator, batching, batch_size, shape, throw,
            shared, keep,
        )  # fmt: skip
    solution = gather(solution)
    if fitted_range is not None:
        fitted_range.warn(
            "jaxmr.sweep",
            solution.displacement,
            solution.velocity,
            solution.current,
        )
    return solution


def _shares_states(damper, currents, batched, grid, dtype) -> bool:
    """Whether a sweep solves the states once per (device, motion) and evaluates the
    force at every current: the currents are a batch of constants (no jumps), each
    (device, motion) pair meets every current (a grid, or currents alone) and the
    damper's state equation does not depend on the current."""
    items, current_batched = currents
    if not current_batched or not (grid or batched == [2]):
        return False
    if not all(type(c) is Constant for c in items):
        return False
    return _state_ignores_current(damper, dtype)
