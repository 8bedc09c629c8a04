r"""A law run as a real controller runs it: on sensor readings, with the velocities no
sensor gives estimated and the damper's hidden state observed."""

import functools
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import PyTree, Scalar
from .._misc import check_concrete
from .base import AbstractController, DamperPlant
from .estimator import EstimatorState, VelocityEstimator
from .observer import DamperObserver, ObserverState
from .sampling import Sampling
from .sensors import readings
from .smooth import clip_command
from .state_space import reads_positions


class ControllerState(eqx.Module):
    """An `ObserverBasedController`'s state: `estimator` (an `EstimatorState`, or
    `()`), `observer` (an `ObserverState`, or `()`) and `law`, the law's own."""

    estimator: EstimatorState | tuple
    observer: ObserverState | tuple
    law: PyTree


class _NoPlant(DamperPlant):
    """The damper a controller gets when it may not read the device: every use says
    so (`simulate_system` without `sensors="oracle"`, or an `ObserverBasedController`
    with neither an observer nor the oracle). A `DamperPlant`, so that the laws' type
    checks pass it on to the use that raises with `why`."""

    damper: Any = None
    state: Any = None
    x: Any = None
    v: Any = None
    why: str = eqx.field(static=True, default="")

    def _refuse(self, *args, **kwargs):
        raise TypeError(self.why)

    force_at = band = yield_force = with_model = current_for_force = _refuse


class ObserverBasedController(AbstractController):
    r"""A law on what a controller can know: sensor readings, estimated velocities,
    and its own nominal damper's observed state for the inverse model.

    At every sample (`sampling.dt`): the `estimator` turns the readings into the
    velocities no sensor gives, and the absolute body and wheel positions where the
    law reads them (`estimates_positions`: the clipped-optimal, Lyapunov and
    backstepping laws); its estimates replace readings of the same name;
    the `observer` brings its nominal damper's state up to this sample and corrects it
    with the measured force (`damper_force`) where one is read; the law then decides
    the command from the readings and estimates, inverting the observer's damper
    (`DamperObserver.plant`) instead of the simulated device; the observer notes the
    command (it acts `sampling.delay` samples later). Where no sensor reads the
    damper's force, the law reads the observer's model force as `damper_force`
    (with perfect readings, `simulate_system`'s default `sensors=None` or
    `"oracle"`, the true force is read, and corrects the observer as a perfect load
    cell would).

    The whole state is a fixed-size pytree (`ControllerState`) stepped by this pure
    function at a fixed sample time: what runs on a real-time target.

    `oracle=True` hands the law the simulated device itself, at its true state (the
    perfect information of a bare law in `simulate_system(..., sensors="oracle")`),
    for research comparisons; it excludes an observer. With neither, the law may not
    invert a damper (laws such as `OnOffSkyhook` need none).

    **Arguments:**

    - `law`: any jaxmr controller (its `i_max` is this controller's).
    - `estimator`: a `VelocityEstimator`, or `None` (default): the law reads the
      readings as they are (sensors that give velocities and, for a law that reads
      them, positions; or perfect information).
    - `observer`: a `DamperObserver` with the nominal damper model, or `None`
      (default).
    - `sampling`: the controller's `Sampling(dt, delay)` [s, samples], at which the
      filters and the observer step; `simulate_system` takes it from here when given
      no `sampling` and refuses a different one. Default `Sampling()`.
    - `oracle`: static, default False; see above.
    """

    law: AbstractController
    estimator: VelocityEstimator | None = None
    observer: DamperObserver | None = None
    sampling: Sampling = Sampling()
    oracle: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if not isinstance(self.law, AbstractController):
            raise TypeError(
                "ObserverBasedController: `law` must be a jaxmr controller, got "
                f"{type(self.law).__name__}."
            )
        if isinstance(self.law, ObserverBasedController):
            raise TypeError(
                "ObserverBasedController: `law` is itself an ObserverBasedController; "
                "wrap the plain law once (its estimator, observer and sampling go in "
                "the one wrapper)."
            )
        if self.estimator is not None and not isinstance(
            self.estimator, VelocityEstimator
        ):
            raise TypeError(
                "ObserverBasedController: `estimator` must be a VelocityEstimator or "
                f"None, got {type(self.estimator).__name__}."
            )
        if self.observer is not None and not isinstance(self.observer, DamperObserver):
            raise TypeError(
                "ObserverBasedController: `observer` must be a DamperObserver or None, "
                f"got {type(self.observer).__name__}."
            )
        if not isinstance(self.sampling, Sampling):
            raise TypeError(
                "ObserverBasedController: `sampling` must be a jaxmr.Sampling(dt, "
                f"delay), got {type(self.sampling).__name__}."
            )
        if self.estimator is not None:
            # A filter's corner at or above half the sample rate is aliased: the
            # tracker's poles wrap round and its estimates are noise or diverge.
            nyquist = 0.5 / self.sampling.dt
            for name in ("crossover", "high_pass", "position_high_pass"):
                value = getattr(self.estimator, name)
                check_concrete(
                    value < nyquist,
                    f"ObserverBasedController: the estimator's `{name}` ({value} Hz) "
                    f"must lie below half the sample rate ({nyquist:g} Hz at dt = "
                    f"{self.sampling.dt:g} s).",
                    value,
                )
        if self.oracle and self.observer is not None:
            raise ValueError(
                "ObserverBasedController: `oracle=True` hands the law the device's true "
                "state; give it without an `observer`."
            )

    @property
    def i_max(self):
        return self.law.i_max

    @property
    def estimates_positions(self) -> bool:
        """Whether the estimator also estimates the body and wheel positions [m or
        rad]: it has one and the law reads them (`reads_positions`)."""
        return self.estimator is not None and reads_positions(self.law)

    def tunable(
        self,
        law: Callable | None = None,
        *,
        law_log_space: bool = True,
        estimator: Sequence[str] | None = None,
        observer: Sequence[str] = (),
    ) -> dict:
        """The keywords `parameters`, `log_space` and `bounds` of `jaxmr.tune` (and
        `cma_es`, `random_search`) that tune the law and this controller's filters
        together, e.g. `jaxmr.tune(car, controller, roads, T, sensors=...,
        sensor_key=..., **controller.tunable(jaxmr.ForceFeedback.weights,
        law_log_space=False))`.

        The selected arrays are the law's (first, in `law`'s order), then the
        estimator's, then the observer's. The estimator's corners [Hz] and damping
        [1] are tuned in log space (positive, relative steps), the observer's `gain`
        [1] in log space within (1e-4, 1).

        **Arguments:**

        - `law`: a selector of the law's arrays on a `(system, law)` pair, as for
          the bare law (`jaxmr.ForceFeedback.weights`, `lambda pair:
          pair[1].c_sky`); it must read the law only (`pair[1]`). `None`: none.
        - `law_log_space`: whether the law's arrays are tuned in log space (True,
          positive gains) or in values (False: signed weights).
        - `estimator`: the `VelocityEstimator` fields to tune, of `crossover`,
          `damping`, `high_pass` and `position_high_pass`; `()` for none. Needs an
          estimator when not empty. Default `None`: every field the commands depend
          on, the first three and, where the estimator estimates positions
          (`estimates_positions`), `position_high_pass`.
        - `observer`: the `DamperObserver` fields to tune: `("gain",)` (useful with
          a load cell, which the gain weighs) or `()` (default).

        **Returns:** `{"parameters": ..., "log_space": ..., "bounds": ...}`.
        """
        if estimator is None:
            estimator = _ESTIMATOR_FIELDS[:3]
            if self.estimates_positions:
                estimator += ("position_high_pass",)
        estimator, observer = tuple(estimator), tuple(observer)
        for fields, part, known in (
            (estimator, self.estimator, _ESTIMATOR_FIELDS),
            (observer, self.observer, _OBSERVER_FIELDS),
        ):
            unknown = sorted(set(fields) - set(known))
            if unknown:
                raise ValueError(
                    f"ObserverBasedController.tunable: no tunable field {unknown[0]!r}; "
                    f"the choices are {known}."
                )
            if fields and part is None:
                raise ValueError(
                    f"ObserverBasedController.tunable: {fields} selects fields of a "
                    "part this controller does not have (its estimator or observer "
                    "is None); give `()`."
                )
        count = 0 if law is None else len(_as_list(law((None, self.law))))
        if count + len(estimator) + len(observer) == 0:
            raise ValueError("ObserverBasedController.tunable: nothing selected.")
        log_space = (bool(law_log_space),) * count + (True,) * (
            len(estimator) + len(observer)
        )
        bounds = (None,) * (count + len(estimator)) + (_GAIN_BOUNDS,) * len(observer)
        return {
            "parameters": _selector(law, estimator, observer),
            "log_space": log_space,
            "bounds": bounds if observer else None,
        }

    def _estimated(self, measurement, state):
        if self.estimator is None:
            return readings(measurement), ()
        estimates, state = self.estimator.step(state, measurement, self.sampling.dt)
        return readings({**measurement, **estimates}), state

    def _observed(self, observer: DamperObserver, measurement, state: ObserverState):
        """The observer brought to this sample, the damper the law inverts, and the
        readings with the model force where no force is measured."""
        force = measurement.get("damper_force")
        state = observer.update(
            state,
            measurement["damper_displacement"],
            measurement["damper_velocity"],
            force,
            self.sampling.dt,
        )
        if force is None:
            measurement = readings(
                {**measurement, "damper_force": observer.force(state)}
            )
        return state, observer.plant(state), measurement

    def init(self, measurement) -> ControllerState:
        """The state before the first sample. The observer's commands before the first
        are the law's first decision at the first readings, the damper at zero
        current, as `simulate_system` starts the device."""
        estimator = (
            ()
            if self.estimator is None
            else self.estimator.init(measurement, positions=self.estimates_positions)
        )
        # The estimates at the first sample, for the law's own `init`.
        merged, _ = self._estimated(measurement, estimator)
        law = self.law.init(merged)
        if self.observer is None:
            return ControllerState(estimator, (), law)
        x, v = merged["damper_displacement"], merged["damper_velocity"]
        zero = jnp.zeros_like(jnp.asarray(x))
        delay = self.sampling.delay
        probe = self.observer.init(x, v, zero, delay)
        probe, plant, merged = self._observed(self.observer, merged, probe)
        first, _ = self.law(merged, law, plant)
        first = clip_command(first, self.law.i_max)
        return ControllerState(estimator, self.observer.init(x, v, first, delay), law)

    def __call__(
        self, measurement, state: ControllerState, plant: DamperPlant
    ) -> tuple[Scalar, ControllerState]:
        """The command [A] at this sample and the next state. A sample with a
        reading that is not finite (a sensor's dropout, a NaN from its driver) is
        skipped: the command is 0 A (the damper's passive state, as when its power
        fails) and the state stays as it was, but for the observer's record of that
        command, so that the next finite sample goes on from it. (Taken in, one NaN
        stayed in the filters' state for good.) `jaxmr.export_c` does the same."""
        command, new = self._step(measurement, state, plant)
        finite = jnp.all(
            jnp.stack(
                [jnp.all(jnp.isfinite(jnp.asarray(v))) for v in measurement.values()]
            )
        )
        zero = jnp.zeros_like(command)
        kept = state
        if self.observer is not None:
            assert isinstance(state.observer, ObserverState)
            kept = ControllerState(
                state.estimator,
                self.observer.commanded(state.observer, zero),
                state.law,
            )
        new = jax.tree.map(lambda a, b: jnp.where(finite, a, b), new, kept)
        return jnp.where(finite, command, zero), new

    def _step(
        self, measurement, state: ControllerState, plant: DamperPlant
    ) -> tuple[Scalar, ControllerState]:
        merged, estimator = self._estimated(measurement, state.estimator)
        if self.observer is None:
            own = plant if self.oracle else _NoPlant(why=_NO_PLANT)
            command, law = self.law(merged, state.law, own)
            command = clip_command(command, self.law.i_max)
            return command, ControllerState(estimator, (), law)
        observer = state.observer
        assert isinstance(observer, ObserverState)  # given an observer, its state
        observer, own, merged = self._observed(self.observer, merged, observer)
        command, law = self.law(merged, state.law, own)
        command = clip_command(command, self.law.i_max)
        observer = self.observer.commanded(observer, command)
        return command, ControllerState(estimator, observer, law)


_ESTIMATOR_FIELDS = ("crossover", "damping", "high_pass", "position_high_pass")
_OBSERVER_FIELDS = ("gain",)
# The observer's gain is a share of the force error removed per sample: within (0, 1].
_GAIN_BOUNDS = (1e-4, 1.0)


def _as_list(leaves) -> list:
    return list(leaves) if isinstance(leaves, (list, tuple)) else [leaves]


@functools.lru_cache(maxsize=64)
def _selector(law, estimator: tuple, observer: tuple) -> Callable:
    # One function per choice, so that tuning twice with the same choice reuses the
    # compiled loss (the tuners' static argument).
    def parameters(pair):
        controller = pair[1]
        out = [] if law is None else _as_list(law((pair[0], controller.law)))
        out += [getattr(controller.estimator, name) for name in estimator]
        out += [getattr(controller.observer, name) for name in observer]
        return out

    return parameters


_NO_PLANT = (
    "This law inverts the damper, but the controller has no damper to invert: give "
    "the ObserverBasedController an `observer=jaxmr.DamperObserver(nominal_damper)` "
    "(or `oracle=True` to read the simulated device's true state, for research "
    "comparisons only)."
)
