"""Current dynamics: what lies between the commanded current and the current the model sees.

A damper's coil and driver do not follow the command at once. These stages hold their own
state, integrated with the hysteresis state, and give the *effective* current at which the
model's current laws are evaluated.
"""

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from ._current_law import _plain, as_parameter
from ._custom_types import Array, Float, Scalar, State
from ._misc import Check, check_concrete


class AbstractCurrentDynamics(eqx.Module):
    """A dynamic map from the commanded current $i_\\mathrm{cmd}$ [A or V] to the effective
    current $u$ that the model's laws see."""

    state_names: eqx.AbstractClassVar[tuple[str, ...]]

    @abc.abstractmethod
    def initial_state(self, command: Scalar) -> State:
        """The state at the start, given the command then (in steady state by default)."""

    @abc.abstractmethod
    def rates(self, state: State, command: Scalar) -> State:
        """Time derivative of the state [state unit / s]."""

    @abc.abstractmethod
    def effective(self, state: State) -> Scalar:
        """The effective current [A or V] for this state."""

    def constraints(self) -> list[Check]:
        """Validity checks of the parameters ([`jaxmr.Check`][jaxmr.Check]s);
        `simulate` raises the message of a failing one (for parameters only known
        under jit)."""
        return []


class FirstOrderLag(AbstractCurrentDynamics):
    r"""First-order lag $\dot u = -\eta\,(u - i_\mathrm{cmd})$.

    Spencer's voltage filter ($\eta = 190$ s⁻¹) and the usual model of an MR coil and its
    driver (time constants $1/\eta$ of 5–15 ms are typical).

    **Arguments:**

    - `rate`: $\eta$ [1/s], the inverse time constant; must be positive. May be a
      fitting constraint (`jaxmr.Positive(200.0)`) to identify it.
    """

    rate: Float[Array, ""] | eqx.Module = eqx.field(converter=as_parameter)
    state_names: ClassVar[tuple[str, ...]] = ("u",)

    def __check_init__(self):
        for check in self.constraints():
            check_concrete(
                check.ok, check.named("FirstOrderLag").message(), _plain(self.rate)
            )

    def constraints(self):
        rate = _plain(self.rate)
        return [
            Check(rate > 0, "`rate` must be positive (1/time constant in 1/s)", rate)
        ]

    def initial_state(self, command: Scalar) -> State:
        return jnp.reshape(command, (1,)).astype(_plain(self.rate).dtype)

    def rates(self, state: State, command: Scalar) -> State:
        # A fit's constraint wrapper is unwrapped before the rates are evaluated.
        return -self.rate * (state - command)  # pyright: ignore[reportOperatorIssue]

    def effective(self, state: State) -> Scalar:
        return state[0]
