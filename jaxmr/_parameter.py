"""Constraints for identification: wrappers that mark a parameter positive, bounded or
fixed. They sit in a model's fields in place of a number and are resolved (`unwrap`)
inside the differentiated function, because optimistix's least-squares solvers take no
bounds (equinox's "custom per-parameter behaviour" pattern).

    model = jaxmr.BoucWen(alpha=jaxmr.Positive(1.0), c0=..., A=jaxmr.Fixed(843.0), ...)
"""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, Float
from ._misc import (
    as_float_array,
    check_concrete,
    default_float,
    is_concrete,
    to_device,
)


class AbstractParameter(eqx.Module):
    """A parameter with a rule for how it is fitted; `value()` is its physical value."""

    @abc.abstractmethod
    def value(self) -> Array:
        """The parameter's value, in its physical unit."""


class Positive(AbstractParameter):
    """A positive parameter, fitted as its logarithm (so it can never cross zero, and
    a step is a relative change: parameters spanning decades are equally scaled).

    **Arguments:** `value`, the (positive) initial value.
    """

    log_value: Float[Array, "..."]

    def __init__(self, value):
        # A concrete value in NumPy: an eager `jnp.log` compiles (per shape) in a
        # fresh process, and templates build dozens of these.
        xp = np if is_concrete(value) else jnp
        value = xp.asarray(value, dtype=default_float())
        check_concrete(
            lambda v: v > 0, f"Positive: the value must be > 0, got {value}.", value
        )
        self.log_value = to_device(xp.log(value))

    def value(self) -> Array:
        return jnp.exp(self.log_value)


class Bounded(AbstractParameter):
    """A parameter kept inside `(lower, upper)` by a logistic map of a free variable.

    **Arguments:** `value` (strictly inside the bounds), `lower`, `upper`.
    """

    raw: Float[Array, "..."]
    lower: float = eqx.field(static=True)
    upper: float = eqx.field(static=True)

    def __init__(self, value, lower: float, upper: float):
        if not float(lower) < float(upper):
            raise ValueError(
                f"Bounded: `lower` must be < `upper`, got {lower} and {upper}."
            )
        xp = np if is_concrete(value) else jnp  # see `Positive`
        value = xp.asarray(value, dtype=default_float())
        check_concrete(
            lambda v: (v > lower) & (v < upper),
            f"Bounded: the value {value} must lie strictly inside ({lower}, {upper}).",
            value,
        )
        self.lower, self.upper = float(lower), float(upper)
        fraction = (value - self.lower) / (self.upper - self.lower)
        self.raw = to_device(xp.log(fraction) - xp.log1p(-fraction))

    def value(self) -> Array:
        return self.lower + (self.upper - self.lower) * jax.nn.sigmoid(self.raw)


class Fixed(AbstractParameter):
    """A parameter held at its value during a fit (e.g. Bouc–Wen's `A`, to remove the
    scaling redundancy)."""

    fixed: Float[Array, "..."] = eqx.field(converter=as_float_array)

    def value(self) -> Array:
        return jax.lax.stop_gradient(self.fixed)


def is_parameter(x) -> bool:
    return isinstance(x, AbstractParameter)


def unwrap(tree):
    """Replace every constraint wrapper in `tree` by its value."""
    return jax.tree.map(
        lambda p: p.value() if is_parameter(p) else p, tree, is_leaf=is_parameter
    )


def numbers_as_arrays(tree):
    """`tree` with its plain Python floats as arrays, as a model's constructor makes
    them: a parameter set with `equinox.tree_at` (which bypasses the constructor)
    stays a float, and a fit would leave it out without a word. Ints and bools are
    left as they are (counts and flags, not parameters)."""
    return jax.tree.map(
        lambda x: as_float_array(x) if type(x) is float else x,
        tree,
        is_leaf=lambda x: isinstance(x, Fixed),
    )


def fixed_modes(tree):
    """`tree` with every parameter that sits at a *mode* of its model `Fixed`: a value
    that selects a form of the model rather than a size (`fit_modes`, a class
    attribute mapping field names to such values: Bingham's `velocity_scale` of 0,
    the exact sign). The force does not change with the parameter there, so a fit
    could only report it unidentified; a fit leaves it alone instead."""

    def has_modes(x) -> bool:
        return isinstance(x, eqx.Module) and bool(getattr(type(x), "fit_modes", None))

    def fix(module):
        if not has_modes(module):
            return module
        for name, mode in type(module).fit_modes.items():
            value = getattr(module, name)
            if (
                eqx.is_array(value)
                and value.ndim == 0
                and is_concrete(value)
                and float(value) == mode
            ):
                module = eqx.tree_at(
                    lambda m, name=name: getattr(m, name), module, Fixed(value)
                )
        return module

    return jax.tree.map(fix, tree, is_leaf=has_modes)


def fixed_fields(tree):
    """`tree` with every field a module names in its class attribute `fit_fixed`
    wrapped in `Fixed`: arrays that place the parameters rather than being ones (a
    `TableLaw`'s tested currents). Free, a fit moved a table's currents out of
    order and off the data."""

    def has_fixed(x) -> bool:
        return isinstance(x, eqx.Module) and bool(getattr(type(x), "fit_fixed", ()))

    def fix(module):
        if not has_fixed(module):
            return module
        for name in type(module).fit_fixed:
            value = getattr(module, name)
            if eqx.is_array(value):
                module = eqx.tree_at(
                    lambda m, name=name: getattr(m, name), module, Fixed(value)
                )
        return module

    return jax.tree.map(fix, tree, is_leaf=has_fixed)


def fitted_form(model):
    """A model as a fit takes it: its plain floats as arrays (`numbers_as_arrays`),
    its parameters at a mode `Fixed` (`fixed_modes`) and the arrays that only place
    parameters too (`fixed_fields`)."""
    return fixed_fields(fixed_modes(numbers_as_arrays(model)))


def free_filter(tree):
    """A filter spec: True for the array leaves a fit varies (not those in `Fixed`)."""

    def spec(x):
        if isinstance(x, Fixed):
            return jax.tree.map(lambda _: False, x)
        return eqx.is_inexact_array(x)

    return jax.tree.map(spec, tree, is_leaf=lambda x: isinstance(x, Fixed))


def fit_only(model, where):
    """`model` with every parameter wrapped in `Fixed` except those `where` selects.

    **Arguments:**

    - `model`: any jaxmr model (a `Damper`, its magnetic stage, laws, ...).
    - `where`: a function returning the parameters to leave free, as for
      `equinox.tree_at`, e.g. `lambda m: (m.dynamics.coil_constant, m.hysteresis.c0)`.
      A selected parameter may already be `Positive` or `Bounded`.
    """

    def select(m):
        chosen = where(m)
        return tuple(chosen) if isinstance(chosen, (tuple, list)) else (chosen,)

    model = numbers_as_arrays(model)
    spec = jax.tree.map(lambda _: False, model, is_leaf=is_parameter)
    count = len(select(model))
    spec = eqx.tree_at(select, spec, replace=(True,) * count)

    def wrap(free, sub):
        if free:
            return sub

        def fix(x):
            # A constrained parameter (`Positive`, `Bounded`) is fixed at its value:
            # left as it was, a fit had varied it.
            if isinstance(x, AbstractParameter) and not isinstance(x, Fixed):
                return Fixed(x.value())
            # An array here (pyright narrows `x` to `Fixed` after the test above).
            return Fixed(x) if eqx.is_inexact_array(x) else x  # pyright: ignore[reportArgumentType]

        return jax.tree.map(fix, sub, is_leaf=is_parameter)

    return jax.tree.map(wrap, spec, model, is_leaf=lambda x: isinstance(x, bool))
