"""The datasets of `generalisation.py`: every damper the project has, each as a
training split and a held-out split (held-out input levels and held-out records).

- `utfsm`: the UTFSM constant-current sine tests (measured), a subset shortened to
  keep each fit in seconds;
- `nees`: the NEES random-motion record of the Spencer/Dyke damper (measured), cut into
  segments, some held out;
- `sim_<preset>`: simulated tests of each linear preset damper of `jaxmr.PRESETS` and
  of the SAS brake's Dahl model (a family other than Bouc–Wen), with white and AR(1)
  noise on the force and small noise on displacement and velocity; two of them also
  with their force-level laws saturating with the input (`sim_<preset>_saturating`,
  session 29); `sim_<preset>@2`, `@3`, `@4`: independent draws of the same (other
  noise and random motions, `DRAW_SEEDS`).

Every dataset also carries, per record, the start [s] left out of the error (the
hysteretic state is unknown there) and the moving-average width [s] the measured
force went through, as the `# discard:` and `# smoothing:` lines of a CSV file give
them to `jaxmr fit`.
"""

import dataclasses
from pathlib import Path

import equinox as eqx
import numpy as np

import jaxmr
import jaxmr.data as jd

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
UTFSM = DATA / "utfsm_mr_damper" / "sine"
NEES = DATA / "nees_dyke_mr_damper" / "ranran_50.csv"

# Seeds of the simulated noise and random motions, one per independent draw of every
# simulated dataset (one stream per dataset, derived from the draw's seed and the
# dataset's position in SIMULATED): the same presets, test plans and noise model,
# other noise and random motions. Draw 1 (`sim_<preset>`) is the draw the screening
# and selection defaults were first looked at on; draw 2 (`sim_<preset>@2`) was added
# to choose them on more evidence (issue 25); draw 3 (`sim_<preset>@3`) was drawn
# after the defaults were frozen, to score them on data they were not chosen on.
# Draw 3's seed was drawn (secrets.randbelow) after the selection defaults were frozen
# on draws 1 and 2 (2026-11-26).
DRAW_SEEDS = (20261125, 20261126, 14855289, 3871964, 6462158)
SEED = DRAW_SEEDS[0]
# The draws the library's selection defaults were chosen on (screening_choice.py),
# with the real datasets (there is one of each, so they were used in the choice too).
CHOICE_DRAWS = (1, 2)
# The draw `generalisation.py` scores the frozen defaults on by default. Draw 4's seed
# was drawn (secrets.randbelow) on 2026-11-28 after the saturating candidates were
# adopted by saturation_choice_rule.md on draws 1 and 2; draw 3 had scored the
# defaults before them (sessions 26-28), so it is neither a choice nor a fresh draw.
# Draw 5's seed was drawn (secrets.randbelow) on 2026-11-28 (session 30) after
# screening_folds_rule.md, on draws 2 and 4, kept the screening on the first fold.
FRESH_DRAW = 5
# Noise on the simulated force, as fractions of its standard deviation: white, plus
# AR(1) with lag-one correlation AR_PHI (a force channel's filter and the model error
# a real rig leaves are correlated from sample to sample).
WHITE_NOISE = 0.02
AR_NOISE = 0.03
AR_PHI = 0.95
# Noise on displacement and velocity, as fractions of each one's amplitude.
MOTION_NOISE = 0.002
# Cycles per simulated sine test (the first is discarded from the error) and samples
# per cycle.
CYCLES = 2.5
SAMPLES_PER_CYCLE = 100
# The random-motion records: length [s], multisine band [Hz] and components, the
# input switching interval [s] (where it varies), and the discarded start [s].
RANDOM_SECONDS = 2.0
RANDOM_BAND = (0.5, 6.0)
RANDOM_COMPONENTS = 12
SWITCH_SECONDS = 0.2
RANDOM_DISCARD = 0.2


@dataclasses.dataclass
class Dataset:
    """A damper's training and held-out records, with each record's discarded start
    and smoothing width [s]."""

    name: str
    truth: str  # the simulated model's family, or "measured"
    train: list
    test: list
    train_discard: list
    test_discard: list
    train_smoothing: list
    test_smoothing: list

    def summary(self) -> dict:
        def samples(es):
            return int(sum(len(e) for e in es))

        return {
            "truth": self.truth,
            "train": [e.name for e in self.train],
            "test": [e.name for e in self.test],
            "train_samples": samples(self.train),
            "test_samples": samples(self.test),
            "input_varies": bool(any(not e.is_constant_current for e in self.train)),
        }


def _decimate(e, step: int):
    """Every `step`-th sample (the data were already smoothed or band-limited)."""
    s = slice(None, None, step)
    return jd.Experiment(
        np.asarray(e.t)[s],
        np.asarray(e.x)[s],
        np.asarray(e.v)[s],
        np.asarray(e.current)[s],
        np.asarray(e.force)[s],
        name=e.name,
        rotary=e.rotary,
        drive=e.drive,
        velocity_source=e.velocity_source,
    )


def _shift(e, name: str):
    """`e` with its time starting at 0 (a segment written as its own file)."""
    t = np.asarray(e.t)
    return jd.Experiment(
        t - t[0],
        e.x,
        e.v,
        e.current,
        e.force,
        name=name,
        rotary=e.rotary,
        drive=e.drive,
        velocity_source=e.velocity_source,
    )


# UTFSM: training pairs (amplitude/frequency) at 0, 0.5, 1 A; held out: the same at
# 0.25 and 0.75 A (held-out levels) and two other pairs at 0.5 A (held-out records).
# (The 25 mm tests are held out only: 2.5 of their cycles take 10 000 steps of 25 µm
# travel per evaluation, which would make every fit minutes long.)
UTFSM_TRAIN_PAIRS = ("2mm5Hz", "10mm1Hz", "5mm3Hz")
UTFSM_TEST_PAIRS = ("25mm0x5Hz",)


def utfsm(quick: bool = False) -> Dataset:
    experiments = jd.load_utfsm(UTFSM)
    period = dict(zip([e.name for e in experiments], jd.utfsm_first_cycle(experiments)))
    width = dict(zip([e.name for e in experiments], jd.utfsm_smoothing(experiments)))
    train_pairs = UTFSM_TRAIN_PAIRS[:2] if quick else UTFSM_TRAIN_PAIRS
    test_pairs = UTFSM_TEST_PAIRS[:1] if quick else UTFSM_TEST_PAIRS
    train, test = [], []
    for e in experiments:
        pair, _, current = e.name.partition("Hz")
        pair += "Hz"
        level = jd.utfsm_test_conditions(e).current
        # Two and a half cycles (the first discarded), at most ~250 samples a cycle.
        t0 = float(np.asarray(e.t)[0])
        cut = e.window(None, t0 + CYCLES * period[e.name])
        step = max(1, int(round(len(cut) / (CYCLES * 250))))
        cut = _decimate(cut, step)
        if pair in train_pairs and level in (0.0, 0.5, 1.0):
            train.append(cut)
        elif (pair in train_pairs and level in (0.25, 0.75)) or (
            pair in test_pairs and level == 0.5
        ):
            test.append(cut)
    return Dataset(
        "utfsm",
        "measured",
        train,
        test,
        [float(period[e.name]) for e in train],
        [float(period[e.name]) for e in test],
        [float(width[e.name]) for e in train],
        [float(width[e.name]) for e in test],
    )


# NEES: the first NEES_SEGMENTS 2 s segments of the random record at 1 kHz (every
# third sample), the 2nd and 4th held out. (Its fast random motion takes 25 µm steps
# at up to 0.5 m/s: a few seconds of it cost as much as all the sine tests.)
NEES_SEGMENTS = 5
NEES_SEGMENT = 2.0  # s
NEES_DECIMATION = 3
NEES_DISCARD = 0.2  # s


def nees() -> Dataset:
    record = _decimate(jd.load_nees(NEES, trim=True), NEES_DECIMATION)
    t = np.asarray(record.t)
    starts = np.arange(t[0], t[-1] - NEES_SEGMENT, NEES_SEGMENT)
    starts = starts[:NEES_SEGMENTS]
    train, test = [], []
    for k, s in enumerate(starts):
        segment = _shift(record.window(s, s + NEES_SEGMENT), f"nees_{s:.0f}s")
        (test if k % 5 in (1, 3) else train).append(segment)
    return Dataset(
        "nees",
        "measured",
        train,
        test,
        [NEES_DISCARD] * len(train),
        [NEES_DISCARD] * len(test),
        [0.0] * len(train),
        [0.0] * len(test),
    )


@dataclasses.dataclass(frozen=True)
class Preset:
    """How a preset damper is tested: its input levels, the sine tests (amplitude in
    the motion's unit, frequency [Hz]) for training and the one held out, the
    random-motion amplitude, and whether the random records' input varies."""

    name: str
    family: str
    levels: tuple
    train_sines: tuple
    test_sine: tuple
    random_amplitude: float
    varying_input: bool
    rotary: bool = False
    # The preset's laws (fields of its hysteresis model) bent to saturate with the
    # input (`saturated`), and the dataset's name where any are.
    saturate: tuple = ()
    label: str = ""

    @property
    def key(self) -> str:
        return self.label or self.name


SIMULATED = (
    Preset(
        "spencer_1997",
        "spencer_lag",
        (0.0, 0.5, 1.0, 1.5, 2.0),  # V
        ((0.01, 2.0), (0.005, 4.0)),
        (0.0075, 3.0),
        0.006,
        True,
    ),
    Preset(
        "passenger_car_mr_damper",
        "bouc_wen_lag",
        (0.0, 0.25, 0.5, 0.75, 1.0),  # A
        ((0.02, 1.5), (0.008, 5.0)),
        (0.012, 3.0),
        0.015,
        True,
    ),
    Preset(
        "review_quarter_car_damper",
        "bouc_wen",
        (0.0, 1.25, 2.5, 3.75, 5.0),  # V
        ((0.02, 1.5), (0.005, 5.0)),
        (0.01, 3.0),
        0.01,
        False,
    ),
    Preset(
        "utfsm_spencer",
        "spencer",
        (0.0, 0.25, 0.5, 0.75, 1.0),  # A
        ((0.005, 3.0), (0.01, 1.0)),
        (0.0075, 2.0),
        0.006,
        False,
    ),
    Preset(
        "sas_brake_dahl",
        "dahl",
        (0.0, 0.25, 0.5, 0.75, 1.0),  # A
        ((np.deg2rad(3.5), 1.0), (np.deg2rad(10.0), 0.5)),
        (np.deg2rad(6.0), 0.75),
        np.deg2rad(5.0),
        False,
        rotary=True,
    ),
)

# Two dampers whose force levels off with the input, as real ones do (the MR fluid's
# yield stress saturates with the field, the magnetic circuit with the coil's
# current): added in session 29 with the saturating candidates
# (saturation_choice_rule.md). The review's quarter-car damper (α and c0) and Spencer
# et al.'s (α), tested as the straight ones; their laws agree with the preset's at
# zero and at the largest input, and rise with input scale SATURATION_SCALE × the
# largest (`saturated`).
_BY_NAME = {p.name: p for p in SIMULATED}
SIMULATED += (
    dataclasses.replace(
        _BY_NAME["review_quarter_car_damper"],
        family="bouc_wen_saturating",
        saturate=("alpha", "c0"),
        label="review_quarter_car_damper_saturating",
    ),
    dataclasses.replace(
        _BY_NAME["spencer_1997"],
        family="spencer_lag_saturating",
        saturate=("alpha",),
        label="spencer_1997_saturating",
    ),
)
# The saturating presets' input scale i0, as a fraction of the largest input: the law
# reaches 1 - e^-1 = 63 % of its rise at a quarter of the range, 98 % at the top.
SATURATION_SCALE = 0.25


def saturated(device, fields, top: float):
    """`device` (a hysteresis model or a `Damper`) with the linear laws `fields` of
    its hysteresis model replaced by `SaturatingLaw`s equal to them at 0 and `top`
    (i0 = SATURATION_SCALE × top)."""
    inner = device.hysteresis if isinstance(device, jaxmr.Damper) else device
    i0 = SATURATION_SCALE * top
    for field in fields:
        law = getattr(inner, field)
        at_zero, at_top = float(law(np.asarray(0.0))), float(law(np.asarray(top)))
        slope = (at_top - at_zero) / (i0 * -np.expm1(-top / i0))
        bent = jaxmr.SaturatingLaw(at_zero, slope, i0)
        inner = eqx.tree_at(lambda m, f=field: getattr(m, f), inner, bent)
    if isinstance(device, jaxmr.Damper):
        return eqx.tree_at(lambda d: d.hysteresis, device, inner)
    return inner


def _noisy(rng, force):
    """The force with white and AR(1) noise (see WHITE_NOISE, AR_NOISE)."""
    scale = np.std(force)
    white = WHITE_NOISE * scale * rng.standard_normal(force.shape)
    innovations = rng.standard_normal(force.shape) * np.sqrt(1 - AR_PHI**2)
    coloured = np.empty_like(force)
    coloured[0] = rng.standard_normal()
    for k in range(1, len(force)):
        coloured[k] = AR_PHI * coloured[k - 1] + innovations[k]
    return force + white + AR_NOISE * scale * coloured


def _record(rng, preset, device, motion, current, ts, name, drive):
    """A simulated test as a measured one: noisy force, displacement and velocity."""
    sol = jaxmr.simulate(device, motion, current, ts)
    x, v = np.asarray(sol.displacement), np.asarray(sol.velocity)
    force = np.asarray(sol.force)
    if isinstance(current, jaxmr.Steps):
        times, values = np.asarray(current.times), np.asarray(current.values)
        index = np.clip(np.searchsorted(times, ts, side="right") - 1, 0, None)
        level = values[index]
    else:
        level = np.full(ts.shape, float(current))
    return jd.Experiment(
        ts,
        x + MOTION_NOISE * np.ptp(x) / 2 * rng.standard_normal(x.shape),
        v + MOTION_NOISE * np.ptp(v) / 2 * rng.standard_normal(v.shape),
        level,
        _noisy(rng, force),
        name=name,
        rotary=preset.rotary,
        drive=drive,
    )


def _random_motion(rng, preset, levels):
    """A multisine of random phases (RANDOM_BAND) scaled to the preset's random
    amplitude, and the input: random switching among `levels`, or the first level."""
    frequencies = np.linspace(*RANDOM_BAND, RANDOM_COMPONENTS)
    # Equal velocity per component: amplitudes falling as 1/f.
    amplitudes = 1.0 / frequencies
    phases = rng.uniform(0, 2 * np.pi, RANDOM_COMPONENTS)
    ts = np.linspace(0, RANDOM_SECONDS, int(RANDOM_SECONDS * 20 * RANDOM_BAND[1]) + 1)
    peak = np.max(
        np.abs(
            np.sum(
                amplitudes[:, None]
                * np.sin(2 * np.pi * frequencies[:, None] * ts + phases[:, None]),
                axis=0,
            )
        )
    )
    motion = jaxmr.Multisine(
        amplitudes * preset.random_amplitude / peak, frequencies, phases
    )
    if preset.varying_input:
        times = np.arange(0.0, RANDOM_SECONDS, SWITCH_SECONDS)
        current = jaxmr.Steps(times, rng.choice(np.asarray(levels), len(times)))
    else:
        current = float(levels[0])
    return motion, current, ts


def simulated(
    preset: Preset, index: int, quick: bool = False, draw: int = 1
) -> Dataset:
    """The simulated tests of `preset` (its position `index` in SIMULATED), drawn
    with the seed of `draw` (1, 2, ...: `DRAW_SEEDS`)."""
    rng = np.random.default_rng([DRAW_SEEDS[draw - 1], index])
    device = jaxmr.PRESETS[preset.name]()
    if preset.saturate:
        device = saturated(device, preset.saturate, max(preset.levels))
    drive = "voltage" if "V" in _unit(preset) else "current"
    levels = preset.levels
    train_levels, test_levels = levels[0::2], levels[1::2]
    train, test, train_discard, test_discard = [], [], [], []

    def sine(amplitude, frequency, level, into, discards):
        period = 1.0 / frequency
        ts = np.linspace(0.0, CYCLES * period, int(CYCLES * SAMPLES_PER_CYCLE) + 1)
        name = f"sine_{amplitude:.4g}_{frequency:g}Hz_{level:g}"
        into.append(
            _record(
                rng,
                preset,
                device,
                jaxmr.Sine(amplitude, frequency),
                level,
                ts,
                name,
                drive,
            )
        )
        discards.append(period)

    sines = preset.train_sines[:1] if quick else preset.train_sines
    for amplitude, frequency in sines:
        for level in train_levels:
            sine(amplitude, frequency, level, train, train_discard)
        for level in test_levels:
            sine(amplitude, frequency, level, test, test_discard)
    sine(*preset.test_sine, levels[len(levels) // 2], test, test_discard)
    # Random records: one for training (its input switching among the training
    # levels, or at the lowest), one held out (among all levels, or at a held-out one).
    for into, discards, pool, name in (
        (train, train_discard, train_levels, "random_train"),
        (
            test,
            test_discard,
            test_levels if not preset.varying_input else levels,
            "random_test",
        ),
    ):
        motion, current, ts = _random_motion(rng, preset, pool)
        into.append(_record(rng, preset, device, motion, current, ts, name, drive))
        discards.append(RANDOM_DISCARD)
    return Dataset(
        simulated_name(preset, draw),
        preset.family,
        train,
        test,
        train_discard,
        test_discard,
        [0.0] * len(train),
        [0.0] * len(test),
    )


def _unit(preset: Preset) -> str:
    """The input's unit: V for the voltage-driven presets."""
    return "V" if preset.name in ("spencer_1997", "review_quarter_car_damper") else "A"


def simulated_name(preset: Preset, draw: int = 1) -> str:
    """`sim_<preset>` for draw 1 (the name it always had), `sim_<preset>@<draw>`
    for the others."""
    return f"sim_{preset.key}" + ("" if draw == 1 else f"@{draw}")


def draw_of(name: str) -> int | None:
    """The draw of a simulated dataset's name (None for a real one)."""
    if not name.startswith("sim_"):
        return None
    return int(name.partition("@")[2] or 1)


def used_in_choice(name: str) -> bool:
    """Whether this dataset was seen before the defaults were frozen: the real
    ones, and every simulated draw before FRESH_DRAW (CHOICE_DRAWS chose the
    selection defaults; draws 3 and 4 scored earlier ones, and draw 4 was one of
    screening_folds_rule.md's choice draws)."""
    draw = draw_of(name)
    return draw is None or draw < FRESH_DRAW


def dataset_names(draws=(1,)) -> list[str]:
    """The real datasets and the simulated ones of `draws`, in a fixed order."""
    return ["utfsm", "nees"] + [
        simulated_name(p, draw) for draw in draws for p in SIMULATED
    ]


def datasets(names=None, quick: bool = False) -> list[Dataset]:
    """The datasets named (default: the real ones and draw 1 of the simulated
    ones), in a fixed order."""
    makers = {"utfsm": lambda: utfsm(quick), "nees": nees}
    for draw in range(1, len(DRAW_SEEDS) + 1):
        for k, preset in enumerate(SIMULATED):
            makers[simulated_name(preset, draw)] = lambda p=preset, k=k, draw=draw: (
                simulated(p, k, quick, draw)
            )
    names = dataset_names() if names is None else names
    unknown = [n for n in names if n not in makers]
    if unknown:
        raise ValueError(f"unknown dataset(s) {unknown}; known: {list(makers)}")
    return [makers[n]() for n in names]
