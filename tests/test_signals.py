"""Signals: derivatives against autodiff, bounds, interpolation, steps, triangle phase.

All comparisons run in float64 (conftest). `derivative` is an analytic formula and
`jax.grad` differentiates the value's formula, so away from kinks and switching times
they agree to rounding: a tolerance of 1e-10 of the derivative's scale leaves room for
the ~1e-16 relative rounding of each term times the condition number of the expressions
(at most ~1e3 here: e.g. arcsin near its ends).

Signals are evaluated through three compiled functions that take the signal as an
argument (compiled once per signal type and shape); the arithmetic of the checks is
numpy.
"""

import equinox as eqx
import jax
import numpy as np
import pytest

import jaxmr

RTOL = 1e-10


@eqx.filter_jit
def _values(signal, ts):
    return jax.vmap(signal)(ts)


@eqx.filter_jit
def _derivatives(signal, ts):
    return jax.vmap(signal.derivative)(ts)


@eqx.filter_jit
def _grads(signal, ts):
    return jax.vmap(jax.grad(signal))(ts)


def values(signal, ts):
    return np.asarray(_values(signal, np.asarray(ts, dtype=float)))


def derivatives(signal, ts):
    return np.asarray(_derivatives(signal, np.asarray(ts, dtype=float)))


def grads(signal, ts):
    return np.asarray(_grads(signal, np.asarray(ts, dtype=float)))


@eqx.filter_jit
def _bounds(signal):
    return signal.bounds()


def bounds(signal):
    lo, hi = _bounds(signal)
    return float(lo), float(hi)


IRREGULAR = np.array([0.0, 0.07, 0.2, 0.26, 0.41, 0.5, 0.73, 0.9, 1.0])

# name -> (signal, times at which to compare, scale of its derivative)
SIGNALS = {
    "constant": (jaxmr.Constant(1.5), [0.0, 0.13, 0.7], 1.0),
    "sine": (
        jaxmr.Sine(0.02, 3.0, phase=0.4, offset=0.1),
        [0.0, 0.013, 0.21, 0.37, 0.52],
        0.02 * 2 * np.pi * 3.0,
    ),
    "multisine": (
        jaxmr.Multisine(
            np.array([0.01, 0.004, 0.002]),
            np.array([1.0, 3.5, 7.0]),
            np.array([0.0, 1.0, -2.0]),
        ),
        [0.0, 0.11, 0.37, 0.8],
        2 * np.pi * (0.01 * 1.0 + 0.004 * 3.5 + 0.002 * 7.0),
    ),
    "multisine-no-phases": (
        jaxmr.Multisine(np.array([1.0, 0.5]), np.array([2.0, 5.0])),
        [0.05, 0.33],
        2 * np.pi * (2.0 + 2.5),
    ),
    "chirp": (
        jaxmr.Chirp(0.01, 1.0, 20.0, 2.0),
        [0.0, 0.3, 1.1, 1.9, 2.5],  # beyond `duration` too
        0.01 * 2 * np.pi * 25.0,
    ),
    # Kinks at the peaks (2π f t + phase = π/2 + kπ: t = 0.125 + 0.25 k at 2 Hz, phase
    # 0): compare between them.
    "triangle": (
        jaxmr.Triangle(0.5, 2.0, offset=-0.2),
        [0.01, 0.06, 0.2, 0.3, 0.44, 0.61],
        4 * 0.5 * 2.0,
    ),
    # Kinks at the sample times (and `jnp.clip` splits the gradient there): compare
    # between them.
    "sampled-linear": (
        jaxmr.Sampled(IRREGULAR, np.sin(3 * IRREGULAR)),
        [0.03, 0.15, 0.3, 0.62, 0.95],
        3.0,
    ),
    "sampled-hermite": (
        jaxmr.Sampled(IRREGULAR, np.sin(3 * IRREGULAR), 3 * np.cos(3 * IRREGULAR)),
        [0.03, 0.15, 0.3, 0.62, 0.95],
        3.0,
    ),
    # Zero derivative; compare away from the switching times.
    "steps": (
        jaxmr.Steps(np.array([0.1, 0.3]), np.array([1.0, -2.0])),
        [0.0, 0.2, 0.5],
        1.0,
    ),
}
PIECEWISE_CONSTANT = ("constant", "steps")


@pytest.mark.parametrize("name", list(SIGNALS))
def test_derivative_matches_grad(name):
    signal, ts, scale = SIGNALS[name]
    derivative = derivatives(signal, ts)
    np.testing.assert_allclose(derivative, grads(signal, ts), rtol=0, atol=RTOL * scale)
    if name not in PIECEWISE_CONSTANT:  # not trivially zero
        assert np.max(np.abs(derivative)) > 0.1 * scale


@pytest.mark.parametrize("name", [n for n in SIGNALS if n not in PIECEWISE_CONSTANT])
def test_derivative_matches_central_differences(name):
    # Independent of autodiff: central differences with step 1e-6 s have truncation
    # error ~ h² |s'''| / 6 ~ 1e-12 |s'''| and rounding ~ 1e-16 |s| / h ~ 1e-10 |s|;
    # 1e-6 of the derivative's scale covers both for these signals.
    signal, ts, scale = SIGNALS[name]
    ts = np.asarray(ts)
    h = 1e-6
    differences = (values(signal, ts + h) - values(signal, ts - h)) / (2 * h)
    np.testing.assert_allclose(
        derivatives(signal, ts), differences, rtol=0, atol=1e-6 * scale
    )


DENSE = np.linspace(-0.5, 3.0, 3501)  # before, over and after every sample time


@pytest.mark.parametrize("name", list(SIGNALS))
def test_bounds_contain_the_values(name):
    signal, _, _ = SIGNALS[name]
    v = values(signal, DENSE)
    lo, hi = bounds(signal)
    slack = 1e-12 * max(1.0, np.max(np.abs(v)))
    assert lo <= hi
    assert np.all(v >= lo - slack), (np.min(v), lo)
    assert np.all(v <= hi + slack), (np.max(v), hi)


@pytest.mark.parametrize(
    "name",
    ["constant", "sine", "triangle", "sampled-linear", "sampled-hermite", "steps"],
)
def test_bounds_are_the_extremes(name):
    # For these the bounds are the exact extremes (the Hermite pieces' overshoot
    # included); 3501 samples over several periods come within 1e-3 of the span.
    signal, _, _ = SIGNALS[name]
    v = values(signal, DENSE)
    lo, hi = bounds(signal)
    span = max(hi - lo, 1.0)
    assert abs(np.min(v) - lo) < 1e-3 * span, (np.min(v), lo)
    assert abs(np.max(v) - hi) < 1e-3 * span, (np.max(v), hi)


def test_hermite_bounds_include_overshoot_between_samples():
    # Steep measured derivatives make the cubic pieces overshoot the samples: the
    # bounds must cover that (the TableLaw range check relies on them).
    derivatives_ = 5 * np.array([1.0, -2.0, 0.5, 3.0, 0.0, -1.0, 2.0, 0.25, -0.5])
    signal = jaxmr.Sampled(IRREGULAR, np.sin(3 * IRREGULAR), derivatives_)
    v = values(signal, np.linspace(0.0, 1.0, 20001))
    lo, hi = bounds(signal)
    assert np.max(v) > np.max(np.sin(3 * IRREGULAR)) + 0.1  # it does overshoot
    assert hi >= np.max(v) - 1e-12 and hi - np.max(v) < 1e-6
    assert lo <= np.min(v) + 1e-12 and np.min(v) - lo < 1e-6


def test_constant():
    signal = jaxmr.Constant(2.5)
    ts = [-1.0, 0.0, 3.0]
    np.testing.assert_array_equal(values(signal, ts), [2.5, 2.5, 2.5])
    np.testing.assert_array_equal(derivatives(signal, ts), [0.0, 0.0, 0.0])
    assert bounds(signal) == (2.5, 2.5)


def test_sampled_linear_reproduces_a_linear_function():
    line = lambda t: 2.0 - 3.0 * np.asarray(t)
    signal = jaxmr.Sampled(IRREGULAR, line(IRREGULAR))
    ts = np.array([0.0, 0.01, 0.07, 0.19, 0.33, 0.5, 0.64, 0.999, 1.0])
    np.testing.assert_allclose(values(signal, ts), line(ts), rtol=0, atol=1e-14)
    inside = [0.01, 0.19, 0.33, 0.64, 0.999]
    np.testing.assert_allclose(derivatives(signal, inside), -3.0, rtol=0, atol=1e-12)
    # Outside the samples the end values are held, with zero derivative.
    np.testing.assert_allclose(values(signal, [-1.0, 2.0]), line([0.0, 1.0]), atol=0)
    np.testing.assert_array_equal(derivatives(signal, [-1.0, 2.0]), [0.0, 0.0])


def test_sampled_linear_is_piecewise_linear_between_samples():
    # Between samples it is the chord (it does not fit a smooth curve).
    signal = jaxmr.Sampled(np.array([0.0, 1.0, 3.0]), np.array([0.0, 4.0, -2.0]))
    np.testing.assert_allclose(
        values(signal, [0.5, 2.0, 2.5]), [2.0, 1.0, -0.5], atol=1e-15
    )
    np.testing.assert_allclose(derivatives(signal, [0.5, 2.0]), [4.0, -3.0], atol=1e-15)


def test_sampled_hermite_reproduces_a_cubic():
    # The cubic Hermite interpolant through values and exact derivatives of a cubic is
    # that cubic: only rounding remains (values ~1, hence 1e-13 absolute).
    cubic = lambda t: 1.0 - 2.0 * t + 0.5 * t**2 + 0.7 * t**3
    slope = lambda t: -2.0 + 1.0 * t + 2.1 * t**2
    times = 2.0 * IRREGULAR  # 0..2, irregular
    signal = jaxmr.Sampled(times, cubic(times), slope(times))
    ts = np.linspace(0.0, 2.0, 57)
    np.testing.assert_allclose(values(signal, ts), cubic(ts), rtol=0, atol=1e-13)
    np.testing.assert_allclose(derivatives(signal, ts), slope(ts), rtol=0, atol=1e-12)


def test_sampled_hermite_matches_the_measured_derivatives_at_the_samples():
    measured = np.array([1.0, -2.0, 0.5, 3.0, 0.0, -1.0, 2.0, 0.25, -0.5])
    signal = jaxmr.Sampled(IRREGULAR, np.cos(IRREGULAR), measured)
    np.testing.assert_allclose(values(signal, IRREGULAR), np.cos(IRREGULAR), atol=1e-15)
    np.testing.assert_allclose(derivatives(signal, IRREGULAR), measured, atol=1e-12)


def test_steps_values_at_before_and_after_switching_times():
    signal = jaxmr.Steps(np.array([0.1, 0.3, 0.6]), np.array([0.5, 1.5, -0.5]))
    cases = {
        -1.0: 0.5,  # before times[0]: values[0]
        0.0: 0.5,
        0.1: 0.5,  # from times[k] on: values[k]
        0.2999: 0.5,
        0.3: 1.5,
        0.45: 1.5,
        0.5999: 1.5,
        0.6: -0.5,
        10.0: -0.5,  # after the last: held
    }
    ts = list(cases)
    np.testing.assert_array_equal(values(signal, ts), list(cases.values()))
    np.testing.assert_array_equal(derivatives(signal, ts), np.zeros(len(ts)))
    assert bounds(signal) == (-0.5, 1.5)


def test_single_step_holds_its_value():
    signal = jaxmr.Steps(np.array([0.2]), np.array([3.0]))
    np.testing.assert_array_equal(values(signal, [0.0, 0.2, 0.5]), [3.0, 3.0, 3.0])


@pytest.mark.parametrize("phase", [0.0, 0.7])
def test_triangle_in_phase_with_sine_at_speed_4af(phase):
    a, f, offset = 0.03, 2.5, 0.01
    sine = jaxmr.Sine(a, f, phase=phase, offset=offset)
    triangle = jaxmr.Triangle(a, f, phase=phase, offset=offset)
    k = np.arange(-1.0, 5.0)
    # Zero crossings (sin = 0) and peaks (sin = ±1) of the sine.
    zeros = (k * np.pi - phase) / (2 * np.pi * f)
    peaks = (np.pi / 2 + k * np.pi - phase) / (2 * np.pi * f)
    np.testing.assert_allclose(values(triangle, zeros), offset, rtol=0, atol=1e-15)
    at_peaks = values(triangle, peaks)
    np.testing.assert_allclose(at_peaks, values(sine, peaks), rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.abs(at_peaks - offset), a, rtol=0, atol=1e-14)
    # Same half-wave (sign) everywhere in between.
    ts = np.linspace(-0.3, 1.7, 2001)
    ts = ts[np.abs(np.sin(2 * np.pi * f * ts + phase)) > 1e-6]
    np.testing.assert_array_equal(
        np.sign(values(triangle, ts) - offset), np.sign(values(sine, ts) - offset)
    )
    # Constant speed 4 a f: one amplitude per quarter period, and the derivative...
    quarter = at_peaks - values(triangle, zeros)
    np.testing.assert_allclose(np.abs(quarter) * 4 * f, 4 * a * f, rtol=1e-12)
    between = (zeros + peaks) / 2
    np.testing.assert_allclose(
        np.abs(derivatives(triangle, between)), 4 * a * f, rtol=1e-14
    )
    # ...with the sign of the sine's.
    np.testing.assert_array_equal(
        np.sign(derivatives(triangle, between)), np.sign(derivatives(sine, between))
    )


def test_signal_fields_batch_under_vmap():
    # A sweep stacks signals, so their fields become batched arrays.
    amplitudes = np.array([0.01, 0.02, 0.03])
    peak = jax.vmap(lambda a: jaxmr.Sine(a, 2.0)(0.125))(amplitudes)  # sin(π/2) = 1
    np.testing.assert_allclose(peak, amplitudes, rtol=1e-14)
