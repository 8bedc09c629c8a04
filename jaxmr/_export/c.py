"""`export_c`: an `ObserverBasedController` as dependency-free C99, a header and a
source file with an `init` and a `step` function over a fixed-size state struct.

The C is written by walking the controller's structure (estimator, observer with its
nominal damper, law, clip), each part the same arithmetic as its JAX method, in the
same order, in double precision; the numbers that depend on the parameters alone
(the estimator's gains, the leak of its high-pass) are taken from JAX's own
computation and written as exact literals."""

import dataclasses
import functools
import re
from pathlib import Path

import jax
import jax.numpy as jnp

from .._control import DamperObserver, ObserverBasedController, VelocityEstimator
from .._version import __version__
from .damper import DamperC
from .law import LawC, law_c
from .plan import Plan, plan
from .syntax import check_identifier, literal
from .write import write_outputs

# Helpers of every generated source; those it does not call are left out (an unused
# static function is a warning, and the code must compile with -Wall -Werror).
_HELPERS = r"""
/* Whether every one of the n values is finite (ObserverBasedController's skip) */
static int all_finite(const double *x, int n)
{
    int k;
    for (k = 0; k < n; ++k) {
        if (!isfinite(x[k])) return 0;
    }
    return 1;
}

/* jnp.clip */
static double clip(double x, double lo, double hi)
{
    return fmin(fmax(x, lo), hi);
}

/* jnp.sign */
static double sign(double x)
{
    return (double)((x > 0.0) - (x < 0.0));
}

/* |z|^p, 0 at z = 0 (jaxmr's abs_pow) */
static double abs_pow(double z, double p)
{
    double a = fabs(z);
    return a > 0.0 ? pow(a, p) : 0.0;
}

/* The Bouc-Wen rate A v - (gamma |v| sgn(z) + beta v) |z|^n */
static double bouc_wen_rate(double z, double v, double A, double beta, double gamma,
                            double n)
{
    double power = abs_pow(z, n);
    return A * v - (gamma * fabs(v) * sign(z) + beta * v) * power;
}

/* (F - f0) / (f1 - f0), 0 where the band has closed */
static double band_fraction(double force, double f0, double f1)
{
    double span = f1 - f0;
    int tiny = fabs(span) < 1e-12 * (1.0 + fabs(f0) + fabs(f1));
    return tiny ? 0.0 : (force - f0) / span;
}

/* jax.nn.softplus: log(1 + e^x) as jnp.logaddexp(x, 0) computes it */
static double softplus(double x)
{
    return fmax(x, 0.0) + log1p(exp(-fabs(x)));
}

/* T [softplus(r / T) - softplus((r - 1) / T)] */
static double soft_unit_clip(double r, double t)
{
    return t * (softplus(r / t) - softplus((r - 1.0) / t));
}

/* jax.nn.sigmoid */
static double sigmoid(double x)
{
    return 1.0 / (1.0 + exp(-x));
}

/* 2 a b / (a^2 + b^2), 0 at a = b = 0 */
static double angular_switch(double a, double b)
{
    double den = a * a + b * b;
    return den > 0.0 ? 2.0 * a * b / den : 0.0;
}
"""

_UNITS = {
    "acceleration": "m/s^2 (rad/s^2 on a rotary machine)",
    "displacement": "m (rad)",
    "velocity": "m/s (rad/s)",
    "force": "N (N m)",
}


def _unit(name: str) -> str:
    return next((u for k, u in _UNITS.items() if name.endswith(k)), "its unit")


def _prune(source: str) -> str:
    """`source` without the static functions nothing calls (to a fixed point). Each
    top-level chunk (blank-line separated) defines at most one function."""
    chunks = source.split("\n\n")
    defines = re.compile(r"^static [\w\s\*]*?\b(\w+)\(", re.MULTILINE)
    while True:
        names = [
            (i, m.group(1)) for i, c in enumerate(chunks) if (m := defines.search(c))
        ]
        unused = [
            i
            for i, name in names
            if not any(
                re.search(rf"\b{name}\(", c) for j, c in enumerate(chunks) if j != i
            )
        ]
        if not unused:
            return "\n\n".join(chunks)
        chunks = [c for i, c in enumerate(chunks) if i not in unused]


@functools.partial(jax.jit, static_argnums=1)
def _estimator_constants(estimator: VelocityEstimator, dt: float):
    """The numbers of `VelocityEstimator.step` that depend on its parameters alone,
    computed as its compiled step computes them (XLA rounds exp, sin and cos in a
    fused kernel apart from op by op by an ulp; the gains are well conditioned, so
    that moves them by a few ulps at most)."""
    leak = jnp.exp(-2 * jnp.pi * estimator.high_pass * dt)
    alpha, beta, gamma = estimator.gains(dt)
    return leak, 1 - leak, alpha, beta / dt, gamma / dt**2


@functools.partial(jax.jit, static_argnums=1)
def _position_leak(estimator: VelocityEstimator, dt: float):
    """The position integrator's leak over a sample, as the compiled step computes
    it (apart from `_estimator_constants`, whose numbers stay those of an estimator
    without positions)."""
    return jnp.exp(-2 * jnp.pi * estimator.position_high_pass * dt)


def _estimator(
    estimator: VelocityEstimator, dt: float, inputs, macro: str, positions: bool
) -> str:
    """`VelocityEstimator.step` on `e`, the estimates written into `r`; with
    `positions`, the body and wheel positions too."""
    leak, one_minus_leak, alpha, beta_dt, gamma_dt2 = _estimator_constants(
        estimator, dt
    )
    wheel = "wheel_acceleration" in inputs
    a_u = f"in[{macro}_IN_WHEEL_ACCELERATION]" if wheel else "0.0 * a_s"
    # The biases' start (`VelocityEstimator.start_biases`): the readings at rest
    # where given, else the first readings.
    body_start = "a_s" if estimator.body_bias is None else literal(estimator.body_bias)
    wheel_start = (
        literal(estimator.wheel_bias)
        if wheel and estimator.wheel_bias is not None
        else "a_u"
    )
    wheel_estimate = "\n    r->wheel_acceleration = a_u - wheel_bias;" if wheel else ""
    position = position_state = position_estimate = ""
    what = ""
    if positions:
        what = f"; the positions, high-pass {float(estimator.position_high_pass)!r} Hz"
        # Before e->body_velocity moves on: the leaky integral of the old and the
        # new body velocity (0 at the first sample), trapezoidal.
        position = f"""
    const double position_leak = {literal(_position_leak(estimator, dt))};
    double new_velocity = started ? body_velocity : 0.0;
    double body_position = position_leak * e->body_position
        + {literal(0.5 * dt)} * (position_leak * e->body_velocity + new_velocity);"""
        position_state = "\n    e->body_position = started ? body_position : 0.0;"
        # The deflection is z_s - z_u.
        position_estimate = (
            "\n    r->body_position = e->body_position;"
            "\n    r->wheel_position = e->body_position - e->displacement;"
        )
    return f"""
/* VelocityEstimator.step (crossover {float(estimator.crossover)!r} Hz, damping
   {float(estimator.damping)!r}, high-pass {float(estimator.high_pass)!r} Hz{what}): the
   estimates into r, the next state into e. */
static void estimator_step(estimator *e, const double *in, readings *r)
{{
    const double leak = {literal(leak)}, one_minus_leak = {literal(one_minus_leak)};
    double a_s = in[{macro}_IN_BODY_ACCELERATION];
    double x = in[{macro}_IN_DAMPER_DISPLACEMENT];
    double a_u = {a_u};
    int started = e->started;
    double body_bias = started ? leak * e->body_bias + one_minus_leak * a_s
                               : {body_start};
    double wheel_bias = started ? leak * e->wheel_bias + one_minus_leak * a_u
                                : {wheel_start};
    double body = a_s - body_bias;
    double body_velocity = leak * e->body_velocity
                           + {literal(0.5 * dt)} * (leak * e->body_previous + body);\
{position}
    double relative = a_s - a_u;
    double before = e->relative_previous - e->relative_bias;
    double now = relative - e->relative_bias;
    double predicted_x = e->displacement + {literal(dt)} * e->damper_velocity
                         + {literal(dt**2)} * (2.0 * before + now) / 6.0;
    double predicted_v = e->damper_velocity + {literal(0.5 * dt)} * (before + now);
    double innovation = x - predicted_x;
    e->relative_bias = started
        ? e->relative_bias + {literal(gamma_dt2)} * innovation
        : body_bias - wheel_bias;
    e->started = 1;
    e->body_bias = body_bias;
    e->wheel_bias = wheel_bias;
    e->body_previous = body;
    e->relative_previous = relative;
    e->body_velocity = started ? body_velocity : 0.0;
    e->displacement = started ? predicted_x + {literal(alpha)} * innovation : x;
    e->damper_velocity = started ? predicted_v + {literal(beta_dt)} * innovation
                                 : 0.0;{position_state}
    r->body_velocity = e->body_velocity;
    r->wheel_velocity = e->body_velocity - e->damper_velocity;
    r->damper_velocity = e->damper_velocity;
    r->damper_displacement = e->displacement;
    r->body_acceleration = body;{wheel_estimate}{position_estimate}
}}
"""


def _observer(
    observer: DamperObserver,
    nominal: DamperC,
    dt: float,
    delay: int,
    measured_force: bool,
) -> str:
    """`DamperObserver.init`, `update`, `force` and `commanded` on `o`."""
    n, k, m = observer.substeps, nominal.nh, nominal.ns
    # Array sizes: C has no empty arrays (a static law, no coil lag, has no state).
    size_k, size_m = max(k, 1), nominal.size
    h = dt / n
    force_argument = ", double force" if measured_force else ""
    correction = ""
    if measured_force and k > 0:  # a static law has no state to correct
        gain = literal(observer.gain)
        correction = f"""
    {{
        /* DamperObserver._corrected: a share of the force error removed. */
        nominal_params q = nominal_at(nominal_effective(s, applied));
        double value = nominal_hysteresis_force(&q, s, x, v), g[{size_k}];
        double norm = 0.0;
        double step;
        nominal_force_gradient(&q, s, x, v, g);
        for (i = 0; i < {k}; ++i) norm += g[i] * g[i];
        step = norm > 0.0 ? (force - value) / norm : 0.0;
        for (i = 0; i < {k}; ++i) s[i] = s[i] + {gain} * step * g[i];
    }}"""
    bounded = ""
    if nominal.bounded:  # the model's bounds; the coil's state has none
        bounded = f"""
    {{
        double bounds[{size_k}];
        nominal_params q = nominal_at(nominal_effective(s, applied));
        nominal_bounds(&q, bounds);
        for (i = 0; i < {k}; ++i) s[i] = clip(s[i], -bounds[i], bounds[i]);
    }}"""
    init = nominal.initial_state("o->damper", "x", "command").replace("\n", "\n    ")
    return f"""
/* DamperObserver.init: the virgin state at x, v; every command before the first
   `command`. */
static void observer_init(observer *o, double x, double v, double command)
{{
    int i;
    o->started = 0;
    {init}
    o->x = x;
    o->v = v;
    for (i = 0; i < {delay + 1}; ++i) o->commands[i] = command;
}}

/* DamperObserver.update: {n} RK4 steps over the sample, the motion linear between the
   samples; then the correction by a measured force; then the model's bounds. */
static void observer_update(observer *o, double x, double v{force_argument})
{{
    double s[{size_m}], applied = o->commands[0];
    int i, j;
    for (i = 0; i < {m}; ++i) s[i] = o->damper[i];
    if (o->started) {{
        for (j = 0; j < {n}; ++j) {{
            double f[3], xs[3], vs[3], k1[{size_m}], k2[{size_m}], k3[{size_m}];
            double k4[{size_m}], y[{size_m}];
            f[0] = (double)j / {literal(n)};
            f[1] = ((double)j + 0.5) / {literal(n)};
            f[2] = ((double)j + 1.0) / {literal(n)};
            for (i = 0; i < 3; ++i) {{
                xs[i] = o->x + f[i] * (x - o->x);
                vs[i] = o->v + f[i] * (v - o->v);
            }}
            nominal_rates(s, xs[0], vs[0], applied, k1);
            for (i = 0; i < {m}; ++i) y[i] = s[i] + {literal(h / 2)} * k1[i];
            nominal_rates(y, xs[1], vs[1], applied, k2);
            for (i = 0; i < {m}; ++i) y[i] = s[i] + {literal(h / 2)} * k2[i];
            nominal_rates(y, xs[1], vs[1], applied, k3);
            for (i = 0; i < {m}; ++i) y[i] = s[i] + {literal(h)} * k3[i];
            nominal_rates(y, xs[2], vs[2], applied, k4);
            for (i = 0; i < {m}; ++i)
                s[i] = s[i] + {literal(h / 6)} * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i]
                                                + k4[i]);
        }}
    }}{correction}{bounded}
    o->started = 1;
    for (i = 0; i < {m}; ++i) o->damper[i] = s[i];
    o->x = x;
    o->v = v;
}}

/* DamperObserver.force [N or N m]: the model's force under the command acting now. */
static double observer_force(const observer *o)
{{
    return nominal_force(o->damper, o->x, o->v, o->commands[0]);
}}

/* DamperObserver.commanded */
static void observer_commanded(observer *o, double command)
{{
    int i;
    for (i = 0; i < {delay}; ++i) o->commands[i] = o->commands[i + 1];
    o->commands[{delay}] = command;
}}
"""


@dataclasses.dataclass(frozen=True)
class _Parts:
    plan: Plan
    law: LawC
    nominal: DamperC | None
    inverse: DamperC | None


def _parts(controller, measurements) -> _Parts:
    the_plan = plan(controller, measurements)
    law = law_c(controller.law)
    observer = controller.observer
    nominal = None if observer is None else DamperC(observer.model, "nominal")
    inverse = None
    if law.inverts:
        if observer is None:
            raise ValueError(
                f"export_c: the law {type(controller.law).__name__} inverts the "
                "damper, but the controller has no observer of its state: give the "
                "ObserverBasedController an `observer=jaxmr.DamperObserver(nominal)`."
            )
        model = observer.model if law.model is None else law.model
        if model.hysteresis.state_names != observer.model.hysteresis.state_names:
            raise ValueError(
                "export_c: the law's inverse `model` reads the observer's state, so "
                f"their states must match: {model.hysteresis.state_names} and "
                f"{observer.model.hysteresis.state_names}."
            )
        inverse = DamperC(model, "inverse")
    missing = [n for n in law.reads if n not in the_plan.readings]
    if missing:
        raise ValueError(
            f"export_c: the law {type(controller.law).__name__} reads {missing}, "
            f"which neither the measurements {the_plan.inputs} nor the estimator "
            "give."
        )
    return _Parts(the_plan, law, nominal, inverse)


def c_source(controller, name: str, measurements=None) -> tuple[str, str]:
    """The header and the source of `export_c` as text."""
    check_identifier(name, "export_c: `name`")
    if not isinstance(controller, ObserverBasedController):
        raise NotImplementedError(
            f"export_c: a {type(controller).__name__} cannot be exported; wrap the law "
            "in a jaxmr.ObserverBasedController(law, estimator=..., observer=..., "
            "sampling=...), which states what it measures, its damper model and its "
            "sample time."
        )
    parts = _parts(controller, measurements)
    p = parts.plan
    dt, delay = controller.sampling.dt, controller.sampling.delay
    macro = name.upper()
    i_max = literal(controller.law.i_max)
    estimator, observer = controller.estimator, controller.observer
    positions = controller.estimates_positions
    force = "damper_force" in p.inputs

    # The header.
    index = "\n".join(
        f"#define {macro}_IN_{n.upper()} {i} /* {n} [{_unit(n)}] */"
        for i, n in enumerate(p.inputs)
    )
    types = []
    position_member = "\n    double body_position;" if positions else ""
    if estimator is not None:
        types.append(f"""\
/* The velocity estimator's memory (jaxmr.EstimatorState). */
typedef struct {{
    int started;
    double body_bias, wheel_bias, body_previous, relative_previous, relative_bias;
    double body_velocity, displacement, damper_velocity;{position_member}
}} {name}_estimator;
""")
    if observer is not None:
        assert parts.nominal is not None
        types.append(f"""\
/* The damper observer's memory (jaxmr.ObserverState): the nominal damper's state
   ({", ".join(observer.model.state_names)}), the deflection and its rate at the last
   sample, and the last {delay + 1} commands [A], oldest (acting now) first. */
typedef struct {{
    int started;
    double damper[{parts.nominal.size}];
    double x, v;
    double commands[{delay + 1}];
}} {name}_observer;
""")
    members = []
    if estimator is not None:
        members.append(f"    {name}_estimator estimator;")
    if observer is not None:
        members.append(f"    {name}_observer observer;")
    members.append(
        "    unsigned long skipped; /* samples skipped for a non-finite input */"
    )
    law_name = type(controller.law).__name__
    biases = ""
    if estimator is not None:
        biases = (
            "\n   The accelerometers' biases start from the first sample's readings:"
            "\n   start it with the machine at rest (or export an estimator given"
            "\n   its readings at rest, VelocityEstimator(body_bias=, wheel_bias=))."
            if estimator.body_bias is None
            else "\n   The accelerometers' biases start from their readings at rest,"
            "\n   as the estimator was given them."
        )
        if "wheel_acceleration" not in p.inputs:
            biases += (
                "\n   No wheel accelerometer among the inputs: the estimator takes the"
                "\n   wheel's acceleration as 0 (the deflection rate from the deflection"
                "\n   sensor alone; a fixed ground, or a car's wheel not measured)."
            )
    header = f"""\
/* {name}.h: a semi-active controller exported by jaxmr {__version__}
   (jaxmr.export_c): {law_name}{" with a velocity estimator" if estimator else ""}\
{" and a damper observer" if observer else ""}.

   Sample period: {dt!r} s ({1 / dt:g} Hz). Call {name}_init once with the first
   sample's measurements, then {name}_step at every sample (the first included),
   every {dt!r} s; its command [A] is meant to act {delay} sample(s) later, as the
   controller was tuned. Dependency-free C99 (math.h), no allocation, double
   precision; the whole state is {name}_state.{biases}
   A sample with an input that is not finite (a sensor's dropout) is skipped, as
   the JAX controller skips it: the command is 0 A (the damper's passive state),
   the state is kept for the next sample, and {name}_state.skipped counts such
   samples (a status to watch). */
#ifndef {macro}_H
#define {macro}_H

#define {macro}_SAMPLE_PERIOD {literal(dt)} /* [s] */
#define {macro}_DELAY_SAMPLES {delay} /* between a command and its action */
#define {macro}_I_MAX {i_max} /* [A]: every command lies in [0, I_MAX] */

/* The measurements, in this order in `inputs` (SI units, as tuned). */
#define {macro}_N_INPUTS {len(p.inputs)}
{index}

{"".join(types)}
typedef struct {{
{chr(10).join(members)}
}} {name}_state;

/* The state before the first sample, from that sample's measurements. */
void {name}_init({name}_state *state, const double inputs[{macro}_N_INPUTS]);

/* The command [A] at this sample; advances the state. */
double {name}_step({name}_state *state, const double inputs[{macro}_N_INPUTS]);

#endif /* {macro}_H */
"""

    # The source.
    fields = ", ".join(p.readings)
    pieces = [
        f"/* {name}.c: generated by jaxmr {__version__} (jaxmr.export_c); see "
        f"{name}.h. Sample period {dt!r} s. */",
        f'#include <math.h>\n\n#include "{name}.h"',
        f"/* What the law reads at a sample: measurements and estimates. */\n"
        f"typedef struct {{ double {fields}; }} readings;",
    ]
    if estimator is not None:
        pieces.append(f"typedef {name}_estimator estimator;")
    if observer is not None:
        pieces.append(f"typedef {name}_observer observer;")
    else:
        pieces.append("typedef int observer; /* no observer */")
    pieces.append(_HELPERS.strip())
    if parts.nominal is not None:
        pieces.append(parts.nominal.hysteresis().strip())
        pieces.append(parts.nominal.dynamics().strip())
    if parts.inverse is not None:
        pieces.append(parts.inverse.hysteresis().strip())
    if estimator is not None:
        pieces.append(_estimator(estimator, dt, p.inputs, macro, positions).strip())
    if observer is not None:
        assert parts.nominal is not None
        pieces.append(_observer(observer, parts.nominal, dt, delay, force).strip())
    pieces.append(parts.law.code.strip())

    # The estimator's state before the first sample (VelocityEstimator.init).
    zero_estimator = (
        "    state->estimator.started = 0;\n"
        "    state->estimator.body_bias = state->estimator.wheel_bias = 0.0;\n"
        "    state->estimator.body_previous = 0.0;\n"
        "    state->estimator.relative_previous = 0.0;\n"
        "    state->estimator.relative_bias = 0.0;\n"
        "    state->estimator.body_velocity = 0.0;\n"
        "    state->estimator.displacement = 0.0;\n"
        "    state->estimator.damper_velocity = 0.0;"
        + ("\n    state->estimator.body_position = 0.0;" if positions else "")
    )

    # The readings at a sample, the observer brought to it, and the command.
    direct = "\n".join(
        f"    r->{n} = in[{macro}_IN_{n.upper()}];" for n in p.inputs if n in p.readings
    )
    estimate = "    estimator_step(e, in, r);" if estimator is not None else ""
    pieces.append(f"""\
/* The readings at this sample (the estimator's replace the measurements of the same
   name); advances the estimator `e`. */
static void read_inputs(const double *in, {"estimator *e" if estimator else "int e"}, \
readings *r)
{{
{direct}
{estimate if estimator else "    (void)e;"}
}}""")
    if observer is not None:
        force_arg = f", in[{macro}_IN_DAMPER_FORCE]" if force else ""
        model_force = "" if force else "\n    r->damper_force = observer_force(o);"
        pieces.append(f"""\
/* ObserverBasedController._observed: the observer brought to this sample; the
   model's force read as damper_force where no load cell measures one. */
static void observe(observer *o, const double *in, readings *r)
{{
    (void)in;
    observer_update(o, r->damper_displacement, r->damper_velocity{force_arg});\
{model_force}
}}""")
        estimator_arg = "&state->estimator" if estimator is not None else "0"
        init_estimator = (
            f"{zero_estimator}\n    probe_estimator = state->estimator;\n"
            if estimator is not None
            else ""
        )
        probe_decl = "    estimator probe_estimator;\n" if estimator is not None else ""
        probe_arg = "&probe_estimator" if estimator is not None else "0"
        pieces.append(f"""\
void {name}_init({name}_state *state, const double inputs[{macro}_N_INPUTS])
{{
    readings r;
    observer probe;
    double first;
{probe_decl}{init_estimator}\
    read_inputs(inputs, {probe_arg}, &r);
    observer_init(&probe, r.damper_displacement, r.damper_velocity, 0.0);
    observe(&probe, inputs, &r);
    first = clip(law_command(&r, &probe), 0.0, {i_max});
    observer_init(&state->observer, r.damper_displacement, r.damper_velocity, first);
    state->skipped = 0;
}}""")
        pieces.append(f"""\
double {name}_step({name}_state *state, const double inputs[{macro}_N_INPUTS])
{{
    readings r;
    double command;
    if (!all_finite(inputs, {macro}_N_INPUTS)) {{
        state->skipped += 1;
        observer_commanded(&state->observer, 0.0);
        return 0.0;
    }}
    read_inputs(inputs, {estimator_arg}, &r);
    observe(&state->observer, inputs, &r);
    command = clip(law_command(&r, &state->observer), 0.0, {i_max});
    observer_commanded(&state->observer, command);
    return command;
}}""")
    else:
        estimator_arg = "&state->estimator" if estimator is not None else "0"
        init_body = (zero_estimator + "\n" if estimator is not None else "") + (
            "    state->skipped = 0;"
        )
        pieces.append(f"""\
void {name}_init({name}_state *state, const double inputs[{macro}_N_INPUTS])
{{
    (void)inputs;
{init_body}
}}""")
        pieces.append(f"""\
double {name}_step({name}_state *state, const double inputs[{macro}_N_INPUTS])
{{
    readings r;
    if (!all_finite(inputs, {macro}_N_INPUTS)) {{
        state->skipped += 1;
        return 0.0;
    }}
    read_inputs(inputs, {estimator_arg}, &r);
    return clip(law_command(&r, 0), 0.0, {i_max});
}}""")
    source = _prune("\n\n".join(pieces) + "\n")
    return header, source


def export_c(
    controller,
    folder,
    *,
    name: str = "controller",
    measurements=None,
    force: bool = False,
) -> tuple[Path, Path]:
    r"""Write `controller` as dependency-free C99: `folder/<name>.h` and
    `folder/<name>.c`, with `<name>_init(state, inputs)` and
    `command = <name>_step(state, inputs)` over the fixed-size struct `<name>_state`
    (no allocation; only math.h), the sample period stated as
    `<NAME>_SAMPLE_PERIOD` [s] and in the header's comment.

    The step does the same arithmetic as the JAX controller's, in double precision:
    the `VelocityEstimator`'s filters (with its leaky position integral where the
    law reads positions), the `DamperObserver`'s RK4 substeps on its
    nominal damper (current laws, the coil's `FirstOrderLag`), its correction by a
    measured force and its bounds, the law's inverse model on the observed state,
    and the clip to $[0, I_\max]$. `tests/test_export.py` checks that the compiled
    C and the JAX controller give the same commands to 1e-9 A.

    Supported: an `ObserverBasedController` (not `oracle`) with a
    `VelocityEstimator` or none, a `DamperObserver` over a `BoucWen`,
    `NormalizedBoucWen`, `BoucWenBaberNoori`, `Spencer`, `ShearThinningSpencer`,
    `Dahl`, `LuGre` or `Bingham` damper (parameters numbers or `LinearLaw`,
    `ConstantLaw`, `ExponentialLaw`, `PolynomialLaw`; current dynamics none or
    `FirstOrderLag`) or none, and the laws `Skyhook`, `OnOffSkyhook`, `Groundhook`,
    `OnOffGroundhook`, `Hybrid`, `ClippedOptimal` (its damper force measured or the
    observer's), `ContinuousClippedOptimal` (both clipped-optimal laws on a measured
    state or on the estimator's, its positions included) and `ForceFeedback`
    (`linear` or `mlp`), hard or relaxed. Anything else raises `NotImplementedError` naming its
    class and what is supported; `export_stablehlo` exports any controller for an
    XLA runtime.

    **Arguments:**

    - `controller`: the tuned `ObserverBasedController`.
    - `folder`: where to write (made if missing).
    - `name`: a C identifier, the files' and the functions' prefix; default
      `"controller"`.
    - `measurements`: the measurement names the controller reads, in the order of
      the C `inputs` array (or a `jaxmr.Sensors` set: its names); what is measured
      changes the arithmetic (a wheel accelerometer, a load cell's `damper_force`).
      Default: with an estimator the quarter car's realistic sensors
      (`body_acceleration`, `wheel_acceleration`, `damper_displacement`), without
      one what the law and the observer read (a law's `features`; `time` for an
      open-loop law such as `CurrentSchedule`; otherwise `body_velocity` and
      `damper_velocity`).
    - `force`: replace existing files (default False: an existing file is an error
      and nothing is written). Each file is written whole or not at all.

    **Returns:** the paths of the header and the source.
    """
    header, source = c_source(controller, name, measurements)
    written = write_outputs(
        Path(folder), {f"{name}.h": header, f"{name}.c": source}, force=force
    )
    return written[0], written[1]
