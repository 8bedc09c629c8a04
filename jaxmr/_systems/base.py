"""The abstract mechanical system that hosts a damper."""

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Scalar, State
from .._damper import Damper
from .._misc import Check
from .._signal import AbstractSignal

# The names every system's `measure` returns, so one controller serves every machine.
# "body" is the part to isolate (sprung mass, upper beam, structure), "wheel" the part
# on the excitation side (unsprung mass, lower beam; zero for a structure on the
# ground); the damper sits between them.
MEASUREMENT_NAMES = (
    "body_position",  # [m] or [rad]
    "body_velocity",  # [m/s] or [rad/s]
    "body_acceleration",  # [m/s²] or [rad/s²]
    "wheel_position",
    "wheel_velocity",
    "damper_displacement",  # across the damper [m] or [rad]
    "damper_velocity",
    "damper_force",  # [N] or [N·m], acting to oppose damper_velocity when passive
    "excitation",  # the input's value: road height [m], cam lift [m], force [N]
)


class AbstractSystem(eqx.Module):
    r"""A mechanical system with one controllable damper in it.

    The mechanical state $q$ (positions and velocities, `state_names`) evolves as
    $\dot q = f(q, t, F)$ under an excitation signal $e(t)$ (a road, a cam, a force)
    and the damper force $F$; the damper sees the relative displacement and velocity
    `damper_motion(q, t)` and holds its own internal state. `simulate_system`
    integrates both together under a digital controller.

    Subclasses hold their physical parameters and the `damper` (any `Damper` or
    hysteresis model: the force law is the damper's, never the system's), implement
    `rates`, `damper_motion`, `measure` and `energy`, and state validity checks in
    `constraints`.
    """

    damper: eqx.AbstractVar[Damper]
    state_names: ClassVar[tuple[str, ...]] = ()

    def initial_state(self, excitation: AbstractSignal, t0: Scalar) -> State:
        """Rest at static equilibrium (zeros: states are deviations from it)."""
        del excitation
        return jnp.zeros(len(self.state_names), dtype=jnp.result_type(t0))

    @abc.abstractmethod
    def damper_motion(
        self, q: State, t: Scalar, excitation: AbstractSignal
    ) -> tuple[Scalar, Scalar]:
        """Displacement [m or rad] and velocity [m/s or rad/s] across the damper."""

    @abc.abstractmethod
    def rates(
        self, q: State, t: Scalar, excitation: AbstractSignal, force: Scalar
    ) -> State:
        """$\\dot q$ given the damper force (torque) `force` [N or N·m]."""

    @abc.abstractmethod
    def measure(
        self, q: State, t: Scalar, excitation: AbstractSignal, force: Scalar
    ) -> dict[str, Scalar]:
        """What sensors would report: every name in `MEASUREMENT_NAMES`, plus any
        system-specific ones."""

    @abc.abstractmethod
    def energy(self, q: State) -> Scalar:
        """Mechanical energy [J] stored in the system (kinetic + potential, relative to
        static equilibrium, with the excitation at rest), for energy balances: with the
        excitation still, its fall over a run equals the work the damper and the
        system's own dampers dissipated."""

    def constraints(self) -> list[Check]:
        """Validity checks of the parameters ([`jaxmr.Check`][jaxmr.Check]s; concrete
        ones are checked at construction, traced ones when simulated)."""
        return []
