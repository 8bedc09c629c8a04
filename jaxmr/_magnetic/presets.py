"""The MR actuator study's device (An & Kwon): a Lord MRB-107-3 rotary brake, in SI units.

The study's material table (Table 1: B_cl, H_cl, B_r, H_c, μ_r, μ_c, μ_s, μ_cl, α, A1–A4
for S15C, SS41, SUS430 and AISI 12L14) and its yield-stress constants K1–K3 are not
legible in the source document, nor the brake's internal dimensions. The values below are
therefore documented substitutes, chosen to reproduce what the study reports: about 6 N·m
at 1 A, torque proportional to current and independent of speed at 60/150/240 rpm,
torque–current loops that widen with amplitude, and a bandwidth of about 20 Hz.
"""

from .._damper import Damper
from .brake import mr_brake_actuator
from .material import HodgdonMaterial

# Major-loop data of the steel (SI). Representative of cold-drawn low-carbon
# free-machining steel such as AISI 12L14 (what Lord builds its brakes of): remanence
# ≈ 10 kG, coercivity ≈ 5 Oe, loop closing near 16 kG at ≈ 38 Oe, the ranges handbooks
# give for cold-worked mild steel (e.g. Bozorth 1951, "Ferromagnetism", tables of
# commercial irons and steels). Not measured data.
AISI_12L14_MAJOR_LOOP = dict(
    B_s=1.6,  # closure induction [T] (16 kG)
    H_s=3000.0,  # closure field [A/m] (≈ 38 Oe)
    B_r=1.0,  # remanence [T] (10 kG)
    H_c=400.0,  # coercivity [A/m] (≈ 5 Oe)
    mu_r=1.0e-3,  # permeability at remanence [H/m] (relative ≈ 800)
    mu_c=3.0e-3,  # permeability at the coercive point [H/m] (relative ≈ 2400)
    mu_s=4.0e-5,  # permeability at closure [H/m] (relative ≈ 32)
)


def aisi_12l14() -> HodgdonMaterial:
    r"""Hodgdon constants of the brake's steel (representative AISI 12L14).

    `HodgdonMaterial.from_major_loop(**AISI_12L14_MAJOR_LOOP)`, evaluated once and
    written out (the test suite checks that the derivation still gives these): $A_1$ =
    332.6 A/m, $A_2$ = 0.9127 1/T, $A_3$ = −18.97, $A_4$ = 0.5313, $\alpha_h$ = 14.32
    1/T, $B_s$ = 1.6 T, $\mu_s$ = 4·10⁻⁵ H/m. The model's major loop passes through
    the remanence 1.0 T exactly and has a coercivity of 395 A/m (data: 400).
    """
    return HodgdonMaterial(
        A1=332.6232344469327,
        A2=0.9127330779619632,
        A3=-18.969424830122723,
        A4=0.5312788478277191,
        alpha_h=14.323271829930084,
        B_s=1.6,
        mu_s=4.0e-5,
    )


def mrb_107_3(velocity_scale: float = 0.05, sign_scale: float = 0.0) -> Damper:
    r"""The study's MR brake actuator (Lord MRB-107-3): current [A] → torque [N·m] with
    magnetic hysteresis, as `mr_brake_actuator(...)`.

    - Steel: `aisi_12l14()`.
    - Circuit (effective constants): coil constant $C$ = 12 900 A/m per A, SI
      demagnetising factor $N$ = 0.0128 (the fluid gap's share of the ampere-turns is
      95 % at 1 A, so the static curve is nearly linear and the steel's hysteresis shows
      as a loop ≈ 13 % of the torque swing at 0.5 ± 0.5 A), flux ratio
      $A_\mathrm{steel}/A_\mathrm{gap}$ = 0.5 (fluid at ≈ 0.6 T with the steel at
      ≈ 1.2 T at 1 A).
    - Coil and driver: $\eta$ = 140 1/s (time constant 7.1 ms, inside Lord's "< 10 ms"
      response), which puts the −3 dB bandwidth at 0.5 A bias near the study's 20 Hz.
    - Fluid: Lord MRF-132DG (the study used the older MRF-240BS, whose data are not at
      hand): yield stress fitted through the origin on 0–1 T to the data-sheet curve,
      $K_1$ = 2.33·10⁴ Pa/T, $K_2$ = 1.015·10⁵ Pa/T², $K_3$ = −7.67·10⁴ Pa/T³ (within
      0.9 kPa of it; the cubic peaks at 0.98 T, past which the yield stress is held
      at its peak, `BinghamDisc.saturation_induction`); plastic
      viscosity 0.1 Pa·s.
    - Disc (assumed, fitting the brake's 92 mm housing): $R_i$ = 10 mm, $R_o$ = 35 mm,
      gap 0.25 mm on each face. The viscous torque is 0.047 N·m at 240 rpm, so the
      torque is independent of speed to within 1 %.

    Calibrated ($\kappa$) so that the effective current equals the coil current on the
    loop's centre curve at 1 A, where the torque is 6.0 N·m.

    **Arguments:**

    - `velocity_scale`: $\Omega_s$ [rad/s] of the smooth $\mathrm{sgn}(\Omega)$ (0 for
      the exact sign); 0.05 rad/s is exact to 1e-50 at 60 rpm.
    - `sign_scale`: $\delta$ [A] of the smooth sign of the field rate (0: exact).
    """
    return mr_brake_actuator(
        aisi_12l14(),
        coil_constant=12_900.0,
        demagnetising_factor=0.0128,
        flux_ratio=0.5,
        coil_rate=140.0,
        K1=2.33e4,
        K2=1.015e5,
        K3=-7.67e4,
        R_i=0.010,
        R_o=0.035,
        gap=0.25e-3,
        viscosity=0.1,
        velocity_scale=velocity_scale,
        sign_scale=sign_scale,
        nominal_current=1.0,
    )
