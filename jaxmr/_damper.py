"""A damper: a hysteresis law, its current laws, and the current dynamics in front of it."""

import copy

import equinox as eqx
import jax
import jax.numpy as jnp

from ._current_dynamics import AbstractCurrentDynamics
from ._current_law import law_ranges
from ._custom_types import Scalar, State
from ._fitted_range import FittedRange
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
    def fitted_range(self) -> FittedRange | None:
        """The range its hysteresis model was fitted on (`AbstractHysteresis`'s
        `fitted_range`; None: not known)."""
        return self.hysteresis.fitted_range

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


def _is_hysteresis(node) -> bool:
    return isinstance(node, AbstractHysteresis)


def with_fitted_range(tree, fitted_range: FittedRange | None):
    """`tree` with every hysteresis model in it given `fitted_range` (None: none
    known), e.g. a model built in code, or fitted by `jaxmr.fit`, that is to warn
    beyond its data: `with_fitted_range(result.model,
    FittedRange.from_experiments(experiments))`.

    **Arguments:**

    - `tree`: a hysteresis model, a `Damper`, a `ChannelDelay`, a system holding a
      damper (`passenger_car(...)`), or any pytree of them.
    - `fitted_range`: a `jaxmr.FittedRange` (displacement [m], velocity [m/s],
      input [A or V]) or None.

    **Returns:** the same tree, the models' parameters untouched (the range is a
    static field: no array changes, and a tree already holding that range is
    returned as it is).
    """
    if fitted_range is not None and not isinstance(fitted_range, FittedRange):
        raise TypeError(
            "`fitted_range` must be a jaxmr.FittedRange (e.g. "
            "jaxmr.FittedRange.from_experiments(experiments)) or None, got "
            f"{type(fitted_range).__name__}."
        )
    models = [
        m for m in jax.tree.leaves(tree, is_leaf=_is_hysteresis) if _is_hysteresis(m)
    ]
    if all(m.fitted_range == fitted_range for m in models):
        return tree

    def set_range(node):
        if not _is_hysteresis(node) or node.fitted_range == fitted_range:
            return node
        # A static field is out of `eqx.tree_at`'s reach, and rebuilding the model
        # through its constructor would convert and check its parameters again (a
        # constraint wrapper's stored variable is not what the constructor takes):
        # a shallow copy with the one field set keeps every parameter as it is.
        new = copy.copy(node)
        object.__setattr__(new, "fitted_range", fitted_range)
        return new

    return jax.tree.map(set_range, tree, is_leaf=_is_hysteresis)


def fitted_range_in(tree, strict: bool = True) -> FittedRange | None:
    """The `fitted_range` the hysteresis models in `tree` hold (None when none
    does); when they hold different ones, `ValueError` (`strict`) or None."""
    ranges = {
        m.fitted_range
        for m in jax.tree.leaves(tree, is_leaf=_is_hysteresis)
        if _is_hysteresis(m) and m.fitted_range is not None
    }
    if len(ranges) > 1:
        if not strict:
            return None
        raise ValueError(
            "the models in this tree hold different fitted ranges; give one "
            "(`fitted_range=`)."
        )
    return ranges.pop() if ranges else None
