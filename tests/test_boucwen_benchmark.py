"""The Bouc–Wen hysteretic benchmark (Noël & Schoukens 2016, SYSTEMS.md §4): the
parameter mapping, the true model against the training record, the band-limited
inputs, the script's input detection, and a small fit on the real record."""

import importlib.util
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
from jaxmr._hysteresis.bouc_wen import bouc_wen_rate
from jaxmr._identify.system import SystemRecord, fit_system
from jaxmr._systems.oscillator import (
    band_limited_input,
    hysteretic_benchmark_oscillator,
)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "boucwen_benchmark"
FS = 750.0
PERIOD = 8192
SUBSTEPS = 10  # 7.5 kHz RK4: ~4e-8 m from the converged response, far below noise


def _script():
    spec = importlib.util.spec_from_file_location(
        "boucwen_benchmark", ROOT / "benchmarks" / "boucwen_benchmark.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("nu", [1.0, 1.5])
def test_parameter_mapping(nu):
    # The benchmark's ż = α ẏ − β(γ |ẏ| |z|^(ν−1) z + δ ẏ |z|^ν), with its own
    # parameters, against jaxmr's rate and force for the factory's system.
    alpha, beta, gamma, delta = 5e4, 1e3, 0.8, -1.1
    system = hysteretic_benchmark_oscillator(nu=nu)
    bw = system.damper.hysteresis
    rng = np.random.default_rng(0)
    z, v = rng.normal(0, 20, 50), rng.normal(0, 0.1, 50)
    benchmark = alpha * v - beta * (
        gamma * np.abs(v) * np.abs(z) ** (nu - 1) * z + delta * v * np.abs(z) ** nu
    )
    jaxmr_rate = bouc_wen_rate(jnp.asarray(z), jnp.asarray(v), bw.A, bw.beta,
                               bw.gamma, bw.n)  # fmt: skip
    np.testing.assert_allclose(jaxmr_rate, benchmark, rtol=1e-12, atol=1e-9)
    # The restoring force is z itself [N]: alpha 1, the spring and dashpot the
    # oscillator's (m ÿ + c ẏ + k y + z = u).
    x = jnp.asarray(1e-3)
    force = bw.force(jnp.asarray([7.0]), x, jnp.asarray(0.2))
    assert float(force) == 7.0
    assert (float(system.mass), float(system.damping), float(system.stiffness)) == (
        2.0,
        10.0,
        5e4,
    )
    assert (float(bw.A), float(bw.beta), float(bw.gamma), float(bw.n)) == (
        5e4,
        -1100.0,
        800.0,
        nu,
    )


def test_input_kind_by_length():
    script = _script()
    assert script.input_kind(np.zeros(8192)) == "multisine"
    assert script.input_kind(np.zeros(153_000)) == "sinesweep"
    with pytest.raises(ValueError, match="8192"):
        script.input_kind(np.zeros(1000))


def test_band_limited_inputs():
    # Periodic: FFT zero-padding is exact for a band-limited periodic signal.
    n, fs = 64, 100.0
    t = np.arange(n) / fs
    tone = lambda t: np.sin(2 * np.pi * 7 * fs / n * t + 0.3)  # noqa: E731
    s = band_limited_input(tone(t), fs, 8, periodic=True)
    np.testing.assert_allclose(s.values, tone(np.asarray(s.times)), atol=1e-12)
    # Transient: the benchmark's sweep 40 sin(2π(18 t + t²/12)) N, from rest. The
    # windowed sinc meets it to 1e-6 of the amplitude (2.2e-7 measured; the start
    # included: the record is continued by point reflection); only the last
    # half-width (32 samples) feel the end (3e-3 N at 3 samples from it).
    t = np.arange(3000) / FS
    sweep = lambda t: 40 * np.sin(2 * np.pi * (18 * t + t**2 / 12))  # noqa: E731
    s = band_limited_input(sweep(t), FS, 8, periodic=False)
    error = np.asarray(s.values) - sweep(np.asarray(s.times))
    assert np.max(np.abs(error[: -8 * 32])) < 40e-6
    # Linear interpolation of the 750 Hz samples is ~1e4x worse (0.12 N here, at
    # 18 Hz; 0.9 N at the end of the benchmark's sweep).
    linear = np.interp(np.asarray(s.times), t, sweep(t)) - sweep(np.asarray(s.times))
    assert np.max(np.abs(linear)) > 1e3 * np.max(np.abs(error[: -8 * 32]))


@pytest.fixture(scope="module")
def window():
    """The first second of the training record (from rest) and its input."""
    train = jaxmr.data.load_boucwen_benchmark_train(DATA / "train.h5")
    excitation = band_limited_input(
        train.u[:PERIOD], FS, 2 * SUBSTEPS, periodic=True
    )  # one whole period: the FFT interpolation needs it; 1 s of it is simulated
    n = 750
    # The noise, from the record's periodicity: periods 2 and 5 are the same steady
    # state, so their difference is noise × √2.
    noise = np.std(train.y[PERIOD : 2 * PERIOD] - train.y[4 * PERIOD :]) / np.sqrt(2)
    return train.t[:n], train.y[:n], excitation, noise


def test_true_model_reproduces_the_training_record(window):
    ts, y, excitation, noise = window
    solution = jaxmr.simulate_system(
        hysteretic_benchmark_oscillator(), excitation, 0.0, ts.size / FS,
        sampling=jaxmr.Sampling(dt=1 / FS), integrator=jaxmr.FixedStep(SUBSTEPS),
    )  # fmt: skip
    error = np.asarray(solution.outputs["body_position"]) - y
    # Within 15 % of the noise (7.4e-6 m rms; 750 samples estimate an rms to ~3 %).
    assert 0.85 * noise < np.sqrt(np.mean(error**2)) < 1.15 * noise
    assert noise < 8e-6


def test_small_fit_on_the_training_record(window):
    # βγ and βδ, 2x off, from one second of the real record (noise 1.1 % of the
    # response).
    ts, y, excitation, _ = window
    start = hysteretic_benchmark_oscillator()
    start = eqx.tree_at(
        lambda s: (s.damper.hysteresis.beta, s.damper.hysteresis.gamma),
        start,
        # float64, not weakly typed (`jnp.asarray(-550.0)`): the statistics, taken at
        # the float64 optimum, then reuse the column scaling's compiled Jacobian.
        (jnp.array(-550.0, float), jnp.array(1600.0, float)),
    )
    start = jaxmr.fit_only(
        start, lambda s: (s.damper.hysteresis.beta, s.damper.hysteresis.gamma)
    )
    record = SystemRecord(ts, y, excitation, name="train, first second")
    result = fit_system(start, record, substeps=SUBSTEPS, patience=4, progress=False)
    assert result.converged, result.reason
    # Standard errors here are ~0.1 % (measured 0.08 %, 0.12 %; recovered to 0.02 %).
    np.testing.assert_allclose(result.values, [-1100.0, 800.0], rtol=5e-3)
    assert np.all(np.abs(result.values - [-1100.0, 800.0]) < 4 * result.std_errors)
