"""Type aliases shared across jaxmr (named axes follow diffrax's convention)."""

from typing import TypeAlias

from jaxtyping import Array, ArrayLike, Bool, Float, Int, PyTree

Scalar: TypeAlias = Float[Array, ""]
ScalarLike: TypeAlias = float | int | Float[ArrayLike, ""]
State: TypeAlias = Float[Array, " states"]
Times: TypeAlias = Float[Array, " times"]

__all__ = [
    "Array",
    "ArrayLike",
    "Bool",
    "Float",
    "Int",
    "PyTree",
    "Scalar",
    "ScalarLike",
    "State",
    "Times",
]
