r"""Smooth relaxations shared by the semi-active laws, and `with_temperature`.

Every law that switches or clips holds a `temperature` $T \ge 0$ (dimensionless).
$T = 0$ is the hard law; $T > 0$ replaces

- a switch "on if $a b \ge 0$" by $\sigma(\hat s / T)$ with the logistic $\sigma$ and the
  *angular* switching function $\hat s = 2ab/(a^2 + b^2) = \sin 2\varphi \in [-1, 1]$,
  $\varphi$ the angle of $(a, b)$ in its plane. Both factors are first brought to one
  unit (each law says how), so $\hat s$ is dimensionless and blind to the signals'
  amplitude: it measures how far the motion is from the switching surface $ab = 0$
  (the two axes) in angle. $T = 0.1$ means the same softness for every law;
- the clip of a desired force to the damper's reachable band (the inverse model) by a
  soft clip of the band fraction $r = (F^* - F_0)/(F_{I_\max} - F_0)$:
  $T\,[\mathrm{softplus}(r/T) - \mathrm{softplus}((r - 1)/T)] \in (0, 1)$, with the
  fraction itself regularised where the band closes over a force width
  $\sqrt{T}\,F_y$ ($F_y$ the device's yield force: `command_for_force`).

A gain that appears only inside a switching condition then has a nonzero gradient;
evaluate with the hard law ($T = 0$).

Orientation: the laws read `damper_velocity` $v$ and `damper_force` $F$ as the quarter
car defines them, $v = \dot z_s - \dot z_u$ (body minus wheel) with the body receiving
$-F$ (`QuarterCar`, `SingleDegreeOfFreedom`). A system that measures them the other way
round must flip both before a velocity- or force-based law sees them.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._custom_types import Scalar
from .._misc import as_float_array, check_concrete
from .base import AbstractController, DamperPlant, band_fraction


def _safe_temperature(temperature):
    # Both branches of the `where` below are evaluated: the unused soft branch must stay
    # finite (and so must its gradient) when the temperature is 0.
    positive = temperature > 0
    return positive, jnp.where(positive, temperature, 1.0)


def angular_switch(a: Scalar, b: Scalar) -> Scalar:
    r"""$\hat s = 2ab/(a^2 + b^2) \in [-1, 1]$ ($0$ at $a = b = 0$), with `a` and `b` in
    one unit."""
    den = a**2 + b**2
    ok = den > 0
    return jnp.where(ok, 2 * a * b / jnp.where(ok, den, 1.0), 0.0)


def gate(
    s: Scalar, s_hat: Scalar, temperature: Scalar, *, strict: bool = False
) -> Scalar:
    r"""The on/off gate: $H(s)$ (with $H(0) = 1$, or $0$ if `strict`) when the
    temperature is 0, else $\sigma(\hat s / T)$ with `s_hat` the dimensionless
    switching function (same sign as `s`)."""
    positive, t = _safe_temperature(temperature)
    hard = (s > 0) if strict else (s >= 0)
    soft = jax.nn.sigmoid(s_hat / t)
    return jnp.where(positive, soft, hard.astype(s_hat.dtype))


def soft_unit_clip(r: Scalar, temperature: Scalar) -> Scalar:
    r"""$\mathrm{clip}(r, 0, 1)$ at $T = 0$, else
    $T\,[\mathrm{softplus}(r/T) - \mathrm{softplus}((r - 1)/T)]$, which lies in $(0, 1)$
    and tends to the clip as $T \to 0$."""
    positive, t = _safe_temperature(temperature)
    soft = t * (jax.nn.softplus(r / t) - jax.nn.softplus((r - 1) / t))
    return jnp.where(positive, soft, jnp.clip(r, 0.0, 1.0))


def command_for_force(
    plant: DamperPlant, force: Scalar, i_max: Scalar, temperature: Scalar
) -> Scalar:
    r"""The current [A] for a desired damper force `force` [N]: the inverse model
    `plant.current_for_force` at $T = 0$ (the semi-active projection onto the damper's
    band); for $T > 0$ a regularised secant inverse (see the comment) with
    `soft_unit_clip` of the band fraction."""
    f0, f1 = plant.band(i_max)
    hard = i_max * jnp.clip(band_fraction(force, f0, f1), 0.0, 1.0)
    span = f1 - f0
    # The hard ratio (F* - f0)/span jumps between ±inf where the band's width changes
    # sign (after a reversal, while the hysteretic state swings through zero), so the
    # command, and the closed loop's loss, jump with it: a rough landscape whose
    # gradient says nothing about the trend. The relaxed ratio
    # (F* - f0) span / (span² + w²) is the hard one wherever the band is wide compared
    # with w and falls smoothly to zero where it closes.
    #
    # The width is w = sqrt(T) F_y, F_y the device's yield force at I_max: a fixed
    # property of the damper, so the relaxation is the same function of the band
    # everywhere (a scale built from the present forces, |f0| + |f1| + |F*|, vanishes
    # exactly where the band closes and brought the roughness back). It must also
    # span what the band sweeps in one controller sample, or the sampled law still
    # jumps across it: on ISO C roads at 72 km/h the passenger-car damper's band
    # crosses zero 22 times a second and moves a median 0.28 F_y per 1 ms sample as it
    # does. With w = T F_y (50-100 N at the usual T = 0.1-0.05) the rich law's loss
    # was jagged at a weight change of 0.005 (steps of ±0.003 in a_w along a random
    # direction), its gradient spiked to 1e3 and Adam stalled at a 14 % comfort gain;
    # sqrt(T) F_y (220-320 N) made the same line smooth to 1e-4 and the same tuning
    # reached 18 % (benchmarks/README.md, quarter_car_control.py). It still tends to
    # the hard law as T -> 0, more slowly than the clip. Models without a yield force
    # fall back to the present forces' scale.
    yield_force = plant.yield_force(i_max)
    if yield_force is None:
        yield_force = jnp.abs(f0) + jnp.abs(f1) + jnp.abs(force)
    positive, t = _safe_temperature(temperature)
    scale = jnp.sqrt(t) * yield_force
    den = span**2 + scale**2
    ok = den > 0
    ratio = jnp.where(ok, (force - f0) * span / jnp.where(ok, den, 1.0), 0.0)
    soft = i_max * soft_unit_clip(ratio, temperature)
    return jnp.where(positive, soft, hard)


def clip_command(command: Scalar, i_max: Scalar) -> Scalar:
    """The last guard of every law: a command in $[0, I_\\max]$."""
    return jnp.clip(command, 0.0, i_max)


def check_range_and_temperature(name: str, i_max, temperature) -> None:
    """`__check_init__` checks shared by every law."""
    check_concrete(
        i_max > 0,
        f"{name}: `i_max` must be > 0 A (the top of the current range), got {i_max}.",
        i_max,
    )
    check_concrete(
        temperature >= 0,
        f"{name}: `temperature` must be >= 0 (0: the hard law; > 0: the smooth "
        f"relaxation for gradient tuning), got {temperature}.",
        temperature,
    )


def with_temperature(controllers, temperature):
    r"""Set the relaxation `temperature` of every controller in a pytree.

    Laws without one (`ConstantCurrent`) are returned unchanged, so a whole set of
    controllers can be softened for tuning and hardened (`temperature=0`) for the
    evaluation. A controller that wraps a law (`ObserverBasedController`) has its
    law's temperature set.

    **Arguments:**

    - `controllers`: a controller or a pytree of them.
    - `temperature`: $T \ge 0$, dimensionless: every law's switching function is an
      angle measure in $[-1, 1]$ and every clip acts on a band fraction (this module's
      docstring), so one value softens every law alike; 0.05–0.2 is a useful range.

    **Returns:** the same pytree with `temperature` replaced.
    """
    value = as_float_array(temperature)
    check_concrete(
        value >= 0,
        f"with_temperature: `temperature` must be >= 0, got {temperature}.",
        value,
    )

    def set_one(node):
        if _relaxable(node):
            # pyright does not narrow on `hasattr`.
            old = node.temperature  # pyright: ignore[reportAttributeAccessIssue]
            shape = jnp.broadcast_shapes(value.shape, jnp.shape(old))
            t = jnp.broadcast_to(value, shape).astype(old.dtype)
            return eqx.tree_at(lambda c: c.temperature, node, t)
        return node

    # The relaxable laws as the leaves: the map descends through everything else,
    # wrappers included, down to the laws they hold. A controller holding no
    # relaxable law is a leaf too, returned as the same object (not rebuilt).
    def leaf(node):
        return _relaxable(node) or (
            isinstance(node, AbstractController) and not _holds_relaxable(node)
        )

    return jax.tree.map(set_one, controllers, is_leaf=leaf)


def _holds_relaxable(node) -> bool:
    return any(_relaxable(x) for x in jax.tree.leaves(node, is_leaf=_relaxable))


def _relaxable(node) -> bool:
    return isinstance(node, AbstractController) and hasattr(node, "temperature")


def temperatures(controllers) -> list:
    """The `temperature` (dimensionless) of every law in a pytree of controllers that
    has one, wrapped laws (`ObserverBasedController.law`) included, in tree order:
    what `with_temperature` sets. Empty when no law has a relaxation."""
    return [
        node.temperature  # pyright: ignore[reportAttributeAccessIssue]
        for node in jax.tree.leaves(controllers, is_leaf=_relaxable)
        if _relaxable(node)
    ]
