"""A nominal damper model in C: its parameters at the effective current (the current
laws), its hysteresis law's rates, force, bounds and yield force, and the current
dynamics, each the same arithmetic as the JAX model's method of the same name."""

import dataclasses

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
from .._hysteresis import (
    Bingham,
    BoucWen,
    BoucWenBaberNoori,
    Dahl,
    LuGre,
    NormalizedBoucWen,
    ShearThinningSpencer,
    Spencer,
)
from .syntax import literal


@dataclasses.dataclass(frozen=True)
class _Model:
    """A hysteresis law in C: its parameters (the model's fields, in order) and the
    bodies of its functions over `const $p_params *q` (the parameters at the
    effective current), the hysteretic state `s`, the deflection `x` and its rate
    `v`; `$p` stands for the prefix. Each is the same arithmetic as the JAX method
    of the same name."""

    fields: tuple[str, ...]
    # (No blank line in any: the source's unused functions are found by splitting it
    # at blank lines.)
    rates: str  # statements: ds[] = d s / dt
    force: str  # an expression [N or N m]
    gradient: str  # statements: g[] = d force / d s, as forward mode computes it
    bounds: str | None  # statements: b[] = state_bounds; None: it states none
    yield_force: str  # an expression [N or N m]
    helpers: str = ""  # functions of q the others call
    initial: tuple[str, ...] = ()  # the virgin state, expressions in x (default 0)


_BOUC_WEN_BOUNDS = """\
    /* z0 where beta + gamma > 0, else no bound. */
    int bounded = q->beta + q->gamma > 0.0;
    double safe = bounded ? q->beta + q->gamma : 1.0;
    double z0 = pow(q->A / safe, 1.0 / q->n);
    b[0] = bounded ? z0 : INFINITY;"""

# Spencer-type models (`Spencer`, `ShearThinningSpencer`) differ only in their
# dashpots c0(v), c1(v) [N s/m]: `dashpots` is the body of `$p_dashpots`, which sets
# c[0] and c[1] as the model's `dashpots(v)` computes them.
_SPENCER_HELPERS = """\
/* $p_dashpots: c0 and c1 [N s/m] at the piston velocity v [m/s]. */
static void $p_dashpots(const $p_params *q, double v, double *c)
{
    (void)v;
%s
}

/* Spencer's z0 = (A / (beta + gamma))^(1/n). */
static double $p_z0(const $p_params *q)
{
    return pow(q->A / (q->beta + q->gamma), 1.0 / q->n);
}

/* The internal displacement's rate [m/s]. */
static double $p_y_rate(const $p_params *q, double z, double y, double x, double v)
{
    double c[2];
    $p_dashpots(q, v, c);
    return (q->alpha * z + c[0] * v + q->k0 * (x - y)) / (c[0] + c[1]);
}

/* Spencer's force [N]: c1(v) y_rate + k1 (x - x0), z unclipped. */
static double $p_spencer_force(const $p_params *q, const double *s, double x,
                               double v)
{
    double c[2];
    $p_dashpots(q, v, c);
    return c[1] * $p_y_rate(q, s[0], s[1], x, v) + q->k1 * (x - q->x0);
}

/* d force / d (z, y), as forward mode computes it: the tangent of the rate's
   numerator (alpha, and k0 times -1) through the division, times c1(v). */
static void $p_spencer_gradient(const $p_params *q, double v, double *g)
{
    double c[2];
    $p_dashpots(q, v, c);
    g[0] = c[1] * (q->alpha / (c[0] + c[1]));
    g[1] = c[1] * (-q->k0 / (c[0] + c[1]));
}
"""


def _spencer(fields: tuple[str, ...], dashpots: str) -> "_Model":
    """A Spencer-type model: `fields` its parameters, `dashpots` C statements setting
    c[0] and c[1] [N s/m] from `q` and the piston velocity `v` [m/s]."""
    return _Model(
        fields,
        # z seen clipped to 1e3 z0, as jaxmr's rates see it.
        rates="""\
    double z0 = $p_z0(q);
    double z_max = (isfinite(z0) && z0 > 0.0) ? 1000.0 * z0 : INFINITY;
    double z = clip(s[0], -z_max, z_max);
    double y_rate = $p_y_rate(q, z, s[1], x, v);
    ds[0] = bouc_wen_rate(z, v - y_rate, q->A, q->beta, q->gamma, q->n);
    ds[1] = y_rate;""",
        force="$p_spencer_force(q, s, x, v)",
        gradient="    $p_spencer_gradient(q, v, g);",
        bounds="    b[0] = $p_z0(q);\n    b[1] = INFINITY;",
        yield_force="q->alpha * $p_z0(q)",
        helpers=_SPENCER_HELPERS % dashpots,
        initial=("0.0", "$x"),  # y starts at x: the device at rest
    )


_SPENCER_FIELDS = ("alpha", "c0", "k0", "c1", "k1", "x0", "gamma", "beta", "A", "n")

_LUGRE_HELPERS = """\
/* LuGre.stribeck [N] */
static double $p_stribeck(const $p_params *q, double v)
{
    double r = v / q->v_s;
    return q->F_c + (q->F_s - q->F_c) * exp(-(r * r));
}

/* LuGre._rate [m/s] */
static double $p_y_rate(const $p_params *q, double y, double v)
{
    return v - q->sigma0 * fabs(v) * y / $p_stribeck(q, v);
}
"""

# BoucWenBaberNoori.rates: pinching h(z) and degradation (nu, eta, A) of the
# dissipated energy, h = 1 where nothing pinches (zeta1 = 0 or A = 0), as its `where`s
# select.
_BWBN_RATES = """\
    double z = s[0], energy = s[1];
    double nu = 1.0 + q->delta_nu * energy;
    double eta = 1.0 + q->delta_eta * energy;
    double A = fmax(q->A0 - q->delta_A * energy, 0.0);
    double zeta1 = q->zeta_s * (1.0 - exp(-q->p * energy));
    double zeta2 = (q->psi + q->delta_psi * energy) * (q->lam + zeta1);
    double h = 1.0;
    if (zeta1 != 0.0 && A > 0.0) {
        double z_u = pow(A / (nu * (q->beta + q->gamma)), 1.0 / q->n);
        double r = (z * sign(v) - q->q * z_u) / zeta2;
        h = 1.0 - zeta1 * exp(-(r * r));
    }
    ds[0] = h * nu * bouc_wen_rate(z, v, A / nu, q->beta, q->gamma, q->n) / eta;
    ds[1] = z * v;"""

_BWBN_FIELDS = tuple(
    "k alpha c A0 beta gamma n f0 delta_nu delta_eta delta_A zeta_s p q psi delta_psi "
    "lam".split()
)

# The hysteresis models written in C.
_MODELS = {
    BoucWen: _Model(
        ("alpha", "c0", "A", "beta", "gamma", "n", "k0", "x0", "f0"),
        rates="    ds[0] = bouc_wen_rate(s[0], v, q->A, q->beta, q->gamma, q->n);",
        force="q->alpha * s[0] + q->c0 * v + q->k0 * (x - q->x0) + q->f0",
        gradient="    g[0] = q->alpha;",
        bounds=_BOUC_WEN_BOUNDS,
        yield_force="fabs(q->alpha) * (isfinite(b[0]) ? b[0] : 1.0)",
    ),
    NormalizedBoucWen: _Model(
        ("kappa_x", "kappa_w", "c0", "rho", "sigma", "n", "x0", "f0"),
        rates="""\
    double power = abs_pow(s[0], q->n);
    ds[0] = q->rho * (v - (q->sigma * fabs(v) * sign(s[0])
                           + (1.0 - q->sigma) * v) * power);""",
        force="q->kappa_x * (x - q->x0) + q->kappa_w * s[0] + q->c0 * v + q->f0",
        gradient="    g[0] = q->kappa_w;",
        bounds="    b[0] = 1.0;",
        yield_force="q->kappa_w",
    ),
    BoucWenBaberNoori: _Model(
        _BWBN_FIELDS,
        rates=_BWBN_RATES,
        force="q->alpha * q->k * x + (1.0 - q->alpha) * q->k * s[0] + q->c * v + q->f0",
        # The force reads z alone: the energy's entry is 0.
        gradient="    g[0] = (1.0 - q->alpha) * q->k;\n    g[1] = 0.0;",
        bounds=None,
        # (1 - alpha) k z_u of the undegraded model.
        yield_force="(1.0 - q->alpha) * q->k\n"
        "           * pow(q->A0 / (q->beta + q->gamma), 1.0 / q->n)",
    ),
    Spencer: _spencer(_SPENCER_FIELDS, "    c[0] = q->c0;\n    c[1] = q->c1;"),
    ShearThinningSpencer: _spencer(
        _SPENCER_FIELDS + ("e0", "e1"),
        # ShearThinningSpencer.dashpots: c_k / (1 + e_k |v|).
        "    c[0] = q->c0 / (1.0 + q->e0 * fabs(v));\n"
        "    c[1] = q->c1 / (1.0 + q->e1 * fabs(v));",
    ),
    Dahl: _Model(
        ("k_x", "k_w", "rho"),
        rates="    ds[0] = q->rho * (v - fabs(v) * s[0]);",
        force="q->k_x * v + q->k_w * s[0]",
        gradient="    g[0] = q->k_w;",
        bounds="    b[0] = 1.0;",
        yield_force="q->k_w",
    ),
    LuGre: _Model(
        ("sigma0", "sigma1", "sigma2", "F_c", "F_s", "v_s"),
        rates="    ds[0] = $p_y_rate(q, s[0], v);",
        force="q->sigma0 * s[0] + q->sigma1 * $p_y_rate(q, s[0], v) + q->sigma2 * v",
        gradient="    g[0] = q->sigma0 + q->sigma1 * -(q->sigma0 * fabs(v) / "
        "$p_stribeck(q, v));",
        bounds="    b[0] = fmax(q->F_c, q->F_s) / q->sigma0;",
        yield_force="fmax(q->F_c, q->F_s)",
        helpers=_LUGRE_HELPERS,
    ),
    Bingham: _Model(
        ("f_c", "c0", "f0", "velocity_scale"),
        rates="    /* no state */",
        force="q->f_c * (q->velocity_scale > 0.0 ? tanh(v / q->velocity_scale)\n"
        "                                      : sign(v))\n"
        "           + q->c0 * v + q->f0",
        gradient="    /* no state */",
        bounds=None,
        yield_force="q->f_c",
    ),
}
SUPPORTED = ", ".join(kind.__name__ for kind in _MODELS)


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
    model reads), `dynamics()` the whole damper's (what an observer integrates).
    `nh` and `ns` are the hysteresis law's and the damper's state sizes (`size` the
    latter at least 1: C has no empty arrays); `bounded` whether the law states
    bounds on its state."""

    def __init__(self, damper: Damper, prefix: str):
        hysteresis = damper.hysteresis
        if type(hysteresis) not in _MODELS:
            raise unsupported("the hysteresis model", hysteresis, SUPPORTED)
        if damper.dynamics is not None and type(damper.dynamics) is not FirstOrderLag:
            raise unsupported(
                "the current dynamics", damper.dynamics, "None, FirstOrderLag"
            )
        self.damper = damper
        self.prefix = prefix
        self.model = _MODELS[type(hysteresis)]
        self.nh = len(hysteresis.state_names)
        self.ns = len(damper.state_names)
        self.size = max(self.ns, 1)
        self.bounded = self.model.bounds is not None

    def hysteresis(self) -> str:
        p, h, model = self.prefix, self.damper.hysteresis, self.model
        name = type(h).__name__
        assign = "\n".join(
            f"    q.{f} = {parameter(getattr(h, f), 'u', f'{name}.{f}')};"
            for f in model.fields
        )
        unused = "    (void)q;\n    (void)s;\n    (void)x;\n    (void)v;"
        bounds = ""
        if model.bounds is not None:
            bounds = f"""
/* {name}.state_bounds */
static void $p_bounds(const $p_params *q, double *b)
{{
{model.bounds}
}}
"""
        # The yield force of a Bouc-Wen law reads its bounds.
        reads_bounds = "b[" in model.yield_force
        yield_bounds = (
            f"    double b[{self.nh}];\n    $p_bounds(q, b);\n" if reads_bounds else ""
        )
        code = f"""\
/* {name} parameters at the effective current u [A or V]. */
typedef struct {{ double {", ".join(model.fields)}; }} $p_params;

static $p_params $p_at(double u)
{{
    $p_params q;
    (void)u;
{assign}
    return q;
}}

{model.helpers}
/* {name}.rates */
static void $p_hysteresis_rates(const $p_params *q, const double *s, double x,
                                 double v, double *ds)
{{
{unused}
    (void)ds;
{model.rates}
}}

/* {name}.force [N or N m] */
static double $p_hysteresis_force(const $p_params *q, const double *s, double x,
                                   double v)
{{
{unused}
    return {model.force};
}}

/* d force / d (hysteresis state), as forward-mode differentiation computes it. */
static void $p_force_gradient(const $p_params *q, const double *s, double x,
                               double v, double *g)
{{
{unused}
    (void)g;
{model.gradient}
}}
{bounds}
/* {name}.yield_force [N or N m] */
static double $p_yield_force(const $p_params *q)
{{
{yield_bounds}    return {model.yield_force};
}}
"""
        return code.replace("$p", p)

    def initial_state(self, s: str, x: str, command: str) -> str:
        """C statements: `s` (an array) the virgin state at deflection `x`, the
        current dynamics settled at `command` (`Damper.initial_state`)."""
        initial = self.model.initial or ("0.0",) * self.nh
        lines = [f"{s}[{i}] = {e.replace('$x', x)};" for i, e in enumerate(initial)]
        if self.ns > self.nh:
            lines.append(f"{s}[{self.nh}] = {command};")
        return "\n".join(lines) or "(void)x;"

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
