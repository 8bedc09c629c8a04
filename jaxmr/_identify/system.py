"""`fit_system`: identify a whole mechanical system (its damper included) from its
measured response to a known excitation.

Where `fit` drives a damper with a measured motion and compares forces, here the system
is simulated by `simulate_system` under the recorded excitation and one of its outputs
(a displacement, an acceleration, ...) is compared with the measurement: the damper's
force is never measured, only its effect on the structure (the Bouc–Wen benchmark of
Noël & Schoukens is this problem). The Levenberg–Marquardt engine, the column scaling,
the statistics and the result are `fit`'s (`jaxmr._identify`).
"""

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._closed_loop import (
    Sampling,
    _as_controller,
    _excitation_checks,
    _simulate_system,
    system_checks,
)
from .._control.base import AbstractController
from .._custom_types import Array, Float
from .._damper import with_fitted_range
from .._integrate import FixedStep
from .._misc import as_float_array, is_concrete, to_device
from .._parameter import fitted_form, free_filter, unwrap
from .._signal import AbstractSignal, _is_uniform, as_signal
from .._systems.base import AbstractSystem
from .data import per_experiment
from .fitting import check_record_lengths, warn_if_float32
from .result import FitResult, assemble, statistics
from .solver import (
    FastLevenbergMarquardt,
    check_budget,
    column_mesh,
    iterate,
    multiply,
    one_start,
    progress_printer,
    scale_and_first_step,
    unscaled_member,
)


def _as_excitation(x) -> AbstractSignal:
    return as_signal(x, "excitation")


def _as_optional_state(x):
    return None if x is None else as_float_array(x)


class SystemRecord(eqx.Module):
    """One measured response of a system to a known excitation, for `fit_system`.

    **Arguments:**

    - `ts`: sample times [s], uniform and starting at 0 (the simulation's start).
    - `measured`: the measured output at `ts`, in the output's unit (e.g. [m] for
      `"body_position"`).
    - `excitation`: the input that produced it: a jaxmr signal (e.g. `Sampled` force
      [N], road height [m]) or a constant; default 0.
    - `initial_state`: the system's state at $t = 0$ (`system.state_names`), or `None`
      for rest; the damper starts virgin either way.
    - `name`: shown in the fit's result.
    """

    ts: Float[Array, " samples"] = eqx.field(converter=as_float_array)
    measured: Float[Array, " samples"] = eqx.field(converter=as_float_array)
    excitation: AbstractSignal = eqx.field(default=0.0, converter=_as_excitation)
    initial_state: Float[Array, " states"] | None = eqx.field(
        default=None, converter=_as_optional_state
    )
    name: str = eqx.field(default="record", static=True)

    def __check_init__(self):
        where = f"SystemRecord {self.name!r}"
        if self.ts.ndim != 1 or self.measured.shape != self.ts.shape:
            raise ValueError(
                f"{where}: `ts` and `measured` must be 1-D arrays of equal length (one "
                f"measured sample per time), got shapes {self.ts.shape} and "
                f"{self.measured.shape}."
            )
        if self.ts.shape[0] < 2:
            raise ValueError(f"{where}: give at least two samples.")
        if not is_concrete(self.ts, self.measured):
            return
        ts, measured = np.asarray(self.ts), np.asarray(self.measured)
        bad = np.flatnonzero(~np.isfinite(measured))
        if bad.size:
            raise ValueError(
                f"{where}: `measured` has a non-finite value (NaN or inf) at index "
                f"{int(bad[0])} (t = {ts[bad[0]]:g} s); drop or repair those samples "
                "(e.g. fit on the finite stretch as its own record)."
            )
        step = ts[1] - ts[0]
        if not (np.all(np.isfinite(ts)) and step > 0 and _is_uniform(ts)):
            raise ValueError(
                f"{where}: `ts` must be uniformly spaced and increasing (the "
                "simulation samples at k·dt); resample the record onto a uniform grid."
            )
        if abs(ts[0]) > 1e-9 * step:
            raise ValueError(
                f"{where}: `ts` must start at 0 (the simulation's start), got "
                f"{ts[0]:g} s; subtract ts[0] (and give the state then as "
                "`initial_state`)."
            )


class _SystemData(eqx.Module):
    """Records padded to a common length and stacked (axis 0: record); the
    excitations stay one per record (they may differ in kind and length)."""

    measured: Float[Array, "records samples"]
    mask: Float[Array, "records samples"]
    weight: Float[Array, " records"]
    excitations: tuple[AbstractSignal, ...]
    initial_states: tuple[Float[Array, " states"] | None, ...]
    samples: tuple[int, ...] = eqx.field(static=True)
    dts: tuple[float, ...] = eqx.field(static=True)
    strides: tuple[int, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)


class _Simulation(eqx.Module):
    """How a candidate system is simulated (the slot `fit` uses for its integrator)."""

    controller: AbstractController
    # The start's parameters: stand-ins while a step has left the valid region, so
    # that `simulate_system`'s own checks never raise inside the fit.
    reference: AbstractSystem
    output: str = eqx.field(static=True)
    substeps: int = eqx.field(static=True)
    delay: int = eqx.field(static=True)


def _stack_records(records, system, dt, discard) -> _SystemData:
    n_states = len(system.state_names)
    skips = per_experiment(discard, records, "discard", "record")
    length = max(r.ts.shape[0] for r in records)
    columns = {"measured": [], "mask": [], "weight": []}
    samples, dts, strides = [], [], []
    for record, skip in zip(records, skips):
        ts, y = np.asarray(record.ts), np.asarray(record.measured)
        n, step = ts.shape[0], float(ts[1] - ts[0])
        if dt is None:
            dts.append(step)
            strides.append(1)
        else:
            stride = int(round(step / dt))
            if stride < 1 or abs(stride * dt - step) > 1e-9 * step:
                raise ValueError(
                    f"`dt` = {dt:g} s must divide the sample time {step:g} s of record "
                    f"{record.name!r} a whole number of times (the simulation is "
                    "compared at every sample), or be None (the sample time)."
                )
            dts.append(float(dt))
            strides.append(stride)
        samples.append(n)
        if record.initial_state is not None and record.initial_state.shape != (
            n_states,
        ):
            raise ValueError(
                f"record {record.name!r}: `initial_state` must have shape ({n_states},) "
                f"for the states {system.state_names}, got "
                f"{record.initial_state.shape}."
            )
        kept = ts >= skip - 1e-9 * step
        if not np.any(kept):
            raise ValueError(
                f"`discard` = {skip:g} s leaves no sample of record {record.name!r} "
                f"(it lasts {ts[-1]:g} s)."
            )
        scale = float(np.std(y[kept]))
        if not scale > 0:
            raise ValueError(
                f"record {record.name!r}: the measured output is constant where it is "
                "scored; there is nothing to fit."
            )
        pad = length - n
        columns["measured"].append(np.concatenate([y, np.zeros(pad)]))
        columns["mask"].append(np.concatenate([kept.astype(float), np.zeros(pad)]))
        # As `fit`'s "nrmse" weighting: the loss is ½ Σ NRMSE², each record counting
        # equally whatever its length and amplitude.
        columns["weight"].append(1.0 / (scale * np.sqrt(np.sum(kept))))
    return _SystemData(
        **{k: to_device(np.stack(v)) for k, v in columns.items()},
        excitations=tuple(r.excitation for r in records),
        initial_states=tuple(r.initial_state for r in records),
        samples=tuple(samples),
        dts=tuple(dts),
        strides=tuple(strides),
        names=tuple(r.name for r in records),
    )


def _validity(system, sim: _Simulation) -> Array:
    """Whether the system passes the checks `simulate_system` makes before it runs
    (`system_checks`: over every current the controller may command)."""
    dtype = jnp.result_type(float)
    checks = system_checks(system, sim.controller.i_max, dtype)
    if not checks:
        return jnp.array(True)
    return jnp.all(jnp.stack([jnp.all(jnp.asarray(check.ok)) for check in checks]))


def _simulate_records(system, data: _SystemData, sim: _Simulation):
    """The simulated output at every record's samples, padded like `data.measured`;
    and whether `system` was valid (if not, the reference system was simulated)."""
    valid = _validity(system, sim)
    arrays, rest = eqx.partition(system, eqx.is_array)
    reference = eqx.filter(sim.reference, eqx.is_array)
    arrays = jax.tree.map(lambda a, b: jnp.where(valid, a, b), arrays, reference)
    system = eqx.combine(arrays, rest)
    length = data.measured.shape[1]
    outputs = []
    # A Python loop, not a vmap: records may differ in length, sample time and in the
    # kind of excitation (a `Sampled` force here, a `Constant` there).
    for k, n in enumerate(data.samples):
        dt, stride = data.dts[k], data.strides[k]
        # The simulation itself, without `simulate_system`'s argument handling and
        # run-time checks: the records were checked once, and `valid` stands an
        # invalid trial point in for the reference, so no check could fire.
        duration = n * stride * dt
        _excitation_checks(data.excitations[k], dt, duration)  # at trace time
        solution = _simulate_system(
            system,
            data.excitations[k],
            sim.controller,
            duration,
            Sampling(dt=dt, delay=sim.delay),
            FixedStep(substeps=sim.substeps),
            data.initial_states[k],
            False,
            checks=False,
        )
        y = solution.outputs[sim.output][::stride][:n]
        outputs.append(jnp.pad(y, (0, length - n)))
    return jnp.stack(outputs), valid


def _system_residuals(free, static, data: _SystemData, sim: _Simulation):
    system = unwrap(eqx.combine(free, static))
    y, valid = _simulate_records(system, data, sim)
    r = (y - data.measured) * data.mask * data.weight[:, None]
    # A diverged simulation, or a step out of the valid region, must not poison the
    # least-squares step with nan: a large finite residual makes it be rejected.
    r = jnp.where(jnp.isfinite(r) & valid, r, 1e6)
    return r.ravel()


def _closed_residuals(static, data: _SystemData, sim: _Simulation):
    """The residual of the free variables (unscaled and scaled by the engine's column
    scale), everything else closed over.

    As compile-time constants the fixed parameters and the data fold away: a `Fixed`
    Bouc–Wen exponent n = 1 removes every power, and the excitation's grid its
    arithmetic. Passed as arguments instead (as `fit` passes them) the benchmark
    oscillator's residual ran 10-25x and its forward-mode Jacobian 2.5x slower. The
    cost: each `fit_system` call compiles anew (the closures are new functions), and
    a long excitation becomes a large constant (the benchmark's five periods at
    30 kHz, 26 MB: the first step, compilation included, took ~7 s).
    The engine's `static`, `data` and `integrator` slots are ignored.
    """

    def residuals(free, _static, _data, _extra):
        return _system_residuals(free, static, data, sim)

    def scaled_residuals(y, _static, _data, scale):
        return _system_residuals(multiply(y, scale), static, data, sim)

    return residuals, scaled_residuals


_simulate_records_jit = eqx.filter_jit(_simulate_records)


def _output_names(system, record: SystemRecord) -> tuple[str, ...]:
    # All inside `eval_shape`: eager, `unwrap`'s exp and the zeros each compiled a
    # program (30 ms of a cold fit).
    def measured(system):
        plain = unwrap(system)
        q = jnp.zeros(len(plain.state_names), dtype=jnp.result_type(float))
        t = jnp.zeros((), dtype=q.dtype)
        return plain.measure(q, t, record.excitation, jnp.zeros_like(t))

    return tuple(sorted(jax.eval_shape(measured, system)))


def fit_system(
    system: AbstractSystem,
    records: SystemRecord | Sequence[SystemRecord],
    *,
    output: str = "body_position",
    controller: AbstractController | float = 0.0,
    dt: float | None = None,
    substeps: int = 4,
    delay: int = 1,
    max_steps: int = 100,
    patience: int = 8,
    ftol: float = 1e-4,
    progress: bool | Callable = True,
    solver: optx.AbstractLeastSquaresSolver | None = None,
    identifiability_threshold: float = 1e-7,
    discard=None,
    stop=None,
) -> FitResult:
    r"""Fit a system's parameters (its damper's included) to measured responses.

    Minimises $\tfrac12 \sum_r \mathrm{NRMSE}_r^2$ with
    $\mathrm{NRMSE}_r = \lVert \hat y_r - y_r \rVert / (\mathrm{std}(y_r)\sqrt{N_r})$,
    where $\hat y_r$ is `simulate_system(system, record.excitation, controller, ...)
    .outputs[output]` at the record's samples and $y_r$ the measurement: each record
    counts equally. Levenberg–Marquardt with exact forward-mode Jacobians through the
    simulation, columns scaled once at the start, stopped on LM's tolerance, on stalled
    progress or at `max_steps`, the best parameters kept on an exception or Ctrl-C
    (all as `jaxmr.fit`). With several devices in the process (a CPU's cores after
    `jaxmr.devices.configure_cpu()`), the Jacobian's columns are split over them: the
    simulation is one sequential loop, and each device pushes its share of the
    tangents (the Bouc–Wen benchmark's step 0.07 s instead of 0.12 s on 2 cores).

    Which parameters are fitted: every array in `system` (mass, stiffness, the damper's
    parameters, ...) except those wrapped in `jaxmr.Fixed`; `jaxmr.Positive` and
    `jaxmr.Bounded` constrain. A step that leaves the region `simulate_system` accepts
    (e.g. a negative mass, or a damper law invalid at any current the controller may
    command) or makes the simulation diverge is rejected, not fatal; the start itself
    must lie in that region (a `ValueError` names the rule it breaks).
    Redundant parameters (a dashpot in both the system and its damper; Bouc–Wen's
    $\alpha$ with $A$, $\beta$, $\gamma$) are reported in `unidentified`: fix one of
    each such set.

    **Arguments:**

    - `system`: a `SingleDegreeOfFreedom`, `QuarterCar`, ... holding its damper; its
      values are the initial guess.
    - `records`: one or more `SystemRecord`s (any lengths; each simulated over its own
      duration, scored at its own samples).
    - `output`: the simulated output compared with `measured` (a name of
      `SystemSolution.outputs`, default `"body_position"`).
    - `controller`: as in `simulate_system`: a constant current [A] (default 0, open
      loop) or a fixed controller (its parameters are not fitted), which reads
      perfect measurements but not the damper being fitted (`sensors=None`): a law
      that inverts the damper runs inside an `ObserverBasedController` with its own
      `DamperObserver`, as it ran on the rig.
    - `dt`: the simulation's sample time [s]; `None` (default): each record's own. A
      smaller `dt` must divide the records' sample times (outputs are compared every
      `sample time / dt` steps).
    - `substeps`: RK4 steps per `dt` (default 4). Use enough that the integration
      error is far below the noise: for a sampled excitation a step at most half the
      excitation's own sample time (its linear interpolation is then exact at the
      RK4 stages when the grids line up).
    - `delay`: the controller's delay in samples, as in `simulate_system`.
    - `max_steps`, `patience`, `ftol`, `progress`, `solver`,
      `identifiability_threshold`, `stop`: as in `jaxmr.fit`.
    - `discard`: the start [s] of each record left out of the residual (one number or
      one per record), e.g. a warm-up period that lets a periodic response reach
      steady state from rest: the simulation still starts at $t = 0$.

    **Returns:** a `jaxmr.FitResult` (`rmse` per record in the output's unit,
    `nrmse` = rmse/std of the measured output, `experiment_names` the records' names).
    """
    warn_if_float32("jaxmr.fit_system")
    check_budget(max_steps, patience)
    if not isinstance(system, AbstractSystem):
        raise TypeError(
            "`system` must be a jaxmr system (SingleDegreeOfFreedom, QuarterCar, ...), "
            f"got {type(system).__name__}."
        )
    system = with_fitted_range(system, None)  # as in `jaxmr.fit`
    if isinstance(records, SystemRecord):
        records = [records]
    records = list(records)
    if not records:
        raise ValueError("`records` is empty: give at least one SystemRecord.")
    for k, record in enumerate(records):
        if not isinstance(record, SystemRecord):
            raise TypeError(
                f"records[{k}] must be a jaxmr.SystemRecord(ts, measured, excitation, "
                f"...), got {type(record).__name__}."
            )
    names = _output_names(system, records[0])
    if output not in names:
        raise ValueError(
            f"`output` = {output!r} is not an output of {type(system).__name__}; "
            f"choose one of {', '.join(names)}."
        )
    if dt is not None and (not isinstance(dt, (int, float)) or not dt > 0):
        raise ValueError(
            f"`dt` must be a positive number of seconds or None, got {dt!r}."
        )
    if not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"`substeps` must be a positive integer, got {substeps!r}.")
    data = _stack_records(records, system, dt, discard)
    system = fitted_form(system)
    free, static = eqx.partition(system, free_filter(system))
    if not jax.tree.leaves(free):
        raise ValueError("nothing to fit: every parameter of `system` is Fixed.")
    check_record_lengths(
        data.names,
        [int(c) for c in np.sum(np.asarray(data.mask) > 0, axis=1)],
        sum(int(np.size(leaf)) for leaf in jax.tree.leaves(free)),
        "record",
    )
    sim = _Simulation(
        controller=_as_controller(controller),
        reference=unwrap(system),
        output=output,
        substeps=substeps,
        delay=delay,
    )
    _check_start(system, sim)
    if solver is None:
        solver = FastLevenbergMarquardt()
    residuals, scaled_residuals = _closed_residuals(static, data, sim)
    # The column scale from the solver's own first step, whose compiled Jacobian the
    # fit then reuses, and which is the fit's first step (as in `fit`;
    # `scale_and_first_step`). The residuals close over
    # `static`: passed as None here as `iterate` is passed it, so that the first
    # step's program is the one the fit reuses (given `static`, whose fixed
    # parameters are arrays, the step compiled twice: 1.4 s more on the Bouc–Wen
    # benchmark).
    # On a multi-core CPU (`jaxmr.devices.configure_cpu`: a device per core) the
    # one simulation loop runs on one core: its Jacobian's columns are split over
    # the devices instead (`column_mesh`).
    columns = column_mesh(solver, free, None)
    scale, first = scale_and_first_step(
        solver, residuals, scaled_residuals, free, None, None, columns
    )
    best_y, (outcome,) = iterate(
        solver,
        # The scaled start, which the first step already holds.
        one_start(free, scale) if first is None else first.outputs[0],
        (scaled_residuals, None, None, scale),
        None,
        max_steps,
        patience,
        ftol,
        progress_printer(progress),
        stop=stop,
        first=first,
        columns=columns,
    )
    free_best = unscaled_member(best_y, scale, 0)
    return _system_result(
        free_best, static, data, sim, residuals, outcome, identifiability_threshold
    )


def _check_start(system, sim: _Simulation) -> None:
    """The start stands in for every invalid trial point (`_validity`): it must pass
    `simulate_system`'s checks itself."""
    start = unwrap(system)
    failed = [
        check.message()
        for check in system_checks(start, sim.controller.i_max, jnp.result_type(float))
        if not bool(np.all(np.asarray(check.ok)))
    ]
    if failed:
        raise ValueError(
            f"fit_system: the start is not a valid {type(start).__name__}: "
            + " ".join(failed)
        )


def _system_result(free, static, data, sim, residuals, outcome, threshold) -> FitResult:
    model = unwrap(eqx.combine(free, static))
    simulated, _ = _simulate_records_jit(model, data, sim)
    mask = np.asarray(data.mask) > 0
    # The residual closes over its own data; `static` gives the parameter values.
    # Its rows are record-major, each record padded to one length: a record's own
    # rows are its scored samples, in time order.
    length = mask.shape[1]
    groups = [k * length + np.flatnonzero(m) for k, m in enumerate(mask)]
    stats = statistics(residuals, free, static, None, None, groups)
    return assemble(
        free,
        static,
        list(np.asarray(simulated)),
        list(np.asarray(data.measured)),
        list(mask),
        data.names,
        stats,
        outcome,
        threshold,
    )
