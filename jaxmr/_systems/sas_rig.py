r"""The SAS rocking-lever rig (SYSTEMS.md §2; source docs 000 and 001), derived from
its energies.

**Geometry.** The pivot is the origin, $x$ horizontal towards the beams' tips, $y$ up;
an angle is measured from the horizontal, counter-clockwise (tip up) positive, as the
source's gravity terms imply.

- Upper beam (the body, angle $\alpha_2$): centre of mass at $c_2$ along the beam,
  spring mount at $r_2$ along it, $P_2 = r_2(\cos\alpha_2, \sin\alpha_2)$.
- Lower beam (the wheel arm, angle $\alpha_1$): spring mount at $r_1$ along the beam,
  $P_1 = r_1(\cos\alpha_1, \sin\alpha_1)$; the wheel (radius $r$) has its centre at
  distance $R$ along the direction $\alpha_1 - \beta$ (the arm is bent down by
  $\beta$), $W = R(\cos(\alpha_1 - \beta), \sin(\alpha_1 - \beta))$, and the lower
  beam's centre of mass (wheel included) lies on that line at $c_1$.
- The spring (stiffness $k_s$, free length $l_{0s}$) joins $P_1$ and $P_2$:
  $L = |P_2 - P_1| = \sqrt{(r_2\cos\alpha_2 - r_1\cos\alpha_1)^2
  + (r_2\sin\alpha_2 - r_1\sin\alpha_1)^2}$, the source's formula. It depends on
  $\alpha_2 - \alpha_1$ only, so it acts on the two beams with equal and opposite
  torques.
- The cam's shaft is $D_x$ below the pivot, under the wheel; its top is at height
  $-D_x + l_{0g} + u(t)$ ($l_{0g}$ the cam's mean radius, $u$ the lift). The tyre's
  compression is
  $$\delta = l_{0g} + R\sin(\beta - \alpha_1) + r - D_x + u,$$
  the source's expression, its force acting vertically at the lever arm
  $R\cos(\beta - \alpha_1)$.

**Energies.** With $q = (\alpha_1, \alpha_2)$,
$$T = \tfrac12 J_1\dot\alpha_1^2 + \tfrac12 J_2\dot\alpha_2^2,$$
$$V = m_1 g c_1\sin(\alpha_1 - \beta) + m_2 g c_2 \sin\alpha_2
+ \tfrac12 k_s (L - l_{0s})^2 + \tfrac12 k_g \max(\delta, 0)^2$$
($J_1$, $J_2$ the inertias about the pivot). The equations of motion are Lagrange's,
$M\ddot q = \partial_q \mathcal L - (\partial_{\dot q}\partial_q\mathcal L)\dot q + Q$
with $\mathcal L = T - V$ and $M = \partial^2_{\dot q} T$, every derivative taken by
`jax` (the mass matrix is constant here, so the middle term vanishes, but nothing
relies on it). The non-conservative generalised forces $Q$ are

- beam friction $-k_1\dot\alpha_1$, $-k_2\dot\alpha_2$;
- the tyre's normal force beyond its elastic part: the total normal force is
  $N = k_g\delta + f_g\dot\delta$ while in contact ($\delta > 0$), clipped at zero
  (the tyre cannot pull: when the wheel leaves the cam faster than the tyre recovers,
  $N = 0$), and $N = 0$ out of contact. Its generalised force is
  $-N\,\partial\delta/\partial q$, of which $-k_g\delta_+\,\partial\delta/\partial q$
  is already in $-\partial V/\partial q$; the rest, $-(N - k_g\delta_+)\,
  \partial\delta/\partial q$, dissipates (it is $-f_g\dot\delta$ unclipped and
  $-k_g\delta$ with $\dot\delta < -k_g\delta/f_g$ when clipped). The clip is not
  smoothed: its kinks only matter for gradients while contact is being lost, which
  the decays and the cam runs used here do not differentiate through.
- the brake: it sees the body's angle relative to the wheel arm, $\theta = \alpha_2 -
  \alpha_1$ (`damper_displacement`, oriented like the quarter car's $z_s - z_u$), and
  gives the torque $T_{MR}$ (`damper_force`) with jaxmr's damper convention,
  $T_{MR}\dot\theta \ge 0$ when it dissipates. It acts with $-T_{MR}$ on the upper
  beam and $+T_{MR}$ on the lower one, $Q = -T_{MR}\,\partial\theta/\partial q$, so
  its power is $-T_{MR}\dot\theta$. The source's encoder angle is
  $\alpha_1 - \alpha_2 = -\theta$; since every brake model is odd in $(\theta,
  \dot\theta, z)$, the orientation only decides which beam receives $+T_{MR}$. This
  one lets the quarter-car laws (skyhook's $F^* = c\,\dot z_s$, groundhook, ...) and
  `Backstepping` with $g = \partial\ddot\alpha_2/\partial T_{MR} = -1/J_2$ run on the
  rig unchanged.

Hence the upper beam's equation reads
$$J_2\ddot\alpha_2 = -m_2 g c_2\cos\alpha_2 - k_s(L - l_{0s})\,\partial L/\partial
\alpha_2 - k_2\dot\alpha_2 - T_{MR}.$$

**Departures from the printed equations** (source doc 001 §4.3, whose signs are
garbled): friction opposes motion on both beams (printed as $-k_2\dot\alpha_2$ on the
left-hand side it would feed energy in); the spring's torque is $k_s(L - l_{0s})\,
\partial L/\partial\alpha$ (the printed $r_2 k_s(l_{0s} - L)$ takes the lever arm as
$r_2$, true only when the spring is perpendicular to the beam); the centres of mass
have their own distances $c_1$, $c_2$ (printed at the spring mounts $r_1$, $r_2$); the
tyre's damping acts on $\dot\delta = \dot u - R\cos(\beta - \alpha_1)\dot\alpha_1$
(printed with $\frac{d}{dt}(D_x - u)$) and the tyre only pushes; the brake torque
enters the two beams with opposite signs (printed on the right-hand side of both with
the same sign).

**States** are the absolute angles and rates `alpha1`, `omega1`, `alpha2`, `omega2`
[rad, rad/s]; the rest state is the static equilibrium (`SASRig.equilibrium`). With
the default parameters the body rests level ($\alpha_2 = 0$ within 0.01°), so the
source's "released from $\alpha_2 = 16°$" is 16° from equilibrium as well.
"""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._current_law import LinearLaw
from .._custom_types import Array, Float, Scalar, ScalarLike, State
from .._damper import Damper, as_damper, fitted_range_in
from .._hysteresis import BoucWen
from .._metrics import settling_time
from .._misc import Check, as_float_array, check_concrete, is_concrete
from .._presets import PRESETS, sas_brake_bouc_wen
from .base import AbstractSystem

GRAVITY = 9.81  # m/s²
_DEG = np.pi / 180.0

# Fields that must be strictly positive (lengths, masses, inertias, stiffnesses) or
# non-negative (friction, damping), with their units for the error messages.
_POSITIVE = {
    "J1": "kg·m²",
    "J2": "kg·m²",
    "m1": "kg",
    "m2": "kg",
    "c1": "m",
    "c2": "m",
    "r1": "m",
    "r2": "m",
    "ks": "N/m",
    "l0s": "m",
    "R": "m",
    "r": "m",
    "l0g": "m",
    "Dx": "m",
    "kg": "N/m",
}
_NON_NEGATIVE = {"k1": "N·m·s/rad", "k2": "N·m·s/rad", "fg": "N·s/m"}


class SASRig(AbstractSystem):
    r"""The SAS rocking-lever rig: two beams on one pivot, the MR rotary brake between
    them, a spring, gravity, beam friction and a tyre on an eccentric cam.

    See the module docstring (`jaxmr._systems.sas_rig`) for the geometry, the
    energies and the sign conventions; in short, with $q = (\alpha_1, \alpha_2)$
    (lower beam / wheel arm, upper beam / body),
    $$M\ddot q = -\partial_q V(q, u) + Q_\mathrm{friction} + Q_\mathrm{tyre}
    - T_{MR}\,\partial_q\theta,\qquad \theta = \alpha_2 - \alpha_1,$$
    with $T_{MR}\dot\theta \ge 0$ when the brake dissipates. The excitation signal is
    the cam's lift $u(t)$ [m] (e.g. `jaxmr.Sine(e, f)` for a cam of eccentricity $e$
    turning at $f$ rev/s), zero at the cam's mid-lift.

    States: `alpha1`, `omega1`, `alpha2`, `omega2` [rad, rad/s], absolute angles.
    Measurements: `jaxmr.constants.MEASUREMENT_NAMES` (body = upper beam [rad], wheel = lower
    beam, damper = brake: $\theta$, $\dot\theta$, $T_{MR}$ [N·m]; excitation = cam
    lift [m]) plus `wheel_acceleration` [rad/s²], `contact_force` $N$ [N] (≥ 0),
    `tyre_compression` $\delta$ [m] and `spring_force` $k_s(l_{0s} - L)$ [N]
    (positive when compressed).

    **Arguments** (`sas_rig()` gives documented defaults):

    - `damper`: the brake (a `Damper` or hysteresis model), torque [N·m] against
      relative angle [rad].
    - `J1`, `J2`: lower and upper beam inertias about the pivot [kg·m²].
    - `m1`, `m2`: their masses [kg]; `c1`, `c2`: distances of their centres of mass
      from the pivot [m] (the lower one along the wheel arm).
    - `k1`, `k2`: viscous friction of the beams [N·m·s/rad].
    - `r1`, `r2`: the spring mounts' distances from the pivot [m].
    - `ks`: spring stiffness [N/m]; `l0s`: its free length [m].
    - `R`: the wheel centre's distance from the pivot [m]; `r`: wheel radius [m];
      `beta`: the wheel arm's bend below the lower beam's line [rad].
    - `Dx`: the cam shaft's depth below the pivot [m]; `l0g`: the cam's mean radius [m].
    - `kg`: tyre stiffness [N/m]; `fg`: tyre damping [N·s/m].
    - `g`: gravity [m/s²], default 9.81.
    """

    damper: Damper = eqx.field(converter=as_damper)
    J1: Float[Array, ""] = eqx.field(converter=as_float_array)
    J2: Float[Array, ""] = eqx.field(converter=as_float_array)
    m1: Float[Array, ""] = eqx.field(converter=as_float_array)
    m2: Float[Array, ""] = eqx.field(converter=as_float_array)
    c1: Float[Array, ""] = eqx.field(converter=as_float_array)
    c2: Float[Array, ""] = eqx.field(converter=as_float_array)
    k1: Float[Array, ""] = eqx.field(converter=as_float_array)
    k2: Float[Array, ""] = eqx.field(converter=as_float_array)
    r1: Float[Array, ""] = eqx.field(converter=as_float_array)
    r2: Float[Array, ""] = eqx.field(converter=as_float_array)
    ks: Float[Array, ""] = eqx.field(converter=as_float_array)
    l0s: Float[Array, ""] = eqx.field(converter=as_float_array)
    R: Float[Array, ""] = eqx.field(converter=as_float_array)
    r: Float[Array, ""] = eqx.field(converter=as_float_array)
    beta: Float[Array, ""] = eqx.field(converter=as_float_array)
    Dx: Float[Array, ""] = eqx.field(converter=as_float_array)
    l0g: Float[Array, ""] = eqx.field(converter=as_float_array)
    kg: Float[Array, ""] = eqx.field(converter=as_float_array)
    fg: Float[Array, ""] = eqx.field(converter=as_float_array)
    g: Float[Array, ""] = eqx.field(converter=as_float_array, default=GRAVITY)
    state_names: ClassVar[tuple[str, ...]] = ("alpha1", "omega1", "alpha2", "omega2")

    def __check_init__(self):
        # The brake's model, where it holds the range it was fitted on, must be a
        # rotary device's: a damper fitted in metres and newtons ran silently in the
        # rig (95 N·m, the body stuck at 8°).
        fitted = fitted_range_in(self.damper, strict=False)
        if fitted is not None and not fitted.rotary:
            raise ValueError(
                "SASRig: its damper is the rig's rotary brake (angle [rad], torque "
                "[N·m]), but this model was fitted on a linear device's records (m, "
                "N): fit a brake model to the brake's records."
            )
        arrays = [getattr(self, name) for name in (*_POSITIVE, *_NON_NEGATIVE)]
        if is_concrete(*arrays, self.beta, self.g):
            for check in self.constraints():
                check_concrete(check.ok, check.named("SASRig").message(), *arrays)

    # -- validity ---------------------------------------------------------------------

    def constraints(self):
        # The parameter checks come first: `__check_init__` raises on the first
        # failure, so a bad mass gets its own message rather than the geometric ones
        # its NaN equilibrium would fail too.
        checks = []
        for name, unit in _POSITIVE.items():
            value = getattr(self, name)
            checks.append(Check(value > 0, f"`{name}` must be > 0 {unit}", value))
        for name, unit in _NON_NEGATIVE.items():
            value = getattr(self, name)
            checks.append(
                Check(
                    value >= 0,
                    f"`{name}` must be >= 0 {unit} (negative friction or damping feeds "
                    "energy in)",
                    value,
                )
            )
        checks.append(Check(self.g >= 0, "gravity `g` must be >= 0 m/s²", self.g))
        for j, m, c in (("J1", "m1", "c1"), ("J2", "m2", "c2")):
            inertia, mass, arm = getattr(self, j), getattr(self, m), getattr(self, c)
            checks.append(
                Check(
                    inertia >= mass * arm**2,
                    f"`{j}` [kg·m²] must be at least `{m}`·`{c}`²: a beam's inertia "
                    "about the pivot is at least its mass times the square of its "
                    "centre of mass's distance (parallel-axis theorem); raise the "
                    "inertia or move the centre of mass in",
                    {j: inertia, f"{m}·{c}²": mass * arm**2},
                )
            )
        reach = jnp.abs(self.Dx - self.l0g - self.r) < self.R
        checks.append(
            Check(
                reach,
                "impossible geometry: the wheel cannot reach the cam, |Dx - l0g - r| "
                "must be < R [m] (the cam shaft is `Dx` below the pivot, the wheel "
                "centre `R` from it); move the cam up (smaller `Dx`) or lengthen the "
                "wheel arm `R`",
                {"|Dx - l0g - r|": jnp.abs(self.Dx - self.l0g - self.r), "R": self.R},
            )
        )
        q, grad, hessian, compression, length = _rest_diagnostics(self)
        scale = 1 + self.g * (self.m1 * self.c1 + self.m2 * self.c2)
        converged = jnp.all(jnp.abs(grad) < 1e-6 * scale)
        stable = (hessian[0, 0] > 0) & (jnp.linalg.det(hessian) > 0)
        checks += [
            Check(
                converged,
                "impossible geometry: no static equilibrium found with the cam at "
                "mid-lift (check that the spring `ks`, `l0s`, `r1`, `r2` can hold the "
                "body's weight m2·g·c2 and that the wheel rests on the cam)",
            ),
            Check(
                (compression > 0) | ~converged,
                "impossible geometry: at rest the wheel does not touch the cam (tyre "
                "compression <= 0); move the cam up (smaller `Dx`) or give it a "
                "larger radius `l0g`",
            ),
            Check(
                (length > 0.05 * self.l0s) | ~converged,
                "impossible geometry: at rest the spring is squeezed to (almost) zero "
                "length; lengthen `l0s` or move the mounts `r1`, `r2`",
            ),
            Check(
                (jnp.abs(q[1]) < 60 * _DEG) | ~converged,
                "the spring cannot hold the body up: its rest angle alpha2 [°] must "
                "be within 60° of level; stiffen `ks` or lengthen `l0s` (the spring "
                "carries m2·g·c2 at rest)",
                jnp.rad2deg(q[1]),
            ),
            Check(
                stable | ~converged,
                "the static equilibrium is unstable (the potential's Hessian is not "
                "positive definite): stiffen the spring `ks` or lower the centres of "
                "mass",
            ),
        ]
        return checks

    # -- geometry and energies --------------------------------------------------------

    def spring_length(self, q: Float[Array, " 2"]) -> Scalar:
        """Spring length $L$ [m] at angles $q = (\\alpha_1, \\alpha_2)$ [rad]."""
        dx = self.r2 * jnp.cos(q[1]) - self.r1 * jnp.cos(q[0])
        dy = self.r2 * jnp.sin(q[1]) - self.r1 * jnp.sin(q[0])
        return jnp.sqrt(dx**2 + dy**2)

    def tyre_compression(self, q: Float[Array, " 2"], lift: ScalarLike) -> Scalar:
        """Tyre compression $\\delta$ [m] (positive in contact) at cam lift `lift` [m]."""
        return self.l0g + self.R * jnp.sin(self.beta - q[0]) + self.r - self.Dx + lift

    def kinetic(self, q: Float[Array, " 2"], qdot: Float[Array, " 2"]) -> Scalar:
        """Kinetic energy $T$ [J]."""
        del q
        return 0.5 * self.J1 * qdot[0] ** 2 + 0.5 * self.J2 * qdot[1] ** 2

    def potential(self, q: Float[Array, " 2"], lift: ScalarLike = 0.0) -> Scalar:
        """Potential energy $V$ [J] of gravity, spring and tyre (absolute, not relative
        to equilibrium) with the cam at lift `lift` [m]."""
        gravity = self.g * (
            self.m1 * self.c1 * jnp.sin(q[0] - self.beta)
            + self.m2 * self.c2 * jnp.sin(q[1])
        )
        spring = 0.5 * self.ks * (self.spring_length(q) - self.l0s) ** 2
        tyre = 0.5 * self.kg * jnp.maximum(self.tyre_compression(q, lift), 0.0) ** 2
        return gravity + spring + tyre

    def contact_force(
        self,
        q: Float[Array, " 2"],
        qdot: Float[Array, " 2"],
        lift: ScalarLike,
        lift_rate: ScalarLike,
    ) -> Scalar:
        """Normal force $N \\ge 0$ [N] of the cam on the tyre, at lift `lift` [m] and
        lift rate `lift_rate` [m/s]."""
        delta = self.tyre_compression(q, lift)
        delta_rate = lift_rate - self.R * jnp.cos(self.beta - q[0]) * qdot[0]
        pushing = jnp.maximum(self.kg * delta + self.fg * delta_rate, 0.0)
        return jnp.where(delta > 0, pushing, 0.0)

    def generalized_forces(
        self,
        q: Float[Array, " 2"],
        qdot: Float[Array, " 2"],
        lift: ScalarLike,
        lift_rate: ScalarLike,
        torque: ScalarLike,
    ) -> Float[Array, " 2"]:
        """The non-conservative generalised forces $Q$ [N·m] on $(\\alpha_1,
        \\alpha_2)$: beam friction, the tyre's dissipative part and the brake torque
        `torque` [N·m]."""
        friction = -jnp.stack([self.k1, self.k2]) * qdot
        delta = self.tyre_compression(q, lift)
        ddelta_dq = jax.grad(self.tyre_compression)(q, lift)
        normal = self.contact_force(q, qdot, lift, lift_rate)
        tyre = -(normal - self.kg * jnp.maximum(delta, 0.0)) * ddelta_dq
        # -T dθ/dq with θ = α2 - α1.
        torque = jnp.asarray(torque, dtype=qdot.dtype)
        brake = jnp.stack([torque, -torque])
        return friction + tyre + brake

    def accelerations(
        self,
        q: Float[Array, " 2"],
        qdot: Float[Array, " 2"],
        lift: ScalarLike,
        lift_rate: ScalarLike,
        torque: ScalarLike,
    ) -> Float[Array, " 2"]:
        """$\\ddot q$ [rad/s²] from Lagrange's equations with the brake torque
        `torque` [N·m], the cam at `lift` [m] rising at `lift_rate` [m/s]."""

        def lagrangian(q, qdot):
            return self.kinetic(q, qdot) - self.potential(q, lift)

        mass = jax.hessian(self.kinetic, argnums=1)(q, qdot)
        dl_dq = jax.grad(lagrangian, argnums=0)(q, qdot)
        mixed = jax.jacfwd(jax.grad(lagrangian, argnums=1), argnums=0)(q, qdot)
        forces = dl_dq - mixed @ qdot
        forces = forces + self.generalized_forces(q, qdot, lift, lift_rate, torque)
        return jnp.linalg.solve(mass, forces)

    # -- AbstractSystem ---------------------------------------------------------------

    def damper_motion(self, q, t, excitation):
        return q[2] - q[0], q[3] - q[1]

    def _accelerations(self, q, t, excitation, force):
        lift, lift_rate = excitation(t), excitation.derivative(t)
        acc = self.accelerations(q[::2], q[1::2], lift, lift_rate, force)
        return acc, lift, lift_rate

    def rates(self, q, t, excitation, force):
        acc, _, _ = self._accelerations(q, t, excitation, force)
        return jnp.stack([q[1], acc[0], q[3], acc[1]])

    def measure(self, q, t, excitation, force):
        acc, lift, lift_rate = self._accelerations(q, t, excitation, force)
        angles, rates = q[::2], q[1::2]
        return {
            "body_position": q[2],
            "body_velocity": q[3],
            "body_acceleration": acc[1],
            "wheel_position": q[0],
            "wheel_velocity": q[1],
            "wheel_acceleration": acc[0],
            "damper_displacement": q[2] - q[0],
            "damper_velocity": q[3] - q[1],
            "damper_force": force,
            "excitation": lift,
            "contact_force": self.contact_force(angles, rates, lift, lift_rate),
            "tyre_compression": self.tyre_compression(angles, lift),
            "spring_force": self.ks * (self.l0s - self.spring_length(angles)),
        }

    def energy(self, q):
        angles, rates = q[::2], q[1::2]
        zero = jnp.zeros_like(q[0])
        rest = jax.lax.stop_gradient(self.equilibrium())
        potential = self.potential(angles, zero) - self.potential(rest, zero)
        return self.kinetic(angles, rates) + potential

    def initial_state(self, excitation, t0):
        """Rest at the static equilibrium with the cam where it is at `t0`."""
        q = self.equilibrium(excitation(t0))
        zero = jnp.zeros_like(q[0])
        return jnp.stack([q[0], zero, q[1], zero]).astype(jnp.result_type(t0))

    # -- statics ------------------------------------------------------------------------

    def _equilibrium_fixed_point(self, lift, hold_body=None, iterations=60):
        """Damped Newton on $\\partial_q V = 0$ (on $\\partial_{\\alpha_1} V = 0$ alone
        with the body held at `hold_body`), without gradients."""
        rig = jax.lax.stop_gradient(self)
        lift = jax.lax.stop_gradient(lift)
        # Start with the tyre just touching the cam and the body level.
        s = jnp.clip((rig.Dx - rig.l0g - rig.r - lift) / rig.R, -0.99, 0.99)
        body = jnp.zeros_like(s) if hold_body is None else hold_body
        q0 = jnp.stack([rig.beta - jnp.arcsin(s), jnp.asarray(body, dtype=s.dtype)])

        def step(_, q):
            grad = jax.grad(rig.potential)(q, lift)
            hess = jax.hessian(rig.potential)(q, lift)
            if hold_body is None:
                # A Levenberg-style shift keeps the step a descent direction where
                # the Hessian is indefinite (far from the rest state).
                shift = 1.1 * jnp.maximum(0.0, -jnp.min(jnp.linalg.eigvalsh(hess)))
                dq = -jnp.linalg.solve(hess + shift * jnp.eye(2, dtype=q.dtype), grad)
            else:
                h00 = jnp.where(hess[0, 0] > 0, hess[0, 0], jnp.abs(hess[0, 0]) + 1.0)
                dq = jnp.stack([-grad[0] / h00, jnp.zeros_like(grad[0])])
            # Steps of at most 0.1 rad: Newton is only trusted near the solution.
            size = jnp.max(jnp.abs(dq))
            return q + dq * jnp.minimum(1.0, 0.1 / jnp.where(size > 0, size, 1.0))

        return jax.lax.fori_loop(0, iterations, step, q0)

    def equilibrium(self, lift: ScalarLike = 0.0) -> Float[Array, " 2"]:
        r"""Static equilibrium angles $(\alpha_1, \alpha_2)$ [rad] with the cam at
        lift `lift` [m] (default: mid-lift): the minimum of $V$ reached by damped
        Newton from the wheel touching the cam and the body level.

        Differentiable with respect to the rig's parameters and the lift by the
        implicit function theorem: one Newton step taken with gradients from the
        converged point (the iterations themselves see none).
        """
        lift = jnp.asarray(lift, dtype=self.R.dtype)
        q = _fixed_point(self, lift)
        grad = jax.grad(self.potential)(q, lift)
        hess = jax.lax.stop_gradient(jax.hessian(self.potential)(q, lift))
        return q - jnp.linalg.solve(hess, grad)

    def held_state(self, alpha2: ScalarLike, lift: ScalarLike = 0.0) -> State:
        """The state [rad, rad/s] with the body held still at `alpha2` [rad] and the
        lower beam at rest on the cam (lift `lift` [m]): the start of a free decay."""
        alpha2 = jnp.asarray(alpha2, dtype=self.R.dtype)
        lift = jnp.asarray(lift, dtype=self.R.dtype)
        a1 = _fixed_point(self, lift, alpha2)[0]

        def lower(a1):
            return jax.grad(self.potential)(jnp.stack([a1, alpha2]), lift)[0]

        a1 = a1 - lower(a1) / jax.lax.stop_gradient(jax.grad(lower)(a1))
        zero = jnp.zeros_like(a1)
        return jnp.stack([a1, zero, alpha2, zero])

    def natural_frequencies(self) -> Float[Array, " 2"]:
        """Undamped frequencies [Hz] of the two modes linearised at rest with the brake
        slipping (no torque), in increasing order (the body mode first with the
        defaults)."""
        q = self.equilibrium()
        zero = jnp.zeros_like(self.R)
        stiffness = jax.hessian(self.potential)(q, zero)
        mass = jax.hessian(self.kinetic, argnums=1)(q, jnp.zeros_like(q))
        root = jnp.sqrt(jnp.diag(mass))
        w2 = jnp.linalg.eigvalsh(stiffness / (root[:, None] * root[None, :]))
        return jnp.sqrt(w2) / (2 * jnp.pi)

    def brake_torque_from_body(
        self,
        alpha1: Float[Array, " times"],
        alpha2: Float[Array, " times"],
        omega2: Float[Array, " times"],
        accel2: Float[Array, " times"],
    ) -> Float[Array, " times"]:
        r"""The brake torque [N·m] that the upper beam's equation of motion implies,
        $T_{MR} = -(J_2\ddot\alpha_2 + \partial V/\partial\alpha_2 + k_2\dot\alpha_2)$
        (the tyre does not act on the upper beam, so the cam is not needed)."""

        def one(a1, a2, w2, acc2):
            dv = jax.grad(self.potential)(jnp.stack([a1, a2]))[1]
            return -(self.J2 * acc2 + dv + self.k2 * w2)

        return jax.vmap(one)(alpha1, alpha2, omega2, accel2)


# Jitted so that the 60 Newton iterations compile once instead of running op by op
# when called outside jit (construction checks, `equilibrium()` in a notebook); inside
# a jitted caller they are inlined.
@eqx.filter_jit
def _fixed_point(rig: SASRig, lift, hold_body=None):
    return jax.lax.stop_gradient(rig._equilibrium_fixed_point(lift, hold_body))


@eqx.filter_jit
def _rest_diagnostics(rig: SASRig):
    zero = jnp.zeros_like(rig.R)
    q = rig._equilibrium_fixed_point(zero)
    return (
        q,
        jax.grad(rig.potential)(q, zero),
        jax.hessian(rig.potential)(q, zero),
        rig.tyre_compression(q, zero),
        rig.spring_length(q),
    )


# -- the rig's brake and defaults -------------------------------------------------------


def sas_rig_brake() -> BoucWen:
    r"""The rig's brake as jaxmr models it by default: the SAS study's Bouc–Wen brake
    (Table 3 of source doc 001, `sas_brake_bouc_wen`) with its viscous law read per
    degree, $C(i) = (0.0015 + 0.07 i)$ N·m·s/deg $= (0.0859 + 4.01 i)$ N·m·s/rad.

    Why: the thesis works in degrees (its torque–velocity loops are against deg/s).
    Read per radian (the preset) the brake gives
    $1.16\,(1 + 0.07 i) + (0.0015 + 0.07 i)\dot\theta$ N·m once $z$ saturates (at
    $z_0 = (\delta/(\beta+\gamma))^{1/n} = 1.16$), at most 1.39 N·m at 1.5 A and
    1 rad/s, where the RD-2087-01's datasheet
    promises ≈ 4 N·m at 1.5 A; and between 0 and 0.2 A its torque changes by 1.4 %,
    which cannot make any plausible rig settle twice as fast at 0.2 A as at 0 A, as
    the source observes. Read per degree it gives $1.16 + 0.0859\dot\theta$ N·m at 0 A
    and $1.28 + 6.1\dot\theta$ N·m at 1.5 A (4 N·m at 0.45 rad/s; above the datasheet's
    figure at the decay's fastest swings, ~3 rad/s, where a real brake's viscous part
    saturates). The hysteretic part (α, δ, β, γ, n) is kept per radian as in the
    preset: read per degree it would switch within 0.0014° instead of 0.08° (both
    below the encoders' 0.088°, so the data cannot tell them apart) and make the
    equations stiff ($|\partial\dot z/\partial z| \approx 4\cdot 10^4 |\dot\theta|$
    s⁻¹, needing ~10 µs steps).
    """
    per_degree = 180.0 / np.pi
    return eqx.tree_at(
        lambda m: m.c0,
        sas_brake_bouc_wen(),
        LinearLaw(0.0015 * per_degree, 0.07 * per_degree),
    )


# Listed with the other presets (`jaxmr.PRESETS`) from here: it is the rig's reading of
# the SAS brake, and the presets' module sits below the machines.
PRESETS["sas_rig_brake"] = sas_rig_brake


# Defaults: see `sas_rig`'s docstring. `l0s` and `Dx` are derived (rounded to 0.1 mm)
# so that the body rests level (α2 = 0) and the lower beam at -25°.
_DEFAULTS = dict(
    J1=1.4,
    J2=2.7,
    m1=6.0,
    m2=6.0,
    c1=0.45,
    c2=0.55,
    k1=0.01,
    k2=0.01,
    r1=0.3,
    r2=0.3,
    ks=2500.0,
    l0s=0.1741,
    R=0.55,
    r=0.08,
    beta=10 * _DEG,
    Dx=0.4525,
    l0g=0.06,
    kg=40e3,
    fg=100.0,
)


def sas_rig(damper=None, **overrides) -> SASRig:
    r"""The SAS rig with jaxmr's default parameters (the source gives none: "given in
    the manufacturer's documentation").

    | | value | why |
    |---|---|---|
    | upper beam | $J_2$ = 2.7 kg·m², $m_2$ = 6 kg, $c_2$ = 0.55 m | a ~1.1 m arm ("about one meter from tip to pivot", source doc 001 §6.1.1) loaded towards its tip (radius of gyration 0.67 m) |
    | lower beam | $J_1$ = 1.4 kg·m², $m_1$ = 6 kg, $c_1$ = 0.45 m | the wheel arm with a small car wheel |
    | spring | $k_s$ = 2500 N/m, $r_1 = r_2$ = 0.3 m, $l_{0s}$ = 0.1741 m | body mode 1.41 Hz; compressed 44 mm at rest, holding the body level |
    | wheel | $R$ = 0.55 m, $r$ = 0.08 m, $\beta$ = 10° | lower beam at −25° at rest, wheel arm at −35° |
    | cam | $D_x$ = 0.4525 m, $l_{0g}$ = 0.06 m | tyre compressed 3 mm at rest |
    | tyre | $k_g$ = 40 kN/m, $f_g$ = 100 N·s/m | a small stiff wheel; wheel-arm mode 12.3 Hz |
    | friction | $k_1 = k_2$ = 0.01 N·m·s/rad | bearings, small against the brake's 0.086 N·m·s/rad at 0 A |

    With the brake `sas_rig_brake()`, the body released from 16° above its rest
    angle with the cam still (`free_decay`) settles, i.e. stays within 0.5° of where
    it comes to rest (`decay_settling_time`), in 9.5–9.8 s at 0 A (the value moves
    with the record's length and the step: the end of the decay is a slow tail), 6.1 s
    at 0.2 A, 2.7 s at 1 A and 2.05 s at 1.5 A; the source reports ≈ 11 s and ≈ 6 s,
    faster with more current. How the numbers were chosen: the brake's hysteretic
    torque $\alpha z \approx 1.16$ N·m is friction-like and nearly independent of the
    current, so at 0 A the swing shrinks by about 1° per half period, then lingers
    in a slow tail (≈ 0.3–0.5°) once the swing is too small to flip $z$; the viscous
    term $C(i)\dot\theta$ adds an exponential decay at the rate $C(i)/2J_2$ =
    0.16 s⁻¹ at 0.2 A, which sets $J_2$. Stiffer or softer springs (1.3–3 Hz), heavier
    or lighter body arms and tyres from 10 to 60 kN/m were tried: none gives more
    than ≈ 10 s at 0 A while keeping 0.2 A near 6 s. At the release the spring pulls
    the wheel off the cam for ≈ 0.1 s (the body arm's weight torque, 32 N·m, is less
    than the spring's 16° of travel asks for); the tyre then stays in contact. The
    weights fix $l_{0s}$ and $D_x$ (rest angles above). Under a 4 mm cam at the body
    mode the body swings 6.3° RMS at 0 A, 2.7° at 0.2 A and 0.9° at 1.5 A
    (`benchmarks/sas_rig.py`).

    **Arguments:**

    - `damper`: the brake (default `sas_rig_brake()`); any `Damper` or hysteresis
      model with torque [N·m] against angle [rad], e.g. `jaxmr.sas_brake_dahl()`.
    - `overrides`: any `SASRig` field, e.g. `sas_rig(J2=2.0)` (the rest angles then
      move: `SASRig.equilibrium`).
    """
    if damper is None:
        damper = sas_rig_brake()
    unknown = set(overrides) - set(_DEFAULTS) - {"g"}
    if unknown:
        raise TypeError(
            f"sas_rig: unknown parameter(s) {sorted(unknown)}; the rig's parameters "
            f"are {sorted(_DEFAULTS)} and `g`."
        )
    return SASRig(damper=damper, **(_DEFAULTS | overrides))


# -- the thesis's experiments -----------------------------------------------------------


def decay_settling_time(
    ts: Float[Array, " samples"],
    alpha2: Float[Array, "*batch samples"],
    band_deg: float = 0.5,
    *,
    final_window: float = 0.5,
) -> Float[Array, "*batch"]:
    r"""Settling time [s] of a free decay: the time after which the body stays within
    `band_deg` of where it comes to rest, $|\alpha_2 - \alpha_{2,\infty}| \le 0.5°$
    to the end of the record, $\alpha_{2,\infty}$ the mean over the last
    `final_window` seconds.

    The rest angle, not the equilibrium, is the reference because the brake's
    friction-like torque (≈ 1.16 N·m at any current) can hold the body up to
    $T/k \approx 0.3°$ off its equilibrium; the band is half a degree because the
    encoders resolve 0.088° and the source reads settling off plots. `inf` if the
    record ends outside the band (make it longer).

    **Arguments:** `ts` [s] (uniform), `alpha2` [rad] (e.g. `solution.ts`,
    `solution["body_position"]`), `band_deg` [°], `final_window` [s].
    """
    ts, alpha2 = as_float_array(ts), as_float_array(alpha2)
    # A mask rather than a slice, so that the window may be traced (under jit).
    last = ts >= ts[-1] - final_window
    total = jnp.sum(jnp.where(last, alpha2, 0.0), axis=-1, keepdims=True)
    final = total / jnp.sum(last.astype(alpha2.dtype))
    return settling_time(ts, alpha2 - final, band_deg * _DEG)


# -- inverse dynamics ---------------------------------------------------------------------


def _savitzky_golay_matrix(window: int, order: int, deriv: int) -> np.ndarray:
    """Row j: the weights that give the `deriv`-th derivative (per sample^deriv) at
    position j of a window from its `window` values, by a least-squares polynomial of
    degree `order`."""
    half = window // 2
    x = np.arange(-half, half + 1, dtype=float)
    coefficients = np.linalg.pinv(np.vander(x, order + 1, increasing=True))
    rows = np.zeros((window, window))
    for k in range(deriv, order + 1):
        factor = np.prod(np.arange(k - deriv + 1, k + 1, dtype=float))
        rows += factor * np.outer(x ** (k - deriv), coefficients[k])
    return rows


def savitzky_golay(
    y: Float[Array, " samples"], dt: float, window: int, order: int, deriv: int
) -> Float[Array, " samples"]:
    """Savitzky–Golay smoothing (`deriv=0`) or differentiation of uniformly sampled
    `y`: a least-squares polynomial of degree `order` over `window` samples centred on
    each sample, the edges fitted on the first and last windows (scipy's
    `mode="interp"`). Units: `y`'s per second^deriv."""
    rows = jnp.asarray(_savitzky_golay_matrix(window, order, deriv), dtype=y.dtype)
    half = window // 2
    middle = jnp.convolve(y, rows[half][::-1], mode="valid")
    head = rows[:half] @ y[:window]
    tail = rows[half + 1 :] @ y[-window:]
    return jnp.concatenate([head, middle, tail]) / dt**deriv


def inverse_dynamics(
    rig: SASRig,
    ts: Float[Array, " samples"],
    alpha2: Float[Array, " samples"],
    alpha1: Float[Array, " samples"] | None = None,
    *,
    window: int = 21,
    order: int = 3,
) -> Float[Array, " samples"]:
    r"""The brake torque [N·m] recovered from measured angles (source doc 001 §4.4),
    by solving the upper beam's equation for it:
    $$T_{MR} = -\big(J_2\ddot\alpha_2 + \partial V/\partial\alpha_2(\alpha_1, \alpha_2)
    + k_2\dot\alpha_2\big).$$

    $\dot\alpha_2$ and $\ddot\alpha_2$ come from a Savitzky–Golay filter (a
    least-squares polynomial of degree `order` over `window` samples), $\alpha_2$ in
    the potential term from the same filter's smoothing. $J_2\ddot\alpha_2$ and the
    spring's torque are tens of N·m and the brake's torque is their small difference,
    so the estimate is only as good as the second derivative. From exact angles at
    1 kHz the default (cubic, 21 samples: ±10 ms) leaves ≈ 2 % RMS error, from the
    torque's sharp reversals, which it blurs over about the window; with the lower
    beam not measured (taken at rest on the cam) ≈ 10 %. Angles quantised to the
    rig's 4096-pulse encoders (0.088°) need a wide window, e.g. `window=201,
    order=5`: ≈ 15 %.

    **Arguments:**

    - `rig`: the `SASRig` whose parameters are trusted.
    - `ts`: uniform sample times [s].
    - `alpha2`: measured body angle [rad] (absolute, as the rig's states).
    - `alpha1`: measured lower-beam angle [rad]; `None` (default) takes the lower
      beam at rest on the still cam for each body angle (`held_state`), adequate when
      the tyre is stiff, as in the source's decays.
    - `window`: odd number of samples of the filter (> `order`); `order`: its degree.

    **Returns:** the torque estimate at `ts` [N·m].
    """
    ts, alpha2 = as_float_array(ts), as_float_array(alpha2)
    if ts.ndim != 1 or alpha2.shape != ts.shape:
        raise ValueError(
            "`ts` and `alpha2` must be 1-D arrays of equal length, got shapes "
            f"{ts.shape} and {alpha2.shape}."
        )
    if not isinstance(window, int) or window % 2 == 0 or window <= order:
        raise ValueError(
            f"`window` must be an odd number of samples > order = {order}, got "
            f"{window!r}."
        )
    if ts.shape[0] < window:
        raise ValueError(
            f"the record has {ts.shape[0]} samples, fewer than the filter's window "
            f"({window}); give a longer record or a smaller `window`."
        )
    if alpha1 is not None:
        alpha1 = as_float_array(alpha1)
        if alpha1.shape != ts.shape:
            raise ValueError(
                f"`alpha1` must have the shape of `ts`, {ts.shape}, got {alpha1.shape}."
            )
    return _inverse_dynamics(rig, float(ts[1] - ts[0]), alpha2, alpha1, window, order)


@eqx.filter_jit
def _inverse_dynamics(rig, dt, alpha2, alpha1, window, order):
    smooth = savitzky_golay(alpha2, dt, window, order, 0)
    rate = savitzky_golay(alpha2, dt, window, order, 1)
    accel = savitzky_golay(alpha2, dt, window, order, 2)
    if alpha1 is None:
        alpha1 = jax.vmap(lambda a2: rig.held_state(a2)[0])(smooth)
    return rig.brake_torque_from_body(alpha1, smooth, rate, accel)
