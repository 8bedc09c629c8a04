"""The data a fit sees: measured experiments packed into lanes of RK4 steps.

Every experiment is integrated with its own step, chosen by a `StepPolicy` from its
own sample interval and peak velocity, and experiments of different lengths are not
padded to the longest: their steps are laid end to end in a few *lanes* (one
`lax.scan` each, the lanes vectorised with `vmap`), the state reset to the virgin state
where each experiment begins. A lane per experiment is the padded layout; one lane for
all is fully packed; in between, longest-first assignment balances the lanes' lengths.
The motion, the input and their stage values at every RK4 stage are computed here once
(they do not depend on the parameters), so the scan does no lookups.

NumPy in, arrays out: this runs once per fit, outside jit.
"""

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Bool, Float, Int
from .._damper import fitted_range_in
from .._integrate import FixedStep
from .._misc import to_device
from .._signal import _hermite, _hermite_slope
from ..data._experiment import check_columns

# Default step limits per kind of device (see `StepPolicy`): (longest step [s], most
# travel per step [m or rad], None: no travel limit).
DEFAULT_LIMITS = {"linear": (2.5e-3, 2.5e-5), "rotary": (5e-4, None)}


class StepPolicy(eqx.Module):
    r"""How long the fixed RK4 steps of a fit, a prediction or a score are, per
    experiment.

    Each sample interval is divided into the fewest equal steps for which a step is at
    most `max_step` [s] long and the piston (rotor) travels at most `max_travel` at the
    peak speed of the motion simulated in it, the cubic Hermite interpolant of the
    displacement and velocity columns (which is the larger of the interval's end
    velocities where the two columns agree; on the 30 UTFSM records it adds 10 steps
    to 685 369, and where x steps and v does not, it keeps the step stable).

    The defaults differ by device, each measured where it applies:

    - linear dampers: 2.5 ms and 25 µm. A hysteretic state that relaxes over a
      displacement has rates proportional to $|v|$, so travel bounds the error where
      the damper moves fast: the published UTFSM Spencer model at 0 A, whose force
      jumps within 30 µm of travel after a reversal, needs 25 µm (1 ms steps at
      77 mm/s diverge). On the 30 UTFSM records this takes 0.69 M steps, where
      uniform steps of 25 µm at each record's peak speed take 1.14 M, for the same
      loss to 4 digits. 2.5 ms integrates a coil lag of 190 1/s at η·h ≤ 0.5.
    - rotary brakes: 0.5 ms and no travel limit. The SAS brake (γ ≪ β) errs most
      where z crosses zero just after a reversal, at low speed, so time bounds the
      error there (travel-limited steps of 2e-4 rad, long near reversals, left
      1.9e-3 of the peak torque); and a brake may turn continuously (a rotor at
      150 rpm), where a travel limit would take thousands of steps per sample for
      nothing. At 1 Hz, ±3.5° sampled at 250 Hz–1 kHz the brake is then within 4e-5
      of its peak torque of an adaptive Dopri8 solve at rtol 1e-8 (asserted < 1e-4 in
      tests/test_identify_engine.py), far below measurement noise (~1 %).

    **Arguments:**

    - `max_step`: the longest step [s] (`None`: the device's default).
    - `max_travel`: the most travel per step, in the motion's unit ([m], or [rad] for
      a rotary device); `None`: the device's default.
    - `substeps`: a fixed number of steps per sample interval for every experiment
      instead (the limits are then ignored), e.g. to reproduce `FixedStep(k)`.
    - `refinement`: every step divided into this many (see `refined`).
    """

    max_step: float | None = eqx.field(static=True, default=None)
    max_travel: float | None = eqx.field(static=True, default=None)
    substeps: int | None = eqx.field(static=True, default=None)
    refinement: int = eqx.field(static=True, default=1)

    def __check_init__(self):
        for name in ("max_step", "max_travel"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(
                    f"StepPolicy: `{name}` must be > 0 (or None), got {value}."
                )
        for name in ("substeps", "refinement"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < 1):
                raise ValueError(
                    f"StepPolicy: `{name}` must be a positive integer, got {value}."
                )

    def limits(self, rotary: bool = False) -> tuple[float, float | None]:
        """(longest step [s], most travel per step or None) for a device kind."""
        step, travel = DEFAULT_LIMITS["rotary" if rotary else "linear"]
        step = step if self.max_step is None else self.max_step
        travel = travel if self.max_travel is None else self.max_travel
        return step, travel

    def counts(self, t, v, rotary: bool = False, x=None) -> np.ndarray:
        """Steps in each sample interval of an experiment at times `t` [s], velocities
        `v` [m/s or rad/s] (see the class docstring) and, when given, displacements
        `x` [m or rad]: the travel limit then holds along the motion actually
        simulated, the cubic Hermite interpolant of (x, v), whose speed between two
        samples can far exceed both end velocities where x and v disagree (a step in
        x that v does not show)."""
        h = np.diff(np.asarray(t, dtype=float))
        if self.substeps is not None:
            return np.full(h.shape, self.substeps * self.refinement, dtype=int)
        max_step, travel = self.limits(rotary)
        # A hair of slack so that an interval exactly k steps long gets k, not k + 1.
        slack = 1 - 1e-9
        counts = np.ceil(h / max_step * slack)
        if travel is not None:
            speed = np.abs(np.asarray(v, dtype=float))
            speed = np.maximum(speed[:-1], speed[1:])
            if x is not None:
                speed = np.maximum(speed, _peak_speed(h, x, v))
            counts = np.maximum(counts, np.ceil(h * speed / travel * slack))
        return (np.maximum(1, counts) * self.refinement).astype(int)

    def step_travel(self, v, rotary: bool = False) -> float:
        """The most travel of one step at the peak speed of `v` [m or rad]."""
        max_step, travel = self.limits(rotary)
        peak = float(np.max(np.abs(np.asarray(v)))) if np.size(v) else 0.0
        by_time = max_step * peak / self.refinement
        return by_time if travel is None else min(by_time, travel / self.refinement)

    def refined(self, factor: int) -> "StepPolicy":
        """The same policy with steps `factor` times shorter."""
        return StepPolicy(
            self.max_step, self.max_travel, self.substeps, self.refinement * factor
        )


def _peak_speed(h, x, v) -> np.ndarray:
    """The largest |slope| [m/s] of the cubic Hermite interpolant of (x, v) in each
    sample interval (of lengths `h` [s]), as `_stage_inputs` simulates it: in s ∈ [0, 1]
    the slope per unit s is the quadratic a s² + b s + c, largest at an end or at its
    vertex."""
    x, v = np.asarray(x, dtype=float), np.asarray(v, dtype=float)
    d0, d1, rise = v[:-1] * h, v[1:] * h, np.diff(x)
    a = 3 * d0 + 3 * d1 - 6 * rise
    b = 6 * rise - 4 * d0 - 2 * d1
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = -b / (2 * a)
        inside = (a != 0) & (vertex > 0) & (vertex < 1)
        at_vertex = np.where(inside, d0 - b * b / (4 * a), 0.0)
        return np.maximum(np.maximum(np.abs(d0), np.abs(d1)), np.abs(at_vertex)) / h


def as_step_policy(integrator) -> StepPolicy:
    """`None` (the default policy), a `StepPolicy`, or `FixedStep(k)` (k steps per
    sample interval, as a `StepPolicy(substeps=k)`)."""
    if integrator is None:
        return StepPolicy()
    if isinstance(integrator, StepPolicy):
        return integrator
    if isinstance(integrator, FixedStep):
        return StepPolicy(substeps=integrator.substeps)
    raise TypeError(
        "identification integrates with fixed RK4 steps chosen per experiment: pass "
        "`integrator=None` (the default jaxmr.StepPolicy()), a jaxmr.StepPolicy "
        "(e.g. StepPolicy(max_travel=1e-5) for shorter steps) or jaxmr.FixedStep(k), "
        f"got {type(integrator).__name__}."
    )


class FitData(eqx.Module):
    """Experiments packed for simulation and scoring (see the module docstring).

    Steps (axis 0: lane, axis 1: step): `inputs[l, s, stage]` is (x, v, input) at the
    step's start, middle and end; `step` its length [s] (0 for padding); `reset` marks
    the first step of an experiment. Samples (all experiments' samples in order):
    `sample_index` is the flat (lane·steps + step) index of the step that starts at each
    sample, `t`, `force` the measured times and forces; the smoothing is a moving
    average of the simulated force over [lo, hi] per sample (`smooth`: whether to);
    `first_sample`, `last_sample` and `interval` are each sample's experiment's first
    and last sample and its local sample interval [s] (for a `ChannelDelay`); the
    residual is over the samples `kept`, times `weight`.
    """

    inputs: Float[Array, "lanes steps 3 3"]
    step: Float[Array, "lanes steps"]
    reset: Bool[Array, "lanes steps"]
    sample_index: Int[Array, " samples"]
    t: Float[Array, " samples"]
    force: Float[Array, " samples"]
    same_run: Float[Array, " samples_minus_1"]
    lo_index: Int[Array, " samples"]
    lo_fraction: Float[Array, " samples"]
    hi_index: Int[Array, " samples"]
    hi_fraction: Float[Array, " samples"]
    span: Float[Array, " samples"]
    smooth: Bool[Array, " samples"]
    first_sample: Int[Array, " samples"]
    last_sample: Int[Array, " samples"]
    interval: Float[Array, " samples"]
    kept: Int[Array, " residuals"]
    weight: Float[Array, " residuals"]
    names: tuple[str, ...] = eqx.field(static=True)
    offsets: tuple[int, ...] = eqx.field(static=True)
    data_steps: int = eqx.field(static=True)
    kept_counts: tuple[int, ...] = eqx.field(static=True)
    num_samples: int = eqx.field(static=True)

    @property
    def num_steps(self) -> int:
        """RK4 steps simulated per evaluation (all lanes, padding included)."""
        return int(self.step.shape[0] * self.step.shape[1])

    def split(self, samples) -> list[np.ndarray]:
        """A per-sample array cut into one array per experiment."""
        samples = np.asarray(samples)
        bounds = list(self.offsets) + [self.num_samples]
        return [samples[a:b] for a, b in zip(bounds[:-1], bounds[1:])]

    def kept_mask(self) -> np.ndarray:
        """Per sample: is it scored (not discarded)?"""
        mask = np.zeros(self.t.shape[0], dtype=bool)
        mask[np.asarray(self.kept)[: sum(self.kept_counts)]] = True
        return mask


def experiment_list(experiments, name: str = "experiments") -> list:
    """`experiments` as a list, refusing one experiment given alone (`list()` of it
    fails with "object is not iterable", which does not say what to do)."""
    if hasattr(experiments, "t") and hasattr(experiments, "x"):
        raise TypeError(
            f"`{name}` is one experiment; give a list of them, e.g. [experiment] "
            "(`jaxmr.predict` takes one)."
        )
    try:
        items = list(experiments)
    except TypeError:
        raise TypeError(
            f"`{name}` must be a list of experiments (jaxmr.data.Experiment), got a "
            f"{type(experiments).__name__}."
        ) from None
    for k, e in enumerate(items):
        missing = [a for a in ("t", "x", "v", "current") if not hasattr(e, a)]
        if missing:
            # An array or a tuple in the list failed later with "has no attribute 't'".
            raise TypeError(
                f"`{name}[{k}]` is a {type(e).__name__}, which has no "
                f"{', '.join(missing)}: give jaxmr.data.Experiment records (times [s], "
                "displacement [m], velocity [m/s], input [A or V] and force [N]), e.g. "
                "from jaxmr.data.read_csv."
            )
    return items


def _device_words(rotary, drive) -> str:
    return f"{'rotary' if rotary else 'linear'}, {drive}-driven"


def check_one_device(experiments: Sequence, model=None) -> None:
    """`ValueError` where `experiments` mix devices (linear and rotary: metres and
    radians, newtons and newton-metres; or current and voltage inputs), or where
    `model` holds the range it was fitted on (`FittedRange`) and that was another
    device's. (The command line refused both; the library fitted N with N·m and
    predicted a damper's force for a brake's record.) Experiments without
    `rotary`/`drive` (duck-typed) are taken as linear and current-driven."""
    kinds = {}
    for e in experiments:
        kind = (bool(getattr(e, "rotary", False)), getattr(e, "drive", "current"))
        kinds.setdefault(kind, []).append(str(getattr(e, "name", "")))
    if len(kinds) > 1:
        listed = "; ".join(
            f"{_device_words(*kind)}: {', '.join(names)}"
            for kind, names in kinds.items()
        )
        raise ValueError(
            f"the experiments mix devices ({listed}): give the records of one "
            "device, driven by one kind of input."
        )
    fitted = None if model is None else fitted_range_in(model, strict=False)
    if fitted is not None and kinds:
        (kind,) = kinds
        if kind != (bool(fitted.rotary), fitted.drive):
            raise ValueError(
                f"the model was fitted on a {_device_words(fitted.rotary, fitted.drive)} "
                f"device and the experiments are a {_device_words(*kind)} one's: its "
                "forces there would mean nothing."
            )


def per_experiment(
    value, experiments: Sequence, what: str, item: str = "experiment"
) -> np.ndarray:
    """`discard` or `smoothing` (`what`) [s], one per experiment (or record, `item`):
    from `None` (each experiment's own attribute `what`, as `jaxmr.data.Experiment`
    carries it; 0 for anything without it), a number for all, one per experiment, or a
    function of the list of experiments giving one of these (e.g.
    `jaxmr.data.utfsm_first_cycle`). Every value finite and >= 0."""
    experiments = list(experiments)
    n = len(experiments)
    if callable(value):
        value = value(experiments)
    if value is None:
        value = [float(getattr(e, what, 0.0)) for e in experiments]
    array = np.asarray(value, dtype=float)
    if array.ndim > 1 or (array.ndim == 1 and array.shape[0] != n):
        raise ValueError(
            f"`{what}` must be one number or one per {item} ({n}), got shape "
            f"{array.shape}."
        )
    array = np.broadcast_to(array, (n,))
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ValueError(f"`{what}` must be finite and >= 0 [s], got {value!r}.")
    return array


def experiment_name(e, k: int) -> str:
    """The name of experiment `e`, the `k`-th of its list: its own, or its place."""
    return str(getattr(e, "name", f"experiment {k}"))


def _columns(e, k: int, need_force: bool):
    name = experiment_name(e, k)
    t, x, v = (np.asarray(getattr(e, key), dtype=float) for key in ("t", "x", "v"))
    i = np.broadcast_to(np.asarray(e.current, dtype=float), t.shape)
    force = getattr(e, "force", None)
    if force is None:
        if need_force:
            raise ValueError(
                f"experiment {k} ({name!r}) has no measured force: fitting and scoring "
                "need the `F` (or `T`) column."
            )
        force = np.zeros_like(t)
    force = np.asarray(force, dtype=float)
    # The checks `Experiment` makes, for anything with these columns.
    check_columns(
        {"t": t, "x": x, "v": v, "input": i, "F": force}, f"experiment {name!r}"
    )
    return name, t, x, v, i, force


def _stage_inputs(t, x, v, i, counts) -> tuple[np.ndarray, np.ndarray]:
    """(x, v, input) at the start, middle and end of each step, `counts[k]` equal steps
    in sample interval k, and the steps' lengths. The motion is the cubic Hermite
    interpolant of (x, v) (as `Sampled` with derivatives), the input linear."""
    h = np.diff(t)
    interval = np.repeat(np.arange(len(h)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    j = np.arange(len(interval)) - first
    r = counts[interval].astype(float)
    s = np.stack([j / r, (j + 0.5) / r, (j + 1.0) / r], axis=-1)
    hk = h[interval][:, None]
    y0, y1 = x[:-1][interval][:, None], x[1:][interval][:, None]
    d0, d1 = (v[:-1] * h)[interval][:, None], (v[1:] * h)[interval][:, None]
    i0, i1 = i[:-1][interval][:, None], i[1:][interval][:, None]
    position = _hermite(s, y0, y1, d0, d1)
    velocity = _hermite_slope(s, y0, y1, d0, d1) / hk
    current = i0 + s * (i1 - i0)
    inputs = np.stack([position, velocity, current], axis=-1)
    steps = h[interval] / r
    # The last sample starts one step of length 0, whose start is that sample.
    last = np.tile(np.array([x[-1], v[-1], i[-1]]), (3, 1))[None]
    return np.concatenate([inputs, last]), np.append(steps, 0.0)


def window(t, width: float):
    """The centred moving-average window of `width` [s] at every sample of `t`,
    shrinking at the ends: for each end, the sample interval it falls in (index) and
    the fraction into it, and the window's length [s] (1 where it is empty)."""
    lo = np.clip(t - width / 2, t[0], t[-1])
    hi = np.clip(t + width / 2, t[0], t[-1])
    ends = []
    for edge in (lo, hi):
        j = np.clip(np.searchsorted(t, edge, side="right") - 1, 0, len(t) - 2)
        ends.append((j, (edge - t[j]) / (t[j + 1] - t[j])))
    return ends[0], ends[1], np.where(hi > lo, hi - lo, 1.0)


def _lanes(sizes: Sequence[int], lanes: int) -> list[list[int]]:
    """Experiments (indices) per lane: longest first, each to the shortest lane."""
    lanes = max(1, min(lanes, len(sizes)))
    content, totals = [[] for _ in range(lanes)], [0] * lanes
    for k in sorted(range(len(sizes)), key=lambda k: -sizes[k]):
        j = int(np.argmin(totals))
        content[j].append(k)
        totals[j] += sizes[k]
    return content


# Lanes `pack` uses by default: on the 30 UTFSM records (2 CPU cores) 8 lanes took
# 0.44 s per residual and 2.3 s with its Jacobian, against 1.8 s / 5.5 s packed into one
# scan and 0.67 s / 4.9 s padded (one lane per record).
LANES = 8


def default_lanes(num_experiments: int) -> int:
    """The number of lanes `pack` uses by default (`LANES`, at most one per
    experiment)."""
    return min(num_experiments, LANES)


def pack(
    experiments: Sequence,
    policy: StepPolicy | None = None,
    *,
    weighting: str = "nrmse",
    discard=None,
    smoothing=None,
    lanes: int | None = None,
    need_force: bool = True,
) -> FitData:
    """Pack experiments for `fit` (and for prediction and scoring: `need_force=False`).

    **Arguments:**

    - `experiments`: `jaxmr.data.Experiment`s (or anything with `t`, `x`, `v`,
      `current`, `force`, `name`), any lengths and sample rates.
    - `policy`: the `StepPolicy` (default `StepPolicy()`).
    - `weighting`: `"nrmse"` (each experiment weighted by 1/(std(F)·sqrt(N)), so the
      loss is half the sum of squared NRMSEs) or `"force"` (unweighted).
    - `discard`, `smoothing`: [s], one number or one per experiment, `None`: each
      experiment's own (see `fit`).
    - `lanes`: how many scans the steps are laid out in (default `default_lanes`):
      `len(experiments)` is the padded layout, 1 packs everything into one scan.

    **Returns:** a `FitData`.
    """
    experiments = experiment_list(experiments)
    if not experiments:
        raise ValueError("`experiments` is empty: give at least one experiment.")
    check_one_device(experiments)
    if weighting not in ("nrmse", "force"):
        raise ValueError(f"`weighting` must be 'nrmse' or 'force', got {weighting!r}.")
    policy = StepPolicy() if policy is None else policy
    n = len(experiments)
    discard = per_experiment(discard, experiments, "discard")
    widths = per_experiment(smoothing, experiments, "smoothing")
    lanes = default_lanes(n) if lanes is None else int(lanes)
    if lanes < 1:
        raise ValueError(f"`lanes` must be >= 1, got {lanes}.")

    names, runs = [], []
    for k, e in enumerate(experiments):
        name, t, x, v, i, force = _columns(e, k, need_force)
        r = policy.counts(t, v, bool(getattr(e, "rotary", False)), x)
        inputs, steps = _stage_inputs(t, x, v, i, r)
        names.append(name)
        runs.append((t, force, inputs, steps, r))

    # Lay the experiments' steps out in lanes.
    layout = _lanes([len(run[3]) for run in runs], lanes)
    length = max(sum(len(runs[k][3]) for k in lane) for lane in layout)
    inputs = np.zeros((len(layout), length, 3, 3))
    step = np.zeros((len(layout), length))
    reset = np.zeros((len(layout), length), dtype=bool)
    first_step = [0] * n  # flat index of each experiment's first step
    for j, lane in enumerate(layout):
        at = 0
        for k in lane:
            _, _, run_inputs, run_steps, _ = runs[k]
            m = len(run_steps)
            inputs[j, at : at + m] = run_inputs
            step[j, at : at + m] = run_steps
            reset[j, at] = True
            first_step[k] = j * length + at
            at += m
        # Padding repeats the lane's last input with steps of length 0.
        if at < length:
            inputs[j, at:] = inputs[j, at - 1]

    # Samples, in experiment order.
    offsets, sample_index, kept, weight, kept_counts = [], [], [], [], []
    t_all, force_all, same_run = [], [], []
    lo_index, lo_fraction, hi_index, hi_fraction, span, smooth = [], [], [], [], [], []
    first_sample, last_sample, interval = [], [], []
    total = 0
    for k, (t, force, _, _, r) in enumerate(runs):
        m = len(t)
        offsets.append(total)
        sample_index.append(first_step[k] + np.append(0, np.cumsum(r)))
        t_all.append(t)
        force_all.append(force)
        same_run.append(np.append(np.ones(m - 1), 0.0))
        keep = t >= t[0] + discard[k]
        if not np.any(keep):
            raise ValueError(
                f"`discard` = {discard[k]:g} s leaves no sample of experiment "
                f"{names[k]!r}."
            )
        if weighting == "nrmse":
            with np.errstate(over="ignore"):
                scale = float(np.std(force[keep]))
            if not np.isfinite(scale):
                raise ValueError(
                    f"experiment {names[k]!r}: the spread of its force overflows "
                    f"float64 (largest |F| = {np.max(np.abs(force)):.3g}); check the "
                    "force's unit (jaxmr expects N or N·m)."
                )
            if not scale > 0:
                raise ValueError(
                    f"experiment {names[k]!r} has a constant force where it is scored: "
                    "NRMSE weighting needs a varying force: check the force channel, "
                    "or leave the record out (from Python, weighting='force' fits it "
                    "as it is)."
                )
            w = 1.0 / (scale * np.sqrt(np.sum(keep)))
        else:
            w = 1.0
        kept.append(total + np.flatnonzero(keep))
        weight.append(np.full(int(np.sum(keep)), w))
        kept_counts.append(int(np.sum(keep)))
        width = widths[k]
        (lo, lo_f), (hi, hi_f), window_span = window(t, width)
        lo_index.append(total + lo)
        lo_fraction.append(lo_f)
        hi_index.append(total + hi)
        hi_fraction.append(hi_f)
        span.append(window_span)
        smooth.append(np.full(m, width > 0))
        first_sample.append(np.full(m, total))
        last_sample.append(np.full(m, total + m - 1))
        h = np.diff(t)
        interval.append(np.concatenate([h[:1], h]))
        total += m

    cat = np.concatenate
    return FitData(
        inputs=to_device(inputs),
        step=to_device(step),
        reset=to_device(reset),
        sample_index=to_device(cat(sample_index)),
        t=to_device(cat(t_all)),
        force=to_device(cat(force_all)),
        same_run=to_device(cat(same_run)[:-1]),
        lo_index=to_device(cat(lo_index)),
        lo_fraction=to_device(cat(lo_fraction)),
        hi_index=to_device(cat(hi_index)),
        hi_fraction=to_device(cat(hi_fraction)),
        span=to_device(cat(span)),
        smooth=to_device(cat(smooth)),
        first_sample=to_device(cat(first_sample)),
        last_sample=to_device(cat(last_sample)),
        interval=to_device(cat(interval)),
        kept=to_device(cat(kept)),
        weight=to_device(cat(weight)),
        names=tuple(names),
        offsets=tuple(offsets),
        data_steps=int(sum(len(run[3]) for run in runs)),
        kept_counts=tuple(kept_counts),
        num_samples=total,
    )


def pad_to(data: FitData, shape: tuple[int, int, int, int]) -> FitData:
    """`data` padded to (lanes, steps, samples, residuals) — for a batch of independent
    problems of one shape (`fit_each`). Padded steps have length 0, padded samples
    point at step 0 (and at sample 0, 1 s apart), padded residuals have weight 0."""
    lanes, steps, samples, residuals = shape

    def grow(a, n, axis=0, value: float | bool = 0):
        width = [(0, 0)] * a.ndim
        width[axis] = (0, n - a.shape[axis])
        return jnp.pad(a, width, constant_values=value)

    inputs = grow(grow(data.inputs, lanes), steps, 1, 0.0)
    # Padded lanes and steps keep a finite, harmless input: the lane's first.
    inputs = jnp.where(
        (jnp.arange(lanes)[:, None, None, None] < data.inputs.shape[0])
        & (jnp.arange(steps)[None, :, None, None] < data.inputs.shape[1]),
        inputs,
        data.inputs[0, :1][None],
    )
    old_steps = data.step.shape[1]
    flat = (data.sample_index // old_steps) * steps + data.sample_index % old_steps
    return eqx.tree_at(
        lambda d: (
            d.inputs,
            d.step,
            d.reset,
            d.sample_index,
            d.t,
            d.force,
            d.same_run,
            d.lo_index,
            d.lo_fraction,
            d.hi_index,
            d.hi_fraction,
            d.span,
            d.smooth,
            d.first_sample,
            d.last_sample,
            d.interval,
            d.kept,
            d.weight,
        ),
        data,
        (
            inputs,
            grow(grow(data.step, lanes), steps, 1),
            grow(grow(data.reset, lanes, 0, True), steps, 1),
            grow(flat, samples),
            grow(data.t, samples),
            grow(data.force, samples),
            grow(data.same_run, samples - 1),
            grow(data.lo_index, samples),
            grow(data.lo_fraction, samples),
            grow(data.hi_index, samples),
            grow(data.hi_fraction, samples),
            grow(data.span, samples, 0, 1.0),
            grow(data.smooth, samples),
            grow(data.first_sample, samples),
            grow(data.last_sample, samples),
            grow(data.interval, samples, 0, 1.0),
            grow(data.kept, residuals),
            grow(data.weight, residuals),
        ),
    )


def shape_of(data: FitData) -> tuple[int, int, int, int]:
    return (
        data.step.shape[0],
        data.step.shape[1],
        data.t.shape[0],
        data.kept.shape[0],
    )


def pad_all(datas: Sequence[FitData]) -> list[FitData]:
    """Independent problems padded to one shape (their own static fields kept)."""
    shape = tuple(max(s) for s in zip(*(shape_of(d) for d in datas)))
    return [pad_to(d, shape) for d in datas]


def stack(datas: Sequence[FitData]) -> FitData:
    """Independent problems padded to one shape and stacked (axis 0: problem); the
    static fields are the first problem's (only the arrays are read under vmap)."""
    padded = pad_all(datas)
    arrays = [eqx.filter(d, eqx.is_array) for d in padded]
    static = eqx.filter(padded[0], eqx.is_array, inverse=True)
    treedef = jax.tree.structure(arrays[0])
    leaves = [jax.tree.leaves(a) for a in arrays]
    stacked = [jnp.stack(xs) for xs in zip(*leaves)]
    return eqx.combine(jax.tree.unflatten(treedef, stacked), static)
