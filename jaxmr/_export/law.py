"""The semi-active laws in C, each the same arithmetic as its JAX `__call__` (with
the relaxations of `jaxmr._control.smooth` at the law's temperature)."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._control import (
    ClippedOptimal,
    ContinuousClippedOptimal,
    ForceFeedback,
    Groundhook,
    Hybrid,
    OnOffGroundhook,
    OnOffSkyhook,
    Skyhook,
)
from .._control.feedback import LinearAndMLP
from .._control.state_space import QUARTER_CAR_STATE
from .._damper import Damper
from .damper import unsupported
from .syntax import literal

SUPPORTED = (
    "Skyhook, OnOffSkyhook, Groundhook, OnOffGroundhook, Hybrid, ClippedOptimal, "
    "ContinuousClippedOptimal, ForceFeedback (linear, or linear + MLP)"
)


@dataclasses.dataclass(frozen=True)
class LawC:
    """A law's C: `reads` the readings it reads, `inverts` whether it inverts the
    damper (an observer's, or `model`, its own), `code` its functions, ending in
    `static double law_command(const readings *r, const observer *o)` (the command
    [A] before the controller's last clip)."""

    reads: tuple[str, ...]
    inverts: bool
    model: Damper | None
    code: str


def _temperature(law) -> float:
    t = np.asarray(law.temperature)
    if t.shape != ():
        raise NotImplementedError(
            f"export_c: {type(law).__name__}.temperature must be one number, got "
            f"shape {t.shape}."
        )
    return float(t)


def _command_for_force(law, inverse: str) -> str:
    """`command_for_force(plant, force, i_max, temperature)` on the damper `inverse`
    (its hysteresis at the observer's state and motion)."""
    i_max, t = literal(law.i_max), _temperature(law)
    if t == 0:
        body = f"""\
    double f0, f1;
    band(o, &f0, &f1);
    return {i_max} * clip(band_fraction(force, f0, f1), 0.0, 1.0);"""
    else:
        # sqrt(T) as JAX rounds it (the law computes it from the same array).
        root = literal(jnp.sqrt(jnp.asarray(law.temperature)))
        body = f"""\
    double f0, f1, span, scale, den, ratio;
    {inverse}_params q = {inverse}_at({i_max});
    band(o, &f0, &f1);
    span = f1 - f0;
    scale = {root} * {inverse}_yield_force(&q);
    den = span * span + scale * scale;
    ratio = den > 0.0 ? (force - f0) * span / den : 0.0;
    return {i_max} * soft_unit_clip(ratio, {literal(t)});"""
    return f"""
/* DamperPlant.band: the forces at 0 and at I_max in the observed state. */
static void band(const observer *o, double *f0, double *f1)
{{
    {inverse}_params q0 = {inverse}_at(0.0);
    {inverse}_params q1 = {inverse}_at({i_max});
    *f0 = {inverse}_hysteresis_force(&q0, o->damper, o->x, o->v);
    *f1 = {inverse}_hysteresis_force(&q1, o->damper, o->x, o->v);
}}

/* command_for_force [A]: the inverse model at temperature {t!r}. */
static double command_for_force(const observer *o, double force)
{{
{body}
}}
"""


def _matrix(name: str, array) -> str:
    a = np.asarray(array, dtype=float)
    if a.ndim == 1:
        values = ", ".join(literal(x) for x in a)
        return f"static const double {name}[{a.shape[0]}] = {{{values}}};"
    rows = ",\n    ".join("{" + ", ".join(literal(x) for x in row) + "}" for row in a)
    return (
        f"static const double {name}[{a.shape[0]}][{a.shape[1]}] = {{\n    {rows}\n}};"
    )


def _linear_c(layer: eqx.nn.Linear, name: str, into: str, source: str) -> list[str]:
    """`eqx.nn.Linear`: `weight @ x (+ bias)`, as C declarations and statements."""
    weight = np.asarray(layer.weight)
    out, n = weight.shape
    decl = [_matrix(f"{name}_weight", weight)]
    bias = None if layer.bias is None else np.asarray(layer.bias)
    if bias is not None:
        decl.append(_matrix(f"{name}_bias", bias))
    body = [
        f"    for (i = 0; i < {out}; ++i) {{",
        "        double sum = 0.0;",
        f"        for (j = 0; j < {n}; ++j) sum += {name}_weight[i][j] * {source}[j];",
        f"        {into}[i] = sum{f' + {name}_bias[i]' if bias is not None else ''};",
        "    }",
    ]
    return decl + ["\f"] + body


def _network_c(network, features: int) -> str:
    """The map g of `ForceFeedback.linear` or `ForceFeedback.mlp`:
    `linear(phi) (+ mlp(phi))`, each layer `weight @ x + bias`, tanh between."""
    if isinstance(network, eqx.nn.Linear):
        linear, mlp = network, None
    elif isinstance(network, LinearAndMLP):
        linear, mlp = network.linear, network.mlp
    else:
        raise unsupported(
            "ForceFeedback's network",
            network,
            "the maps of ForceFeedback.linear and ForceFeedback.mlp",
        )
    decls, body = [], []

    def add(lines):
        split = lines.index("\f")
        decls.extend(lines[:split])
        body.extend(lines[split + 1 :])

    add(_linear_c(linear, "linear", "out", "phi"))
    body.append("    g = out[0];")
    width = features
    if mlp is not None:
        probe = jnp.linspace(-3.0, 3.0, 7)
        identity = np.array_equal(
            np.asarray(jnp.stack([mlp.final_activation(p) for p in probe])),
            np.asarray(probe),
        )
        if mlp.scan or mlp.activation is not jnp.tanh or not identity:
            raise NotImplementedError(
                "export_c: ForceFeedback's MLP must be ForceFeedback.mlp's (tanh "
                "hidden layers, no final activation, scan=False)."
            )
        width = max([features] + [np.shape(layer.weight)[0] for layer in mlp.layers])
        body.append(f"    for (i = 0; i < {features}; ++i) h[i] = phi[i];")
        for index, layer in enumerate(mlp.layers):
            add(_linear_c(layer, f"layer{index}", "next", "h"))
            rows = np.shape(layer.weight)[0]
            last = index == len(mlp.layers) - 1
            value = "next[i]" if last else "tanh(next[i])"
            body.append(f"    for (i = 0; i < {rows}; ++i) h[i] = {value};")
        body.append("    g = g + h[0];")
    declarations = "\n".join(decls)
    statements = "\n".join(body)
    return f"""
{declarations}

/* g(phi), dimensionless. */
static double network(const double *phi)
{{
    double out[1], h[{width}], next[{width}], g;
    int i, j;
    (void)h;
    (void)next;
{statements}
    return g;
}}
"""


def _gate(a: str, b: str, t: float) -> str:
    """`smooth.gate(a b, angular_switch(a, b), T)` on the C expressions `a`, `b` (one
    unit): H(a b) (H(0) = 1) at T = 0, else sigmoid(angular_switch(a, b) / T)."""
    if t == 0:
        return f"({a} * {b} >= 0.0 ? 1.0 : 0.0)"
    return f"sigmoid(angular_switch({a}, {b}) / {literal(t)})"


def _force_law(law, what: str, target: str, reads, model=None, code="") -> LawC:
    """A law that asks for a force `target` [N] (C statements setting `double
    target` from the readings `r`) and commands the current for it through the
    inverse model: `clip(command_for_force(plant, target, i_max, T), 0, i_max)`."""
    return LawC(
        tuple(reads),
        True,
        model,
        code
        + _command_for_force(law, "inverse")
        + f"""
/* {what}, through the inverse model. */
static double law_command(const readings *r, const observer *o)
{{
    double target;
{target}
    return clip(command_for_force(o, target), 0.0, {literal(law.i_max)});
}}
""",
    )


def _gain_row(law) -> np.ndarray:
    gain = np.asarray(law.gain)
    if gain.shape != (len(QUARTER_CAR_STATE),):
        raise NotImplementedError(
            f"export_c: {type(law).__name__}.gain must have shape (4,), got "
            f"{gain.shape} (a batch of laws exports one at a time)."
        )
    return gain


def _switch_law(law, what: str, setup: str, a: str, b: str, reads) -> LawC:
    """An on/off law: `I_max gate(a b, angular_switch(a, b), T)`, clipped to
    [0, I_max], with `a` and `b` C variables (one unit) that the statements `setup`
    declare from the readings `r`. It inverts nothing."""
    t, i_max = _temperature(law), literal(law.i_max)
    code = f"""
/* {what} (temperature {t!r}). */
static double law_command(const readings *r, const observer *o)
{{
{setup}
    (void)o;
    return clip({i_max} * {_gate(a, b, t)}, 0.0, {i_max});
}}
"""
    return LawC(tuple(reads), False, None, code)


def _primary(law, indent: str) -> str:
    """The primary controller's force f_c = -K x [N] of a clipped-optimal law on the
    state x = (z_s, v_s, z_u, v_u) (measured or estimated), a C expression (continued
    lines start with `indent`)."""
    terms = f"\n{indent}+ ".join(
        f"{literal(k)} * r->{name}"
        for k, name in zip(_gain_row(law), QUARTER_CAR_STATE)
    )
    return f"-({terms})"


def _clipped_optimal_setup(law) -> str:
    """`ClippedOptimal`: the lag of the damper force behind the primary controller's
    f_c [N], and the force [N] (measured, or the observer's model force)."""
    return f"""\
    double target = {_primary(law, " " * 22)};
    double force = r->damper_force;
    double lag = target - force;"""


# The on/off laws: (what, the C statements declaring the switch's two factors, the
# factors, what the law reads).
_SWITCHES = {
    OnOffSkyhook: (
        "OnOffSkyhook: I_max H(body_velocity v)",
        lambda law: "    double body = r->body_velocity, v = r->damper_velocity;",
        "body",
        "v",
        ("body_velocity", "damper_velocity"),
    ),
    OnOffGroundhook: (
        "OnOffGroundhook: I_max H(-wheel_velocity v)",
        # -wheel_velocity as JAX negates it before the product (a sign flip, exact).
        lambda law: "    double wheel = -r->wheel_velocity, v = r->damper_velocity;",
        "wheel",
        "v",
        ("wheel_velocity", "damper_velocity"),
    ),
    ClippedOptimal: (
        "ClippedOptimal: I_max H((f_c - f) f), f_c = -K x",
        _clipped_optimal_setup,
        "lag",
        "force",
        QUARTER_CAR_STATE + ("damper_force",),
    ),
}


def law_c(law) -> LawC:
    """The C of `law` (one of `SUPPORTED`)."""
    kind = type(law)
    if kind is Skyhook:
        return _force_law(
            law,
            "Skyhook: F* = c_sky body_velocity",
            f"    target = {literal(law.c_sky)} * r->body_velocity;",
            ("body_velocity",),
        )
    if kind is Groundhook:
        # -c_gnd as JAX negates it before the product (a sign flip, exact).
        return _force_law(
            law,
            "Groundhook: F* = -c_gnd wheel_velocity",
            f"    target = {literal(-np.asarray(law.c_gnd))} * r->wheel_velocity;",
            ("wheel_velocity",),
        )
    if kind is Hybrid:
        t = _temperature(law)
        alpha = np.asarray(law.alpha)
        target = f"""\
    double v = r->damper_velocity, body = r->body_velocity;
    double wheel = -r->wheel_velocity;
    double sky = body * {_gate("body", "v", t)};
    double ground = wheel * {_gate("wheel", "v", t)};
    target = {literal(law.gain)} * ({literal(alpha)} * sky + {literal(1 - alpha)}
                                    * ground);"""
        return _force_law(
            law,
            f"Hybrid at temperature {t!r}: F* = G [alpha sky + (1 - alpha) ground]",
            target,
            ("body_velocity", "wheel_velocity", "damper_velocity"),
        )
    if kind is ContinuousClippedOptimal:
        return _force_law(
            law,
            "ContinuousClippedOptimal: F* = -K x",
            f"    target = {_primary(law, ' ' * 16)};",
            QUARTER_CAR_STATE,
        )
    if kind in _SWITCHES:
        what, setup, a, b, reads = _SWITCHES[kind]
        return _switch_law(law, what, setup(law), a, b, reads)
    if kind is ForceFeedback:
        features = law.features
        scales = np.asarray(law.scales)
        phi = "\n".join(
            f"    phi[{k}] = r->{name} / {literal(scales[k])};"
            for k, name in enumerate(features)
        )
        target = f"""\
    double phi[{len(features)}];
    inverse_params q = inverse_at({literal(law.i_max)});
{phi}
    target = inverse_yield_force(&q) * network(phi);"""
        return _force_law(
            law,
            "ForceFeedback: F* = F_y g(m / s)",
            target,
            features,
            law.model,
            _network_c(law.network, len(features)),
        )
    raise unsupported("the law", law, SUPPORTED)
