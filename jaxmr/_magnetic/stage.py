r"""The magnetic stage: coil current → field → hysteretic steel → fluid-gap induction.

Units: SI. Field $H$ [A/m], induction $B$ [T], current [A].

**Demagnetisation, from Gaussian to SI.** The source study writes, in Gaussian units
($B = H + 4\pi M$, demagnetising field $H_d = N_d M$ with $0 \le N_d \le 4\pi$),
$H = H_a - N_d M$ and so $H = (H_a - \tfrac{N_d}{4\pi}B)/(1 - \tfrac{N_d}{4\pi})$. In SI
($B = \mu_0(H + M)$, $H_d = N M$ with $0 \le N < 1$) the same steps give

$$H = \frac{H_a - N B/\mu_0}{1 - N}.$$

The two agree term by term with $N = N_d/4\pi$ and $B$ [G] $\to B/\mu_0$ [A/m] (1 G of
induction is $\mu_0 \cdot$ 1 Oe). jaxmr takes the SI factor $N$.

**The factor as a circuit's gap.** For a magnetic circuit of steel path $l_s$ and area
$A_s$, fluid gap $l_g$ of permeability $\mu_f$ and area $A_g$, driven by $n$ turns,
Ampère's law $n i = H l_s + B\,(A_s/A_g)\,l_g/\mu_f$ has exactly this form with
$N/(1 - N) = (\mu_0/\mu_f)(A_s/A_g)(l_g/l_s)$ and $C = (1 - N)\,n/l_s$: the
"demagnetising factor" of an MR device is the shear of its loop by the fluid gap.
"""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from .._current_dynamics import AbstractCurrentDynamics
from .._current_law import as_parameter
from .._custom_types import Array, ArrayLike, Float, Scalar, ScalarLike, State
from .._misc import Check, as_float_array, check_concrete, is_concrete
from .material import (
    MU_0,
    HodgdonMaterial,
    field_slope,
    has_wrapped_fields,
    smooth_sign,
    trace_induction,
)

_VIRGIN_STEPS = 64  # RK4 steps along the initial magnetisation curve


class MagneticStage(AbstractCurrentDynamics):
    r"""Coil, hysteretic steel and fluid gap between the commanded current and the
    model: the effective current is the fluid-gap induction, expressed as a current.

    State: the coil current $i_c$ [A] and the steel's induction $B$ [T].

    $$\dot i_c = \eta\,(i_\mathrm{cmd} - i_c),\qquad H_a = C i_c,\qquad
    H = \frac{H_a - N B/\mu_0}{1 - N},$$
    $$\dot B = \frac{\dot H_a}{(1 - N)\big(\alpha_h\,\mathrm{sgn}(\dot H_a)(f(B) - H) +
    g(B)\big) + N/\mu_0},\qquad B_f = r B,\qquad i_\mathrm{eff} = B_f/\kappa.$$

    The $\dot B$ law is Hodgdon's model (`HodgdonMaterial`) with the demagnetising
    relation substituted: $(1 - N)\dot H = \dot H_a - (N/\mu_0)\dot B$, and since
    $\dot B$, $\dot H$ and $\dot H_a$ share their sign wherever the model's slope is
    positive, $\mathrm{sgn}\,\dot H = \mathrm{sgn}\,\dot H_a$.

    **Why a coil state.** Hodgdon's law needs the field's rate $\dot H_a$, but a current
    dynamics receives only the command. The coil current with its first-order lag (the
    coil's $L/R$ with its driver: $\eta = R/L$) is physical, and its rate
    $\dot H_a = C\eta(i_\mathrm{cmd} - i_c)$ comes from the state. It is also the stage's
    only time scale (the steel is rate-independent): the current→torque bandwidth is
    about $\eta/2\pi$.

    **Why this effective current.** $i_\mathrm{eff} = B_f/\kappa$ is the fluid-gap
    induction in units of current: $\kappa$ [T/A] is a normalisation, conventionally the
    fluid induction per ampere of the device's static curve (`calibrated` sets it so
    that $i_\mathrm{eff} = i$ on the centre curve $f$ at a chosen current). So any current-
    dependent model of the library can sit behind this stage in place of its static
    current law (`Damper(BoucWen(...), MagneticStage(...))`): it then sees the current
    that the fluid's field corresponds to, hysteresis and lag included. `BinghamDisc`
    reads the induction back exactly with its `induction = LinearLaw(0, κ)`.
    $\kappa$ only sets a unit: fix it when fitting.

    **Sign at reversals.** $\mathrm{sgn}(\dot H_a) = \mathrm{sgn}(i_\mathrm{cmd} - i_c)$.
    $\dot B$ is continuous through a reversal ($\dot H_a = 0$ there from both sides) and
    the exact sign has zero derivative, so gradients stay finite; `sign_scale`
    $\delta > 0$ [A] uses $\tanh((i_\mathrm{cmd} - i_c)/\delta)$, which also makes the
    rate differentiable in the state.

    **Arguments:**

    - `material`: the steel, a `HodgdonMaterial`.
    - `coil_constant`: $C$ [A/m per A = 1/m], field per ampere; > 0.
    - `demagnetising_factor`: $N$ [1], SI, in $[0, 1)$ ($N_d/4\pi$ of a Gaussian source).
    - `flux_ratio`: $r = A_\mathrm{steel}/A_\mathrm{gap}$ [1], flux continuity
      $B_f = rB$; > 0.
    - `coil_rate`: $\eta$ [1/s], inverse coil time constant; > 0.
    - `induction_per_current`: $\kappa$ [T/A]; > 0.
    - `sign_scale`: $\delta$ [A], 0 (default) for the exact sign.
    """

    material: HodgdonMaterial
    coil_constant: Float[Array, ""] = eqx.field(converter=as_parameter)
    demagnetising_factor: Float[Array, ""] = eqx.field(converter=as_parameter)
    flux_ratio: Float[Array, ""] = eqx.field(converter=as_parameter)
    coil_rate: Float[Array, ""] = eqx.field(converter=as_parameter)
    induction_per_current: Float[Array, ""] = eqx.field(converter=as_parameter)
    sign_scale: Float[Array, ""] = eqx.field(converter=as_parameter, default=0.0)
    state_names: ClassVar[tuple[str, ...]] = ("i_coil", "B")

    def __check_init__(self):
        if not isinstance(self.material, HodgdonMaterial):
            raise TypeError(
                "MagneticStage: `material` must be a HodgdonMaterial (e.g. "
                "HodgdonMaterial.from_major_loop(...)), got "
                f"{type(self.material).__name__}."
            )
        # Parameters inside fitting wrappers (`Positive`, ...) or traced are checked
        # when `simulate` runs, after they are resolved.
        wrapped = has_wrapped_fields(self, exclude=("material",))
        if wrapped or has_wrapped_fields(self.material) or not is_concrete(self):
            return
        with jax.ensure_compile_time_eval():
            constraints = self.constraints()
        for check in constraints:
            check_concrete(check.ok, check.named("MagneticStage").message(), self)

    def constraints(self) -> list[Check]:
        N = self.demagnetising_factor
        return [
            Check(
                self.coil_constant > 0,
                "`coil_constant` must be > 0 (field per ampere, 1/m)",
                self.coil_constant,
            ),
            Check(
                (N >= 0) & (N < 1),
                "`demagnetising_factor` must be in [0, 1) (SI; N_d/(4 pi) of a "
                "Gaussian source)",
                N,
            ),
            Check(
                self.flux_ratio > 0,
                "`flux_ratio` (steel/gap area) must be > 0",
                self.flux_ratio,
            ),
            Check(
                self.coil_rate > 0,
                "`coil_rate` must be > 0 (R/L of the coil, 1/s)",
                self.coil_rate,
            ),
            Check(
                self.induction_per_current > 0,
                "`induction_per_current` must be > 0 (T/A)",
                self.induction_per_current,
            ),
            Check(
                self.sign_scale >= 0,
                "`sign_scale` must be >= 0 (0: exact sign)",
                self.sign_scale,
            ),
        ] + self.material.constraints()

    # -- the circuit -------------------------------------------------------------------

    def field(self, i_coil: Scalar, B: Scalar) -> Scalar:
        r"""The steel's field $H$ [A/m] for coil current [A] and induction [T]."""
        N = self.demagnetising_factor
        return (self.coil_constant * i_coil - N * B / MU_0) / (1 - N)

    def fluid_induction(self, state: State) -> Scalar:
        """$B_f = r B$ [T] in the fluid gap."""
        return self.flux_ratio * state[1]

    def induction_along(
        self, currents: Float[ArrayLike, " points"], initial_induction: ScalarLike = 0.0
    ) -> Float[Array, " points"]:
        """Steel induction $B$ [T] along a (quasi-static) coil-current history [A],
        from `initial_induction` at `currents[0]`; put reversals among the samples."""
        applied = self.coil_constant * as_float_array(currents)
        return trace_induction(
            self.material,
            self.demagnetising_factor,
            applied,
            as_float_array(initial_induction),
            8,
        )

    def reference_induction(self, current: ScalarLike) -> Scalar:
        r"""Steel induction [T] on the centre curve $H = f(B)$ at coil current [A]: the
        root of $(1 - N) f(B) + N B/\mu_0 = C i$ (monotone; bisection)."""
        target = self.coil_constant * jnp.asarray(current)
        N = self.demagnetising_factor
        m = self.material
        # A bracket: beyond B_s the left side grows at least as fast as
        # B/max(mu_s, mu_0), so |B| < B_s + |C i| (mu_s + mu_0).
        reach = 2 * m.B_s + jnp.abs(target) * (m.mu_s + MU_0)
        lo, hi = -reach, reach

        def body(_, bounds):
            lo, hi = bounds
            mid = 0.5 * (lo + hi)
            high = (1 - N) * m.f(mid) + N * mid / MU_0 > target
            return jnp.where(high, lo, mid), jnp.where(high, mid, hi)

        lo, hi = jax.lax.fori_loop(0, 200, body, (lo, hi))
        return 0.5 * (lo + hi)

    def calibrated(self, current: ScalarLike = 1.0) -> "MagneticStage":
        r"""This stage with $\kappa$ set so that $i_\mathrm{eff} = i$ on the centre
        curve at `current` [A] (the fluid induction per ampere of the static curve)."""
        kappa = self.flux_ratio * self.reference_induction(current) / current
        return eqx.tree_at(lambda s: s.induction_per_current, self, kappa)

    # -- AbstractCurrentDynamics -------------------------------------------------------

    def initial_state(self, command: Scalar) -> State:
        """Coil settled at `command`; steel demagnetised, then magnetised along its
        initial curve to the command's field (as after a slow ramp from 0 A)."""
        command = jnp.asarray(command, dtype=self.coil_constant.dtype)
        applied = jnp.stack([jnp.zeros_like(command), self.coil_constant * command])
        B = trace_induction(
            self.material,
            self.demagnetising_factor,
            applied,
            jnp.zeros_like(command),
            _VIRGIN_STEPS,
        )[-1]
        return jnp.stack([command, B])

    def rates(self, state: State, command: Scalar) -> State:
        i_coil, B = state[0], state[1]
        error = command - i_coil
        di = self.coil_rate * error
        direction = smooth_sign(error, self.sign_scale)
        slope = field_slope(
            self.material,
            self.demagnetising_factor,
            B,
            self.coil_constant * i_coil,
            direction,
        )
        return jnp.stack([di, self.coil_constant * di / slope])

    def effective(self, state: State) -> Scalar:
        return self.fluid_induction(state) / self.induction_per_current
