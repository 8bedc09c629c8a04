"""Closed-loop simulation: a system, its damper and a digital controller."""

import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._control.base import AbstractController, ConstantCurrent, DamperPlant
from ._control.observer import ObserverState
from ._control.observer_based import ObserverBasedController, _NoPlant
from ._control.sampling import Sampling
from ._control.sensors import Sensors, readings
from ._custom_types import Array, Float, PyTree, Scalar
from ._damper import with_fitted_range
from ._fitted_range import FittedRange, check_fitted_range
from ._integrate import FixedStep
from ._metrics import dissipated_energy
from ._misc import Check, guarded, is_concrete, rk4_step, warn_if_float32
from ._road import RandomRoad
from ._signal import AbstractSignal, Sampled, as_signal
from ._solution import RESULTS
from ._systems.base import AbstractSystem
from ._systems.sas_rig import SASRig

_DEGREE = math.pi / 180  # [rad]


def loop_settings(
    who: str, sampling, integrator, deprecated: dict, stacklevel: int = 3
) -> tuple[Sampling, FixedStep]:
    """The checked `sampling` and `integrator` of a closed-loop entry point `who`, with
    the keywords that preceded them (`dt`, `substeps`, `delay`, in `deprecated`)
    still accepted for one release, with a `DeprecationWarning`."""
    unknown = sorted(set(deprecated) - {"dt", "substeps", "delay"})
    if unknown:
        raise TypeError(f"{who}() got an unexpected keyword argument {unknown[0]!r}")
    if deprecated:
        given = [k for k in ("dt", "delay") if k in deprecated]
        if given and sampling is not None:
            raise TypeError(
                f"{who}: give `sampling` alone, not with the deprecated "
                f"{', '.join(f'`{k}`' for k in given)}."
            )
        if "substeps" in deprecated and integrator is not None:
            raise TypeError(
                f"{who}: give `integrator` alone, not with the deprecated `substeps`."
            )
        replacements = []
        if given:
            arguments = ", ".join(f"{k}={deprecated[k]!r}" for k in given)
            replacements.append(f"sampling=jaxmr.Sampling({arguments})")
            sampling = Sampling(**{k: deprecated[k] for k in given})
        if "substeps" in deprecated:
            substeps = deprecated["substeps"]
            replacements.append(f"integrator=jaxmr.FixedStep(substeps={substeps!r})")
            integrator = FixedStep(substeps=substeps)
        names = ", ".join(
            f"`{k}`" for k in ("dt", "substeps", "delay") if k in deprecated
        )
        warnings.warn(
            f"{who}: {names} {'is' if len(deprecated) == 1 else 'are'} deprecated and "
            f"will be removed in the next release; pass {' and '.join(replacements)} "
            "instead.",
            DeprecationWarning,
            stacklevel=stacklevel,
        )
    sampling = Sampling() if sampling is None else sampling
    integrator = FixedStep() if integrator is None else integrator
    if not isinstance(sampling, Sampling):
        raise TypeError(
            f"{who}: `sampling` must be a jaxmr.Sampling(dt, delay), got "
            f"{type(sampling).__name__}."
        )
    if not isinstance(integrator, FixedStep):
        raise TypeError(
            f"{who}: `integrator` must be jaxmr.FixedStep(substeps): the closed loop "
            "takes fixed RK4 steps aligned with the controller's samples (the held "
            f"command jumps at each), got {type(integrator).__name__}."
        )
    return sampling, integrator


class SystemSolution(eqx.Module):
    """The result of `simulate_system`, sampled at the controller's rate (every array
    gains leading axes under `vmap`).

    **Attributes:**

    - `ts`: sample times $t_k = k\\,dt$ [s].
    - `outputs`: the measurements at each sample (`jaxmr.constants.MEASUREMENT_NAMES` plus the
      system's own), e.g. `outputs["body_acceleration"]` [m/s²].
    - `command`: the controller's output at each sample [A].
    - `applied`: the command acting on the damper over $[t_k, t_{k+1})$ [A] (the
      command `sampling.delay` samples earlier, held).
    - `current`: the effective current the damper's model saw at $t_k$ [A], just
      after the command applied at $t_k$ (the outputs, `damper_force` among them,
      are read just before it: `outputs["damper_force"][k]` is the force at
      `current[k - 1]`).
    - `states`: system state then damper state at each sample.
    - `final_state`: the state at the end, `duration` [s].
    - `result`: a `jaxmr.RESULTS` code.
    - `dt`: the sample time [s] (a Python number, for filters that need it concrete).
    - `measured`: with `sensors`, the readings the controller got at each sample, by
      name (each in its measurement's unit); `None` with perfect information (it read
      `outputs`).
    - `controller_states`: the controller's state after each sample (a pytree of
      arrays with a leading samples axis, `()` for a law without memory), e.g. an
      `ObserverBasedController`'s observed damper state.
    """

    ts: Float[Array, "*batch samples"]
    outputs: dict[str, Float[Array, "*batch samples"]]
    command: Float[Array, "*batch samples"]
    applied: Float[Array, "*batch samples"]
    current: Float[Array, "*batch samples"]
    states: Float[Array, "*batch samples states"]
    final_state: Float[Array, "*batch states"]
    result: RESULTS
    state_names: tuple[str, ...] = eqx.field(static=True)
    dt: float = eqx.field(static=True, default=1e-3)
    measured: dict[str, Float[Array, "*batch samples"]] | None = None
    controller_states: PyTree = ()

    def __getitem__(self, name: str) -> Float[Array, "*batch samples"]:
        """`solution["body_acceleration"]`: an output by name."""
        if name not in self.outputs:
            raise KeyError(f"no output {name!r}; outputs are {sorted(self.outputs)}.")
        return self.outputs[name]

    @property
    def power(self) -> Float[Array, "*batch samples"]:
        """Power the damper dissipates, $F v$ [W]."""
        return self.outputs["damper_force"] * self.outputs["damper_velocity"]


def _as_controller(controller) -> AbstractController:
    if isinstance(controller, AbstractController):
        return controller
    if isinstance(controller, (int, float)) or eqx.is_array_like(controller):
        return ConstantCurrent(controller)
    raise TypeError(
        "`controller` must be a jaxmr controller (ConstantCurrent, Skyhook, ...) or a "
        f"constant current [A], got {type(controller).__name__}."
    )


def _check_arguments(system, excitation, duration, sampling: Sampling):
    if not isinstance(system, AbstractSystem):
        raise TypeError(
            "`system` must be a jaxmr system (QuarterCar, SingleDegreeOfFreedom, "
            f"SASRig, ...), got {type(system).__name__}."
        )
    dt = sampling.dt
    if not isinstance(duration, (int, float)) or duration < dt:
        raise ValueError(
            f"`duration` must be a number of seconds >= the sample time "
            f"sampling.dt = {dt}, got {duration!r}."
        )
    samples = duration / dt
    if abs(samples - round(samples)) > 1e-6 * max(1.0, samples):
        # The loop runs whole samples: 0.0105 s at 1 ms had run 0.010 s silently.
        raise ValueError(
            f"`duration` = {duration!r} s is not a whole number of samples of "
            f"sampling.dt = {dt} s ({samples:.6g}): give a multiple of it, e.g. "
            f"{round(samples) * dt:.6g} s."
        )
    return as_signal(excitation, "excitation")


# `sensors="oracle"`: perfect information, the simulated device included.
ORACLE = "oracle"


def check_sensors(
    sensors, key, who: str = "simulate_system", key_name: str = "key"
) -> Sensors | str | None:
    """`sensors` checked against its noise `key` (named `key_name` in `who`'s
    errors): a `Sensors` set, `None` (perfect readings, no device) or `ORACLE`
    (perfect readings and the device): what `simulate_system` and every tuner
    accept."""
    if sensors is None or (isinstance(sensors, str) and sensors == ORACLE):
        if key is not None:
            raise ValueError(
                f"{who}: `{key_name}` draws the sensors' noise; give it with "
                "`sensors=` (e.g. jaxmr.realistic_sensors(system)), not with the "
                f"perfect readings of `sensors={sensors!r}`."
            )
        return sensors
    if not isinstance(sensors, Sensors):
        raise TypeError(
            f"{who}: `sensors` must be a jaxmr.Sensors set (e.g. "
            "jaxmr.realistic_sensors(system)), None (perfect readings, the default) "
            f'or "oracle" (perfect information, the device included), got {sensors!r}.'
        )
    if not isinstance(key, jax.Array):
        raise TypeError(
            f"{who}: `sensors` need `{key_name}=jax.random.key(...)` for their noise, "
            f"got {type(key).__name__}."
        )
    return sensors


def system_checks(system, i_max, dtype) -> list[Check]:
    """What `simulate_system` checks before it runs: the system's own constraints and
    its damper's laws over every current the controller may command, [0, `i_max`]
    [A]. `fit_system` asks the same of each trial point (`_validity`)."""
    zero = jnp.zeros((), dtype)
    return list(system.constraints()) + system.damper.hysteresis.checks_over(
        zero, jnp.asarray(i_max, dtype)
    )


def _system_checks(system, q0, i_max):
    # The message quotes a value only where it is concrete (`Check.message`).
    return guarded(
        q0,
        system_checks(system, i_max, q0.dtype),
        prefix=f"{type(system).__name__}: ",
        suffix=" (found while simulating).",
    )


def _excitation_checks(excitation, dt, duration):
    # A sampled road is only as fine as its samples: coarser than the controller's
    # sample time, the simulation would interpolate away the content it runs at; and
    # past its end it would hold its last value. Its grid is static, so these are
    # plain errors at trace time.
    if isinstance(excitation, Sampled) and is_concrete(excitation.times):
        # A measured profile (a `Sampled` road) held its last height past its end
        # without a word, where a `RandomRoad` of the same length is refused.
        times = np.asarray(excitation.times)
        # Within a sample of the end: a record of N samples spans (N - 1) intervals,
        # and a run of N samples ends one interval later.
        spacing = float(times[-1] - times[-2]) if times.size > 1 else 0.0
        end = float(times[-1])
        if end < duration - max(dt, spacing) - 1e-9:
            raise ValueError(
                f"the excitation (a Sampled signal) ends at {end:g} s, before the "
                f"simulation's duration = {duration} s: past its end it would hold "
                "its last value. Give samples up to the duration, or a shorter "
                "duration."
            )
        return
    if not isinstance(excitation, RandomRoad):
        return
    if excitation.dt > dt * (1 + 1e-9):
        raise ValueError(
            f"the road is sampled more coarsely (dt = {excitation.dt} s) than the "
            f"controller's sample time sampling.dt = {dt} s: generate it with `dt` "
            "at most that (e.g. iso8608_road(..., dt=...))."
        )
    if excitation.end < duration - 1e-9:
        raise ValueError(
            f"the road ends before the simulation's duration = {duration} s (at "
            f"{excitation.end} s): generate it at least that long."
        )


def simulate_system(
    system: AbstractSystem,
    excitation: AbstractSignal | float,
    controller: AbstractController | float,
    duration: float,
    *,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    initial_state: Float[Array, " states"] | None = None,
    throw: bool = True,
    unroll: int = 1,
    fitted_range: FittedRange | None = None,
    sensors: Sensors | str | None = None,
    key: jax.Array | None = None,
    **deprecated,
) -> SystemSolution:
    r"""Simulate a system with its damper under a digital controller.

    Every `sampling.dt` the controller reads the measurements and commands a current;
    the command reaches the damper `sampling.delay` samples later and is held until the
    next one (sample-and-hold). The damper's own current dynamics (`FirstOrderLag` in
    its `Damper`) then filter it. In between, the system and damper states are
    integrated together by `integrator.substeps` classical RK4 steps: the hold makes the
    right-hand side discontinuous at every sample, so a fixed step aligned with the
    samples is both exact in that respect and the fast choice (a `lax.scan`,
    differentiable in both modes; each sample is rematerialised in reverse mode to keep
    memory to the states).

    **Arguments:**

    - `system`: a `QuarterCar`, `SingleDegreeOfFreedom`, `SASRig`, or your own
      `AbstractSystem`, holding its damper.
    - `excitation`: the input signal: road height [m], cam lift [m] or force [N]
      (a jaxmr signal or a constant).
    - `controller`: a jaxmr controller, or a number for a constant current [A].
    - `duration`: simulated time [s] (python float: it sets the number of samples).
    - `sampling`: the controller's sample time and delay, a `Sampling` (default: an
      `ObserverBasedController`'s own `sampling`, else `Sampling()`).
    - `integrator`: the RK4 steps per sample, a `FixedStep`. Default: chosen from
      the damper's own stiffness along the run, as `fit`'s `StepPolicy` chooses its
      steps from the motion: `FixedStep()` (4 substeps) where the largest rate λ
      [1/s] of the damper's states (the norm of the Jacobian of their rates, which
      grows with |v| for a hysteretic state) keeps h·λ <= 2 (RK4 is stable below
      2.78), else the run again with the next power of two of substeps that does,
      or 16 times as many after a diverged run (at most 1024). A stiff fitted model
      driven far beyond its data (a Spencer fit of ±0.09 m/s rig data at 2 m/s in
      `passenger_car`) needs 64. Under jit, vmap or grad `FixedStep()` is used as is.
    - `initial_state`: the system's state at $t = 0$ (default: its rest state); the
      damper starts virgin, its current dynamics in steady state at the first command.
    - `throw`: raise on failure (default); `False` returns the code in `result`. A
      non-finite solve raises with what to change (the substeps to try, the fitted
      range).
    - `unroll`: substeps unrolled in the compiled loop (default 1). Unrolled, XLA
      fuses across substeps and the reverse pass loses a nested loop, but with
      `jaxmr.devices.configure_cpu`'s flags `jaxmr.tune`'s gradient gained nothing
      with 4 (as fast for a skyhook, 4x slower for an observer-based controller on
      realistic sensors) and compiled 1.7-2.3x longer. The forward pass gains
      nothing and can lose much: the Bouc–Wen benchmark oscillator's residual (20
      substeps, a long sampled excitation) ran 10x slower with 8, its forward-mode
      Jacobian 2.6x, and compiling took 3-6x longer.
    - `fitted_range`: the range the damper's model was fitted on (`jaxmr.FittedRange`);
      default: the damper's own (`system.damper.fitted_range`, which `load_model`
      sets from the file: `passenger_car(jaxmr.load_model("params.json"))` is
      checked with no argument). When the damper's displacement, velocity or
      current leave it, warn once (`OutsideFittedRange`) naming each interval
      exceeded and by how much, before raising if the run failed (a damper driven
      far beyond its data is a common cause). Skipped when traced (under jit, vmap
      or grad).
    - `sensors`: what the controller reads (an `ObserverBasedController` is handed
      the device in every case and decides itself what its law inverts: its
      observer's damper, or with `oracle=True` the device):
        - `None` (default): perfect readings of every measurement the system
          gives, by name, and the time; but no device: a bare law that inverts the
          damper (`DamperPlant`: `Skyhook`, `Groundhook`, `Hybrid`,
          `ContinuousClippedOptimal`, `PowerDrivenDamper`, `Backstepping`,
          `ForceFeedback`) raises, saying to run it inside
          `ObserverBasedController(law, estimator=...,
          observer=DamperObserver(nominal_model))`, which inverts its own nominal
          model at its observed state, as a real controller must. Laws that invert
          nothing (`ConstantCurrent`, `OnOffSkyhook`, ...) run as with `"oracle"`,
          to the bit.
        - `"oracle"`: perfect information, for research comparisons only: the
          readings above and the simulated device itself, at its true hysteretic
          state, for a bare law's inverse model, which no real controller has.
        - A `Sensors` set (e.g. `realistic_sensors(system)`): the controller reads
          only those sensors' readings (noise, bias, bandwidth, quantisation,
          sample-and-hold) and the time; a law then runs inside an
          `ObserverBasedController`, which estimates the velocities and observes the
          damper's state (a bare law that inverts the damper, or reads a quantity no
          sensor gives, raises saying so). The readings are in `measured`.
    - `key`: the `jax.random` key of the sensors' noise, required with `sensors`
      (the run's noise is `sensors.noise(key, samples)`, row $k$ for sample $k$;
      gradients flow through the sampled noise).

    The keywords `dt`, `substeps` and `delay` of earlier releases still work, with a
    `DeprecationWarning`: they are `sampling=Sampling(dt, delay)` and
    `integrator=FixedStep(substeps)`.

    **Returns:** a `SystemSolution`.
    """
    warn_if_float32(
        "jaxmr.simulate_system",
        needs="closed-loop simulations need float64 (accumulated time and the "
        "gradients of tuning lose their digits in float32)",
    )
    # Numbers become arrays before the jit boundary: a Python float current or
    # excitation would be a static argument there, one compilation per value.
    # No step given: it is chosen from the damper's stiffness (`_with_chosen_steps`).
    choose = integrator is None and "substeps" not in deprecated
    controller = _as_controller(controller)
    own = (
        controller.sampling if isinstance(controller, ObserverBasedController) else None
    )
    if sampling is None and own is not None and not {"dt", "delay"} & set(deprecated):
        sampling = own
    sampling, integrator = loop_settings(
        "simulate_system", sampling, integrator, deprecated
    )
    if own is not None and (own.dt, own.delay) != (sampling.dt, sampling.delay):
        raise ValueError(
            "simulate_system: the ObserverBasedController steps its filters and "
            f"observer at {own}, but the loop samples at {sampling}: give the "
            "controller the loop's `sampling` (or leave `sampling` out here)."
        )
    sensor_set = check_sensors(sensors, key)
    excitation = _check_arguments(system, excitation, duration, sampling)
    _excitation_checks(excitation, sampling.dt, duration)
    if not isinstance(unroll, int) or not 1 <= unroll:
        raise ValueError(f"`unroll` must be a positive integer, got {unroll!r}.")
    fitted_range = check_fitted_range(fitted_range)
    if fitted_range is None:
        fitted_range = system.damper.hysteresis.fitted_range
    # Read here, outside the jit: off the system, a loaded damper shares the
    # compilation of the same damper built in code.
    system = with_fitted_range(system, None)
    traced = not is_concrete(
        eqx.filter(
            (system, excitation, controller, initial_state, sensor_set, key),
            eqx.is_array,
        )
    )

    def run(integrator, throw):
        return _simulate_system(
            system,
            excitation,
            controller,
            duration,
            sampling,
            integrator,
            initial_state,
            throw,
            min(unroll, integrator.substeps),
            sensor_set,
            key,
        )

    if traced:  # no value to look at: the solve raises by itself
        return run(integrator, throw)
    # Concrete: failures are raised below, after the step is chosen and the range
    # checked, with advice.
    solution = run(integrator, False)
    if choose:
        solution, integrator = _with_chosen_steps(
            run, system, excitation, sampling, integrator, solution
        )
    if solution.result != RESULTS.nonfinite:
        _warn_stiff_observer(controller, sampling, solution)
    if fitted_range is not None:
        outputs = solution.outputs
        fitted_range.warn(
            "jaxmr.simulate_system",
            outputs.get("damper_displacement"),
            outputs.get("damper_velocity"),
            solution.current,
        )
    if throw and solution.result == RESULTS.nonfinite:
        raise eqx.EquinoxRuntimeError(
            _diverged_advice(sampling, integrator, choose, fitted_range)
        )
    if throw:
        solution = solution.result.error_if(
            solution, solution.result != RESULTS.successful
        )
    return solution


# The closed loop's default step (`simulate_system` with no `integrator`): `FixedStep()`
# where the damper's stiffness allows h·λ <= 2 (RK4 is stable below 2.78), else the
# next power of two of substeps that does, up to `_MOST_SUBSTEPS`.
_STEP_STIFFNESS = 2.0
_MOST_SUBSTEPS = 1024


def choose_substeps(run, failed, stiffness, dt: float, integrator, result):
    """`run(integrator)` again with more substeps while `failed(result)` (16 times
    as many: a diverged run's stiffness is read from nonsense states) or the
    damper's stiffness `stiffness(result)` [1/s] asks for more (h·λ <= 2, rounded
    up to a power of two), as `fit`'s `StepPolicy` chooses its steps from the
    motion; `result` is the run at `integrator`. A run that is stable at it is
    returned as it is. **Returns:** `(result, integrator)`, the last run's."""
    substeps = integrator.substeps
    for _ in range(6):
        if failed(result):
            needed = 16 * substeps  # each new count costs a compilation, of seconds
        else:
            needed = dt * stiffness(result) / _STEP_STIFFNESS
            needed = 2 ** math.ceil(math.log2(needed)) if needed > 1 else 1
        if needed <= substeps or substeps >= _MOST_SUBSTEPS:
            break
        substeps = min(needed, _MOST_SUBSTEPS)
        integrator = FixedStep(substeps=substeps)
        result = run(integrator)
    return result, integrator


def _with_chosen_steps(run, system, excitation, sampling, integrator, solution):
    """`simulate_system`'s run (`run(integrator, throw)`, `solution` at
    `integrator`) at the substeps `choose_substeps` chooses from its damper's
    stiffness (`_damper_stiffness`)."""
    return choose_substeps(
        lambda integrator: run(integrator, False),
        lambda solution: bool(solution.result == RESULTS.nonfinite),
        lambda solution: float(_damper_stiffness(system, excitation, solution)),
        sampling.dt,
        integrator,
        solution,
    )


def steps_for_runs(who: str, runs, duration: float, sampling: Sampling) -> FixedStep:
    """The RK4 substeps per sample that `simulate_system` with no `integrator`
    chooses, for the stiffest of several runs: what a batch that runs under `vmap`
    (and so cannot choose per run) takes. Each run is `(name, system, excitation,
    controller, sensors, key)` (`name` for the error, e.g. "road 2"; `sensors` as
    `check_sensors` returns it), simulated concretely, one at a time, from `FixedStep()`
    on. Where the runs' damper holds its fitted range, one `OutsideFittedRange`
    warning (from `who`) covers every run that leaves it. `ValueError`, with what to
    change, when a run still diverges at the most substeps (`_MOST_SUBSTEPS`)."""
    runs = list(runs)
    for _, system, excitation, *_ in runs:
        excitation = _check_arguments(system, excitation, duration, sampling)
        _excitation_checks(excitation, sampling.dt, duration)
    fitted_range = runs[0][1].damper.hysteresis.fitted_range if runs else None
    # Off the systems, as in `simulate_system`: one compilation with or without.
    runs = [(n, with_fitted_range(system, None), *rest) for n, system, *rest in runs]

    def run(integrator):
        return [
            _simulate_system(
                system,
                excitation,
                _as_controller(controller),
                duration,
                sampling,
                integrator,
                initial_state=None,
                throw=False,
                sensors=sensors,
                key=key,
            )
            for _, system, excitation, controller, sensors, key in runs
        ]

    def diverged(solutions):
        return [
            k
            for k, solution in enumerate(solutions)
            if bool(solution.result == RESULTS.nonfinite)
        ]

    def stiffness(solutions):
        return max(
            float(_damper_stiffness(system, excitation, solution))
            for (_, system, excitation, *_), solution in zip(runs, solutions)
        )

    first = FixedStep()
    solutions, integrator = choose_substeps(
        run,
        lambda solutions: bool(diverged(solutions)),
        stiffness,
        sampling.dt,
        first,
        run(first),
    )
    if fitted_range is not None:
        outputs = [solution.outputs for solution in solutions]
        fitted_range.warn(
            who,
            np.concatenate([np.ravel(o["damper_displacement"]) for o in outputs]),
            np.concatenate([np.ravel(o["damper_velocity"]) for o in outputs]),
            np.concatenate([np.ravel(solution.current) for solution in solutions]),
            stacklevel=5,  # the caller of the tuner: tuner, `choose_integrator`, here
        )
    failed = diverged(solutions)
    if failed:
        raise ValueError(
            f"{who}: the starting parameters' run on {runs[failed[0]][0]} diverged "
            "(inf or nan) "
            f"even at the {integrator.substeps} RK4 substeps per {sampling.dt:g} s "
            f"sample chosen from the damper's stiffness (at most {_MOST_SUBSTEPS}): a "
            f"shorter `sampling=jaxmr.Sampling(dt={sampling.dt / 4:g})` may help. A "
            "fitted damper driven far beyond the range it was fitted on is a common "
            "cause: `jaxmr.simulate_system` of that run warns where the damper holds "
            "its range (`jaxmr.load_model` gives it)."
        )
    return integrator


def step_advice(sampling, integrator, chosen: bool, who="simulate_system") -> str:
    """What to change when a closed-loop run at `integrator` went non-finite
    (`chosen`: the substeps `who` chose from the damper's stiffness)."""
    substeps = integrator.substeps
    if chosen:
        return (
            f"the damper diverged even at the {substeps} RK4 substeps per sample that "
            f"{who} chose (at most {_MOST_SUBSTEPS}); a shorter "
            f"`sampling=jaxmr.Sampling(dt={sampling.dt / 4:g})` may help"
        )
    return (
        f"the {substeps} RK4 substeps per {sampling.dt:g} s sample are too long "
        "for the damper's stiffness at this motion: pass "
        f"`integrator=jaxmr.FixedStep(substeps={4 * substeps})` or more, or no "
        f"`integrator` ({who} then chooses the substeps from the damper's "
        "stiffness)"
    )


def _diverged_advice(sampling, integrator, chosen, fitted_range) -> str:
    """The error of a closed-loop solve that went non-finite: what to change."""
    step = step_advice(sampling, integrator, chosen)
    if fitted_range is None:
        where = (
            "A fitted model driven beyond the range it was fitted on is a common "
            "cause; this damper holds no fitted range to check: read it with "
            "`jaxmr.load_model` from the file `jaxmr fit` wrote, or pass "
            "`fitted_range=jaxmr.load_fitted_range(params)`"
        )
    else:
        where = (
            "If an OutsideFittedRange warning came first, the model is driven beyond "
            "the range it was fitted on: refit on data that cover the motion"
        )
    return (
        "Nonfinite (inf or nan) values detected during the closed-loop solve: "
        f"{step}. {where}."
    )


@eqx.filter_jit
@eqx.filter_jit
def _observer_stiffness(observer, states) -> Scalar:
    """`_damper_stiffness` of a `DamperObserver`'s nominal damper along its own
    states over a run (`ObserverState`s stacked by sample) [1/s]."""

    def at(s, x, v, command):
        jacobian = jax.jacfwd(lambda s: observer.model.rates(s, x, v, command))(s)
        norm = jnp.max(jnp.sum(jnp.abs(jacobian), axis=-1), initial=0.0)
        return jnp.where(jnp.isfinite(norm), norm, 0.0)

    return jnp.max(
        jax.vmap(at)(states.damper, states.x, states.v, states.commands[:, 0])
    )


# An observer is warned of where its steps' h·λ (`_observer_stiffness`, a bound of
# the largest rate, max over the run) exceeds the loop's own rule (`_STEP_STIFFNESS`,
# 2). Measured (session 27; ISO D road at 25 m/s, realistic sensors, relaxed skyhook,
# 0-1 A): the passenger car's own damper as the observer's model reads 0.2-0.6 at 4
# substeps, and its commands agree with 256 substeps' to 2e-4 A; the UTFSM Spencer
# damper reads 7.9 at 4 substeps (commands 0.31 A from 256 substeps'), 2.0 at 16
# (0.11 A) and 0.5 at 64 (4e-6 A). The rule is a bound, not a guarantee: the
# recommended count is where to start.


def _warn_stiff_observer(controller, sampling: Sampling, solution) -> None:
    """Warn where an `ObserverBasedController`'s `DamperObserver` integrates its
    nominal damper with steps too long for its stiffness along the run (h·λ above
    2, the loop's own rule): its state, and so the law's commands, are then off
    (by 0.31 A in the case above), and the exported C parts from JAX, as rounding
    grows from step to step."""
    observer = getattr(controller, "observer", None)
    states = getattr(solution.controller_states, "observer", None)
    if observer is None or not isinstance(states, ObserverState):
        return
    stiffness = float(_observer_stiffness(observer, states))
    ratio = sampling.dt / observer.substeps * stiffness
    if ratio > _STEP_STIFFNESS:
        needed = 2 ** math.ceil(math.log2(sampling.dt * stiffness / _STEP_STIFFNESS))
        warnings.warn(
            f"simulate_system: the DamperObserver's {observer.substeps} RK4 substeps "
            f"per sample step its nominal damper at h·λ = {ratio:.3g} along this run "
            f"(a bound of its largest rate; above {_STEP_STIFFNESS:g}, the loop's "
            "own rule, its state and so the commands lose accuracy): give it "
            f"`substeps={needed}`, or a nominal damper that is less stiff.",
            UserWarning,
            stacklevel=3,
        )


def _damper_stiffness(system, excitation, solution: SystemSolution) -> Scalar:
    """The largest rate [1/s] at which the damper's states respond to themselves over
    a run, max over its samples of the row-sum norm of the Jacobian of the damper's
    rates with respect to its states (which bounds every eigenvalue's modulus). For a
    hysteretic state it is of order |v| over the travel in which the state relaxes,
    so it follows the motion as `StepPolicy`'s travel limit does; RK4 is stable for
    steps h with h·λ below 2.78. Samples that are not finite are left out."""
    nq = len(system.state_names)
    damper = system.damper

    def at(y, t, applied):
        q, s = y[:nq], y[nq:]
        x, v = system.damper_motion(q, t, excitation)
        jacobian = jax.jacfwd(lambda s: damper.rates(s, x, v, applied))(s)
        norm = jnp.max(jnp.sum(jnp.abs(jacobian), axis=-1), initial=0.0)
        return jnp.where(jnp.isfinite(norm), norm, 0.0)

    return jnp.max(jax.vmap(at)(solution.states, solution.ts, solution.applied))


@eqx.filter_jit
def _simulate_system(
    system,
    excitation,
    controller,
    duration,
    sampling: Sampling,
    integrator: FixedStep,
    initial_state,
    throw,
    unroll=1,
    sensors: Sensors | str | None = None,
    key=None,
    checks: bool = True,
) -> SystemSolution:
    dt, delay, substeps = sampling.dt, sampling.delay, integrator.substeps
    samples = int(round(duration / dt))
    damper = system.damper
    t0 = jnp.zeros((), dtype=jnp.result_type(float))
    q0 = (
        system.initial_state(excitation, t0)
        if initial_state is None
        else jnp.asarray(initial_state, dtype=t0.dtype)
    )
    if q0.shape != (len(system.state_names),):
        raise ValueError(
            f"`initial_state` must have shape ({len(system.state_names)},) for the "
            f"states {system.state_names}, got {q0.shape}."
        )
    # The checks guard a value the loop uses (an unused `error_if` is optimised away).
    # `checks=False`: the caller asked `system_checks` itself (`fit_system` swaps an
    # invalid trial point for a valid one).
    i_max = jnp.asarray(controller.i_max, dtype=t0.dtype)
    if checks:
        q0 = _system_checks(system, q0, i_max)
    nq = q0.shape[0]

    def split(y):
        return y[:nq], y[nq:]

    def observe(y, t, applied):
        q, s = split(y)
        x, v = system.damper_motion(q, t, excitation)
        force = damper.force(s, x, v, applied)
        measurement = system.measure(q, t, excitation, force)
        measurement["time"] = t
        return measurement, DamperPlant(damper, s, x, v)

    def vector_field(t, y, applied):
        q, s = split(y)
        x, v = system.damper_motion(q, t, excitation)
        force = damper.force(s, x, v, applied)
        return jnp.concatenate(
            [system.rates(q, t, excitation, force), damper.rates(s, x, v, applied)]
        )

    # What the controller reads: the truth (perfect readings), or the sensors'
    # readings at sample k; and the device only with the oracle's perfect
    # information, or for an `ObserverBasedController`, which decides itself what its
    # law may invert (its observer's damper, or the device on `oracle=True`).
    blind = not isinstance(controller, ObserverBasedController)

    def read(truth, plant, sensor_state, k, eps):
        if not isinstance(sensors, Sensors):
            if blind and sensors is None:
                plant = _NoPlant(why=_NO_DEVICE)
            return truth, plant, sensor_state
        values, sensor_state = sensors.step(sensor_state, truth, eps, k, dt)
        values["time"] = truth["time"]
        if blind:
            plant = _NoPlant(why=_BLIND)
        return readings(values), plant, sensor_state

    # The first command is decided on the rest state, with the damper at zero current.
    x0, v0 = system.damper_motion(q0, t0, excitation)
    s_probe = damper.initial_state(x0, v0, jnp.zeros_like(t0))
    truth0, plant0 = observe(jnp.concatenate([q0, s_probe]), t0, jnp.zeros_like(t0))
    if not isinstance(sensors, Sensors) or key is None:
        sensor0 = ()
        noise = jnp.zeros((samples, 0), t0.dtype)  # nothing to draw
    else:
        sensor0 = sensors.init(truth0)
        noise = sensors.noise(key, samples, t0.dtype)
    k0 = jnp.zeros((), dtype=int)
    m0, plant0, _ = read(truth0, plant0, sensor0, k0, noise[0])
    c_state0 = controller.init(m0)
    first, _ = controller(m0, c_state0, plant0)
    y0 = jnp.concatenate([q0, damper.initial_state(x0, v0, first)])
    pending0 = jnp.full((max(delay, 1),), first, dtype=t0.dtype)

    def sample(carry, inputs):
        y, c_state, pending, applied_before, sensor_state = carry
        k, eps = inputs
        t = k.astype(t0.dtype) * dt
        measurement, plant = observe(y, t, applied_before)
        seen, plant, sensor_state = read(measurement, plant, sensor_state, k, eps)
        command, c_state = controller(seen, c_state, plant)
        command = jnp.asarray(command, dtype=t0.dtype)
        if delay == 0:
            applied = command
        else:
            applied = pending[0]
            pending = jnp.concatenate([pending[1:], command[None]])
        h = dt / substeps
        y_next = jax.lax.fori_loop(
            0,
            substeps,
            lambda j, y: rk4_step(vector_field, t + j * h, y, h, applied),
            y,
            unroll=unroll,  # see `simulate_system`
        )
        _, s = split(y)
        record = (
            measurement,
            command,
            applied,
            damper.effective_current(s, applied),
            y,
            {n: seen[n] for n in sensors.names}
            if isinstance(sensors, Sensors)
            else None,
            c_state,
        )
        return (y_next, c_state, pending, applied, sensor_state), record

    sample = jax.checkpoint(sample, prevent_cse=False)
    ks = jnp.arange(samples)
    carry = (y0, c_state0, pending0, first, sensor0)
    (y_end, *_), records = jax.lax.scan(sample, carry, (ks, noise))
    outputs, command, applied, current, states, measured, c_states = records
    ts = outputs.pop("time")

    slack = 1e-9 * (1 + i_max)
    in_range = jnp.all((command >= -slack) & (command <= i_max + slack))
    finite = jnp.all(jnp.isfinite(states)) & jnp.all(jnp.isfinite(y_end))
    # jaxmr's RESULTS extends diffrax's, whose codes pyright types as diffrax's enum.
    result = RESULTS.where(finite, RESULTS.successful, RESULTS.nonfinite)  # pyright: ignore[reportArgumentType]
    result = RESULTS.where(
        (result == RESULTS.successful) & ~in_range, RESULTS.command_out_of_range, result
    )
    solution = SystemSolution(
        ts=ts,
        outputs=outputs,
        command=command,
        applied=applied,
        current=current,
        states=states,
        final_state=y_end,
        result=result,
        state_names=system.state_names + damper.state_names,
        dt=float(dt),
        measured=measured,
        controller_states=c_states,
    )
    if throw:
        solution = result.error_if(solution, result != RESULTS.successful)
    return solution


_BLIND = (
    "With `sensors`, a controller reads only their readings: this law inverts the "
    "damper, whose state no sensor gives. Run it inside "
    "jaxmr.ObserverBasedController(law, estimator=jaxmr.VelocityEstimator(), "
    "observer=jaxmr.DamperObserver(nominal_damper)), which observes that state with "
    "its own model (or, for research comparisons only, oracle=True)."
)
_NO_DEVICE = (
    "This law inverts the damper at its hysteretic state, which no sensor gives, "
    "and simulate_system's default `sensors=None` hands a controller perfect "
    "readings but not the simulated device. Run the law as a real controller would, "
    "inside jaxmr.ObserverBasedController(law, observer=jaxmr.DamperObserver("
    "nominal_damper)), which inverts its own nominal model at its observed state "
    "(add `estimator=jaxmr.VelocityEstimator()` where the sensors give no "
    'velocities); or pass `sensors="oracle"` (simulate_system, '
    "tune, cma_es, random_search, evaluate) for research comparisons with perfect "
    "information, the device's true state included."
)


def dissipated_work(solution: SystemSolution) -> Scalar:
    """$\\int F v\\,dt$ [J]: the work the damper absorbed over the run (trapezoid,
    `jaxmr.metrics.dissipated_energy` of the solution's samples) of a closed-loop
    run (`simulate_system`)."""
    if not isinstance(solution, SystemSolution):
        raise TypeError(
            "dissipated_work takes a closed-loop run (`simulate_system`), got a "
            f"{type(solution).__name__}; for a damper under prescribed motion use "
            "jaxmr.metrics.energy_per_cycle or dissipated_energy(sol.ts, sol.force, "
            "sol.velocity)."
        )
    outputs = solution.outputs
    return dissipated_energy(
        solution.ts, outputs["damper_force"], outputs["damper_velocity"]
    )


# -- the SAS study's identification experiment -------------------------------------


@eqx.filter_jit
def _release_state(rig: SASRig, release):
    rest = rig.equilibrium()
    return rig.held_state(rest[1] + release), rest


def free_decay(
    rig: SASRig,
    controller=0.0,
    *,
    release_angle_deg: float = 16.0,
    duration: float = 15.0,
    sampling: Sampling | None = None,
    integrator: FixedStep | None = None,
    sensors: Sensors | str | None = None,
    key: jax.Array | None = None,
    **deprecated,
):
    r"""The source's identification experiment: the body held `release_angle_deg`
    above its rest angle, the lower beam resting on the still cam, then released.

    The same as `simulate_system(rig, 0.0, controller, duration,
    initial_state=rig.held_state(rest + release))` with `rest = rig.equilibrium()[1]`.
    Give currents as `jnp.asarray(i)` or `ConstantCurrent(jnp.asarray(i), i_max)` to
    reuse one compilation for several currents (a Python float is a static argument
    of the jitted `simulate_system`).

    **Arguments:**

    - `rig`: a `SASRig`.
    - `controller`: a constant current [A] or a jaxmr controller (default 0 A).
    - `release_angle_deg`: the release angle above rest [°] (default 16, the source's).
    - `duration`: simulated time [s] (default 15).
    - `sampling`, `integrator`: as in `simulate_system` (`dt`, `substeps`, `delay`
      deprecated as there); with no `integrator` the substeps are chosen from the
      brake's stiffness, as there.
    - `sensors`, `key`: what the controller reads, as in `simulate_system` (default
      `None`: perfect readings, no device; `"oracle"` for a bare law that inverts
      the brake, such as `Backstepping`, with perfect information).

    **Returns:** a `SystemSolution`; see `decay_settling_time`.
    """
    chosen = integrator is None and "substeps" not in deprecated
    sampling, integrator = loop_settings("free_decay", sampling, integrator, deprecated)
    if not isinstance(rig, SASRig):
        raise TypeError(f"`rig` must be a SASRig, got {type(rig).__name__}.")
    release = jnp.asarray(release_angle_deg * _DEGREE, dtype=rig.R.dtype)
    q0, _ = _release_state(rig, release)
    return simulate_system(
        rig,
        0.0,
        controller,
        duration,
        sampling=sampling,
        integrator=None if chosen else integrator,  # None: `simulate_system` chooses
        initial_state=q0,
        sensors=sensors,
        key=key,
    )
