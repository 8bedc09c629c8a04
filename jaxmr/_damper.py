"""A damper: a hysteresis law, its current laws, and the current dynamics in front of it."""

import equinox as eqx
import jax.numpy as jnp

from ._current_dynamics import AbstractCurrentDynamics
from ._current_law import law_ranges
from ._custom_types import Scalar, State
from ._hysteresis import AbstractHysteresis


class Damper(eqx.Module):
    r"""An MR damper or brake: hysteresis law + (optional) current dynamics.

    The state is the hysteresis state followed by the current-dynamics state. With no
    dynamics the model sees the commanded current at once; with `FirstOrderLag(eta)` it
    sees $u$, $\dot u = -\eta (u - i_\mathrm{cmd})$.

    **Arguments:**

    - `hysteresis`: any `AbstractHysteresis`, its parameters numbers or current laws.
    - `dynamics`: an `AbstractCurrentDynamics` or `None`.
    """

    hysteresis: AbstractHysteresis
    dynamics: AbstractCurrentDynamics | None = None

    def __check_init__(self):
        if not isinstance(self.hysteresis, AbstractHysteresis):
            raise TypeError(
                "Damper: `hysteresis` must be a jaxmr hysteresis model (BoucWen, Dahl, "
                f"...), got {type(self.hysteresis).__name__}."
            )
        if self.dynamics is not None and not isinstance(
            self.dynamics, AbstractCurrentDynamics
        ):
            raise TypeError(
                "Damper: `dynamics` must be None or a current dynamics such as "
                f"FirstOrderLag(rate), got {type(self.dynamics).__name__}."
            )

    @property
    def state_names(self) -> tuple[str, ...]:
        extra = () if self.dynamics is None else self.dynamics.state_names
        return self.hysteresis.state_names + extra

    @property
    def _split(self) -> int:
        return len(self.hysteresis.state_names)

    def initial_state(self, x: Scalar, v: Scalar, command: Scalar) -> State:
        """Virgin hysteresis state; current dynamics in steady state at `command`."""
        h = self.hysteresis.initial_state(x, v)
        if self.dynamics is None:
            return h
        d = self.dynamics.initial_state(command).astype(h.dtype)
        return jnp.concatenate([h, d])

    def effective_current(self, state: State, command: Scalar) -> Scalar:
        """The current [A or V] the hysteresis law sees in this state."""
        if self.dynamics is None:
            return command
        return self.dynamics.effective(state[self._split :])

    def rates(self, state: State, x: Scalar, v: Scalar, command: Scalar) -> State:
        """$\\dot s$ for the whole damper state."""
        k = self._split
        model = self.hysteresis.at(self.effective_current(state, command))
        h = model.rates(state[:k], x, v)
        if self.dynamics is None:
            return h
        return jnp.concatenate([h, self.dynamics.rates(state[k:], command)])

    def force(self, state: State, x: Scalar, v: Scalar, command: Scalar) -> Scalar:
        """Force [N] (torque [N·m]) for the whole damper state."""
        model = self.hysteresis.at(self.effective_current(state, command))
        return model.force(state[: self._split], x, v)

    def state_bounds(self, state: State, command: Scalar):
        """Bounds on `|state|` at this state's effective current (inf: unbounded), or
        `None` when the hysteresis law states none."""
        model = self.hysteresis.at(self.effective_current(state, command))
        bounds = model.state_bounds()
        if bounds is None:
            return None
        extra = len(state) - self._split
        return jnp.concatenate([bounds, jnp.full((extra,), jnp.inf, bounds.dtype)])

    def current_ranges(self):
        """Validity ranges of the laws (tables) of the hysteresis model."""
        return law_ranges(self.hysteresis)


def as_damper(device) -> Damper:
    """Accept a bare hysteresis law wherever a damper is expected."""
    if isinstance(device, Damper):
        return device
    if isinstance(device, AbstractHysteresis):
        return Damper(device)
    # A wrapper that is not a device (`ChannelDelay`) says what to simulate instead.
    hint = getattr(type(device), "not_a_device", None)
    if isinstance(hint, str):
        raise TypeError(hint)
    raise TypeError(
        "expected a jaxmr Damper or hysteresis model (e.g. BoucWen(...)), got "
        f"{type(device).__name__}."
    )
