"""The abstract semi-active controller and the damper as the controller sees it."""

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Array, Float, PyTree, Scalar, State
from .._damper import Damper
from .._misc import as_float_array, check_concrete


class DamperPlant(eqx.Module):
    """The damper at one control sample: its state and motion, for inverse models.

    A law is handed the simulated device itself only with perfect information
    (`simulate_system(..., sensors="oracle")`); an `ObserverBasedController` hands
    its law its observer's nominal model at the observed state
    (`DamperObserver.plant`); otherwise every use raises, saying what to do.

    **Attributes:** `damper`, `state` (the damper's internal state), `x` [m or rad],
    `v` [m/s or rad/s] across it.
    """

    damper: Damper
    state: State
    x: Scalar
    v: Scalar

    def force_at(self, command: Scalar) -> Scalar:
        """Force [N or N·m] the damper would give now at current `command` [A], its
        internal state held (the coil lag bypassed: the steady-state answer)."""
        k = len(self.damper.hysteresis.state_names)
        model = self.damper.hysteresis.at(command)
        return model.force(self.state[:k], self.x, self.v)

    def band(self, i_max: Scalar) -> tuple[Scalar, Scalar]:
        """The forces [N or N·m] at $0$ and at $I_\\max$ now: the band a semi-active
        command can reach."""
        return self.force_at(jnp.zeros_like(i_max)), self.force_at(i_max)

    def yield_force(self, current: Scalar) -> Scalar | None:
        """The damper's force scale [N or N·m] at `current` [A]: its hysteresis
        model's `yield_force` (`None` when the model states none)."""
        return self.damper.hysteresis.at(current).yield_force()

    def with_model(self, model: Damper | None) -> "DamperPlant":
        """The plant as a controller's own damper model sees it: `model` (a `Damper`
        of the same hysteresis family) in place of the device, at the device's present
        state and motion; `None` leaves the device itself (a perfect inverse model).

        A real controller inverts a nominal model, not the unit it drives: with
        `model` fixed and the simulated damper drawn from a spread (robust tuning),
        the law's force request and the force delivered differ as they would on a car.
        """
        if model is None:
            return self
        if not isinstance(model, Damper):
            raise TypeError(
                "A controller's inverse `model` must be a jaxmr Damper (e.g. the "
                f"nominal fit's), got {type(model).__name__}."
            )
        mine = model.hysteresis.state_names
        theirs = self.damper.hysteresis.state_names
        if mine != theirs:
            raise ValueError(
                "A controller's inverse `model` reads the device's hysteresis state, "
                f"so their states must match: the model has {mine}, the simulated "
                f"damper {theirs}. Use a model of the device's family."
            )
        return DamperPlant(model, self.state, self.x, self.v)

    def current_for_force(self, force: Scalar, i_max: Scalar) -> Scalar:
        r"""Inverse damper model: the current [A] in $[0, I_\max]$ whose force is
        closest to `force` [N].

        Interpolates linearly between the forces at $0$ and $I_\max$ in the present
        state: exact when the force is affine in the current at fixed state (Bingham and
        Bouc–Wen with linear current laws, the usual MR fits), a secant approximation
        otherwise. A force outside the reachable band is clipped to it: the semi-active
        projection of CONTROL.md, done on the real device's band instead of an
        idealised $[c_\min v, c_\max v]$.
        """
        f0, f1 = self.band(i_max)
        return i_max * jnp.clip(band_fraction(force, f0, f1), 0.0, 1.0)


def band_fraction(force: Scalar, f0: Scalar, f1: Scalar) -> Scalar:
    """$(F - f_0)/(f_1 - f_0)$, the position of `force` in the band $[f_0, f_1]$; 0
    where the band has collapsed ($v = 0$ and $z = 0$: any current gives the same force),
    without a division by zero in value or gradient."""
    span = f1 - f0
    tiny = jnp.abs(span) < 1e-12 * (1 + jnp.abs(f0) + jnp.abs(f1))
    return jnp.where(tiny, 0.0, (force - f0) / jnp.where(tiny, 1.0, span))


class AbstractController(eqx.Module):
    """A digital semi-active controller: at every sample it reads the measurements and
    returns the commanded current [A] (or voltage [V]) in $[0, I_\\max]$.

    Subclasses implement `__call__`; those with memory (a filter, the previous
    acceleration) override `init`. Built-in laws clip their output to the current range;
    `simulate_system` raises if a controller leaves it.
    """

    i_max: eqx.AbstractVar[Float[Array, ""]]

    def init(self, measurement: dict[str, Scalar]) -> PyTree:
        """The controller's state at the first sample (none by default)."""
        del measurement
        return ()

    @abc.abstractmethod
    def __call__(
        self, measurement: dict[str, Scalar], state: PyTree, plant: DamperPlant
    ) -> tuple[Scalar, PyTree]:
        """The command [A] from the measurements (names in
        `jaxmr.constants.MEASUREMENT_NAMES`), the controller state and the damper, and the next
        controller state."""


class ConstantCurrent(AbstractController):
    """A constant current [A] (`0`: passive-off; `I_max`: passive-on).

    **Arguments:** `current` [A]; `i_max` [A], the current range's top (default: the
    current itself).
    """

    current: Float[Array, ""] = eqx.field(converter=as_float_array)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array, default=None)
    # It reads only the clock (for the command's dtype and batch axes): an export's
    # default measurements are then the time alone.
    reads_time: ClassVar[bool] = True

    def __init__(self, current, i_max=None):
        self.current = current
        self.i_max = current if i_max is None else i_max

    def __check_init__(self):
        # A negative current first (the range would read [0, -1] A: i_max defaults
        # to the current itself).
        check_concrete(
            lambda current: current >= 0,
            f"ConstantCurrent: `current` must be >= 0 A (an MR device's coil current "
            f"sets a field's magnitude), got {self.current}.",
            self.current,
        )
        check_concrete(
            lambda current, i_max: current <= i_max,
            f"ConstantCurrent: `current` must lie in [0, i_max] = [0, {self.i_max}] A, "
            f"got {self.current}.",
            self.current,
            self.i_max,
        )

    def __call__(self, measurement, state, plant):
        # Read the clock, which every controller gets (a machine's sensors may read
        # no position): the command takes its dtype and batch axes.
        return self.current + 0.0 * measurement["time"], state
