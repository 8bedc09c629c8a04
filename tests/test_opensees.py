"""`jaxmr.to_opensees` / `jaxmr.from_opensees`: OpenSees' BoucWen and BWBN materials.

The correspondence is the project specification's (MODELS.md §6, measured against
OpenSees): the β/γ swap, per-energy coefficients scaled by (1 − α)·ko, and BWBN's q
scaled by Ao^(−1/n). The numerical tests integrate OpenSees' equations as the
specification writes them (an independent NumPy RK4 in the displacement, in OpenSees'
own parameters) and compare jaxmr's simulation of the converted model. OpenSees
itself (openseespy, not a dependency) is compared by `benchmarks/opensees_check.py`.
"""

import dataclasses

import numpy as np
import pytest

import jaxmr

# Three materials that exercise every part of the correspondence: β ≠ γ (the swap),
# n ≠ 1 and Ao ≠ 1; degradation of A, ν and η with (1 − α)·ko ≠ 1 (the energy scale);
# pinching with Ao ≠ 1 (q) and energy-dependent p and Shi. Units: m, N, J.
BOUC_WEN = {
    "alpha": 0.1,
    "ko": 2e5,  # N/m
    "n": 1.5,
    "gamma": 3e2,  # 1/m^n
    "beta": 6e2,  # 1/m^n
    "Ao": 1.3,
    "deltaA": 0.0,  # 1/J
    "deltaNu": 0.0,  # 1/J
    "deltaEta": 0.0,  # 1/J
}
DEGRADING = {
    "alpha": 0.05,
    "ko": 2e5,
    "n": 2.0,
    "gamma": 5e3,
    "beta": 2e4,
    "Ao": 1.0,
    "deltaA": 0.05,
    "deltaNu": 0.1,
    "deltaEta": 0.08,
}
PINCHED = {
    "alpha": 0.08,
    "ko": 1.3e6,
    "n": 2.0,
    "gamma": 9.6e6,
    "beta": 6.4e6,
    "Ao": 1.4,
    "q": 0.1,
    "zetas": 0.8,
    "p": 2.0,  # 1/J
    "Shi": 5e-5,  # m
    "deltaShi": 1e-6,  # 1/N
    "lambda": 0.5,
}
CASES = [  # (material, parameters, displacement amplitude [m])
    ("BoucWen", BOUC_WEN, 0.01),
    ("BoucWen", DEGRADING, 0.01),
    ("BWBN", PINCHED, 1e-3),
]
FREQUENCY = 1.0  # Hz
SAMPLES = 400  # per cycle: the reversals at T/4 + k T/2 fall on samples


def _opensees_rate(material, p, z, e, direction):
    """dz/du and de/du of OpenSees' material, as the specification writes them:
    ż = h(z)·[A − ν|z|^n (β sgn(u̇ z) + γ)] u̇ / η, ė = (1 − α) ko z u̇."""
    if material == "BoucWen":
        A = p["Ao"] - p["deltaA"] * e
        nu, eta, h = 1 + p["deltaNu"] * e, 1 + p["deltaEta"] * e, 1.0
    else:
        A, nu, eta = p["Ao"], 1.0, 1.0
        z_u = (1 / (p["beta"] + p["gamma"])) ** (1 / p["n"])
        zeta1 = p["zetas"] * (1 - np.exp(-p["p"] * e))
        zeta2 = (p["Shi"] + p["deltaShi"] * e) * (p["lambda"] + zeta1)
        h = 1 - zeta1 * np.exp(-(((z * direction - p["q"] * z_u) / zeta2) ** 2))
    bracket = p["beta"] * np.sign(direction * z) + p["gamma"]
    dz = h * (A - nu * abs(z) ** p["n"] * bracket) / eta
    return dz, (1 - p["alpha"]) * p["ko"] * z


def _opensees_force(material, p, u, substeps=20):
    """OpenSees' force along the displacements `u` (reversing only at samples), by
    RK4 in u with `substeps` steps between samples, from z = e = 0."""
    z = e = 0.0
    z_path = [z]
    for a, b in zip(u[:-1], u[1:]):
        du = (b - a) / substeps
        direction = np.sign(b - a)
        for _ in range(substeps):
            k1 = _opensees_rate(material, p, z, e, direction)
            k2 = _opensees_rate(
                material, p, z + du / 2 * k1[0], e + du / 2 * k1[1], direction
            )
            k3 = _opensees_rate(
                material, p, z + du / 2 * k2[0], e + du / 2 * k2[1], direction
            )
            k4 = _opensees_rate(material, p, z + du * k3[0], e + du * k3[1], direction)
            z += du / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            e += du / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        z_path.append(z)
    u = np.asarray(u)
    return p["alpha"] * p["ko"] * u + (1 - p["alpha"]) * p["ko"] * np.array(z_path)


# Tighter than the default (rtol 1e-8, which leaves 2e-5 of the peak force where z
# crosses zero with n = 1.5): the comparisons test the mapping, not the integrator.
TIGHT = jaxmr.Adaptive(rtol=1e-11, atol=1e-13)


def _jaxmr_force(model, amplitude, ts):
    motion = jaxmr.Sine(amplitude, FREQUENCY)
    return np.asarray(jaxmr.simulate(model, motion, 0.0, ts, integrator=TIGHT).force)


@pytest.mark.parametrize(("material", "params", "amplitude"), CASES)
def test_converted_model_follows_opensees_equations(material, params, amplitude):
    """Two cycles from the virgin state: jaxmr's simulation of `from_opensees(...)`
    against OpenSees' equations in OpenSees' parameters."""
    ts = np.arange(2 * SAMPLES + 1) / (SAMPLES * FREQUENCY)
    u = amplitude * np.sin(2 * np.pi * FREQUENCY * ts)
    reference = _opensees_force(material, params, u)
    force = _jaxmr_force(jaxmr.from_opensees(material, params), amplitude, ts)
    # Dopri8 at rtol 1e-11 against RK4 at 1/8000 of a cycle's travel per step (which
    # changes by 2e-10 of the peak with 4 times more steps): they agree to 7e-9 of
    # the peak force or better; 1e-7 leaves a margin, while a wrong mapping (β and γ
    # not swapped, the energy or q unscaled) is off by 1e-3 or more (the next test).
    peak = np.max(np.abs(reference))
    np.testing.assert_allclose(force, reference, rtol=0, atol=1e-7 * peak)


def test_the_mapping_is_what_the_comparison_checks():
    """The comparison above can fail: without the β/γ swap, the energy scale or the
    q scale, jaxmr's loop leaves OpenSees' by far more than its tolerance."""
    ts = np.arange(SAMPLES + 1) / (SAMPLES * FREQUENCY)
    for material, params, amplitude in CASES:
        reference = _opensees_force(
            material, params, amplitude * np.sin(2 * np.pi * FREQUENCY * ts)
        )
        model = jaxmr.from_opensees(material, params)
        if material == "BWBN":  # q not scaled by Ao^(-1/n)
            wrong = dict(q=params["q"])
        elif params["deltaA"]:  # degradation not scaled by (1 - alpha) ko
            wrong = dict(delta_A=params["deltaA"], delta_nu=params["deltaNu"])
        else:  # beta and gamma not swapped
            wrong = dict(beta=model.gamma, gamma=model.beta)
        fields = {f.name: getattr(model, f.name) for f in dataclasses.fields(model)}
        mistaken = type(model)(**(fields | wrong))
        peak = np.max(np.abs(reference))
        error = np.max(np.abs(_jaxmr_force(mistaken, amplitude, ts) - reference))
        assert error > 1e-3 * peak, (material, error / peak)


# ---------------------------------------------------------------------------------------
# Round trips


def _assert_same_models(a, b):
    """Same class and every parameter equal to rounding (the conversions multiply and
    divide by (1 − α)·ko and take powers: 1e-13 relative)."""
    assert type(a) is type(b)
    # `fitted_range` is where the model was fitted (static metadata, None here), not
    # a parameter the conversion carries.
    assert a.fitted_range is None and b.fitted_range is None
    for field in dataclasses.fields(a):
        if field.name == "fitted_range":
            continue
        x, y = getattr(a, field.name), getattr(b, field.name)
        np.testing.assert_allclose(
            float(x), float(y), rtol=1e-13, atol=0, err_msg=field.name
        )


@pytest.mark.parametrize(("material", "params", "amplitude"), CASES)
def test_round_trip_from_opensees(material, params, amplitude):
    converted = jaxmr.to_opensees(jaxmr.from_opensees(material, params))
    assert converted["material"] == material
    assert list(converted["params"]) == list(params)  # uniaxialMaterial's order
    np.testing.assert_allclose(
        list(converted["params"].values()), list(params.values()), rtol=1e-13, atol=0
    )
    # As uniaxialMaterial's arguments after the tag, with BWBN's iteration settings.
    settings = [1e-8, 50] if material == "BWBN" else []
    _assert_same_models(
        jaxmr.from_opensees(material, [*params.values(), *settings]),
        jaxmr.from_opensees(material, params),
    )


def test_round_trip_from_jaxmr():
    bouc_wen = jaxmr.BoucWen(
        alpha=1.8e5, c0=0.0, A=1.3, beta=300.0, gamma=600.0, n=1.5, k0=2e4
    )
    pinched = jaxmr.BoucWenBaberNoori(
        k=1.3e6, alpha=0.08, c=0.0, A0=1.4, beta=3e6, gamma=1.6e7, n=2.0, zeta_s=0.8,
        p=5e7, q=0.1, psi=5e-5, delta_psi=3.0, lam=0.5,
    )  # fmt: skip
    degrading = jaxmr.BoucWenBaberNoori(
        k=2e5, alpha=0.05, c=0.0, A0=1.0, beta=2e4, gamma=5e3, n=2.0,
        delta_A=9.5e3, delta_nu=1.9e4, delta_eta=1.5e4,
    )  # fmt: skip
    for model, material in [
        (bouc_wen, "BoucWen"),
        (pinched, "BWBN"),
        (degrading, "BoucWen"),  # no pinching: OpenSees' BoucWen holds its degradation
    ]:
        converted = jaxmr.to_opensees(model)
        assert converted["material"] == material
        _assert_same_models(jaxmr.from_opensees(**converted), model)
    # The β/γ swap and the energy scale, written out for the degrading model.
    params = jaxmr.to_opensees(degrading)["params"]
    assert (params["gamma"], params["beta"]) == (2e4, 5e3)
    np.testing.assert_allclose(params["deltaNu"], 1.9e4 / (0.95 * 2e5), rtol=1e-15)


def test_constant_laws_and_fitting_wrappers_are_numbers():
    model = jaxmr.BoucWen(
        alpha=jaxmr.ConstantLaw(2.0),
        c0=jaxmr.Fixed(0.0),
        A=jaxmr.Positive(1.0),
        beta=5.0,
        gamma=jaxmr.Bounded(1.0, 0.0, 10.0),
        n=1.0,
    )
    params = jaxmr.to_opensees(model)["params"]
    np.testing.assert_allclose(
        [params[k] for k in ("ko", "alpha", "Ao", "gamma", "beta")],
        [2.0, 0.0, 1.0, 5.0, 1.0],
        rtol=1e-12,  # Positive and Bounded store a logarithm and a logit
    )


# ---------------------------------------------------------------------------------------
# What cannot be converted: clear errors


@pytest.mark.parametrize(
    ("model", "kwargs", "match"),
    [
        (
            lambda: jaxmr.sas_brake_bouc_wen(),
            {},
            r"of the BoucWen depends on the current \(LinearLaw\).*"
            r"model\.at\(current\)\)` \(a dashpot .* Viscous material in Parallel",
        ),
        (
            lambda: jaxmr.BoucWen(alpha=1.0, c0=0.1, A=1.0, beta=1.0, gamma=1.0, n=1.0),
            {},
            r"`c0` = 0\.1 .* no counterpart .* Viscous material in Parallel",
        ),
        (
            lambda: jaxmr.BoucWen(
                alpha=1.0, c0=0.0, A=1.0, beta=1.0, gamma=1.0, n=1.0, f0=3.0
            ),
            {},
            r"`f0` = 3 .* no force offset",
        ),
        (
            lambda: jaxmr.BoucWen(
                alpha=1.0, c0=0.0, A=1.0, beta=1.0, gamma=1.0, n=1.0, k0=2.0, x0=0.1
            ),
            {},
            r"`x0` = 0\.1 .*no counterpart",
        ),
        (
            lambda: jaxmr.from_opensees("BWBN", PINCHED),
            {"material": "BoucWen"},
            r"`zeta_s` = 0\.8 .* OpenSees' BoucWen has no pinching",
        ),
        (
            lambda: jaxmr.from_opensees("BoucWen", DEGRADING),
            {"material": "BWBN"},
            r"`delta_nu` = .* OpenSees' BWBN has no degradation",
        ),
        (
            lambda: jaxmr.BoucWenBaberNoori(
                k=1.0,
                alpha=1.0,
                c=0.0,
                A0=1.0,
                beta=1.0,
                gamma=1.0,
                n=1.0,
                delta_A=0.1,
            ),  # fmt: skip
            {},
            r"`delta_A` = 0\.1 .* \(1 - alpha\)·k = 0",
        ),
        (
            lambda: jaxmr.BoucWen(alpha=1.0, c0=0.0, A=1.0, beta=1.0, gamma=1.0, n=1.0),
            {"material": "Steel01"},
            r"`material` must be 'BoucWen' or 'BWBN'",
        ),
    ],
)
def test_to_opensees_refuses_what_has_no_counterpart(model, kwargs, match):
    with pytest.raises(ValueError, match=match):
        jaxmr.to_opensees(model(), **kwargs)


def test_to_opensees_refuses_other_models():
    with pytest.raises(TypeError, match="correspond to jaxmr.BoucWen"):
        jaxmr.to_opensees(jaxmr.sas_brake_dahl())
    with pytest.raises(TypeError, match=r"damper\.hysteresis\.at\(current\)"):
        jaxmr.to_opensees(jaxmr.passenger_car_mr_damper())


@pytest.mark.parametrize(
    ("material", "params", "error", "match"),
    [
        ("Steel01", BOUC_WEN, ValueError, "'BoucWen' or 'BWBN'"),
        ("BoucWen", BOUC_WEN | {"deltaNU": 0.0}, ValueError, "did you mean 'deltaNu'"),
        ("BWBN", {"alpha": 0.1}, ValueError, "needs ko, n, gamma"),
        ("BoucWen", list(BOUC_WEN.values())[:5], ValueError, "takes 9 parameters"),
        ("BoucWen", BOUC_WEN | {"ko": "stiff"}, ValueError, "ko must be a number"),
        ("BoucWen", BOUC_WEN | {"n": float("nan")}, ValueError, "n must be finite"),
        (
            "BoucWen",
            BOUC_WEN | {"beta": -5.0},  # jaxmr's gamma < 0 generates energy
            ValueError,
            "has no jaxmr counterpart .*`gamma` must be >= 0",
        ),
        # In OpenSees' names (jaxmr's constructor had named its own `alpha`).
        (
            "BoucWen",
            BOUC_WEN | {"alpha": 1.5},
            ValueError,
            r"OpenSees' `alpha` \(the ratio of post-yield to initial stiffness\) "
            r"must be in \[0, 1\], got 1.5",
        ),
        ("BoucWen", BOUC_WEN | {"ko": -1.0}, ValueError, r"OpenSees' `ko` .* > 0"),
    ],
)
def test_from_opensees_names_what_is_wrong(material, params, error, match):
    with pytest.raises(error, match=match):
        jaxmr.from_opensees(material, params)
