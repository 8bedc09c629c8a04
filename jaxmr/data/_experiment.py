"""One measured test of a damper or brake: motion, input and force, with their checks."""

import contextlib
import contextvars
import os
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import TypeAlias

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, ArrayLike, Float
from .._misc import as_float_array, is_concrete, user_stacklevel
from .._signal import Constant, Sampled

# Plain lists are accepted as well as arrays: measured columns often arrive as lists.
DataLike: TypeAlias = ArrayLike | Sequence[float]
# A column as an experiment keeps it: float64 NumPy (a traced JAX array under jit).
Column: TypeAlias = Float[np.ndarray, " samples"] | Float[Array, " samples"]

VELOCITY_MEASURED = "measured"
VELOCITY_CENTRAL = (
    "computed: central differences of x, numpy.gradient(x, t, edge_order=2)"
)

# Thresholds of the unit-plausibility warnings (SI units expected). Each is far outside
# what a laboratory MR damper or brake produces in SI, and close to what the common unit
# mistake gives: a stroke of 0.5 m is beyond any MR damper test rig (±25 mm is typical;
# millimetres in a metre column give hundreds), a 0.05 s sample step (20 Hz) is beyond
# any dynamic test (milliseconds in a seconds column give 0.05 or more at up to 20 kHz:
# a 1 kHz rig's exactly 1, which a bound of 1 s had let through), 1 MN is beyond the
# largest (200 kN seismic) MR dampers, and 50 A is ten times the largest coil currents
# (milliamperes in an ampere column give hundreds).
MAX_DISPLACEMENT_AMPLITUDE = 0.5  # m, half the peak-to-peak displacement
MAX_TIME_STEP = 0.05  # s, median sample step
MAX_FORCE = 1e6  # N (N·m for a brake), largest magnitude
MAX_CURRENT = 50.0  # A, largest magnitude (not checked for a voltage drive)
# A measured velocity whose RMS differs from that of the derivative of the displacement
# by more than this factor has other units (mm/s with m: 1000; cm/s with m: 100; deg/s
# with rad: 57). Measurement noise and filtering change the ratio by far less.
MAX_VELOCITY_RATIO = 10.0

# A measured velocity and the displacement disagree at a sample step when the step's
# displacement differs from the velocity's trapezoid over it by more than this many times
# the record's large steps (the 95th percentile of |x[k+1] - x[k]|). There the cubic
# Hermite motion through the samples (`Experiment.motion`), whose slopes are the
# velocity column, has to cover the displacement step: it moves about 1.5 times the
# mismatch per sample step, i.e. over 4 times faster than the column's large
# velocities, which the step policy did not plan for. Consistent records stay far below:
# a velocity lagging by half a sample or 10 % off in scale gives about 0.1-0.2, the
# UTFSM sine files with their own velocity column at most 0.09, the NEES white-noise
# record 0.7 (measured).
MAX_MOTION_MISMATCH = 3.0

# A passive device (an MR damper or brake, whatever its current) takes energy from the
# motion: with jaxmr's convention (the force the device resists the motion with, positive
# along the velocity: F = c v for a viscous damper) the mean power mean(F v) is positive.
# Normalised by rms(F) rms(v) (so within [-1, 1]) the UTFSM sine files give +0.94 to
# +0.97 and the NEES random record +0.86 (measured); a force read the other way round
# gives the same negated. A record below this feeds energy into the rig, which no
# passive device does.
MIN_NORMALISED_POWER = -0.3
# A velocity computed by differencing the displacement carries the displacement's
# sample-to-sample noise divided by the sample time. Where that noise is above this
# share of the velocity's RMS, the fit sees it (a user's trial, session 26: 20 µm of
# noise at 1 kHz on a ±10 mm, 2 Hz test gave 16 %, and a held-out NRMSE of 0.087
# against 0.060 with a Savitzky–Golay velocity). A smooth motion's own third
# differences stay far below it (band-limited 0-50 Hz at 1 kHz: 1 %; a clean sine:
# 4e-5).
MAX_DIFFERENCED_NOISE = 0.10

_DRIVES = ("current", "voltage")


class DataWarning(UserWarning):
    """A warning about measured data, with what it found as data (attributes), so that
    a program can act on it (`jaxmr fit` refuses an implausible unit) without reading
    its text.

    **Attributes:**

    - `kind`: `"unit"` (a column's values are implausible in SI units), `"noise"` (a
      velocity computed from a noisy displacement), `"motion"`
      (a measured velocity and the displacement disagree: a step in one that the other
      does not show) or `"sign"` (the force has the opposite sign to jaxmr's
      convention, so that it would feed energy into the motion, or the measured
      velocity runs against the displacement's derivative).
    - `column`: the column concerned (`"t"`, `"x"`, `"v"`, `"F"`, `"i"`; `"theta"`,
      `"omega"`, `"T"` for a brake).
    - `suggested`: the unit the values look like (e.g. `"mm"` for `x`), or None.
    - `time`: for `"motion"`, the time [s] of the first sample where the step starts
      (None otherwise).
    """

    def __init__(
        self,
        message: str,
        *,
        kind: str,
        column: str,
        suggested: str | None = None,
        time: float | None = None,
    ):
        super().__init__(message)
        self.kind = kind
        self.column = column
        self.suggested = suggested
        self.time = time


def as_column(a: DataLike) -> Float[np.ndarray, "..."] | Float[Array, "..."]:
    """A measured column as an `Experiment` keeps it: a float64 NumPy array, whatever
    JAX's precision. Measured data are not jit-able, and in float32 a file's
    `t = 0.001` would become 0.0010000000474974513 and be written back so by
    `write_csv`; the simulation converts the columns to JAX's precision where it uses
    them (`motion`, `current_signal`, `jaxmr.fit`). An experiment built under jit from
    traced arrays keeps them (JAX's default float)."""
    if isinstance(a, jax.Array) and not is_concrete(a):
        return as_float_array(a)
    return np.asarray(a, dtype=np.float64)


# The source named in the unit warnings while a file is read (`named_by_file`).
_SOURCE: contextvars.ContextVar[str | None] = contextvars.ContextVar(
    "jaxmr_experiment_source", default=None
)


# False while an experiment is cut from one already checked (`Experiment.window`): its
# units were warned about once, with the whole record, and its processing checked
# against the whole record's length (a cut may be shorter than a discarded start,
# which then discards all of it).
_WHOLE_RECORD: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "jaxmr_experiment_warn_units", default=True
)


@contextlib.contextmanager
def named_by_file(path: str | os.PathLike) -> Iterator[None]:
    """Experiments built in this context name `path` in their unit warnings (the file
    the user can open), not their own name."""
    token = _SOURCE.set(str(path))
    try:
        yield
    finally:
        _SOURCE.reset(token)


def _seconds(name: str, value) -> float:
    """A processing duration [s]: a finite number >= 0."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not (np.isfinite(number) and number >= 0):
        raise ValueError(
            f"Experiment: `{name}` must be a finite number of seconds >= 0 (0: none), "
            f"got {value!r}."
        )
    return number


def _index_label(k: int) -> str:
    return f"index {k}"


def check_columns(
    columns: dict[str, np.ndarray],
    where: str,
    row: Callable[[int], str] = _index_label,
) -> None:
    """Raise `ValueError` if the named 1-D columns are unfit for an experiment.

    Checks, in this order: each column is 1-D, all have one length, there are at least
    3 samples, every value is finite, and the time column `t` (the first column) is
    strictly increasing. `row(k)` names sample `k` in the messages ("index 17", or
    "line 19" for a file).
    """
    for name, column in columns.items():
        if column.ndim != 1:
            raise ValueError(
                f"{where}: column `{name}` must be 1-D (one value per sample), got "
                f"shape {column.shape}."
            )
    lengths = {name: column.shape[0] for name, column in columns.items()}
    if len(set(lengths.values())) > 1:
        listed = ", ".join(f"`{name}`: {n}" for name, n in lengths.items())
        raise ValueError(
            f"{where}: columns must have equal lengths (one value per sample time), got "
            f"{listed}."
        )
    n = next(iter(lengths.values()))
    if n < 3:
        raise ValueError(
            f"{where}: at least 3 samples are needed (for central differences and a "
            f"motion interpolant), got {n}."
        )
    for name, column in columns.items():
        bad = np.flatnonzero(~np.isfinite(column))
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"{where}: column `{name}` has a non-finite value ({float(column[k])}) at "
                f"{row(k)} ({bad.size} non-finite in that column); repair or remove "
                "those samples (jaxmr drops nothing silently)."
            )
    time_name, t = next(iter(columns.items()))
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise ValueError(
            f"{where}: time `{time_name}` must be strictly increasing, but "
            f"{time_name}={float(t[k])!r} at {row(k)} does not exceed "
            f"{float(t[k - 1])!r} at "
            f"{row(k - 1)} ({bad.size} such steps). Where the time starts again (a "
            "file that joins several runs), split it into one file per run; else "
            "sort the samples and remove repeated time stamps."
        )


def central_velocity(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    r"""$\dot x$ at the samples by second-order finite differences on the actual
    (possibly uneven) sample times: central inside, one-sided second order at both ends
    (`numpy.gradient(x, t, edge_order=2)`). For a sine of angular frequency $\omega$
    sampled every $h$ the relative error is about $(\omega h)^2/6$ inside and
    $(\omega h)^2/3$ at the ends."""
    return np.gradient(x, t, edge_order=2)


def differenced_noise(t: np.ndarray, x: np.ndarray, v: np.ndarray) -> float:
    """The share of `v`'s RMS that is `x`'s sample-to-sample noise carried by central
    differences: the noise σ from `x`'s third differences (robustly, by their
    median absolute value; 20 σ² is their variance for white noise), then
    σ / (√2 h) for the velocity's (h the median sample time)."""
    if x.size < 8:
        return 0.0
    third = np.diff(x, 3)
    sigma = float(np.median(np.abs(third))) / 0.6745 / np.sqrt(20.0)
    h = float(np.median(np.diff(t)))
    scale = _rms(v)
    return sigma / (np.sqrt(2.0) * h) / scale if scale > 0 and h > 0 else 0.0


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def warn_implausible_units(
    t: np.ndarray,
    x: np.ndarray,
    v: np.ndarray,
    current: np.ndarray,
    force: np.ndarray | None,
    *,
    rotary: bool,
    drive: str,
    velocity_measured: bool,
    where: str,
) -> None:
    """`DataWarning`s for values that are implausible in SI units, a force of the
    reversed sign and a velocity that disagrees with the displacement (thresholds
    above)."""
    position, velocity, load = ("theta", "omega", "T") if rotary else ("x", "v", "F")

    def warn(message, column, suggested=None):
        warnings.warn(
            DataWarning(
                f"{where}: {message}", kind="unit", column=column, suggested=suggested
            ),
            stacklevel=user_stacklevel(sys._getframe()),
        )

    dt = float(np.median(np.diff(t)))
    if dt >= MAX_TIME_STEP:
        warn(
            f"the median time step is {dt:g} s (sampled at {1 / dt:g} Hz, below "
            f"{1 / MAX_TIME_STEP:g} Hz): is `t` in milliseconds? jaxmr expects "
            "seconds.",
            "t",
            "ms",
        )
    if not rotary:
        amplitude = 0.5 * float(np.max(x) - np.min(x))
        if amplitude > MAX_DISPLACEMENT_AMPLITUDE:
            warn(
                f"the displacement amplitude (half peak-to-peak) is {amplitude:g} m "
                f"(> {MAX_DISPLACEMENT_AMPLITUDE:g} m): is `x` in millimetres? jaxmr "
                "expects metres.",
                "x",
                "mm",
            )
    if force is not None:
        peak = float(np.max(np.abs(force)))
        if peak > MAX_FORCE:
            unit = "N·m" if rotary else "N"
            warn(
                f"the largest |{load}| is {peak:g} {unit} (> {MAX_FORCE:g} {unit}): check "
                f"its unit; jaxmr expects {unit}.",
                load,
            )
    if drive == "current":
        peak = float(np.max(np.abs(current)))
        if peak > MAX_CURRENT:
            warn(
                f"the largest |current| is {peak:g} A (> {MAX_CURRENT:g} A): is it in "
                "milliamperes? jaxmr expects amperes.",
                "i",
                "mA",
            )
    if not velocity_measured:
        share = differenced_noise(t, x, v)
        if share > MAX_DIFFERENCED_NOISE:
            warnings.warn(
                DataWarning(
                    f"{where}: `{velocity}` is computed by differencing `{position}`, "
                    f"whose sample-to-sample noise makes about {share:.0%} of its RMS "
                    "(differences divide the noise by the sample time); give a "
                    f"measured or filtered `{velocity}`, e.g. scipy.signal.savgol_"
                    f"filter({position}, 21, 3, deriv=1, delta=dt).",
                    kind="noise",
                    column=velocity,
                ),
                stacklevel=user_stacklevel(sys._getframe()),
            )
    # The displacement's derivative, for the velocity column's sign and unit checks.
    derivative = np.gradient(x, t) if velocity_measured else None
    along = None if derivative is None else _normalised_product(derivative, v)
    if along is not None and along < MIN_NORMALISED_POWER:
        warnings.warn(
            DataWarning(
                f"{where}: `{velocity}` runs against the derivative of `{position}` "
                f"(their mean product is {along:.2f} of their RMS values' product): "
                f"one of them has the opposite sign; negate `{velocity}` (or "
                f"`{position}`) so that `{velocity}` is the rate of `{position}`.",
                kind="sign",
                column=velocity,
            ),
            stacklevel=user_stacklevel(sys._getframe()),
        )
        # The force's sign is then judged against a reversed velocity: left out, so
        # that the one warning names the column to fix.
    elif force is not None:
        _warn_force_sign(v, force, load, velocity, where)
    if derivative is not None:
        expected = _rms(derivative)
        measured = _rms(v)
        if expected > 0 and measured > 0:
            ratio = measured / expected
            if not 1 / MAX_VELOCITY_RATIO <= ratio <= MAX_VELOCITY_RATIO:
                warn(
                    f"the RMS of `{velocity}` is {ratio:g} times that of the derivative "
                    f"of `{position}`: their units disagree (e.g. mm/s with m, or deg/s "
                    f"with rad); give `{position}` and `{velocity}` in SI units.",
                    velocity,
                )
            else:  # units agree: do the samples agree with each other?
                _warn_motion_steps(t, x, v, position, velocity, rotary, where)


def _normalised_product(a: np.ndarray, b: np.ndarray) -> float | None:
    """mean(a b) / (rms(a) rms(b)), in [-1, 1]: +1 where `a` and `b` move together,
    -1 where one is the other negated; None where either is all zero."""
    scale = _rms(a) * _rms(b)
    return float(np.mean(a * b)) / scale if scale > 0 else None


def _warn_force_sign(v, force, load, velocity, where) -> None:
    """A `DataWarning` (kind "sign") where the force's mean power is clearly negative
    (`MIN_NORMALISED_POWER`): the record's force has the opposite sign to jaxmr's
    convention (a load cell read the other way round)."""
    power = _normalised_product(force, v)
    if power is None or power >= MIN_NORMALISED_POWER:
        return  # no motion or no force to judge, or the convention's sign
    warnings.warn(
        DataWarning(
            f"{where}: `{load}` works against `{velocity}` (mean power {load}·{velocity} "
            f"is {power:.2f} of rms({load})·rms({velocity})): with this sign the device "
            "would feed energy into the motion, which no passive device does. jaxmr "
            f"takes `{load}` as the force the device resists the motion with, positive "
            f"along `{velocity}` (F = c v for a viscous damper); negate `{load}` (or, "
            "if the motion's sign is the one reversed, the displacement and the "
            "velocity).",
            kind="sign",
            column=load,
        ),
        stacklevel=user_stacklevel(sys._getframe()),
    )


def _warn_motion_steps(t, x, v, position, velocity, rotary, where) -> None:
    """A `DataWarning` (kind "motion") naming the first sample step where the
    displacement and the measured velocity disagree (`MAX_MOTION_MISMATCH`): a step in
    one that the other does not show, e.g. two runs joined into one file."""
    dx = np.diff(x)
    along = 0.5 * np.diff(t) * (v[:-1] + v[1:])  # the velocity's trapezoid per step
    scale = float(np.percentile(np.abs(dx), 95))
    if not scale > 0:
        return
    mismatch = np.abs(dx - along)
    bad = np.flatnonzero(mismatch > MAX_MOTION_MISMATCH * scale)
    if not bad.size:
        return
    k = int(bad[0])
    unit = "rad" if rotary else "m"
    which = position if abs(dx[k]) > abs(along[k]) else velocity
    shows = (
        f"`{position}` steps by {dx[k]:.4g} {unit} but `{velocity}` integrates to "
        f"{along[k]:.4g} {unit}"
    )
    more = f" (and {bad.size - 1} more such step(s))" if bad.size > 1 else ""
    warnings.warn(
        DataWarning(
            f"{where}: between t = {t[k]:.6g} s and {t[k + 1]:.6g} s {shows}{more}: "
            f"a step in `{which}` that the other column does not show (two records "
            "joined? a glitch?). The mismatch is "
            f"{mismatch[k] / scale:.3g} times the record's large sample steps, so the "
            f"interpolated motion there moves far faster than `{velocity}` says; check "
            "the data, or cut the step out (`Experiment.window`).",
            kind="motion",
            column=which,
            time=float(t[k]),
        ),
        stacklevel=user_stacklevel(sys._getframe()),
    )


class Experiment(eqx.Module):
    r"""One measured test of an MR damper (or brake): prescribed motion, input and the
    measured force, sampled at the times `t`.

    All columns are 1-D arrays of one length, in SI units: for a linear damper
    displacement $x$ [m], velocity $v$ [m/s] and force $F$ [N]; for a brake
    (`rotary=True`) angle [rad], angular velocity [rad/s] and torque [N·m] in the same
    fields. The input is the coil current [A] (`drive="current"`) or the command voltage
    [V] (`drive="voltage"`); a constant input is stored as a constant array. The
    columns are float64 NumPy arrays whatever JAX's precision (`as_column`): measured
    data keep their digits, and the simulation converts them where it uses them.

    The constructor checks the data at once (when the arrays are concrete): every column
    finite (the error names the column and the first bad index; nothing is dropped),
    equal lengths, strictly increasing time, at least 3 samples. It warns
    (`jaxmr.data.DataWarning`, a `UserWarning`, kind `"unit"`) about values that are
    implausible in SI units: a displacement amplitude above 0.5 m, a median time step
    above 1 s, a force above 1e6 N, a current above 50 A, or a measured velocity whose
    RMS is more than 10 times off that of the displacement's derivative; and (kind
    `"motion"`, with the time) about a measured velocity that disagrees with the
    displacement at a sample step, i.e. a step in `x` that `v` does not show or the
    reverse (two runs joined into one file): the step's displacement differs from the
    trapezoid of `v` over it by more than 3 times the record's large sample steps
    (the 95th percentile of $|x_{k+1} - x_k|$); and (kind `"sign"`) about a force
    that feeds energy into the motion, i.e. has the opposite sign to the convention
    below: its mean power $\overline{F v}$ below −0.3 of
    $\mathrm{rms}(F)\,\mathrm{rms}(v)$; or (kind `"sign"`, column `v`) about a
    measured velocity that runs against the derivative of `x` by the same measure
    (then the force's sign is not judged).

    **Sign convention.** `force` is the force the device resists the motion with,
    counted positive along the velocity: $F = c\,v$ for a viscous damper, so that a
    passive device, which takes energy from the motion, has $F v > 0$ on average. A
    load cell that reads the other way round gives the negated force: negate the
    column (`read_table`: a unit with a minus sign, e.g. `F:-kN`).

    **Arguments:**

    - `t`: sample times [s], strictly increasing.
    - `x`: displacement [m] (angle [rad]).
    - `v`: velocity [m/s] (angular velocity [rad/s]). Use `Experiment.from_arrays` to
      compute it from `x`.
    - `current`: the input, current [A] or voltage [V]: one value per sample or a
      scalar (broadcast).
    - `force`: measured force [N] (torque [N·m]), positive along the velocity (see
      the sign convention above), or `None` (prediction only).
    - `name`: a label, e.g. the file stem.
    - `rotary`: a brake (angle, torque) rather than a linear damper.
    - `drive`: `"current"` or `"voltage"`: what `current` holds.
    - `velocity_source`: `"measured"`, or how `v` was computed.
    - `smoothing`: the width [s] of the centred moving average the measured force
      went through (0: none). A fit (`jaxmr.fit`, `record_nrmse`, ...) passes the
      model's force through the same before comparing, unless told otherwise.
    - `discard`: the start [s] of the record to leave out of every score and
      residual (0: none), e.g. the first cycle of a sine test, where the hysteretic
      state is unknown.

    `jaxmr.data.read_csv` reads `smoothing` and `discard` from a file's
    `# smoothing:` and `# discard:` lines and `write_csv` writes them; the dataset
    loaders set them where the data's processing is known (`load_utfsm`,
    `load_nees`).
    """

    t: Column = eqx.field(converter=as_column)
    x: Column = eqx.field(converter=as_column)
    v: Column = eqx.field(converter=as_column)
    current: Column = eqx.field(converter=as_column)
    force: Column | None = eqx.field(
        converter=lambda f: None if f is None else as_column(f)
    )
    name: str = eqx.field(static=True)
    rotary: bool = eqx.field(static=True)
    drive: str = eqx.field(static=True)
    velocity_source: str = eqx.field(static=True)
    smoothing: float = eqx.field(static=True, default=0.0)
    discard: float = eqx.field(static=True, default=0.0)

    def __init__(
        self,
        t: DataLike,
        x: DataLike,
        v: DataLike,
        current: DataLike | float = 0.0,
        force: DataLike | None = None,
        *,
        name: str = "",
        rotary: bool = False,
        drive: str = "current",
        velocity_source: str = VELOCITY_MEASURED,
        smoothing: float = 0.0,
        discard: float = 0.0,
    ):
        if drive not in _DRIVES:
            raise ValueError(
                f"`drive` must be 'current' (input in A) or 'voltage' (input in V), "
                f"got {drive!r}."
            )
        if not isinstance(name, str) or not isinstance(velocity_source, str):
            raise TypeError("`name` and `velocity_source` must be strings.")
        if v is None:
            raise TypeError(
                "`v` is None: give the velocity, or let Experiment.from_arrays(t, x, "
                "...) compute it from the displacement."
            )
        self.t = as_column(t)
        self.x = as_column(x)
        self.v = as_column(v)
        column = as_column(current)
        if column.ndim == 0 and self.t.ndim == 1:
            # A constant input is stored broadcast so every column has one length.
            column = (
                np.full(self.t.shape, column)
                if isinstance(column, np.ndarray)
                else jnp.broadcast_to(column, self.t.shape)
            )
        self.current = column
        self.force = None if force is None else as_column(force)
        self.name = name
        self.rotary = bool(rotary)
        self.drive = drive
        self.velocity_source = velocity_source
        self.smoothing = _seconds("smoothing", smoothing)
        self.discard = _seconds("discard", discard)

    def __check_init__(self):
        arrays = (self.t, self.x, self.v, self.current, self.force)
        if not is_concrete(*arrays):
            return  # built under jit from traced arrays: nothing to check by value
        columns = self._columns()
        check_columns(columns, self._where())
        if not _WHOLE_RECORD.get():
            return
        t = columns["t"]
        duration = float(t[-1] - t[0]) if t.size else 0.0
        # Both would only fail later, deep inside a fit or prediction (a discard past
        # the end leaves nothing to score; a moving average wider than the record
        # flattens the model's force, an NRMSE of 1 whatever the parameters).
        if self.discard > duration:
            raise ValueError(
                f"{self._where()}: `discard` = {self.discard:g} s leaves no sample of "
                f"a record {duration:g} s long."
            )
        if self.smoothing > duration:
            raise ValueError(
                f"{self._where()}: `smoothing` = {self.smoothing:g} s is wider than "
                f"the record ({duration:g} s): a moving average that wide flattens "
                "the force. Give the width of the filter the force went through, or 0."
            )
        warn_implausible_units(
            *(columns[k] for k in ("t", "x", "v", "current")),
            columns.get("force"),  # pyright: ignore[reportCallIssue]  # four columns before it
            rotary=self.rotary,
            drive=self.drive,
            velocity_measured=self.velocity_source == VELOCITY_MEASURED,
            where=self._where(),
        )

    def _where(self) -> str:
        source = _SOURCE.get()
        if source is not None:
            return source
        return f"Experiment {self.name!r}" if self.name else "Experiment"

    def _columns(self) -> dict[str, np.ndarray]:
        columns = {
            "t": np.asarray(self.t),
            "x": np.asarray(self.x),
            "v": np.asarray(self.v),
            "current": np.asarray(self.current),
        }
        if self.force is not None:
            columns["force"] = np.asarray(self.force)
        return columns

    @classmethod
    def from_arrays(
        cls,
        t: DataLike,
        x: DataLike,
        *,
        v: DataLike | None = None,
        current: DataLike | float = 0.0,
        force: DataLike | None = None,
        name: str = "",
        rotary: bool = False,
        drive: str = "current",
        smoothing: float = 0.0,
        discard: float = 0.0,
    ) -> "Experiment":
        r"""An experiment from arrays, computing the velocity when it is not measured.

        Without `v` the velocity is computed from `x` by second-order finite
        differences on the actual sample times (`numpy.gradient(x, t, edge_order=2)`:
        central inside, one-sided at both ends; relative error about $(\omega h)^2/6$
        for a sine of angular frequency $\omega$ sampled every $h$), and
        `velocity_source` says so. Noisy displacements give noisy velocities: filter
        `x` first, or pass a measured `v`.

        **Arguments:** as `Experiment`; `current` a scalar (constant) or one value per
        sample.

        **Returns:** an `Experiment`.
        """
        where = f"Experiment {name!r}" if name else "Experiment"
        if v is None:
            t_np = np.asarray(t, dtype=np.float64)
            x_np = np.asarray(x, dtype=np.float64)
            # Checked before differencing so that a bad time column is reported as such
            # rather than as a division by zero.
            check_columns({"t": t_np, "x": x_np}, where)
            v = central_velocity(t_np, x_np)
            source = VELOCITY_CENTRAL
        else:
            source = VELOCITY_MEASURED
        return cls(
            t,
            x,
            v,
            current,
            force,
            name=name,
            rotary=rotary,
            drive=drive,
            velocity_source=source,
            smoothing=smoothing,
            discard=discard,
        )

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def duration(self) -> float:
        """`t[-1] - t[0]` [s]."""
        t = np.asarray(self.t)
        return float(t[-1] - t[0])

    @property
    def sample_rate(self) -> float:
        """The median sampling rate [Hz]: 1 / median time step."""
        return float(1.0 / np.median(np.diff(np.asarray(self.t))))

    @property
    def is_constant_current(self) -> bool:
        """Whether the input (current or voltage) is the same at every sample. False
        for traced arrays (under jit), where it cannot be known."""
        if not is_concrete(self.current):
            return False
        current = np.asarray(self.current)
        return bool(np.all(current == current[0]))

    def motion(self) -> Sampled:
        """The displacement (angle) as a signal: the cubic Hermite interpolant through
        `x` with derivatives `v`, so the model sees exactly the measured (or computed)
        velocity at the samples."""
        return Sampled(self.t, self.x, derivatives=self.v)

    def current_signal(self) -> Constant | Sampled:
        """The input (current [A], or voltage [V] when `drive="voltage"`) as a signal:
        `Constant` when it is constant, else the piecewise-linear `Sampled`."""
        if self.is_constant_current:
            return Constant(self.current[0])
        return Sampled(self.t, self.current)

    def window(
        self, start: float | None = None, end: float | None = None
    ) -> "Experiment":
        """The samples with `start <= t <= end` [s] (either bound may be `None`), as an
        `Experiment` with the same metadata; time is not shifted. E.g. drop the first
        cycle of a sine test, whose hysteretic state starts unknown. The `smoothing`
        is kept; the `discard` still ends at the same time (what of it the window
        cuts off is no longer discarded)."""
        t = np.asarray(self.t)
        keep = np.ones(t.shape, dtype=bool)
        if start is not None:
            keep &= t >= start
        if end is not None:
            keep &= t <= end
        kept = t[keep]
        if kept.size < 3:
            raise ValueError(
                f"Experiment.window({start!r}, {end!r}) keeps {kept.size} sample(s) of "
                f"{self._where()}, which spans [{t[0]:g}, {t[-1]:g}] s; a window needs "
                "at least 3 (the times are absolute, not from the record's start)."
            )
        discard = max(0.0, float(t[0] + self.discard - kept[0]))
        token = _WHOLE_RECORD.set(False)
        try:
            return Experiment(
                self.t[keep],
                self.x[keep],
                self.v[keep],
                self.current[keep],
                None if self.force is None else self.force[keep],
                name=self.name,
                rotary=self.rotary,
                drive=self.drive,
                velocity_source=self.velocity_source,
                smoothing=self.smoothing,
                discard=discard,
            )
        finally:
            _WHOLE_RECORD.reset(token)
