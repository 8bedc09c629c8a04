"""Small helpers used by several models: numerics, and validity checks as data."""

import dataclasses
import warnings
from collections.abc import Callable

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, ArrayLike, Bool


def default_float():
    """The floating dtype jax uses now (float64 only when the user enabled x64)."""
    return jnp.result_type(float)


def warn_if_float32(
    what: str,
    stacklevel: int = 3,
    needs: str = "identification needs float64 (solver tolerances, Jacobian "
    "conditioning, accumulated time)",
) -> None:
    """Warn that `what` runs in float32 when jax's default float is float32.

    `needs` says why float64 matters there. The default `stacklevel` points at the
    caller of the public function that calls this one.
    """
    if jnp.result_type(float) != jnp.float64:
        warnings.warn(
            f"{what} is running in float32: {needs}. Call "
            "jax.config.update('jax_enable_x64', True) before creating arrays.",
            UserWarning,
            stacklevel=stacklevel,
        )


def to_device(x) -> Array:
    """A host array (NumPy, or anything `np.asarray` takes) as a JAX array, with
    `jnp.asarray`'s dtype (float64 only under x64), without compiling anything.

    Outside a trace, `jnp.asarray` of a NumPy array runs `lax.stage`, which JAX (0.10)
    compiles once per shape and dtype: a fit's data, packed anew for every set of
    experiments, paid 10-30 ms for each of its arrays. `jax.device_put` copies.
    A JAX array or tracer is returned as it is."""
    if isinstance(x, (jax.Array, jax.core.Tracer)):
        return x
    return jax.device_put(np.asarray(x))


def as_float_array(x: ArrayLike) -> Array:
    """Converter for numeric fields: a float array of jax's default float dtype."""
    if isinstance(x, (jax.Array, jax.core.Tracer)):
        return jnp.asarray(x, dtype=default_float())
    # A host value is converted in NumPy: see `to_device`. NumPy would read the text
    # "2000" as a number; a string here is a mistake (a value read from a file and
    # not converted), so it is named rather than taken.
    array = np.asarray(x)  # one conversion, checked, then cast
    if array.dtype.kind in "USO":
        raise TypeError(f"expected a number or an array of numbers, got {x!r}.")
    return to_device(array.astype(default_float(), copy=False))


def abs_pow(z: Array, p: Array) -> Array:
    """$|z|^p$ with finite derivatives at $z = 0$.

    Writing `jnp.abs(z) ** p` is fine in the forward pass for `p > 0`, but its derivative
    with respect to `p` is `log|z|·|z|^p = -inf·0 = nan` at `z = 0` (the usual initial
    hysteretic state), and its derivative with respect to `z` is infinite for `p < 1`.
    The double `where` evaluates the power only where `|z| > 0` and returns the exact
    limits (value 0, derivatives 0) at `z = 0`, so no nan reaches the gradient.
    """
    a = jnp.abs(z)
    positive = a > 0
    a_safe = jnp.where(positive, a, 1.0)
    return jnp.where(positive, a_safe**p, 0.0)


def signed_pow(z: Array, p: Array) -> Array:
    r"""$z |z|^{p-1} = \mathrm{sgn}(z) |z|^p$, finite at $z = 0$ (see `abs_pow`)."""
    return jnp.sign(z) * abs_pow(z, p)


def is_concrete(*xs) -> bool:
    """True when every array in `xs` has a value now (not a tracer under jit/vmap/grad)."""
    leaves = jax.tree.leaves(xs)
    return not any(isinstance(x, jax.core.Tracer) for x in leaves)


class Check(eqx.Module):
    """A validity check as data: whether it holds, the rule it states and the value
    it is about, from which its message is built (`message`).

    `constraints()` and `checks()` of models, current dynamics, systems and signals
    return these. A check of parameters known only under `jit` has a traced `ok` and
    `value`: it raises at run time (`equinox.error_if`) with a message that quotes the
    value only when it is concrete, since a tracer's repr says nothing to a user.

    **Arguments:**

    - `ok`: whether the check holds, a boolean or boolean array (all must hold),
      maybe traced.
    - `rule`: what must hold, in words, without a final full stop: "`rho` must be
      > 0".
    - `value`: the value the rule is about (a number or array, in the rule's units),
      quoted by the message when concrete; a dict `{name: value}` for a rule about
      several (quoted `name=value, ...`); `None` for a rule that quotes none.

    ```python
    def constraints(self):
        return [jaxmr.Check(self.rho > 0, "`rho` must be > 0", self.rho)]
    ```
    """

    ok: Bool[ArrayLike, "..."]
    rule: str = eqx.field(static=True)
    value: object = None

    def message(self) -> str:
        """`"{rule}, got {value}."`, or `"{rule}."` when there is no value or it is
        traced."""
        if self.value is None or not is_concrete(self.value):
            return f"{self.rule}."
        if isinstance(self.value, dict):
            got = ", ".join(f"{name}={value}" for name, value in self.value.items())
        else:
            got = f"{self.value}"
        return f"{self.rule}, got {got}."

    def named(self, prefix: str) -> "Check":
        """This check with its rule prefixed by `prefix` (`"{prefix}: {rule}"`): the
        model or argument it belongs to."""
        return Check(self.ok, f"{prefix}: {self.rule}", self.value)


def guarded(x, checks, prefix: str = "", suffix: str = ""):
    """`x`, raising at run time the message (`prefix + Check.message() + suffix`) of
    the first of `checks` that fails: one `equinox.branched_error_if` for them all.
    One `error_if` per check traced slower: a quarter car's simulation, 19 checks,
    took 0.33 s to trace against 0.21 s with this."""
    checks = list(checks)
    if not checks:
        return x
    failed = jnp.stack([jnp.logical_not(jnp.all(check.ok)) for check in checks])
    messages = [f"{prefix}{check.message()}{suffix}" for check in checks]
    return eqx.branched_error_if(x, jnp.any(failed), jnp.argmax(failed), messages)


def check_concrete(condition_ok, message: str, *values) -> None:
    """Raise `ValueError(message)` now if `values` are concrete and `condition_ok` fails.

    Used in `__check_init__`: parameters built by hand are checked at once with a message
    that says how to fix them; parameters that are traced (inside a fit) are checked by
    the simulation's runtime checks instead.

    `condition_ok` may be a function of the `values` (as NumPy arrays), called only
    when they are concrete: the check then compiles nothing (each eager `jnp`
    operation compiles once per shape, tens of ms in a fresh process).
    """
    if callable(condition_ok):
        if is_concrete(*values) and not bool(
            np.all(np.asarray(condition_ok(*(np.asarray(v) for v in values))))
        ):
            raise ValueError(message)
        return
    # A condition computed under an outer trace (a module built inside jit from closed-over
    # constants) is a tracer even when the values are not: leave it to the runtime checks.
    if is_concrete(*values, condition_ok) and not bool(
        np.all(np.asarray(condition_ok))
    ):
        raise ValueError(message)


def check_finite_fields(module: eqx.Module) -> None:
    """`ValueError` naming the first field of `module` whose concrete numbers are not
    all finite (traced ones are left to the runtime checks). A NaN amplitude or law
    coefficient was accepted when built and surfaced only inside a simulation, whose
    error pointed at the first compilation's line."""
    for field in dataclasses.fields(module):
        value = getattr(module, field.name, None)
        leaves = [x for x in jax.tree.leaves(value) if eqx.is_array(x)]
        if not leaves or not is_concrete(*leaves):
            continue
        if not all(np.all(np.isfinite(np.asarray(x))) for x in leaves):
            raise ValueError(
                f"{type(module).__name__}: `{field.name}` must be finite, got "
                f"{np.asarray(leaves[0]) if len(leaves) == 1 else value}."
            )


def rk4_stages(rates: Callable, y, h, start, middle, end):
    r"""One step of the classical fourth-order Runge–Kutta method for
    $\dot y = \mathrm{rates}(y, s)$, where `start`, `middle` and `end` are what `rates`
    reads besides the state at the step's start, midpoint and end (the time, or the
    inputs there: a fit computes its inputs at every stage once, before its scans).

    The one RK4 of jaxmr (`rk4_step`, `FixedStep`, the closed loop, the magnetic
    material and the fit's residual all take this step). Written out rather than taken
    from diffrax (which ships no RK4): diffrax's generic Runge–Kutta step loops over
    stages with a checkpointed custom-vjp loop that forbids forward-mode autodiff, and
    its "bounded" alternative triples compile time.
    """
    k1 = rates(y, start)
    k2 = rates(y + (h / 2) * k1, middle)
    k3 = rates(y + (h / 2) * k2, middle)
    k4 = rates(y + h * k3, end)
    return y + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)


def rk4_step(vector_field: Callable, t, y, h, args):
    r"""One classical RK4 step of $\dot y = f(t, y, \mathrm{args})$ from time `t` [s]
    with step `h` [s] (`rk4_stages` with the time as the stage's input)."""
    return rk4_stages(lambda y, s: vector_field(s, y, args), y, h, t, t + h / 2, t + h)


# The packages whose frames lie between a user's call and a warning: jaxmr, and
# the libraries that build and check its modules (equinox runs `__check_init__`;
# jaxtyping and beartype wrap functions when runtime type checking is on).
_INTERNAL = ("jaxmr", "equinox", "jaxtyping", "beartype", "typeguard")


def user_stacklevel(frame) -> int:
    """The `stacklevel` for `warnings.warn` called in `frame` that points at the first
    frame outside `_INTERNAL`: the user's line (that read the file, built the
    experiment or predicted), not equinox's line that runs `__check_init__` or a
    jaxmr function's that called the one warning (a fixed level cannot be
    right: the number of frames between depends on the path taken, and on runtime type
    checking's wrappers)."""
    level = 1
    while frame is not None:
        package = frame.f_globals.get("__name__", "").partition(".")[0]
        if package not in _INTERNAL:
            break
        frame, level = frame.f_back, level + 1
    return level
