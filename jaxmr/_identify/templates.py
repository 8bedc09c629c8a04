r"""Model templates: a constrained initial guess for each model family, scaled from data.

`MODEL_TEMPLATES[name](experiments)` gives a model ready for `jaxmr.fit`: its free
parameters wrapped in `Positive` (they are all physically positive, and a log-scaled
variable makes a step a relative change; the normalised Bouc–Wen's shape σ in
`Bounded`), the redundant or unneeded ones `Fixed`, and
the current-dependent ones as `LinearLaw`s in the input (current [A] or voltage [V])
when the experiments span more than one input level (with a single level a slope could
not be identified).

The initial values come from the data, by linear least squares over all samples (each
experiment weighted by 1/std(F), as `fit` weights them) of
$F \approx f(i)\,s + c(i)\,v + f_0$ with $f$, $c$ linear in the input and a shape
signal $s$ in [−1, 1]:

- for the Bingham template $s = \tanh(v/v_s)$, with $v_s$ the best of a few fractions
  (1–40 %) of the velocity amplitude;
- for the hysteretic templates $s$ is the Dahl state run along the measured
  displacement, $dz = (\mathrm{sgn}(dx) - z)(1 - e^{-|dx|/x_s})$ from $z = 0$, with
  the saturation displacement $x_s$ the best of a few fractions (2–40 %) of the
  smallest displacement amplitude. A hysteretic state lags the velocity: a device
  whose force flips well after each reversal (the SAS brake: about 0.5° after it, at
  half the peak velocity) looks viscous to a function of the velocity, and a guess
  from the Bingham regression started such fits far off (α at its floor, c0 at its
  ceiling).

$f$ and $c$ are clipped to physically sensible ranges of the force and velocity
amplitudes. Each template maps them onto its parameters ($\alpha \approx f$ with the
state scaled to saturate at ±1, $c_0 \approx c$, and the state's rate $1/x_s$).

A rotary brake reads the same with angle [rad], angular velocity [rad/s] and torque
[N·m].
"""

from collections.abc import Callable, Sequence
from typing import NamedTuple

import equinox as eqx
import numpy as np

from .._channel import ChannelDelay
from .._current_dynamics import FirstOrderLag
from .._current_law import ExponentialLaw, LinearLaw, PolynomialLaw, SaturatingLaw
from .._damper import Damper
from .._hysteresis import (
    AbstractHysteresis,
    Bingham,
    BoucWen,
    Dahl,
    LuGre,
    NormalizedBoucWen,
    ShearThinningSpencer,
    Spencer,
)
from .._parameter import Bounded, Fixed, Positive
from .data import StepPolicy, experiment_list

# Candidates for the displacement over which the hysteretic state saturates, as
# fractions of the smallest displacement amplitude (MR fluids yield within a fraction
# of the stroke, so that the state saturates in every test).
SATURATION_FRACTIONS = (0.02, 0.05, 0.1, 0.2, 0.4)
# The saturation displacement is at least this many times the travel of one default
# step (`StepPolicy`): the state's rate |v|/x_s then stays below 1/4 per step, well
# inside fixed-step RK4's stability limit (2.8).
STEPS_PER_SATURATION = 4.0
# Candidates for the smooth Bingham law's velocity scale, as fractions of the velocity
# amplitude.
VELOCITY_SCALE_FRACTIONS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.4)
# Relative floor of a positive parameter's initial value (Positive needs > 0, and a
# slope of a law that the data show as flat still needs a value to start from).
FLOOR = 0.02


class DataScales(NamedTuple):
    """Characteristic magnitudes of a set of experiments (SI units)."""

    force: float
    """Median over the experiments of the force amplitude [N] (half the 1–99 %
    percentile range)."""
    displacement: float
    """Smallest displacement amplitude [m] (half the peak-to-peak)."""
    velocity: float
    """Median velocity amplitude [m/s] (the 99th percentile of |v|)."""
    velocity_scale: float
    """$v_s$ [m/s] of the smooth Bingham law that fits the data best."""
    current_min: float
    """Smallest input [A or V] over all samples."""
    current_max: float
    """Largest input [A or V] over all samples."""
    yield_force: tuple[float, float]
    """$f_c$ at `current_min` and `current_max` [N], from the Bingham regression."""
    viscous: tuple[float, float]
    """$c_0$ at `current_min` and `current_max` [N·s/m], from the Bingham regression."""
    saturation: float
    """$x_s$ [m] of the Dahl-state regression that fits the data best."""
    hysteretic_force: tuple[float, float]
    """The force at a saturated state, at `current_min` and `current_max` [N], from the
    Dahl-state regression."""
    hysteretic_viscous: tuple[float, float]
    """The viscous coefficient at `current_min` and `current_max` [N·s/m], from the
    Dahl-state regression."""

    @property
    def varying_current(self) -> bool:
        return self.current_max > self.current_min


def _columns(e):
    t = np.asarray(e.t, dtype=float)
    x = np.asarray(e.x, dtype=float)
    v = np.asarray(e.v, dtype=float)
    i = np.broadcast_to(np.asarray(e.current, dtype=float), t.shape)
    force = getattr(e, "force", None)
    if force is None:
        name = getattr(e, "name", "")
        raise ValueError(
            f"experiment {name!r} has no measured force: a template is scaled from the "
            "force (the `F` or `T` column)."
        )
    return t, x, v, i, np.asarray(force, dtype=float)


def _half_range(a) -> float:
    lo, hi = np.percentile(a, [1.0, 99.0])
    return 0.5 * float(hi - lo)


def data_scales(experiments: Sequence) -> DataScales:
    """The magnitudes a template scales its initial guess by (see the module docstring).

    **Arguments:** `experiments`, `jaxmr.data.Experiment`s with force (or anything with
    `t`, `x`, `v`, `current`, `force`).

    **Returns:** a `DataScales`.
    """
    experiments = experiment_list(experiments)
    if not experiments:
        raise ValueError("`experiments` is empty: give at least one experiment.")
    columns = [_columns(e) for e in experiments]
    force = float(np.median([_half_range(c[4]) for c in columns]))
    displacement = float(min(0.5 * np.ptp(c[1]) for c in columns))
    velocity = float(np.median([np.percentile(np.abs(c[2]), 99.0) for c in columns]))
    if not (force > 0 and displacement > 0 and velocity > 0):
        raise ValueError(
            "the experiments need a varying force and a moving displacement to scale a "
            f"template from (force amplitude {force:g}, displacement amplitude "
            f"{displacement:g}, velocity amplitude {velocity:g})."
        )
    i_all = np.concatenate([c[3] for c in columns])
    i_min, i_max = float(np.min(i_all)), float(np.max(i_all))
    c_scale = force / velocity

    def best(signals_by_candidate):
        fits = [
            _regression(columns, signals, i_min, i_max)
            for signals in signals_by_candidate
        ]
        k = int(np.argmin([f[2] for f in fits]))
        f, c, _ = fits[k]
        f = tuple(float(a) for a in np.clip(f, FLOOR * force, 3 * force))
        c = tuple(float(a) for a in np.clip(c, 1e-3 * c_scale, c_scale))
        return k, f, c

    # The smooth sign's velocity scale: MR devices differ (a sharp yield, or a gradual
    # one as shear-thinning fluids give).
    v_scales = [fraction * velocity for fraction in VELOCITY_SCALE_FRACTIONS]
    k, yield_force, viscous = best(
        [[np.tanh(c[2] / v_s) for c in columns] for v_s in v_scales]
    )
    policy = StepPolicy()
    floor = STEPS_PER_SATURATION * max(
        policy.step_travel(c[2], bool(getattr(e, "rotary", False)))
        for c, e in zip(columns, experiments)
    )
    saturations = sorted(
        {
            float(max(fraction * displacement, floor))
            for fraction in SATURATION_FRACTIONS
        }
    )
    j, hysteretic_force, hysteretic_viscous = best(
        [[_dahl_state(c[1], x_s) for c in columns] for x_s in saturations]
    )
    return DataScales(
        force=force,
        displacement=displacement,
        velocity=velocity,
        current_min=i_min,
        current_max=i_max,
        velocity_scale=v_scales[k],
        yield_force=yield_force,  # pyright: ignore[reportArgumentType]  # pairs from `best`
        viscous=viscous,  # pyright: ignore[reportArgumentType]  # pairs from `best`
        saturation=saturations[j],
        hysteretic_force=hysteretic_force,  # pyright: ignore[reportArgumentType]  # pairs from `best`
        hysteretic_viscous=hysteretic_viscous,  # pyright: ignore[reportArgumentType]  # pairs from `best`
    )


def _dahl_state(x, saturation: float) -> np.ndarray:
    r"""The Dahl state along the samples of `x`, exact for piecewise-linear motion
    between them: $z \to \mathrm{sgn}(dx) + (z - \mathrm{sgn}(dx)) e^{-|dx|/x_s}$."""
    dx = np.diff(x)
    targets = np.sign(dx).tolist()
    decays = np.exp(-np.abs(dx) / saturation).tolist()
    z, out = 0.0, [0.0]
    # A linear recurrence with varying coefficients: a plain loop (its cumulative
    # product form underflows on long records).
    for target, decay in zip(targets, decays):
        z = target + (z - target) * decay
        out.append(z)
    return np.asarray(out)


def _regression(columns, signals, i_min, i_max):
    """$f$ and $c$ at the smallest and largest input, and the residual, by weighted
    linear least squares of $F = (f_a + f_b i) s + (c_a + c_b i) v + f_0$."""
    varying = i_max > i_min
    rows, rhs = [], []
    for (_, _, v, i, f), s in zip(columns, signals):
        w = 1.0 / (max(float(np.std(f)), 1e-300) * np.sqrt(len(f)))
        # The input scaled to [0, 1], so the columns are of one magnitude.
        u = (i - i_min) / (i_max - i_min) if varying else np.zeros_like(i)
        features = [s, v, np.ones_like(v)]
        if varying:
            features += [u * s, u * v]
        rows.append(w * np.stack(features, axis=1))
        rhs.append(w * f)
    matrix, target = np.concatenate(rows), np.concatenate(rhs)
    coef, *_ = np.linalg.lstsq(matrix, target, rcond=None)
    f_a, c_a = coef[0], coef[1]
    f_b, c_b = (coef[3], coef[4]) if varying else (0.0, 0.0)
    residual = float(np.sum((matrix @ coef - target) ** 2))
    return (f_a, f_a + f_b), (c_a, c_a + c_b), residual


def _law(at_min: float, at_max: float, scales: DataScales):
    """A positive parameter: a `LinearLaw` through the values at the smallest and
    largest input with positive intercept and slope, or a constant with one input
    level."""
    if not scales.varying_current:
        return Positive(max(at_min, at_max))
    return LinearLaw(*map(Positive, _line(at_min, at_max, scales)))


def _line(at_min: float, at_max: float, scales: DataScales) -> tuple[float, float]:
    """`_law`'s intercept and slope (numbers, both positive), for varying input."""
    span = scales.current_max - scales.current_min
    top = max(at_min, at_max)
    slope = max((at_max - at_min) / span, FLOOR * top / span)
    intercept = max(at_min - slope * scales.current_min, FLOOR * top)
    return intercept, slope


def bingham(experiments: Sequence) -> Bingham:
    r"""Smooth Bingham: $F = f_c(i)\tanh(v/v_s) + c_0(i) v$; $v_s$ fixed at the
    regression's best, no offset."""
    s = data_scales(experiments)
    return Bingham(
        f_c=_law(*s.yield_force, s),
        c0=_law(*s.viscous, s),
        f0=Fixed(0.0),
        velocity_scale=Fixed(s.velocity_scale),
    )


def bouc_wen(experiments: Sequence) -> BoucWen:
    r"""Bouc–Wen, $F = \alpha(i) z + c_0(i) v + k_0 x + f_0$, with $A = 1/x_s$ fixed
    (removing the $(\alpha, A, \beta, \gamma)$ redundancy) and $\beta = \gamma =
    A/2$, $n = 1$ to start: $z$ saturates at $\pm 1$ over $x_s$ (and after a reversal
    crosses zero at $x_s$), so $\alpha$ starts at the hysteretic force. The
    accumulator's stiffness $k_0$ and force offset $f_0$ free (`accumulator_stiffness`), $x_0$
    fixed at 0 (it would repeat $f_0$)."""
    s = data_scales(experiments)
    A = 1.0 / s.saturation
    return BoucWen(
        alpha=_law(*s.hysteretic_force, s),
        c0=_law(*s.hysteretic_viscous, s),
        A=Fixed(A),
        beta=Positive(0.5 * A),
        gamma=Positive(0.5 * A),
        n=Positive(1.0),
        k0=accumulator_stiffness(s),
        x0=Fixed(0.0),
        f0=0.0,
    )


def normalized_bouc_wen(experiments: Sequence) -> NormalizedBoucWen:
    r"""Normalised Bouc–Wen, $F = \kappa_w(i) w + c_0(i) v$, $\rho = 1/x_s$,
    $\sigma = 1/2$ (kept in (0, 1)), $n = 1$ to start; $\kappa_x$, $x_0$, $f_0$ fixed
    at 0. The same start as `bouc_wen`'s."""
    s = data_scales(experiments)
    return NormalizedBoucWen(
        kappa_x=Fixed(0.0),
        kappa_w=_law(*s.hysteretic_force, s),
        c0=_law(*s.hysteretic_viscous, s),
        rho=Positive(1.0 / s.saturation),
        # σ in (0, 1) is β, γ ≥ 0 of `BoucWen`, the family of the `bouc_wen` template;
        # unbounded, fits drifted to σ ~ 1e4, whose recovery rate ~2σρ|v| after a
        # reversal is too stiff for the fixed-step integrator on faster held-out tests.
        sigma=Bounded(0.5, 0.0, 1.0),
        n=Positive(1.0),
        x0=Fixed(0.0),
        f0=Fixed(0.0),
    )


def dahl(experiments: Sequence) -> Dahl:
    r"""Dahl, $F = k_x(i) v + k_w(i) z$: the Dahl-state regression itself, $\rho =
    1/x_s$."""
    s = data_scales(experiments)
    return Dahl(
        k_x=_law(*s.hysteretic_viscous, s),
        k_w=_law(*s.hysteretic_force, s),
        rho=Positive(1.0 / s.saturation),
    )


def lugre(experiments: Sequence) -> LuGre:
    r"""LuGre with $F_c(i)$, $F_s(i) = 1.2 F_c(i)$, $\sigma_2(i)$ laws; the bristles
    deflect over $x_s$ ($\sigma_0 = F_c/x_s$), Stribeck velocity 10 % of the velocity
    amplitude. The bristle damping $\sigma_1$ is fixed at 0: it acts only during the
    bristles' micro-deflection, which force measurements of MR devices do not resolve
    (a free $\sigma_1$ is not identified)."""
    s = data_scales(experiments)
    f_lo, f_hi = s.hysteretic_force
    return LuGre(
        sigma0=Positive(max(f_lo, f_hi) / s.saturation),
        sigma1=Fixed(0.0),
        sigma2=_law(*s.hysteretic_viscous, s),
        F_c=_law(f_lo, f_hi, s),
        F_s=_law(1.2 * f_lo, 1.2 * f_hi, s),
        v_s=Positive(0.1 * s.velocity),
    )


def accumulator_stiffness(s: DataScales) -> Positive:
    r"""The stiffness of a damper's gas accumulator to start from: 2 % of the force
    over the displacement amplitude. The templates with hysteresis fit it and the
    force offset of the accumulator's pre-charge (Spencer's $k_1 (x - x_0)$,
    Bouc–Wen's $k_0 x + f_0$). Real dampers have both; without them, the `spencer`
    template fitted to simulated sine tests of Spencer et al.'s (1997) damper, whose
    accumulator pushes 72 N, ended at a median NRMSE of 0.13, with them at 0.03, the
    noise being 0.02 (2026-11-24)."""
    return Positive(FLOOR * s.force / s.displacement)


def _spencer_start(s: DataScales) -> dict:
    r"""What the Spencer templates' starts share: $c_0(i)$ and $c_1(i)$ laws, $c_1 =
    10 f / v_\mathrm{amp}$ (the low-velocity roll-off at a tenth of the velocity
    amplitude), $k_0$ fixed at 0 and $A = 1/x_s$ fixed."""
    f_lo, f_hi = s.hysteretic_force
    rolloff = 0.1 * s.velocity
    return dict(
        c0=_law(*s.hysteretic_viscous, s),
        k0=Fixed(0.0),
        c1=_law(f_lo / rolloff, f_hi / rolloff, s),
        A=Fixed(1.0 / s.saturation),
    )


def spencer(experiments: Sequence) -> Spencer:
    r"""Spencer's model with $\alpha(i)$, $c_0(i)$, $c_1(i)$ linear in the input
    (current or voltage; no input filter). $A = 1/x_s$ fixed, $\beta = \gamma = A/2$,
    $n = 2$ to start, so $\alpha$ starts at the hysteretic force; $c_1 = 10 f /
    v_\mathrm{amp}$ puts the low-velocity roll-off at a tenth of the velocity
    amplitude. The accumulator $k_1$, $x_0$ free (`accumulator_stiffness`), $k_0$ fixed at 0."""
    s = data_scales(experiments)
    half_A = 0.5 / s.saturation
    return Spencer(
        alpha=_law(*s.hysteretic_force, s),
        k1=accumulator_stiffness(s),
        x0=0.0,
        gamma=Positive(half_A),
        beta=Positive(half_A),
        n=Positive(2.0),
        **_spencer_start(s),
    )


def _curved_law(at_min: float, at_max: float, scales: DataScales):
    """A quadratic law through the values at the smallest and largest input, no
    curvature to start (MR yield stress saturates with field: the fit bends it), or a
    positive constant with one input level."""
    if not scales.varying_current:
        return Positive(max(at_min, at_max))
    # The line's numbers, not its `Positive`s' values: each `.value()` an eager
    # program compiled in a fresh process.
    a, b = _line(at_min, at_max, scales)
    return PolynomialLaw(np.array([a, b, 0.0]))


def _saturation_law(value: float, scales: DataScales, input_varies: bool):
    r"""A positive shape parameter ($\beta$, $\gamma$) that may vary exponentially
    with the input ($a e^{b i}$, $b$ = 0 to start), or a positive constant with one
    input level or an input that varies within an experiment.

    Why not a law under a time-varying input: $z$ stays within
    $\pm(A/(\beta+\gamma))^{1/n}$ only while $\beta$ and $\gamma$ hold still.
    When the input drops and that bound shrinks, a $z$ saturated at the old input
    lies outside it, and with $\beta > \gamma$ it then grows without bound in finite
    time. A shear-thinning Spencer model fitted to the first part of the NEES
    ranran_50 record ($\beta(i)$ over five decades) did exactly that on the rest.
    Spencer et al. (1997) kept both constant for the same kind of record."""
    if not scales.varying_current or input_varies:
        return Positive(value)
    return ExponentialLaw(Positive(value), 0.0)


def shear_thinning_spencer(experiments: Sequence) -> ShearThinningSpencer:
    r"""Spencer's model with shear-thinning dashpots and per-current laws: $\alpha(i)$
    quadratic, $c_0(i)$, $c_1(i)$ linear, $\beta(i)$, $\gamma(i)$ exponential in the
    input (the structure of the published UTFSM model, which needed them; constant
    when the input varies within an experiment, see `_saturation_law`), the
    accumulator $k_1$ and its offset $x_0$ free, $c_0$ thinning with velocity
    ($e_0$, halving at the velocity amplitude to start; $e_1$ = 0 fixed, see
    `ShearThinningSpencer`). $A = 1/x_s$ and $n = 2$ fixed, $\beta = \gamma = A/2$ to
    start, $k_0$ fixed at 0; the rest as `spencer`."""
    s = data_scales(experiments)
    half_A = 0.5 / s.saturation
    varies = input_varies_in_time(experiments)
    return ShearThinningSpencer(
        alpha=_curved_law(*s.hysteretic_force, s),
        k1=accumulator_stiffness(s),
        x0=0.0,
        gamma=_saturation_law(half_A, s, varies),
        beta=_saturation_law(half_A, s, varies),
        n=Fixed(2.0),
        **_spencer_start(s),
        e0=Positive(1.0 / s.velocity),
        e1=Fixed(0.0),
    )


# The coil and driver lag's rate to start from [1/s]: a time constant of 5 ms, the
# order of MR dampers' measured response times (Spencer et al. 1997: 190 1/s).
LAG_RATE = 200.0


def with_lag(template: Callable[[Sequence], AbstractHysteresis]):
    """A template whose model sees its input through a fitted first-order lag
    (`Damper(model, FirstOrderLag(rate))`, rate free from `LAG_RATE`): for inputs
    that vary within an experiment (the voltage of a random on/off test)."""

    def lagged(experiments: Sequence) -> Damper:
        return Damper(template(experiments), FirstOrderLag(Positive(LAG_RATE)))

    lagged.__name__ = f"{template.__name__}_lag"
    lagged.__doc__ = f"`{template.__name__}` behind a fitted first-order input lag."
    return lagged


# `with_saturation` starts each law's input scale i0 at this multiple of the largest
# input: its rise over the inputs is then within 15 % of the template's line
# (3 (1 - e^(-1/3)) = 0.85 of it at the largest), and the fit bends it as far as the
# data ask.
SATURATION_START = 3.0
# With two input levels (a default candidate on a cross-validation fold that holds
# the middle one of three out), a saturating law's input scale cannot be fitted: it
# is fixed at SATURATION_PRIOR × the largest input, the law through the template's
# values at zero and at the largest input. A physical prior, not a fitted value: a
# damper driven to its rated input gets about 86 % of the way to its saturated
# force (1 - e^-2), so the fold tests whether the force bends as an MR damper's
# typically does, against the straight law's interpolation. (Chosen before any run:
# saturation_choice_rule.md.)
SATURATION_PRIOR = 0.5


def with_saturation(
    template: Callable[[Sequence], AbstractHysteresis | Damper],
    fields: Sequence[str],
    *,
    strict: bool = True,
):
    """A template whose linear current laws in `fields` (names of the hysteresis
    model's parameters, e.g. `("alpha",)` for a Bouc–Wen or Spencer model's
    hysteretic force, `("f_c",)` for Bingham's yield force) saturate instead: each
    becomes a `SaturatingLaw` with the template's value and slope at zero input and a
    free input scale i0 started at `SATURATION_START` × the largest input (nearly the
    line). For a damper whose force levels off with current; it needs 3 or more
    input levels (3 parameters per law): with fewer, `strict=True` raises, and
    `strict=False` (the default candidates `*_saturating`) fixes i0 at
    `SATURATION_PRIOR` × the largest input with 2 levels (a fold that holds one of
    3 out) and gives the template's model unchanged with 1. Only the laws named:
    a law the data show straight (a viscous coefficient, often) would have an
    undetermined i0."""
    fields = (fields,) if isinstance(fields, str) else tuple(fields)
    if not fields:
        raise ValueError("with_saturation: name at least one field, e.g. ('alpha',).")

    def saturating(experiments: Sequence):
        experiments = experiment_list(experiments)
        levels = input_levels(experiments)
        if len(levels) < 2 and not strict:
            return template(experiments)
        if len(levels) < 3 and strict:
            raise ValueError(
                f"with_saturation: a saturating law has 3 parameters and the "
                f"experiments have {len(levels)} input level(s); give 3 or more."
            )
        top = max(float(np.max(np.abs(np.asarray(e.current)))) for e in experiments)
        model = template(experiments)
        inner = model.hysteresis if isinstance(model, Damper) else model
        for field in fields:
            law = getattr(inner, field, None)
            if not (isinstance(law, LinearLaw) and isinstance(law.b, Positive)):
                raise ValueError(
                    f"with_saturation: `{field}` of the template's "
                    f"{type(inner).__name__} is not a linear law with a free slope "
                    f"(got {type(law).__name__}); name a field that is."
                )
            if len(levels) >= 3:
                bent = SaturatingLaw(law.a, law.b, Positive(SATURATION_START * top))
            else:  # the prior's input scale, through the line's value at the top
                i0 = SATURATION_PRIOR * top
                slope = float(law.b.value()) * top / (i0 * -np.expm1(-top / i0))
                bent = SaturatingLaw(law.a, Positive(slope), Fixed(i0))
            inner = eqx.tree_at(lambda m, f=field: getattr(m, f), inner, bent)
        if isinstance(model, Damper):
            return eqx.tree_at(lambda d: d.hysteresis, model, inner)
        return inner

    name = getattr(template, "__name__", "model")
    saturating.__name__ = f"{name}_saturating"
    saturating.__doc__ = f"`{name}` with saturating laws for {', '.join(fields)}."
    return saturating


# The largest force-channel delay a fit with `with_channel_delay` considers [s]: a few
# milliseconds is what load-cell amplifiers' filters and multiplexed acquisition
# cause; at least `CHANNEL_DELAY_SAMPLES` sample intervals for slowly sampled data.
CHANNEL_DELAY_BOUND = 0.01
CHANNEL_DELAY_SAMPLES = 5


def channel_delay_bound(experiments: Sequence) -> float:
    """The bound [s] on |τ| of a fitted `ChannelDelay` for these experiments."""
    intervals = [
        float(np.median(np.diff(np.asarray(e.t, dtype=float)))) for e in experiments
    ]
    return max(CHANNEL_DELAY_BOUND, CHANNEL_DELAY_SAMPLES * max(intervals))


def with_channel_delay(template: Callable[[Sequence], AbstractHysteresis | Damper]):
    """A template whose model is seen through a fitted force-channel delay
    (`ChannelDelay(model, Bounded(0, -b, b))`, b from `channel_delay_bound`), for rigs
    whose force and motion channels are skewed."""

    def delayed(experiments: Sequence) -> ChannelDelay:
        b = channel_delay_bound(experiments)
        return ChannelDelay(template(experiments), Bounded(0.0, -b, b))

    name = getattr(template, "__name__", "model")
    delayed.__name__ = f"{name}_channel_delay"
    delayed.__doc__ = f"`{name}` seen through a fitted force-channel delay."
    return delayed


def input_levels(experiments: Sequence) -> list[float]:
    """The distinct input levels [A or V] of these experiments (each one's mean
    input, to 9 decimals), sorted: what `cv_folds` holds out and a saturating law
    needs 3 of."""
    return sorted(
        {round(float(np.mean(np.asarray(e.current))), 9) for e in experiments}
    )


def saturating_candidates(experiments: Sequence) -> list[str]:
    """The `_saturating` variants (`SATURATING_FIELDS`) that apply to these
    experiments: none with fewer than 3 input levels, the `_lag` ones only where
    the input varies within an experiment."""
    experiments = experiment_list(experiments)
    if len(input_levels(experiments)) < 3:
        return []
    varies = input_varies_in_time(experiments)
    return [
        f"{name}_saturating"
        for name in SATURATING_FIELDS
        if varies or not name.endswith("_lag")
    ]


def input_varies_in_time(experiments: Sequence) -> bool:
    """Whether the input changes within an experiment (not only between them)."""
    for e in experiments:
        i = np.ravel(np.asarray(e.current, dtype=float))
        if i.size > 1 and np.ptp(i) > 1e-6 * max(1.0, float(np.max(np.abs(i)))):
            return True
    return False


# The default candidates of `select_model` and `jaxmr fit --model auto`: one of each
# family the library has, simplest first (the order of `select_model`'s parsimony
# rule). Chosen from a six-dataset table (benchmarks/README.md, "generalisation":
# held-out NRMSE of plain fits on the UTFSM damper and simulated presets with white
# and AR(1) noise), NOT yet by a finished leave-one-dataset-out: Dahl won or tied on
# 2 dampers, LuGre came second on 2, shear-thinning Spencer won on UTFSM, and the
# narrower Bouc-Wen/Spencer set lost badly on an unseen damper where LuGre won
# (issue 25). Bingham never won; it stays as the memoryless baseline, and it is
# cheap.
DEFAULT_CANDIDATES = (
    "bingham",
    "dahl",
    "lugre",
    "bouc_wen",
    "spencer",
    "shear_thinning_spencer",
)
"""The default candidates (template names) of `select_model` and `jaxmr fit --model
auto`, one per family, simplest first (see `default_candidates`)."""
DEFAULT_LAG_CANDIDATES = ("bouc_wen_lag", "spencer_lag", "shear_thinning_spencer_lag")
"""The default candidates added when the input varies within an experiment: the
variants behind a fitted first-order input lag (see `default_candidates`)."""


def default_candidates(experiments: Sequence) -> list[str]:
    """The default candidates (template names) of `jaxmr.select_model` and `jaxmr fit
    --model auto` for these experiments: `DEFAULT_CANDIDATES` (Bingham, Dahl, LuGre,
    Bouc–Wen, Spencer, shear-thinning Spencer, simplest first), their `_lag`
    variants (`DEFAULT_LAG_CANDIDATES`) when `input_varies_in_time`, and with 3 or
    more input levels the `_saturating` variants (`saturating_candidates`).

    The families were chosen from a six-dataset table of held-out NRMSE
    (benchmarks/README.md, "generalisation"), not by a finished
    leave-one-dataset-out; the saturating variants joined by the rule of
    benchmarks/saturation_choice_rule.md, on 16 datasets (session 29: the former
    defaults' worst regret 4.85 on two dampers whose force levels off, 0.23 with
    them)."""
    names: list[str] = list(DEFAULT_CANDIDATES)
    if input_varies_in_time(experiments):
        names += list(DEFAULT_LAG_CANDIDATES)
    return names + saturating_candidates(experiments)


# The force-level laws of each family that its `_saturating` variant bends
# (`with_saturation`): the hysteretic force (Bouc–Wen's and Spencer's alpha, Dahl's
# k_w) or the friction levels (LuGre's F_c and F_s). Bingham has none that the
# others lack (its yield force is a function of the velocity alone), and the
# shear-thinning Spencer's alpha is already curved (a quadratic).
SATURATING_FIELDS = {
    "dahl": ("k_w",),
    "lugre": ("F_c", "F_s"),
    "bouc_wen": ("alpha",),
    "spencer": ("alpha",),
    "bouc_wen_lag": ("alpha",),
    "spencer_lag": ("alpha",),
}
"""The templates with a `_saturating` variant in `MODEL_TEMPLATES` (`bouc_wen_saturating`
is `with_saturation(bouc_wen, ("alpha",), strict=False)`), and the laws each bends."""

MODEL_TEMPLATES: dict[str, Callable[[Sequence], AbstractHysteresis | Damper]] = {
    "bingham": bingham,
    "bouc_wen": bouc_wen,
    "normalized_bouc_wen": normalized_bouc_wen,
    "dahl": dahl,
    "lugre": lugre,
    "spencer": spencer,
    "shear_thinning_spencer": shear_thinning_spencer,
    "bouc_wen_lag": with_lag(bouc_wen),
    "spencer_lag": with_lag(spencer),
    "shear_thinning_spencer_lag": with_lag(shear_thinning_spencer),
}
MODEL_TEMPLATES.update(
    {
        f"{name}_saturating": with_saturation(
            MODEL_TEMPLATES[name], fields, strict=False
        )
        for name, fields in SATURATING_FIELDS.items()
    }
)
"""Model templates by name: `MODEL_TEMPLATES[name](experiments)` is a constrained
initial guess for `jaxmr.fit`, scaled from the experiments."""
