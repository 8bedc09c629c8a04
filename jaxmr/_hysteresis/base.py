"""The abstract hysteresis law every damper model implements."""

import abc
import dataclasses
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from .._current_law import is_law, resolve
from .._custom_types import Array, Scalar, ScalarLike, State
from .._fitted_range import FittedRange
from .._misc import Check, check_concrete, is_concrete

# Currents at which a model with current laws is checked, evenly over the range the
# input spans (both ends included): linear and exponential laws are extreme at the
# ends, and 17 points catch the interior extremum of a quadratic or the knots of a
# table to within 1/16 of the range.
CHECK_CURRENTS = 17


class AbstractHysteresis(eqx.Module):
    r"""A hysteresis law: force from motion and an internal state.

    A model is $\dot s = g(s, x, v; p(i))$, $F = h(s, x, v; p(i))$ with state $s$,
    relative displacement $x$ [m] (or angle [rad]), velocity $v$ [m/s] (or [rad/s]),
    force $F$ [N] (or torque [N·m]) and parameters $p$ that may depend on the effective
    current $i$ through current laws.

    To add a model, subclass this and implement `rates` and `force` for *resolved*
    parameters (every current law already replaced by its value: the framework calls
    `model.at(i)` first), set `state_names`, and optionally override `initial_state` and
    `constraints`. Nothing else in jaxmr needs to change.

    Every model also takes the keyword `fitted_range`: the operating range it was
    fitted on (a `jaxmr.FittedRange`, default None: not known). `load_model` sets it
    from the file and `save_model` writes it; `simulate`, `sweep` and
    `simulate_system` warn (`OutsideFittedRange`) when they drive the model beyond
    it. It is a static field, not a parameter: no array, never fitted, differentiated
    or batched, and a model without one has the pytree it always had.
    """

    # Static (part of the pytree's structure, not a leaf): it rides along through
    # `eqx.tree_at`, `vmap`, `Damper(...)` and the systems, costs nothing in the
    # solve, and None (the default) leaves every model's leaves and results as they
    # were. Keyword-only so that subclasses' fields keep their positions.
    fitted_range: FittedRange | None = eqx.field(
        default=None, static=True, kw_only=True, repr=False
    )
    state_names: ClassVar[tuple[str, ...]] = ()

    def at(self, current: ScalarLike) -> "AbstractHysteresis":
        """This model with every current law evaluated at `current` [A or V]."""
        return resolve(self, jnp.asarray(current))

    def initial_state(self, x: Scalar, v: Scalar) -> State:
        """The internal state at the start of a simulation (zeros: a virgin device)."""
        del v
        return jnp.zeros(len(self.state_names), dtype=jnp.result_type(x))

    @abc.abstractmethod
    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        """$\\dot s$, with resolved parameters."""

    @abc.abstractmethod
    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        """$F$ [N] (or torque [N·m]), with resolved parameters."""

    def state_bounds(self) -> Array | None:
        """Theoretical bounds on `|state|`, one per state (inf where unbounded), for
        resolved parameters; `None` when the model states none.

        `simulate` flags a run whose state leaves its bound by more than 1 % as
        `RESULTS.state_out_of_bounds`: a fixed-step integration that diverged without
        reaching inf.
        """
        return None

    def yield_force(self) -> Scalar | None:
        """The model's force scale [N or N·m], for resolved parameters: its yield
        (or friction) force, the force the hysteretic part holds once saturated; `None`
        when the model states none.

        The smooth relaxations of the semi-active laws measure how near the damper's
        force band is to closing against this scale, a property of the device, so that
        tuning's loss is smooth wherever the device is the same.
        """
        return None

    def constraints(self) -> list[Check]:
        """Physical-validity checks for resolved parameters, as
        [`jaxmr.Check`][jaxmr.Check]s.

        `simulate` raises the message of any failing check; construction raises it at
        once when the parameters are concrete numbers.
        """
        return []

    def checks(self) -> list[Check]:
        """Every parameter finite, named, then `constraints` (resolved parameters):
        a NaN fails every comparison, and "`alpha` must be >= 0, got nan" would
        blame the sign."""
        finite = [
            Check(
                jnp.all(jnp.isfinite(value)),
                f"`{name}` is NaN or infinite; give a finite number (for a current "
                "law, finite coefficients)",
            )
            for name, value in zip(
                (f.name for f in dataclasses.fields(self)), _parameters(self)
            )
            if eqx.is_inexact_array(value)
        ]
        return finite + self.constraints()

    def checks_over(self, lo: Scalar, hi: Scalar) -> list[Check]:
        """`checks` at `CHECK_CURRENTS` currents evenly over [lo, hi], in A (or V),
        when a parameter is a current law: a law may meet a constraint at one current
        and break it at another (a linear $c_0(i)$ negative at 0 A). The checks name
        the model."""
        name = type(self).__name__
        if not any(is_law(p) for p in jax.tree.leaves(self, is_leaf=is_law)):
            return [check.named(name) for check in self.checks()]
        lo, hi = jnp.asarray(lo), jnp.asarray(hi)
        rules = [check.rule for check in self.at(lo).checks()]
        grid = lo + (hi - lo) * jnp.linspace(0.0, 1.0, CHECK_CURRENTS, dtype=lo.dtype)
        oks = jax.vmap(
            lambda i: jnp.stack([jnp.all(check.ok) for check in self.at(i).checks()])
        )(grid)
        where = f"{name} (its current laws checked over the input's range)"
        # The value quoted is the input where the rule fails (the one nearest the
        # range's low end), not the law's value there: a user sets the current.
        return [
            Check(
                jnp.all(oks[:, k]),
                f"{where}: {rule}",
                {"at the input [A or V]": grid[jnp.argmin(oks[:, k])]},
            )
            for k, rule in enumerate(rules)
        ]

    def __check_init__(self):
        if self.fitted_range is not None and not isinstance(
            self.fitted_range, FittedRange
        ):
            raise TypeError(
                f"{type(self).__name__}: `fitted_range` must be a jaxmr.FittedRange "
                f"or None, got {type(self.fitted_range).__name__}."
            )
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if eqx.is_array(value) and value.ndim != 0:
                # An array broadcast silently: BoucWen(alpha=jnp.ones(3), ...) gave a
                # force of shape (samples, 3). (Under `vmap` each value is a scalar.)
                raise ValueError(
                    f"{type(self).__name__}: `{field.name}` must be a number or a "
                    f"current law, got an array of shape {value.shape}; for several "
                    "models, give `sweep` a list of them or build them under jax.vmap."
                )
        # Only parameters given as plain numbers can be checked before a current is known
        # (laws) or before a fit resolves them (constraint wrappers).
        if any(isinstance(p, eqx.Module) for p in _parameters(self)):
            return
        if not is_concrete(self):
            return
        with jax.ensure_compile_time_eval():
            constraints = self.checks()
        for check in constraints:
            check_concrete(check.ok, check.named(type(self).__name__).message(), self)


def _parameters(model) -> list:
    return [getattr(model, f.name) for f in dataclasses.fields(model)]
