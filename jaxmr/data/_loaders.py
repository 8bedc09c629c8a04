"""Loaders of public measurements, converted to SI units.

The data are not shipped with jaxmr: every loader takes the path where the user put the
downloaded files, and its docstring says where to download them.
"""

import importlib
import os
import re
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from .._custom_types import Float
from ._experiment import (
    VELOCITY_CENTRAL,
    Experiment,
    central_velocity,
    named_by_file,
)

MM = 1e-3  # m
CM = 1e-2  # m


def _require(module: str, what: str):
    # Imported lazily: only these loaders need h5py or scipy, so `import jaxmr.data`
    # works without them.
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise ImportError(
            f"{what} needs the optional package {module.split('.')[0]!r}: "
            "`pip install h5py scipy`."
        ) from e


def _existing(path: str | os.PathLike, what: str, source: str) -> Path:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(
            f"{what}: {str(path)!r} does not exist. Download the data from {source} and "
            "pass the path where you saved it."
        )
    return path


# ---------------------------------------------------------------------------------------
# UTFSM linear MR damper, constant-current sine tests

_UTFSM_SOURCE = (
    "GitHub repository DanielMaurelE/vRTHS_AMBC_MRdamper, folder "
    "'Cap7_ModeloMR/BoucWen Ajuste 2/Preprocesamiento-sinusoidales/Preprocesados/'"
)
_UTFSM_NAME = re.compile(
    r"^(?P<amplitude>\d+(?:x\d+)?)mm(?P<frequency>\d+(?:x\d+)?)Hz"
    r"(?P<current>\d+(?:x\d+)?)A$"
)
_UTFSM_VELOCITY_FILE = (
    "file: backward differences (x[k] - x[k-1])/dt by the data's authors (lag dt/2)"
)


class UTFSMConditions(NamedTuple):
    """The nominal conditions of a UTFSM sine test, parsed from its file name."""

    amplitude: float
    """Nominal displacement amplitude [m] (the measured one is smaller: 2 mm → 1.6 mm,
    5 → 4.55, 10 → 9.7, 25 → 24.5)."""
    frequency: float
    """Excitation frequency [Hz]."""
    current: float
    """Constant coil current [A]."""


def _decimal(text: str) -> float:
    return float(text.replace("x", "."))


def utfsm_test_conditions(name: str | Experiment) -> UTFSMConditions:
    """Nominal amplitude [m], frequency [Hz] and current [A] of a UTFSM sine test.

    **Arguments:**

    - `name`: the file stem, `<amplitude>mm<frequency>Hz<current>A` with `x` for the
      decimal point (e.g. `"25mm0x25Hz0x5A"`), or an `Experiment` from `load_utfsm`.

    **Returns:** a `UTFSMConditions(amplitude, frequency, current)`.
    """
    stem = name.name if isinstance(name, Experiment) else name
    match = _UTFSM_NAME.match(stem)
    if match is None:
        raise ValueError(
            f"{stem!r} is not a UTFSM test name: expected <amplitude>mm<frequency>Hz"
            "<current>A with 'x' as the decimal point, e.g. '25mm0x25Hz0x5A'."
        )
    return UTFSMConditions(
        amplitude=_decimal(match["amplitude"]) * MM,
        frequency=_decimal(match["frequency"]),
        current=_decimal(match["current"]),
    )


def load_utfsm(
    directory: str | os.PathLike,
    *,
    velocity: Literal["central", "file"] = "central",
) -> list[Experiment]:
    r"""The UTFSM constant-current sine tests of a linear MR damper, in SI units.

    Thesis data of M. Quiroz, Universidad Técnica Federico Santa María (Chile): a linear
    MR damper driven by an MTS uniaxial test machine; 30 tests, amplitude/frequency
    pairs 2 mm/5 Hz, 5 mm/3 Hz, 10 mm/1 Hz, 25 mm/0.1, 0.25 and 0.5 Hz, each at 0,
    0.25, 0.5, 0.75 and 1 A. The authors smoothed displacement and force with a
    moving average of a tenth of the period and removed the means; sample time 1 ms
    (5 ms for 2 mm/5 Hz and the 25 mm tests).

    Download: the 30 files `<amplitude>mm<frequency>Hz<current>A.txt` of the GitHub
    repository `DanielMaurelE/vRTHS_AMBC_MRdamper` (MIT licence; commit 08753ff, 2022),
    folder `Cap7_ModeloMR/BoucWen Ajuste 2/Preprocesamiento-sinusoidales/Preprocesados/`.

    Each file has 4 whitespace-separated columns: time [s], displacement [mm], velocity
    [mm/s], force [N]; they are converted to m and m/s.

    **Arguments:**

    - `directory`: the folder holding the 30 files (other files are ignored).
    - `velocity`: `"central"` (default) recomputes the velocity from the displacement
      by central differences (`Experiment.from_arrays`); `"file"` keeps the file's
      column, which is the backward difference $(x_k - x_{k-1})/\Delta t$ and so lags
      the displacement by half a sample (4.5° of phase at 5 Hz, 5 ms).

    **Returns:** the experiments, sorted by nominal amplitude, frequency and current;
    each is named by its file stem (`utfsm_test_conditions(experiment)` gives the
    nominal conditions) and has a constant `current`, the authors' `smoothing` (a
    tenth of the nominal period, `utfsm_smoothing`) and a `discard` of one nominal
    period (`utfsm_first_cycle`: the hysteretic state is unknown there and the moving
    average starts), which `jaxmr.fit` and the scores use unless told otherwise.
    """
    what = "load_utfsm"
    directory = _existing(directory, what, _UTFSM_SOURCE)
    if velocity not in ("central", "file"):
        raise ValueError(f"`velocity` must be 'central' or 'file', got {velocity!r}.")
    if not directory.is_dir():
        raise NotADirectoryError(
            f"{what}: {str(directory)!r} is not a folder; pass the folder that holds "
            "the 30 files <amplitude>mm<frequency>Hz<current>A.txt."
        )
    files = [p for p in directory.glob("*.txt") if _UTFSM_NAME.match(p.stem)]
    if not files:
        raise FileNotFoundError(
            f"{what}: no file named <amplitude>mm<frequency>Hz<current>A.txt in "
            f"{str(directory)!r}. Download them from {_UTFSM_SOURCE}."
        )
    experiments = []
    for path in sorted(files, key=lambda p: utfsm_test_conditions(p.stem)):
        data = np.loadtxt(path, dtype=np.float64, ndmin=2)
        if data.shape[1] != 4:
            raise ValueError(
                f"{what}: {str(path)!r} has {data.shape[1]} columns; expected 4 (time "
                "[s], displacement [mm], velocity [mm/s], force [N])."
            )
        t, x, v, force = data.T
        x, v = x * MM, v * MM
        conditions = utfsm_test_conditions(path.stem)
        current = conditions.current
        period = 1.0 / conditions.frequency  # `utfsm_first_cycle`
        smoothing = UTFSM_SMOOTHING * period
        with named_by_file(path):  # unit warnings name the file
            if velocity == "central":
                experiment = Experiment.from_arrays(
                    t,
                    x,
                    current=current,
                    force=force,
                    name=path.stem,
                    smoothing=smoothing,
                    discard=period,
                )
            else:
                experiment = Experiment(
                    t,
                    x,
                    v,
                    current,
                    force,
                    name=path.stem,
                    velocity_source=_UTFSM_VELOCITY_FILE,
                    smoothing=smoothing,
                    discard=period,
                )
        experiments.append(experiment)
    return experiments


# ---------------------------------------------------------------------------------------
# NEES prototype MR damper (Spencer et al. 1997, Dyke et al. 1996) under random motion

_NEES_SOURCE = (
    "DesignSafe/NEES project NEES-2012-1158 (DOI 10.4231/D3V11VM6X); CSV copy "
    "'ranran_50.csv' in the GitHub repository Abhay3757/PSO-Optimized-Dual-Attention-"
    "LSTM-for-MR-Damper-Force-Prediction"
)
_NEES_COLUMNS = ("t", "A", "D", "Y", "fs", "V", "F")
_NEES_VELOCITY_FILE = (
    "file: velocity computed by the data's authors (method undocumented)"
)
# Trimming to the moving part: 0.1 s blocks whose velocity RMS exceeds 5 % of the
# largest block RMS count as moving. At rest the file's velocity has an RMS of about
# 0.15 cm/s against 24 cm/s in the busiest block (and about 0.4 cm/s for central
# differences of D, whose single-sample spikes after the motion are why the rule uses
# the file's smoother column); the last moving block ends at 21.3 s.
_NEES_BLOCK = 0.1  # s
_NEES_MOVING = 0.05  # fraction of the largest block RMS


# The start of the NEES record left out of scores [s]: it starts during the motion,
# its hysteretic state unknown.
NEES_DISCARD = 0.2


def _nees_end_of_motion(v: np.ndarray, fs: float) -> int:
    """The number of samples up to the end of the last moving block plus one block."""
    n = max(int(round(_NEES_BLOCK * fs)), 1)
    blocks = len(v) // n
    rms = np.sqrt(np.mean(np.square(v[: blocks * n].reshape(blocks, n)), axis=1))
    moving = np.flatnonzero(rms > _NEES_MOVING * np.max(rms))
    if moving.size == 0:
        return len(v)
    return min((int(moving[-1]) + 2) * n, len(v))


def load_nees(
    path: str | os.PathLike,
    *,
    trim: bool = False,
    velocity: Literal["file", "central"] = "file",
) -> Experiment:
    r"""The Spencer/Dyke prototype MR damper under band-limited random motion and a
    random on/off command voltage, in SI units.

    S. Dyke, "Prototype MR Damper Characterization Tests Using White Noise",
    DesignSafe/NEES project NEES-2012-1158, DOI 10.4231/D3V11VM6X (tests 1994–96 of the
    damper of Spencer et al. 1997 and Dyke et al. 1996). The record `ranran_50`:
    displacement 0–50 Hz random (±0.6 cm), command voltage switching between about
    −0.2 and 2.25 V, forces about ±1.9 kN, 74 068 samples at 3004.8 Hz (24.6 s); the
    motion stops at about 21.3 s and the rest is the damper at rest. The record starts
    during the motion (the hysteretic state at $t = 0$ is unknown).

    Download: the DOI above (DesignSafe data depot), or its CSV copy `ranran_50.csv` in
    the GitHub repository
    `Abhay3757/PSO-Optimized-Dual-Attention-LSTM-for-MR-Damper-Force-Prediction`
    (commit 92619e4); cite the DOI.

    The CSV has the columns `t, A, D, Y, fs, V, F`: time (rounded), actuator
    acceleration (dropped here), displacement [cm], command voltage [V], the sampling
    rate [Hz] (first row only), velocity [cm/s] and force [N]. The time is rebuilt from
    the row index, $t_k = k / f_s$, because the `t` column is rounded; centimetres
    are converted to metres.

    **Arguments:**

    - `path`: the CSV file.
    - `trim`: keep only the moving part (up to 0.1 s after the last 0.1 s block whose
      velocity RMS exceeds 5 % of the largest one: 21.37 s for `ranran_50`).
    - `velocity`: `"file"` (default) keeps the file's velocity column (zero-lag and
      smoother than differences of the displacement); `"central"` recomputes it from
      the displacement by central differences.

    **Returns:** an `Experiment` with `drive="voltage"` (`current` holds the command
    voltage [V]), named after the file stem, with a `discard` of `NEES_DISCARD`
    (0.2 s: the record starts during the motion, its hysteretic state unknown).
    """
    what = "load_nees"
    path = _existing(path, what, _NEES_SOURCE)
    if velocity not in ("file", "central"):
        raise ValueError(f"`velocity` must be 'file' or 'central', got {velocity!r}.")
    with open(path, encoding="utf-8") as file:
        header = file.readline()
        first = file.readline()
    names = [n.strip().strip('"') for n in header.strip().split(",")]
    while names and not names[-1]:
        names.pop()  # the file ends every line with a comma
    missing = [n for n in _NEES_COLUMNS if n not in names]
    if missing:
        raise ValueError(
            f"{what}: {str(path)!r} lacks the columns {missing}; expected the header "
            f'"t","A","D","Y","fs","V","F", found {names}.'
        )
    index = {n: names.index(n) for n in _NEES_COLUMNS}
    try:
        fs = float(first.split(",")[index["fs"]])
    except (ValueError, IndexError):
        raise ValueError(
            f"{what}: the sampling rate `fs` must be in the first data row of "
            f"{str(path)!r}; found {first.strip()!r}."
        ) from None
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"{what}: the sampling rate in {str(path)!r} is {fs}.")
    used = ("t", "D", "Y", "V", "F")
    data = np.loadtxt(
        path,
        delimiter=",",
        skiprows=1,
        usecols=[index[n] for n in used],
        dtype=np.float64,
        ndmin=2,
    )
    t_file, d, y, v, force = data.T
    t = np.arange(len(t_file)) / fs
    # The rounded time column must still agree with the rebuilt one to within a sample,
    # else `fs` is not the rate of this record.
    mismatch = float(np.max(np.abs(t - t_file)))
    if mismatch > 1 / fs:
        raise ValueError(
            f"{what}: the time column of {str(path)!r} departs by {mismatch:g} s from "
            f"k/fs with fs = {fs} Hz; the file is not the expected record."
        )
    x, v = d * CM, v * CM
    if trim:
        end = _nees_end_of_motion(v, fs)
        t, x, v, y, force = (a[:end] for a in (t, x, v, y, force))
    if velocity == "central":
        v, source = central_velocity(t, x), VELOCITY_CENTRAL
    else:
        source = _NEES_VELOCITY_FILE
    with named_by_file(path):  # unit warnings name the file
        return Experiment(
            t,
            x,
            v,
            y,
            force,
            name=path.stem,
            drive="voltage",
            velocity_source=source,
            discard=NEES_DISCARD,
        )


# ---------------------------------------------------------------------------------------
# Bouc–Wen hysteretic benchmark (Noël & Schoukens 2016)

BOUCWEN_BENCHMARK_FS = 750.0  # Hz
_BOUCWEN_SOURCE = (
    "nonlinearbenchmark.org, 'Hysteretic benchmark with a dynamic nonlinearity' "
    "(Noël & Schoukens 2016, data DOI 10.4121/12967592); train.h5 as in the GitHub "
    "repository forgi86/dynonet, examples/BW/data/Test signals/train.h5"
)
_BOUCWEN_INPUTS = {"multisine": 8192, "sinesweep": 153000}


class BoucWenBenchmarkTrain(NamedTuple):
    """The benchmark's training record (a force input, a displacement output)."""

    t: Float[np.ndarray, " samples"]
    """Time [s], $k / f_s$."""
    u: Float[np.ndarray, " samples"]
    """Input force [N]."""
    y: Float[np.ndarray, " samples"]
    """Output displacement [m] (with measurement noise of about 8e-6 m RMS)."""
    fs: float
    """Sampling rate [Hz] (750)."""


class BoucWenBenchmarkInput(NamedTuple):
    """One of the benchmark's official test inputs (its outputs are scored
    elsewhere)."""

    t: Float[np.ndarray, " samples"]
    """Time [s], $k / f_s$ with $f_s$ = 750 Hz."""
    u: Float[np.ndarray, " samples"]
    """Input force [N]."""
    kind: str
    """`"multisine"` (8192 samples, one steady-state period) or `"sinesweep"` (153 000
    samples, from rest)."""


def load_boucwen_benchmark_train(path: str | os.PathLike) -> BoucWenBenchmarkTrain:
    r"""The training data of the Bouc–Wen hysteretic benchmark.

    J.-P. Noël and M. Schoukens (2016), "Hysteretic benchmark with a dynamic
    nonlinearity", Workshop on Nonlinear System Identification Benchmarks; data DOI
    10.4121/12967592, nonlinearbenchmark.org. A single-degree-of-freedom oscillator
    with a Bouc–Wen hysteretic restoring force, driven by a force.

    Download: the benchmark's files from nonlinearbenchmark.org (DOI above); the HDF5
    file read here is `examples/BW/data/Test signals/train.h5` of the GitHub repository
    `forgi86/dynonet`, made with the benchmark's own generator: `/multisine/u` and
    `/multisine/y` (40 960 × 1: five periods of an 8192-point multisine from rest,
    5–150 Hz, 50 N RMS) and `/multisine/fs` (750 Hz). Needs `h5py`.

    Unlike an `Experiment` (motion in, force out), this system takes a force in and
    gives a displacement out, so a plain record is returned.

    **Arguments:**

    - `path`: the `train.h5` file.

    **Returns:** `BoucWenBenchmarkTrain(t, u, y, fs)` (a named tuple; unpack it as
    `t, u, y, fs = ...`): float64 NumPy arrays of time [s], force [N], displacement
    [m], and the rate [Hz].
    """
    what = "load_boucwen_benchmark_train"
    h5py = _require("h5py", what)
    path = _existing(path, what, _BOUCWEN_SOURCE)
    with h5py.File(path, "r") as file:
        keys = ("multisine/u", "multisine/y", "multisine/fs")
        missing = [k for k in keys if k not in file]
        if missing:
            found = []
            file.visit(found.append)
            raise ValueError(
                f"{what}: {str(path)!r} lacks the datasets {missing}; found {found}."
            )
        u = np.asarray(file["multisine/u"][()], dtype=np.float64).reshape(-1)
        y = np.asarray(file["multisine/y"][()], dtype=np.float64).reshape(-1)
        fs = float(np.asarray(file["multisine/fs"][()]).reshape(-1)[0])
    if u.shape != y.shape:
        raise ValueError(
            f"{what}: u and y have different lengths ({u.size}, {y.size}) in "
            f"{str(path)!r}."
        )
    for name, a in (("u", u), ("y", y)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise ValueError(
                f"{what}: `{name}` has a non-finite value at index {int(bad[0])} in "
                f"{str(path)!r}."
            )
    return BoucWenBenchmarkTrain(np.arange(u.size) / fs, u, y, fs)


def load_boucwen_benchmark_input(path: str | os.PathLike) -> BoucWenBenchmarkInput:
    """One official test input of the Bouc–Wen hysteretic benchmark.

    Noël & Schoukens (2016), data DOI 10.4121/12967592 (see
    `load_boucwen_benchmark_train`). Download `uval_multisine.mat` (variable
    `uval_multisine`, 1 × 8192: one steady-state period of a multisine) or
    `uval_sinesweep.mat` (variable `uval_sinesweep`, 1 × 153 000: a sine sweep from
    rest) from nonlinearbenchmark.org. Sampled at 750 Hz. Needs `scipy`.

    **Arguments:**

    - `path`: one of the two `.mat` files.

    **Returns:** `BoucWenBenchmarkInput(t, u, kind)`: time [s] ($k$/750 Hz) and force
    [N] as float64 NumPy arrays, and `"multisine"` or `"sinesweep"` (from the variable's
    name, checked against its length).
    """
    what = "load_boucwen_benchmark_input"
    scipy_io = _require("scipy.io", what)
    path = _existing(path, what, _BOUCWEN_SOURCE)
    content = scipy_io.loadmat(path)
    variables = {k: v for k, v in content.items() if not k.startswith("__")}
    kinds = [k for k in _BOUCWEN_INPUTS if f"uval_{k}" in variables]
    if len(kinds) != 1:
        raise ValueError(
            f"{what}: {str(path)!r} should hold exactly one of the variables "
            f"'uval_multisine' or 'uval_sinesweep'; found {sorted(variables)}."
        )
    kind = kinds[0]
    u = np.asarray(variables[f"uval_{kind}"], dtype=np.float64).reshape(-1)
    if u.size != _BOUCWEN_INPUTS[kind]:
        raise ValueError(
            f"{what}: `uval_{kind}` in {str(path)!r} has {u.size} samples; the "
            f"benchmark's has {_BOUCWEN_INPUTS[kind]}."
        )
    bad = np.flatnonzero(~np.isfinite(u))
    if bad.size:
        raise ValueError(
            f"{what}: `uval_{kind}` has a non-finite value at index {int(bad[0])}."
        )
    return BoucWenBenchmarkInput(np.arange(u.size) / BOUCWEN_BENCHMARK_FS, u, kind)


# The UTFSM authors' moving average, as a fraction of the nominal period.
UTFSM_SMOOTHING = 0.1


def utfsm_first_cycle(experiments) -> np.ndarray:
    """One nominal period [s] per UTFSM test (the start to discard from the error: the
    hysteretic state is unknown there and the authors' moving average starts)."""
    return np.array([1.0 / utfsm_test_conditions(e).frequency for e in experiments])


def utfsm_smoothing(experiments) -> np.ndarray:
    """The width [s] of the authors' moving average per UTFSM test: a tenth of the
    nominal period. Both the displacement and the force went through it, so a model's
    force is compared like with like after the same smoothing (`jaxmr.record_nrmse`'s and
    `jaxmr.fit`'s `smoothing`); it spreads each force reversal over 36° of phase."""
    return UTFSM_SMOOTHING * utfsm_first_cycle(experiments)
