"""Published parameter sets as named presets (SI units throughout).

Functions rather than module constants, so that the arrays take the float precision in
force when they are called (jaxmr never changes JAX's configuration).
"""

import numpy as np

from ._current_dynamics import FirstOrderLag
from ._current_law import ExponentialLaw, LinearLaw, PolynomialLaw
from ._damper import Damper
from ._hysteresis import Bingham, BoucWen, Dahl, Spencer

CM = 1e-2  # m
MM = 1e-3  # m

# Quiroz's current-dependent Spencer model of the UTFSM damper, as published, in N, mm,
# s, A: alpha(i) = p4 i^2 + p5 i + p6 [N/mm], beta(i) = gamma(i) = p7 exp(p8 i)
# [mm^-2], c0(i) = p9 i + p10, c1(i) = p11 i + p12 [N s/mm], A = 300, n = 2.
UTFSM_SPENCER_PUBLISHED = {
    "k0": 1.5013279e-04,  # N/mm
    "k1": 1.2387977,  # N/mm
    "x0": 2.3091420e-03,  # mm
    "p4": -38.152004,
    "p5": 41.508406,
    "p6": 15.221096,
    "p7": 1.8940755,
    "p8": -3.6561085,
    "p9": 7.6259640,
    "p10": 0.92491133,
    "p11": 78.336693,
    "p12": 9.8671284,
    "A": 300.0,
    "n": 2.0,
}
# Its median NRMSE on the 30 sine tests (first cycle discarded), as the data's README
# states it; `utfsm_spencer` reproduces 0.105 (range 0.069-0.247) with jaxmr.
UTFSM_SPENCER_MEDIAN_NRMSE = 0.109


def utfsm_spencer() -> Spencer:
    r"""The published current-dependent Spencer model of the UTFSM damper, in SI units.

    M. Quiroz's thesis (Universidad Técnica Federico Santa María; data and model in the
    GitHub repository `DanielMaurelE/vRTHS_AMBC_MRdamper`, see `jaxmr.data.load_utfsm`)
    fits, in N, mm, s and A: $A = 300$, $n = 2$, $\beta(i) = \gamma(i) = p_7 e^{p_8 i}$,
    $\alpha(i) = p_4 i^2 + p_5 i + p_6$, $c_0(i) = p_9 i + p_{10}$,
    $c_1(i) = p_{11} i + p_{12}$, and constants $k_0$, $k_1$, $x_0$
    (`UTFSM_SPENCER_PUBLISHED`). Converted here: stiffnesses and $\alpha$ N/mm → ×1e3
    N/m, dashpots N·s/mm → ×1e3 N·s/m, $\beta$, $\gamma$ mm⁻² → ×1e6 m⁻², $x_0$ mm →
    ×1e-3 m ($z$ then has the unit of $x$, m; $A$ is dimensionless).

    Scored like the authors (`jaxmr.record_nrmse`, first cycle discarded) it gives a median
    NRMSE of 0.105 on the 30 files (0.069–0.247; the data's README quotes 0.109);
    with its force smoothed like the data (`smoothing=utfsm_smoothing(...)`), 0.086.
    """
    p = UTFSM_SPENCER_PUBLISHED
    beta_gamma = ExponentialLaw(p["p7"] / MM**2, p["p8"])
    return Spencer(
        alpha=PolynomialLaw(np.array([p["p6"], p["p5"], p["p4"]]) / MM),
        c0=LinearLaw(p["p10"] / MM, p["p9"] / MM),
        k0=p["k0"] / MM,
        c1=LinearLaw(p["p12"] / MM, p["p11"] / MM),
        k1=p["k1"] / MM,
        x0=p["x0"] * MM,
        gamma=beta_gamma,
        beta=beta_gamma,
        A=p["A"],
        n=p["n"],
    )


def sas_brake_bouc_wen() -> BoucWen:
    r"""The SAS study's rotary MR brake, Bouc–Wen (its Table 1).

    $T = (\alpha_a + \alpha_b i) z + (C_{0a} + C_{0b} i)\dot\theta$,
    $\dot z = \delta\dot\theta - \gamma|\dot\theta| z|z|^{n-1} - \beta\dot\theta|z|^n$ with
    β = 737, γ = 1, δ = 843, n = 0.9, C0a = 0.0015 N·m·s/rad, C0b = 0.07 N·m·s/(rad·A),
    αa = 1 N·m, αb = 0.07 N·m/A (printed as "Ns/m" and "N/m"; rotary units here).
    Angle in rad, torque in N·m, current in A.
    """
    return BoucWen(
        alpha=LinearLaw(1.0, 0.07),
        c0=LinearLaw(0.0015, 0.07),
        A=843.0,
        beta=737.0,
        gamma=1.0,
        n=0.9,
    )


def sas_brake_dahl() -> Dahl:
    r"""The SAS study's rotary MR brake, Dahl model (its Table 2): $k_x = 0.001 +
    0.001 i$ N·m·s/rad, $k_w = 5 + 1.5 i$ N·m, $\rho = 5$ 1/rad."""
    return Dahl(k_x=LinearLaw(0.001, 0.001), k_w=LinearLaw(5.0, 1.5), rho=5.0)


def sas_brake_bingham(f_c: float = 0.1, f0: float = 0.0) -> Bingham:
    r"""The SAS study's rotary MR brake, Bingham model: $c_0 = 0.002$ N·m·s/rad and
    $f_c$ = 0.1 or 0.2 N·m (the two values it plots). It calls $f_0$ "non-zero" and
    prints 1; 0 by default here so the loop is centred, pass `f0=1.0` for the print."""
    return Bingham(f_c=f_c, c0=0.002, f0=f0)


def spencer_1997() -> Damper:
    r"""Spencer et al. (1997) prototype damper, voltage-driven, in SI units.

    From the commonly quoted values: $c_{0a}$ = 21.0 N·s/cm, $c_{0b}$ = 3.50
    N·s/(cm·V), $k_0$ = 46.9 N/cm, $c_{1a}$ = 283 N·s/cm, $c_{1b}$ = 2.95 N·s/(cm·V),
    $k_1$ = 5.00 N/cm, $x_0$ = 14.3 cm, $\alpha_a$ = 140 N/cm, $\alpha_b$ = 695
    N/(cm·V), γ = β = 363 cm⁻², A = 301, n = 2, η = 190 s⁻¹. The current input of the
    returned damper is the command voltage [V]; it passes the 190 s⁻¹ filter.
    """
    return Damper(
        Spencer(
            alpha=LinearLaw(140.0 / CM, 695.0 / CM),
            c0=LinearLaw(21.0 / CM, 3.50 / CM),
            k0=46.9 / CM,
            c1=LinearLaw(283.0 / CM, 2.95 / CM),
            k1=5.00 / CM,
            x0=14.3 * CM,
            gamma=363.0 / CM**2,
            beta=363.0 / CM**2,
            A=301.0,
            n=2.0,
        ),
        FirstOrderLag(190.0),
    )


def review_quarter_car_damper() -> BoucWen:
    r"""The review paper's quarter-car MR damper, a current-dependent simple Bouc–Wen
    model, values as printed: γ = 1, β = 0, A = 1.5, n = 2, k0 = 300 N/m,
    $c_0 = 4400 + 442 u$ N·s/m, $\alpha = 10872 + 49616 u$ N/m, f0 = 0, with the command
    voltage $u$ [V] (the paper drives it at 5 V)."""
    return BoucWen(
        alpha=LinearLaw(10872.0, 49616.0),
        c0=LinearLaw(4400.0, 442.0),
        A=1.5,
        beta=0.0,
        gamma=1.0,
        n=2.0,
        k0=300.0,
    )


def passenger_car_mr_damper() -> Damper:
    r"""A passenger-car MR damper for control studies (jaxmr's choice, documented here;
    no source publishes one): a Bouc–Wen law with a yield force of 30 N at 0 A and
    1 000 N at 1 A, viscous $c_0 = 200 + 1800 i$ N·s/m, and an 8 ms current lag.

    $\alpha = 3\cdot10^4 + 9.7\cdot10^5 i$ N/m with $A = 1$, $\beta = \gamma = 500$ 1/m,
    $n = 1$: $z$ saturates at $z_0 = A/(\beta + \gamma) = 1$ mm, so the hysteretic force
    $\alpha z$ is a yield force $\alpha z_0$ reached within about a millimetre of
    travel. The range (0.13 kN at 0.5 m/s and 0 A to 2 kN at 1 A, a dynamic range of
    15) spans comfort to sport settings for a 350 kg quarter (critical damping ≈ 5
    kN·s/m). A soft off-state is what gives a semi-active law room to act: with a
    floor of 100 N + 500 N·s/m no law tried beat the softest constant current in
    Wk-weighted comfort on an ISO C road, and the review paper's damper
    (`review_quarter_car_damper`, $c_0 \ge 4400$ N·s/m at 0 V) is stiffer still.
    Drive it with currents in [0, 1] A.
    """
    return Damper(
        BoucWen(
            alpha=LinearLaw(3e4, 9.7e5),
            c0=LinearLaw(200.0, 1800.0),
            A=1.0,
            beta=500.0,
            gamma=500.0,
            n=1.0,
        ),
        FirstOrderLag(125.0),
    )


PRESETS = {
    "sas_brake_bouc_wen": sas_brake_bouc_wen,
    "sas_brake_dahl": sas_brake_dahl,
    "sas_brake_bingham": sas_brake_bingham,
    "spencer_1997": spencer_1997,
    "review_quarter_car_damper": review_quarter_car_damper,
    "passenger_car_mr_damper": passenger_car_mr_damper,
    "utfsm_spencer": utfsm_spencer,
}


def _register_magnetic():
    # The magnetic brake lives in its own subpackage, which imports this one.
    from ._magnetic import mrb_107_3

    PRESETS["mrb_107_3"] = mrb_107_3


_register_magnetic()
