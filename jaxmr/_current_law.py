"""Current laws: how a model parameter depends on the coil current (or command voltage).

Any numeric parameter of a hysteresis model may be given as a law instead of a number;
the model resolves it at the effective current with `AbstractHysteresis.at`. The law's
input is in A (or V for voltage-driven dampers such as Spencer's); its output carries the
unit of the parameter it stands for.
"""

import abc
from typing import TYPE_CHECKING, Any, ClassVar, TypeAlias

import equinox as eqx
import jax
import jax.numpy as jnp

from ._custom_types import Array, Float, Scalar, ScalarLike
from ._misc import as_float_array, check_concrete, check_finite_fields


def _plain(x):
    """A parameter's array, looking through a fitting constraint wrapper."""
    # Every Module here is a fitting constraint wrapper (`jaxmr.AbstractParameter`).
    return x.value() if isinstance(x, eqx.Module) else x  # pyright: ignore[reportAttributeAccessIssue]


# Typed `Any` for the checker: a field keeps its law or constraint wrapper until
# `resolve` (or the fit's unwrapping) puts an array in its place, and fields are
# annotated with the array the model's methods see.
def as_parameter(x: Any) -> Any:
    """Converter for model parameters: keep a current law or a fitting constraint
    (`Positive`, `Bounded`, `Fixed`: any equinox Module), make anything else an array."""
    return x if isinstance(x, eqx.Module) else as_float_array(x)


class AbstractCurrentLaw(eqx.Module):
    """A parameter as a function of the effective current $i$ [A] (or voltage [V])."""

    @abc.abstractmethod
    def __call__(self, current: Scalar) -> Scalar:
        """The parameter's value at `current`."""

    def __check_init__(self):
        check_finite_fields(self)

    def range(self) -> tuple[Array, Array] | None:
        """The currents this law is valid for, or `None` when it is valid for any."""
        return None


if TYPE_CHECKING:
    # A model's methods run on the model `resolve`d at the current, where every law
    # has become its value: the checker reads a parameter as that array.
    Parameter: TypeAlias = Float[Array, ""]
else:
    Parameter = Float[Array, ""] | AbstractCurrentLaw


class ConstantLaw(AbstractCurrentLaw):
    r"""$p(i) = p_0$: a parameter that does not depend on current (useful when fitting
    switches a parameter between shared and current-dependent).

    **Arguments:** `value`, $p_0$ in the parameter's own unit (e.g. N·s/m for a
    viscous coefficient).
    """

    value: Float[Array, ""] = eqx.field(converter=as_parameter)

    def __call__(self, current: Scalar) -> Scalar:
        return self.value + 0.0 * current


class LinearLaw(AbstractCurrentLaw):
    r"""$p(i) = a + b\,i$ (the SAS study's choice for $C$, $\alpha$, $k_x$, $k_w$).

    **Arguments:**

    - `a`: value at zero current, in the parameter's unit.
    - `b`: slope, in the parameter's unit per A (or per V).
    """

    a: Float[Array, ""] = eqx.field(converter=as_parameter)
    b: Float[Array, ""] = eqx.field(converter=as_parameter)

    def __call__(self, current: Scalar) -> Scalar:
        return self.a + self.b * current


class PolynomialLaw(AbstractCurrentLaw):
    r"""$p(i) = \sum_k c_k i^k$, coefficients in increasing order of power.

    **Arguments:**

    - `coefficients`: $c_0, c_1, \dots$ in the parameter's unit per A^k. The UTFSM
      damper's $\alpha(i) = p_6 + p_5 i + p_4 i^2$ is `PolynomialLaw([p6, p5, p4])`.
    """

    coefficients: Float[Array, " degree_plus_one"] = eqx.field(converter=as_parameter)

    def __check_init__(self):
        coefficients = _plain(self.coefficients)
        if coefficients.ndim != 1 or coefficients.shape[0] < 1:
            raise ValueError(
                "PolynomialLaw: `coefficients` must be a non-empty 1-D array "
                f"(c0, c1, ...), got shape {coefficients.shape}."
            )

    def __call__(self, current: Scalar) -> Scalar:
        # Horner's scheme, highest power first.
        return jnp.polyval(self.coefficients[::-1], current)


class ExponentialLaw(AbstractCurrentLaw):
    r"""$p(i) = a\,e^{b i}$ (the UTFSM damper's $\beta(i) = \gamma(i)$).

    **Arguments:**

    - `a`: value at zero current, in the parameter's unit.
    - `b`: rate, in 1/A (or 1/V).
    """

    a: Float[Array, ""] = eqx.field(converter=as_parameter)
    b: Float[Array, ""] = eqx.field(converter=as_parameter)

    def __call__(self, current: Scalar) -> Scalar:
        return self.a * jnp.exp(self.b * current)


class SaturatingLaw(AbstractCurrentLaw):
    r"""$p(i) = a + s\,i_0\,(1 - e^{-i/i_0})$: slope $s$ at zero input, bending over
    to the ceiling $a + s\,i_0$ as the input grows past $i_0$ (an MR fluid's yield
    stress saturates with the field, and a damper's magnetic circuit with the
    coil's current). For $i_0 \to \infty$ it is the linear law $a + s\,i$, so a fit
    started with $i_0$ a few times the inputs starts from the line and bends it
    only as far as the data ask (`jaxmr.templates.with_saturation`).

    **Arguments:**

    - `a`: value at zero input, in the parameter's unit.
    - `slope`: $s$, the slope at zero input, in the parameter's unit per A (or V).
    - `i0`: $i_0$ > 0, the input scale of the saturation [A] (or [V]).
    """

    a: Float[Array, ""] = eqx.field(converter=as_parameter)
    slope: Float[Array, ""] = eqx.field(converter=as_parameter)
    i0: Float[Array, ""] = eqx.field(converter=as_parameter)

    def __check_init__(self):
        i0 = _plain(self.i0)
        check_concrete(
            lambda v: v > 0,
            f"SaturatingLaw: `i0` must be > 0 [A or V], got {i0}.",
            i0,
        )

    def __call__(self, current: Scalar) -> Scalar:
        # expm1: exact to rounding where i << i0 (the law is then the line).
        return self.a - self.slope * self.i0 * jnp.expm1(-current / self.i0)


class TableLaw(AbstractCurrentLaw):
    r"""One value per tested current, linearly interpolated in between.

    What the BWBN study does: it identifies each parameter separately at each test
    current. A current outside `[currents[0], currents[-1]]` is an error, not an
    extrapolation: `simulate` checks the current signal's range before it integrates.

    **Arguments:**

    - `currents`: the tested currents in A, strictly increasing.
    - `values`: the parameter at each of them, in the parameter's unit.
    """

    currents: Float[Array, " table"] = eqx.field(converter=as_float_array)
    values: Float[Array, " table"] = eqx.field(converter=as_parameter)
    # A fit varies the values at the tested currents, never the currents
    # (`jaxmr._parameter.fixed_by_class`).
    fit_fixed: ClassVar[tuple[str, ...]] = ("currents",)

    def __check_init__(self):
        values = _plain(self.values)
        if self.currents.ndim != 1 or self.currents.shape != values.shape:
            raise ValueError(
                "TableLaw: `currents` and `values` must be 1-D arrays of equal length, "
                f"got shapes {self.currents.shape} and {values.shape}."
            )
        if self.currents.shape[0] < 1:
            raise ValueError("TableLaw: give at least one (current, value) pair.")
        check_concrete(
            jnp.all(jnp.isfinite(self.currents)) & jnp.all(jnp.isfinite(values)),
            "TableLaw: `currents` and `values` must be finite (no NaN or inf).",
            self.currents,
            values,
        )
        check_concrete(
            jnp.all(jnp.diff(self.currents) > 0),
            "TableLaw: `currents` must be strictly increasing; sort the table by "
            f"current (got {self.currents}).",
            self.currents,
        )

    def __call__(self, current: Scalar) -> Scalar:
        return jnp.interp(current, self.currents, self.values)

    def range(self) -> tuple[Array, Array]:
        return self.currents[0], self.currents[-1]


def is_law(x) -> bool:
    return isinstance(x, AbstractCurrentLaw)


def resolve(tree, current: ScalarLike):
    """Replace every current law inside `tree` by its value at `current`."""
    current = jnp.asarray(current)
    return jax.tree.map(lambda p: p(current) if is_law(p) else p, tree, is_leaf=is_law)


def ranged_laws(tree) -> list[tuple[str, AbstractCurrentLaw]]:
    """`(path, law)` for every law in `tree` with a validity range (a `TableLaw`);
    `path` locates it in `tree`, e.g. `".alpha"`, for messages."""
    found = jax.tree_util.tree_leaves_with_path(tree, is_leaf=is_law)
    return [
        (jax.tree_util.keystr(path), law)
        for path, law in found
        if is_law(law) and law.range() is not None
    ]


def law_ranges(tree) -> list[tuple[Array, Array]]:
    """The validity ranges of all the laws in `tree` that have one."""
    laws = [p for p in jax.tree.leaves(tree, is_leaf=is_law) if is_law(p)]
    return [r for r in (law.range() for law in laws) if r is not None]
