"""The semi-active laws in C, each the same arithmetic as its JAX `__call__` (with
the relaxations of `jaxmr._control.smooth` at the law's temperature)."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._control import ForceFeedback, OnOffSkyhook, Skyhook
from .._control.feedback import _LinearAndMLP
from .._damper import Damper
from .damper import unsupported
from .syntax import literal

SUPPORTED = "Skyhook, OnOffSkyhook, ForceFeedback (linear, or linear + MLP)"


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
    elif isinstance(network, _LinearAndMLP):
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


def law_c(law) -> LawC:
    """The C of `law` (a `Skyhook`, `OnOffSkyhook` or `ForceFeedback`)."""
    kind = type(law)
    i_max = literal(law.i_max)
    if kind is Skyhook:
        code = (
            _command_for_force(law, "inverse")
            + f"""
/* Skyhook: the force c_sky * body_velocity through the inverse model. */
static double law_command(const readings *r, const observer *o)
{{
    return clip(command_for_force(o, {literal(law.c_sky)} * r->body_velocity), 0.0,
                {i_max});
}}
"""
        )
        return LawC(("body_velocity",), True, None, code)
    if kind is OnOffSkyhook:
        t = _temperature(law)
        on = (
            "(s >= 0.0 ? 1.0 : 0.0)"
            if t == 0
            else f"sigmoid(angular_switch(body, v) / {literal(t)})"
        )
        code = f"""
/* OnOffSkyhook at temperature {t!r}. */
static double law_command(const readings *r, const observer *o)
{{
    double body = r->body_velocity, v = r->damper_velocity, s = body * v;
    (void)o;
    (void)s;
    return clip({i_max} * {on}, 0.0, {i_max});
}}
"""
        return LawC(("body_velocity", "damper_velocity"), False, None, code)
    if kind is ForceFeedback:
        features = law.features
        scales = np.asarray(law.scales)
        phi = "\n".join(
            f"    phi[{k}] = r->{name} / {literal(scales[k])};"
            for k, name in enumerate(features)
        )
        inverse = "inverse"
        code = (
            _network_c(law.network, len(features))
            + _command_for_force(law, inverse)
            + f"""
/* ForceFeedback: F* = F_y g(m / s) through the inverse model. */
static double law_command(const readings *r, const observer *o)
{{
    double phi[{len(features)}];
    {inverse}_params q = {inverse}_at({i_max});
{phi}
    return clip(command_for_force(o, {inverse}_yield_force(&q) * network(phi)), 0.0,
                {i_max});
}}
"""
        )
        return LawC(tuple(features), True, law.model, code)
    raise unsupported("the law", law, SUPPORTED)
