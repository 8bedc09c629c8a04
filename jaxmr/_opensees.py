r"""Conversion between jaxmr's Bouc–Wen models and OpenSees' `BoucWen` and `BWBN`
uniaxial materials, both ways.

OpenSees (`uniaxialMaterial BoucWen tag alpha ko n gamma beta Ao deltaA deltaNu
deltaEta` and `uniaxialMaterial BWBN tag alpha ko n gamma beta Ao q zetas p Shi
deltaShi lambda tol maxIter`) writes

$$F = \alpha k_o u + (1-\alpha) k_o z,\qquad
\dot z = h(z)\,\frac{A - \nu |z|^n\,[\beta\,\mathrm{sgn}(\dot u z) + \gamma]}{\eta}
\,\dot u,\qquad \dot e = (1-\alpha) k_o z \dot u,$$

so its $\beta$ sits on the $|\dot u|$ term: jaxmr's $\beta$ is OpenSees' $\gamma$ and
jaxmr's $\gamma$ is OpenSees' $\beta$. Its dissipated energy $e$ is jaxmr's
$\varepsilon = \int z\,du$ times $(1-\alpha) k_o$, so every per-energy coefficient
($\delta_A$, $\delta_\nu$, $\delta_\eta$, $p$, $\delta_\psi$) is OpenSees' value times
$(1-\alpha) k_o$ in jaxmr. OpenSees' BWBN takes $z_u = (1/(\beta+\gamma))^{1/n}$ (as if
$A = 1$); jaxmr's is $(A_0/(\beta+\gamma))^{1/n}$, so jaxmr's $q$ is OpenSees'
$q\,A_0^{-1/n}$. This correspondence was measured against OpenSees: jaxmr's loops
agree to 5e-8 of the peak force once OpenSees' first-order step error is
extrapolated away (16 Bouc–Wen cases, degradation, pinching; the project's
specification, MODELS.md §6).
"""

import difflib
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ._current_law import ConstantLaw, is_law
from ._damper import Damper
from ._hysteresis import BoucWen, BoucWenBaberNoori
from ._parameter import is_parameter, unwrap

# The parameters of each material, in the order `uniaxialMaterial` takes them after the
# tag, under the names of OpenSees' manual.
_SHARED = ("alpha", "ko", "n", "gamma", "beta", "Ao")
OPENSEES_PARAMETERS = {
    "BoucWen": (*_SHARED, "deltaA", "deltaNu", "deltaEta"),
    "BWBN": (*_SHARED, "q", "zetas", "p", "Shi", "deltaShi", "lambda"),
}
# Settings of OpenSees' Newton iteration on z, not model parameters: accepted and
# ignored by `from_opensees` (BWBN requires them, BoucWen takes them optionally).
_SOLVER_SETTINGS = ("tol", "maxIter")


def _number(model, name: str) -> float:
    """The value of a parameter as a float: a number, or a constant law or a fitting
    wrapper around one. A law that depends on the current has no OpenSees
    counterpart."""
    value = getattr(model, name)
    if is_parameter(value):
        value = unwrap(value)
    if isinstance(value, ConstantLaw):
        value = value.value
    if is_law(value):
        raise ValueError(
            f"`{name}` of the {type(model).__name__} depends on the current "
            f"({type(value).__name__}); OpenSees' materials have constant parameters. "
            "Convert the model at one current: `to_opensees(model.at(current))` (a "
            "dashpot or force offset at that current has no counterpart either: put "
            "a Viscous material in Parallel in OpenSees, and convert with them at "
            "0)."
        )
    array = np.asarray(value, dtype=np.float64)
    if array.shape != ():
        raise ValueError(
            f"`{name}` of the {type(model).__name__} has shape {array.shape}: convert "
            "one model (not a batch) at a time."
        )
    return float(array)


def _no_counterpart(model, names: Sequence[str], why: str) -> None:
    for name in names:
        value = _number(model, name)
        if value != 0:
            raise ValueError(
                f"`{name}` = {value:g} of the {type(model).__name__} has no "
                f"counterpart in OpenSees' material: {why}"
            )


_DASHPOT = (
    "it has no dashpot; add one in OpenSees as a Viscous material in Parallel with "
    "it, and convert the model with c = 0."
)
_OFFSET = "it has no force offset (f0); convert the model with f0 = 0."


def to_opensees(model, material: str | None = None) -> dict:
    r"""OpenSees material parameters of a jaxmr `BoucWen` or `BoucWenBaberNoori`.

    The correspondence (see the module docstring; OpenSees on the right):
    $k_o = \alpha_{jaxmr} + k_0$ and $\alpha = k_0/k_o$ for `BoucWen`
    ($F = \alpha_{jaxmr} z + k_0 x$), $k_o = k$ and $\alpha$ as is for
    `BoucWenBaberNoori`; OpenSees' `gamma` = jaxmr's `beta` and OpenSees' `beta` =
    jaxmr's `gamma`; `Ao` = `A` (`A0`); `n` as is; per-energy coefficients divided by
    $(1-\alpha) k_o$; `q` = jaxmr's $q\,A_0^{1/n}$; `Shi` = `psi`, `lambda` = `lam`,
    `zetas` = `zeta_s`.

    Units: OpenSees takes any consistent units; these are jaxmr's SI ones. `ko` [N/m]
    (N·m/rad for a brake), `gamma`, `beta` [1/m^n], `Ao`, `n`, `alpha`, `q`, `zetas`,
    `lambda` [1], `Shi` [m]; `deltaA`, `deltaNu`, `deltaEta`, `p` [1/J] and `deltaShi`
    [1/N], per unit of OpenSees' energy $e = \int (1-\alpha) k_o z\,du$ [J].

    **Arguments:**

    - `model`: a `jaxmr.BoucWen` or `jaxmr.BoucWenBaberNoori` whose parameters are
      numbers (or constant laws, or fitting wrappers: `jaxmr.Fixed`, ...).
    - `material`: `"BoucWen"` or `"BWBN"`. Default: `"BoucWen"` for a `BoucWen`, and for
      a `BoucWenBaberNoori` without pinching (`zeta_s = 0`; its degradation maps onto
      OpenSees' BoucWen); `"BWBN"` for one with pinching.

    **Returns:** `{"material": name, "params": {parameter: value}}`, the parameters in
    `uniaxialMaterial`'s order:
    `ops.uniaxialMaterial(d["material"], tag, *d["params"].values())` (BWBN also needs
    OpenSees' iteration settings `tol` and `maxIter` after them).
    `from_opensees(**d)` gives the model back.

    **Raises:** `TypeError` for another model; `ValueError` for what has no OpenSees
    counterpart, naming it: a parameter that depends on the current, a dashpot (`c0`,
    `c`) or an offset (`f0`, `k0·x0`), pinching in OpenSees' BoucWen, degradation
    (`delta_nu`, `delta_eta`, `delta_A`) in OpenSees' BWBN, or per-energy coefficients
    when $(1-\alpha) k_o = 0$ (OpenSees' energy is then always 0).
    """
    if isinstance(model, Damper):
        raise TypeError(
            "to_opensees: a Damper (a model with current dynamics) has no OpenSees "
            "counterpart; convert its hysteresis model at one current, "
            "`to_opensees(damper.hysteresis.at(current))`."
        )
    if not isinstance(model, (BoucWen, BoucWenBaberNoori)):
        raise TypeError(
            "to_opensees: OpenSees' BoucWen and BWBN materials correspond to "
            f"jaxmr.BoucWen and jaxmr.BoucWenBaberNoori, not {type(model).__name__}."
        )
    if material is not None and material not in OPENSEES_PARAMETERS:
        raise ValueError(
            f"to_opensees: `material` must be 'BoucWen' or 'BWBN', got {material!r}."
        )
    if isinstance(model, BoucWen):
        if material == "BWBN":
            raise ValueError(
                "to_opensees: a jaxmr.BoucWen is OpenSees' BoucWen material (BWBN "
                "without pinching is the same model): use material='BoucWen'."
            )
        return {"material": "BoucWen", "params": _bouc_wen(model)}
    if material is None:
        material = "BWBN" if _number(model, "zeta_s") != 0 else "BoucWen"
    return {"material": material, "params": _bwbn(model, material)}


def _bouc_wen(model: BoucWen) -> dict[str, float]:
    _no_counterpart(model, ["c0"], _DASHPOT)
    _no_counterpart(model, ["f0"], _OFFSET)
    k0, x0 = _number(model, "k0"), _number(model, "x0")
    if k0 * x0 != 0:
        raise ValueError(
            f"`x0` = {x0:g} of the BoucWen (with k0 = {k0:g}) has no counterpart in "
            "OpenSees' material: its spring acts from u = 0; shift the displacement "
            "instead, or convert the model with x0 = 0."
        )
    ko = _number(model, "alpha") + k0
    if ko == 0:
        raise ValueError(
            "to_opensees: the BoucWen has alpha = k0 = 0 (no force at all), so "
            "OpenSees' alpha = k0/ko is undefined."
        )
    return {
        "alpha": k0 / ko,
        "ko": ko,
        "n": _number(model, "n"),
        "gamma": _number(model, "beta"),
        "beta": _number(model, "gamma"),
        "Ao": _number(model, "A"),
        "deltaA": 0.0,
        "deltaNu": 0.0,
        "deltaEta": 0.0,
    }


def _bwbn(model: BoucWenBaberNoori, material: str) -> dict[str, float]:
    _no_counterpart(model, ["c"], _DASHPOT)
    _no_counterpart(model, ["f0"], _OFFSET)
    alpha, ko, n, A0 = (_number(model, k) for k in ("alpha", "k", "n", "A0"))
    hysteretic = (1 - alpha) * ko  # OpenSees' energy per unit of jaxmr's

    def per_energy(name: str) -> float:
        value = _number(model, name)
        if value == 0:
            return 0.0
        if hysteretic == 0:
            raise ValueError(
                f"`{name}` = {value:g} of the BoucWenBaberNoori has no counterpart in "
                f"OpenSees' material: with (1 - alpha)·k = 0 its energy e = ∫(1 - "
                "alpha) k z du is always 0."
            )
        return value / hysteretic

    common = {
        "alpha": alpha,
        "ko": ko,
        "n": n,
        "gamma": _number(model, "beta"),
        "beta": _number(model, "gamma"),
        "Ao": A0,
    }
    if material == "BoucWen":
        _no_counterpart(
            model,
            ["zeta_s"],
            "OpenSees' BoucWen has no pinching; use material='BWBN' (which has no "
            "degradation).",
        )
        return common | {
            "deltaA": per_energy("delta_A"),
            "deltaNu": per_energy("delta_nu"),
            "deltaEta": per_energy("delta_eta"),
        }
    _no_counterpart(
        model,
        ["delta_nu", "delta_eta", "delta_A"],
        "OpenSees' BWBN has no degradation of A, nu or eta; use material='BoucWen' "
        "(which has no pinching).",
    )
    return common | {
        # jaxmr's z_u is (A0/(beta+gamma))^(1/n), OpenSees' (1/(beta+gamma))^(1/n).
        "q": _number(model, "q") * A0 ** (1 / n),
        "zetas": _number(model, "zeta_s"),
        "p": per_energy("p"),
        "Shi": _number(model, "psi"),
        "deltaShi": per_energy("delta_psi"),
        "lambda": _number(model, "lam"),
    }


def _parameters(material: str, params) -> dict[str, float]:
    """OpenSees' parameters by name, from a mapping or from `uniaxialMaterial`'s
    arguments after the tag."""
    names = OPENSEES_PARAMETERS[material]
    allowed = (*names, *_SOLVER_SETTINGS)
    if isinstance(params, Mapping):
        given = dict(params)
    elif isinstance(params, Sequence) and not isinstance(params, str):
        if not len(names) <= len(params) <= len(allowed):
            raise ValueError(
                f"from_opensees: OpenSees' {material} takes {len(names)} parameters "
                f"({' '.join(names)}), then optionally tol and maxIter; got "
                f"{len(params)} values."
            )
        given = dict(zip(allowed, params))
    else:
        raise TypeError(
            "from_opensees: `params` must be a mapping from OpenSees' parameter names "
            "to values, or the list of uniaxialMaterial's arguments after the tag."
        )
    for name in given:
        if name not in allowed:
            near = difflib.get_close_matches(str(name), allowed, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise ValueError(
                f"from_opensees: {name!r} is not a parameter of OpenSees' {material}"
                f"{hint}; its parameters are {', '.join(names)}."
            )
    missing = [name for name in names if name not in given]
    if missing:
        raise ValueError(
            f"from_opensees: OpenSees' {material} needs {', '.join(missing)} too (its "
            f"parameters are {', '.join(names)})."
        )
    values = {}
    for name in names:
        try:
            values[name] = float(given[name])
        except (TypeError, ValueError):
            raise ValueError(
                f"from_opensees: {name} must be a number, got {given[name]!r}."
            ) from None
        if not math.isfinite(values[name]):
            raise ValueError(
                f"from_opensees: {name} must be finite, got {values[name]}."
            )
    return values


def from_opensees(
    material: str, params: Mapping[str, float] | Sequence[float | int]
) -> BoucWen | BoucWenBaberNoori:
    r"""The jaxmr model of an OpenSees `BoucWen` or `BWBN` uniaxial material.

    The correspondence is `to_opensees`'s, the other way. OpenSees' `BoucWen` without
    degradation (`deltaA = deltaNu = deltaEta = 0`) is a `jaxmr.BoucWen`:
    `alpha` = $(1-\alpha) k_o$ [N/m], `k0` = $\alpha k_o$ [N/m], `A` = `Ao`, `beta` =
    OpenSees' `gamma`, `gamma` = OpenSees' `beta`, `n`; with degradation it is a
    `jaxmr.BoucWenBaberNoori` without pinching, each `delta` times $(1-\alpha) k_o$.
    OpenSees' `BWBN` is a `jaxmr.BoucWenBaberNoori` without degradation, with
    `q` = OpenSees' $q\,A_o^{-1/n}$, `p` and `delta_psi` times $(1-\alpha) k_o$,
    `psi` = `Shi`, `lam` = `lambda`, `zeta_s` = `zetas`. No dashpot and no offset
    (`c0 = 0`, `f0 = 0`). Give the parameters in SI units (m, N; for a brake rad,
    N·m), the per-energy ones per joule of OpenSees' energy (see `to_opensees`).

    One difference remains where degradation takes $A(\varepsilon)$ below zero:
    OpenSees integrates on with a negative $A$, jaxmr holds it at 0 (no restoring
    capacity left; a negative one would generate energy).

    **Arguments:**

    - `material`: `"BoucWen"` or `"BWBN"`.
    - `params`: the parameters by OpenSees' names (`alpha`, `ko`, `n`, `gamma`,
      `beta`, `Ao`, then `deltaA`, `deltaNu`, `deltaEta` for BoucWen or `q`, `zetas`,
      `p`, `Shi`, `deltaShi`, `lambda` for BWBN), or `uniaxialMaterial`'s arguments
      after the tag in that order. OpenSees' iteration settings `tol` and `maxIter`
      are accepted and ignored (jaxmr integrates the rate equation).

    **Returns:** a `jaxmr.BoucWen` or a `jaxmr.BoucWenBaberNoori`.

    **Raises:** `ValueError` naming an unknown, missing or non-numeric parameter, or
    one outside what jaxmr's model accepts (its constructor's message).
    """
    if material not in OPENSEES_PARAMETERS:
        raise ValueError(
            f"from_opensees: `material` must be 'BoucWen' or 'BWBN' (the OpenSees "
            f"materials of the Bouc–Wen family), got {material!r}."
        )
    p = _parameters(material, params)
    # In OpenSees' own names first: past these, jaxmr's constructor named its own
    # parameters (its `alpha` = (1 - alpha) ko "got -10000" for OpenSees' alpha 1.5).
    if not p["ko"] > 0:
        raise ValueError(
            f"from_opensees: OpenSees' `ko` (the initial stiffness) must be > 0 [N/m], "
            f"got {p['ko']!r}."
        )
    if not 0 <= p["alpha"] <= 1:
        raise ValueError(
            "from_opensees: OpenSees' `alpha` (the ratio of post-yield to initial "
            f"stiffness) must be in [0, 1], got {p['alpha']!r}: jaxmr's hysteretic "
            "stiffness (1 - alpha) ko and linear stiffness alpha ko must be >= 0."
        )
    hysteretic = (1 - p["alpha"]) * p["ko"]
    common: dict[str, Any] = dict(
        A0=p["Ao"], beta=p["gamma"], gamma=p["beta"], n=p["n"], c=0.0, f0=0.0
    )
    try:
        if material == "BWBN":
            return BoucWenBaberNoori(
                k=p["ko"],
                alpha=p["alpha"],
                zeta_s=p["zetas"],
                p=p["p"] * hysteretic,
                q=p["q"] * p["Ao"] ** (-1 / p["n"]),
                psi=p["Shi"],
                delta_psi=p["deltaShi"] * hysteretic,
                lam=p["lambda"],
                **common,
            )
        if p["deltaA"] == p["deltaNu"] == p["deltaEta"] == 0:
            return BoucWen(
                alpha=hysteretic,
                c0=0.0,
                A=p["Ao"],
                beta=p["gamma"],
                gamma=p["beta"],
                n=p["n"],
                k0=p["alpha"] * p["ko"],
            )
        return BoucWenBaberNoori(
            k=p["ko"],
            alpha=p["alpha"],
            delta_A=p["deltaA"] * hysteretic,
            delta_nu=p["deltaNu"] * hysteretic,
            delta_eta=p["deltaEta"] * hysteretic,
            **common,
        )
    except ValueError as e:
        raise ValueError(
            f"from_opensees: OpenSees' {material} with {p} has no jaxmr counterpart "
            f"(in jaxmr's names, alpha = (1 - alpha) ko, k0 = alpha ko, beta and "
            f"gamma swapped: see the docstring): {e}"
        ) from e
