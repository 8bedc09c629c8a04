"""A nominal damper model in C: its parameters at the effective current (the current
laws), its hysteresis law's rates, force, bounds and yield force, and the current
dynamics, each the same arithmetic as the JAX model's method of the same name."""

import equinox as eqx
import numpy as np

from .._current_dynamics import FirstOrderLag
from .._current_law import (
    AbstractCurrentLaw,
    ConstantLaw,
    ExponentialLaw,
    LinearLaw,
    PolynomialLaw,
)
from .._damper import Damper
from .._hysteresis import BoucWen, Spencer
from .syntax import literal

# The hysteresis models written in C: their parameters, in the order of the model's
# fields.
_FIELDS = {
    BoucWen: ("alpha", "c0", "A", "beta", "gamma", "n", "k0", "x0", "f0"),
    Spencer: ("alpha", "c0", "k0", "c1", "k1", "x0", "gamma", "beta", "A", "n"),
}


def unsupported(kind: str, obj, supported: str) -> NotImplementedError:
    return NotImplementedError(
        f"export_c: {kind} {type(obj).__name__} has no C writer (supported: "
        f"{supported}). jaxmr.export_stablehlo exports any controller for an XLA "
        "runtime."
    )


def _number(value, where: str) -> str:
    array = np.asarray(value)
    if array.shape != ():
        raise NotImplementedError(
            f"export_c: {where} must be a single number, got shape {array.shape} (a "
            "batch of models exports one at a time)."
        )
    return literal(array)


def parameter(value, current: str, where: str) -> str:
    """The C expression of a model parameter at the effective current `current` (a C
    expression), as `jaxmr.AbstractHysteresis.at` resolves it."""
    if isinstance(value, LinearLaw):  # a + b i
        a, b = _number(value.a, where), _number(value.b, where)
        return f"({a} + {b} * {current})"
    if isinstance(value, ConstantLaw):  # value + 0 i
        return f"({_number(value.value, where)} + 0.0 * {current})"
    if isinstance(value, ExponentialLaw):  # a exp(b i)
        a, b = _number(value.a, where), _number(value.b, where)
        return f"({a} * exp({b} * {current}))"
    if isinstance(value, PolynomialLaw):  # jnp.polyval: Horner from 0, highest first
        expression = "0.0"
        for c in np.asarray(value.coefficients)[::-1]:
            expression = f"({expression} * {current} + {literal(c)})"
        return expression
    if isinstance(value, (AbstractCurrentLaw, eqx.Module)):
        raise unsupported(
            f"the parameter {where}, a",
            value,
            "numbers, LinearLaw, ConstantLaw, "
            "ExponentialLaw, PolynomialLaw; a fit's constraint wrappers removed",
        )
    return _number(value, where)


class DamperC:
    """The C functions of `damper` under the prefix `prefix` (`<prefix>_at`,
    `<prefix>_rates`, ...): `hysteresis()` the hysteresis law's alone (what an inverse
    model reads), `dynamics()` the whole damper's (what an observer integrates)."""

    def __init__(self, damper: Damper, prefix: str):
        hysteresis = damper.hysteresis
        if type(hysteresis) not in _FIELDS:
            raise unsupported("the hysteresis model", hysteresis, "BoucWen, Spencer")
        if damper.dynamics is not None and type(damper.dynamics) is not FirstOrderLag:
            raise unsupported(
                "the current dynamics", damper.dynamics, "None, FirstOrderLag"
            )
        self.damper = damper
        self.prefix = prefix
        self.kind = type(hysteresis)
        self.nh = len(hysteresis.state_names)
        self.ns = len(damper.state_names)

    def hysteresis(self) -> str:
        p, h = self.prefix, self.damper.hysteresis
        fields = _FIELDS[self.kind]
        assign = "\n".join(
            f"    q.{f} = {parameter(getattr(h, f), 'u', f'{type(h).__name__}.{f}')};"
            for f in fields
        )
        common = f"""\
/* {type(h).__name__} parameters at the effective current u [A or V]. */
typedef struct {{ double {", ".join(fields)}; }} {p}_params;

static {p}_params {p}_at(double u)
{{
    {p}_params q;
    (void)u;
{assign}
    return q;
}}
"""
        if self.kind is BoucWen:
            return (
                common
                + f"""
/* BoucWen.rates */
static void {p}_hysteresis_rates(const {p}_params *q, const double *s, double x,
                                 double v, double *ds)
{{
    (void)x;
    ds[0] = bouc_wen_rate(s[0], v, q->A, q->beta, q->gamma, q->n);
}}

/* BoucWen.force [N or N m] */
static double {p}_hysteresis_force(const {p}_params *q, const double *s, double x,
                                   double v)
{{
    return q->alpha * s[0] + q->c0 * v + q->k0 * (x - q->x0) + q->f0;
}}

/* d force / d (hysteresis state) */
static void {p}_force_gradient(const {p}_params *q, const double *s, double x,
                               double v, double *g)
{{
    (void)s;
    (void)x;
    (void)v;
    g[0] = q->alpha;
}}

/* BoucWen.state_bounds: z0 where beta + gamma > 0, else no bound. */
static void {p}_bounds(const {p}_params *q, double *b)
{{
    int bounded = q->beta + q->gamma > 0.0;
    double safe = bounded ? q->beta + q->gamma : 1.0;
    double z0 = pow(q->A / safe, 1.0 / q->n);
    b[0] = bounded ? z0 : INFINITY;
}}

/* BoucWen.yield_force [N or N m] */
static double {p}_yield_force(const {p}_params *q)
{{
    double b[1];
    {p}_bounds(q, b);
    return fabs(q->alpha) * (isfinite(b[0]) ? b[0] : 1.0);
}}
"""
            )
        return (
            common
            + f"""
/* Spencer's z0 = (A / (beta + gamma))^(1/n). */
static double {p}_z0(const {p}_params *q)
{{
    return pow(q->A / (q->beta + q->gamma), 1.0 / q->n);
}}

/* The internal displacement's rate [m/s]. */
static double {p}_y_rate(const {p}_params *q, double z, double y, double x, double v)
{{
    return (q->alpha * z + q->c0 * v + q->k0 * (x - y)) / (q->c0 + q->c1);
}}

/* Spencer.rates: z seen clipped to 1e3 z0, as jaxmr's rates see it. */
static void {p}_hysteresis_rates(const {p}_params *q, const double *s, double x,
                                 double v, double *ds)
{{
    double z0 = {p}_z0(q);
    double z_max = (isfinite(z0) && z0 > 0.0) ? 1000.0 * z0 : INFINITY;
    double z = clip(s[0], -z_max, z_max);
    double y_rate = {p}_y_rate(q, z, s[1], x, v);
    ds[0] = bouc_wen_rate(z, v - y_rate, q->A, q->beta, q->gamma, q->n);
    ds[1] = y_rate;
}}

/* Spencer.force [N] */
static double {p}_hysteresis_force(const {p}_params *q, const double *s, double x,
                                   double v)
{{
    return q->c1 * {p}_y_rate(q, s[0], s[1], x, v) + q->k1 * (x - q->x0);
}}

/* d force / d (z, y), as forward-mode differentiation computes it. */
static void {p}_force_gradient(const {p}_params *q, const double *s, double x,
                               double v, double *g)
{{
    (void)s;
    (void)x;
    (void)v;
    g[0] = q->c1 * (q->alpha / (q->c0 + q->c1));
    g[1] = q->c1 * (-q->k0 / (q->c0 + q->c1));
}}

/* Spencer.state_bounds */
static void {p}_bounds(const {p}_params *q, double *b)
{{
    b[0] = {p}_z0(q);
    b[1] = INFINITY;
}}

/* Spencer.yield_force [N] */
static double {p}_yield_force(const {p}_params *q)
{{
    return q->alpha * {p}_z0(q);
}}
"""
        )

    def initial_state(self, s: str, x: str, command: str) -> str:
        """C statements: `s` (an array) the virgin state at deflection `x`, the
        current dynamics settled at `command` (`Damper.initial_state`)."""
        lines = [f"{s}[0] = 0.0;"]
        if self.kind is Spencer:
            lines.append(f"{s}[1] = {x};")  # y starts at x: the device at rest
        if self.ns > self.nh:
            lines.append(f"{s}[{self.nh}] = {command};")
        return "\n".join(lines)

    def dynamics(self) -> str:
        p, k = self.prefix, self.nh
        dynamics = self.damper.dynamics
        if dynamics is None:
            effective = "    (void)s;\n    return command;"
            lag = ""
        else:
            assert isinstance(dynamics, FirstOrderLag)  # checked in __init__
            effective = f"    (void)command;\n    return s[{k}];"
            if isinstance(dynamics.rate, eqx.Module):
                raise unsupported("FirstOrderLag's rate, a", dynamics.rate, "a number")
            rate = _number(dynamics.rate, "FirstOrderLag.rate")
            lag = f"\n    ds[{k}] = -{rate} * (s[{k}] - command);"
        return f"""
/* Damper.effective_current [A or V] */
static double {p}_effective(const double *s, double command)
{{
{effective}
}}

/* Damper.rates: the hysteresis at the effective current, then the coil's lag. */
static void {p}_rates(const double *s, double x, double v, double command, double *ds)
{{
    {p}_params q = {p}_at({p}_effective(s, command));
    {p}_hysteresis_rates(&q, s, x, v, ds);{lag}
}}

/* Damper.force [N or N m] */
static double {p}_force(const double *s, double x, double v, double command)
{{
    {p}_params q = {p}_at({p}_effective(s, command));
    return {p}_hysteresis_force(&q, s, x, v);
}}
"""
