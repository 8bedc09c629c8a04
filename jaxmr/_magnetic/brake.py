r"""The MR brake actuator: a Bingham fluid sheared by a disc, its yield stress set by the
fluid-gap induction that the magnetic stage provides."""

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from .._current_law import LinearLaw, Parameter, as_parameter
from .._custom_types import Array, ArrayLike, Float, Scalar, ScalarLike, State
from .._damper import Damper
from .._hysteresis import AbstractHysteresis
from .._misc import Check, check_concrete
from .material import HodgdonMaterial, smooth_sign
from .stage import MagneticStage


class BinghamDisc(AbstractHysteresis):
    r"""Bingham fluid in the two gaps of a rotating disc (an MR brake's torque law).

    $$T = \tfrac{4\pi}{3}\,\tau_y(B_f)\,(R_o^3 - R_i^3)\,\mathrm{sgn}(\Omega)
      + \frac{\pi\eta_f\Omega}{g}\,(R_o^4 - R_i^4),\qquad
      \tau_y = K_1|B_f| + K_2 B_f^2 + K_3|B_f|^3,$$

    ($\tau_y$ held at its peak past it where $K_3 < 0$: `saturation_induction`),
    the integral of $\tau = \tau_y\,\mathrm{sgn}\,\dot\gamma + \eta_f\dot\gamma$,
    $\dot\gamma = r\Omega/g$, over both faces of the disc (the study's eq. 6). The yield
    stress depends on the field's magnitude only (hence $|B_f|$). The motion is the rotor
    angle [rad] and $\Omega$ its rate [rad/s]; the output is torque [N·m]. Static: no
    state of its own.

    The fluid induction $B_f$ [T] is a parameter resolved at the effective current,
    normally `LinearLaw(0, κ)`: behind a `MagneticStage` of the same $\kappa$ (whose
    effective current is $B_f/\kappa$) it is the hysteretic gap induction exactly; with
    no stage it is a linear magnetic circuit, $B_f = \kappa i$. `mr_brake_actuator`
    builds the pair.

    **Arguments:**

    - `K1`, `K2`, `K3`: yield-stress polynomial [Pa/T], [Pa/T²], [Pa/T³].
    - `R_i`, `R_o`: inner and outer radius of the sheared annulus [m], 0 ≤ R_i < R_o.
    - `gap`: fluid gap $g$ on each face [m]; > 0.
    - `viscosity`: plastic viscosity $\eta_f$ [Pa·s]; ≥ 0.
    - `induction`: $B_f$ [T], a number or a current law (see above).
    - `velocity_scale`: $\Omega_s$ [rad/s]; > 0 uses $\tanh(\Omega/\Omega_s)$ for the sign
      (what gradients through a speed reversal need), 0 (default) the exact sign (a
      form of the model that a fit leaves alone).
    """

    K1: Float[Array, ""] = eqx.field(converter=as_parameter)
    K2: Float[Array, ""] = eqx.field(converter=as_parameter)
    K3: Float[Array, ""] = eqx.field(converter=as_parameter)
    R_i: Float[Array, ""] = eqx.field(converter=as_parameter)
    R_o: Float[Array, ""] = eqx.field(converter=as_parameter)
    gap: Float[Array, ""] = eqx.field(converter=as_parameter)
    viscosity: Float[Array, ""] = eqx.field(converter=as_parameter)
    induction: Parameter = eqx.field(converter=as_parameter)
    velocity_scale: Float[Array, ""] = eqx.field(converter=as_parameter, default=0.0)
    state_names: ClassVar[tuple[str, ...]] = ()
    # 0 is the exact sign, a form of the model: a fit leaves it there
    # (`jaxmr._parameter.fixed_by_class`).
    fit_modes: ClassVar[dict[str, float]] = {"velocity_scale": 0.0}

    def saturation_induction(self) -> Scalar:
        """The induction [T] past which the yield stress is held at its value there:
        the peak of the cubic where $K_3 < 0$ (where $dτ_y/dB = 0$), else `inf`."""
        falls = self.K3 < 0
        K3 = jnp.where(falls, self.K3, -1.0)  # a safe value where it is unused
        root = jnp.sqrt(jnp.maximum(self.K2**2 - 3 * self.K1 * K3, 0.0))
        return jnp.where(falls, -(self.K2 + root) / (3 * K3), jnp.inf)

    def yield_stress(self, B_f: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
        """$\\tau_y$ [Pa] at fluid induction $B_f$ [T], held at its peak past
        `saturation_induction`: an MR fluid's yield stress saturates with the field,
        and a cubic fitted below that turns down past its peak (MRF-132DG's at
        0.98 T), which had made the torque fall and then oppose the rotation (the
        MRB-107-3 brake at 6 A: -4.5 N·m at +60 rpm)."""
        a = jnp.minimum(jnp.abs(jnp.asarray(B_f)), self.saturation_induction())
        return a * (self.K1 + a * (self.K2 + a * self.K3))

    def yield_torque_per_stress(self) -> Scalar:
        """$\\frac{4\\pi}{3}(R_o^3 - R_i^3)$ [m³]: yield torque per Pa of yield stress."""
        return 4 * math.pi / 3 * (self.R_o**3 - self.R_i**3)

    def viscous_coefficient(self) -> Scalar:
        """$\\pi\\eta_f(R_o^4 - R_i^4)/g$ [N·m·s/rad]."""
        return math.pi * self.viscosity * (self.R_o**4 - self.R_i**4) / self.gap

    def rates(self, state: State, x: Scalar, v: Scalar) -> State:
        return state

    def force(self, state: State, x: Scalar, v: Scalar) -> Scalar:
        yield_torque = self.yield_torque_per_stress() * self.yield_stress(
            self.induction
        )
        direction = smooth_sign(v, self.velocity_scale)
        return yield_torque * direction + self.viscous_coefficient() * v

    def __check_init__(self):
        # The geometry and the fluid, checked when built even where the induction is
        # a law or a magnetic stage's (the base class then waits for a current): a
        # bad radius or gap was first named inside a simulation, as if the current
        # were wrong.
        plain = {
            name: getattr(self, name)
            for name in ("R_i", "R_o", "gap", "viscosity", "velocity_scale", "K1")
        }
        if any(isinstance(v, eqx.Module) for v in plain.values()):
            return  # a fit's constraint wrappers: checked when resolved
        for check in self._geometry():
            check_concrete(
                check.ok, check.named(type(self).__name__).message(), *plain.values()
            )

    def _geometry(self) -> list[Check]:
        return [
            Check(
                (self.R_i >= 0) & (self.R_o > self.R_i),
                "the radii must satisfy 0 <= R_i < R_o (m)",
                {"R_i": self.R_i, "R_o": self.R_o},
            ),
            Check(self.gap > 0, "`gap` must be > 0 (m)", self.gap),
            Check(
                self.viscosity >= 0, "`viscosity` must be >= 0 (Pa s)", self.viscosity
            ),
            Check(
                self.velocity_scale >= 0,
                "`velocity_scale` must be >= 0 (0 for the exact sign)",
                self.velocity_scale,
            ),
            Check(
                self.K1 >= 0,
                "`K1` must be >= 0 (Pa/T): the yield stress rises from 0 with the "
                "field (a negative one drives the rotor instead of braking it)",
                self.K1,
            ),
        ]

    def constraints(self):
        return self._geometry() + [
            Check(
                self.yield_stress(self.induction) >= 0,
                "the yield stress τ_y(B_f) must be >= 0 (Pa) at the fluid's field: "
                "check K1, K2, K3 (a negative one drives the rotor)",
                self.induction,
            )
        ]


def mr_brake_actuator(
    material: HodgdonMaterial,
    *,
    coil_constant: ScalarLike,
    demagnetising_factor: ScalarLike,
    flux_ratio: ScalarLike,
    coil_rate: ScalarLike,
    K1: ScalarLike,
    K2: ScalarLike,
    K3: ScalarLike,
    R_i: ScalarLike,
    R_o: ScalarLike,
    gap: ScalarLike,
    viscosity: ScalarLike,
    velocity_scale: ScalarLike = 0.0,
    sign_scale: ScalarLike = 0.0,
    nominal_current: ScalarLike = 1.0,
) -> Damper:
    r"""An MR brake actuator: current → torque through magnetic hysteresis (An & Kwon).

    The chain $i \to H_a = C i_c \to H \to B$ (Hodgdon) $\to B_f = rB \to \tau_y(B_f) \to T$
    as a `Damper`: a `BinghamDisc` torque law behind a `MagneticStage`, sharing the
    normalisation $\kappa$ (the stage's effective current is $B_f/\kappa$, calibrated so
    that it equals the coil current on the centre curve at `nominal_current`).
    Simulate it with `jaxmr.simulate(actuator, rotor_angle, current, ts)`, the rotor
    angle [rad] as motion (`Ramp(speed)` for a constant speed).

    **Arguments:** the steel `material`; the stage's `coil_constant` [1/m],
    `demagnetising_factor` [1], `flux_ratio` [1], `coil_rate` [1/s], `sign_scale` [A]
    (see `MagneticStage`); the disc's `K1..K3`, `R_i`, `R_o`, `gap`, `viscosity`,
    `velocity_scale` (see `BinghamDisc`); `nominal_current` [A] for $\kappa$.

    **Returns:** a `Damper(BinghamDisc(...), MagneticStage(...))`.
    """
    stage = MagneticStage(
        material,
        coil_constant=coil_constant,
        demagnetising_factor=demagnetising_factor,
        flux_ratio=flux_ratio,
        coil_rate=coil_rate,
        induction_per_current=1.0,
        sign_scale=sign_scale,
    ).calibrated(nominal_current)
    disc = BinghamDisc(
        K1=K1,
        K2=K2,
        K3=K3,
        R_i=R_i,
        R_o=R_o,
        gap=gap,
        viscosity=viscosity,
        induction=LinearLaw(0.0, stage.induction_per_current),
        velocity_scale=velocity_scale,
    )
    return Damper(disc, stage)
