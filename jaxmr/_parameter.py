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


def fixed_by_class(tree):
    """`tree` with the parameters its modules' classes say a fit leaves alone wrapped
    in `Fixed`:

    - a parameter at a *mode* of its model (`fit_modes`, a class attribute mapping
      field names to such values: Bingham's `velocity_scale` of 0, the exact sign):
      a value that selects a form of the model rather than a size, where the force
      does not change with it, so that a fit could only report it unidentified;
    - arrays that place the parameters rather than being ones (`fit_fixed`, a class
      attribute naming fields: a `TableLaw`'s tested currents). Free, a fit moved a
      table's currents out of order and off the data."""

    def at_mode(value, mode) -> bool:
        return (
            eqx.is_array(value)
            and value.ndim == 0
            and is_concrete(value)
            and float(value) == mode
        )

    def fix(module):
        if not isinstance(module, eqx.Module):
            return module
        # The modules inside first (a `TableLaw` in a Bingham model, which has rules
        # of its own), then this one's fields.
        module = jax.tree.map(
            fix, module, is_leaf=lambda x: x is not module and isinstance(x, eqx.Module)
        )
        kind = type(module)
        names = [
            name
            for name, mode in getattr(kind, "fit_modes", {}).items()
            if at_mode(getattr(module, name), mode)
        ]
        names += [
            name
            for name in getattr(kind, "fit_fixed", ())
            if eqx.is_array(getattr(module, name))
        ]
        for name in names:
            module = eqx.tree_at(
                lambda m, name=name: getattr(m, name),
                module,
                Fixed(getattr(module, name)),
            )
        return module

    return jax.tree.map(fix, tree, is_leaf=lambda x: isinstance(x, eqx.Module))


def fitted_form(model):
    """A model as a fit takes it: its plain floats as arrays (`numbers_as_arrays`)
    and the parameters its classes leave to the model `Fixed` (`fixed_by_class`)."""
    return fixed_by_class(numbers_as_arrays(model))


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
