"""C99 spelling of the numbers and names the generated code holds."""

import math
import re

import numpy as np

_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
# C99's keywords, which no generated name may be.
_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for "
    "goto if inline int long register restrict return short signed sizeof static "
    "struct switch typedef union unsigned void volatile while _Bool _Complex "
    "_Imaginary".split()
)


def literal(value) -> str:
    """A double literal that reads back as exactly `value` (shortest round-trip
    decimal, `repr`), in parentheses when negative; `INFINITY`/`NAN` from math.h."""
    x = float(np.asarray(value))
    if math.isnan(x):
        return "NAN"
    if math.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    text = repr(x)
    if "e" not in text and "." not in text:
        text += ".0"
    return f"({text})" if x < 0 else text


def check_identifier(name: str, what: str) -> str:
    """`name` if it is a C identifier (and no keyword), else `ValueError`."""
    if not isinstance(name, str) or not _IDENTIFIER.match(name) or name in _KEYWORDS:
        raise ValueError(
            f"{what} must be a C identifier (letters, digits and '_', not starting "
            f"with a digit, no C keyword), got {name!r}."
        )
    return name
