"""`ChannelDelay`: a force channel that lags the motion, in prediction, fitting,
files and the command line (issue 9)."""

import json
from types import SimpleNamespace

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.data
from jaxmr._cli import main
from jaxmr._damper import as_damper
from jaxmr._identify.data import pack
from jaxmr._identify.residual import residuals
from jaxmr._parameter import free_filter, unwrap

from .helpers import dahl_guess

# The runs of `helpers.dahl_runs`: 1 Hz, ±20°, one cycle sampled at 100 Hz.
TRUTH = jaxmr.Dahl(k_x=0.01, k_w=3.0, rho=5.0)
INTERVAL = 0.01  # s


def _runs(delay):
    """Two noise-free Dahl runs (0 and a second amplitude) whose force channel lags
    by `delay` [s], made by jaxmr's own prediction of `ChannelDelay(TRUTH, delay)`."""
    ts = np.linspace(0.0, 1.0, 101)
    runs = []
    for amplitude in (20.0, 10.0):
        sol = jaxmr.simulate(
            TRUTH, jaxmr.Sine(jnp.deg2rad(amplitude), 1.0), 0.0, jnp.asarray(ts)
        )
        runs.append(
            SimpleNamespace(
                t=ts,
                x=np.asarray(sol.displacement),
                v=np.asarray(sol.velocity),
                current=np.zeros(ts.shape),
                force=np.zeros(ts.shape),
                name=f"{amplitude:g} deg",
            )
        )
    forces = jaxmr.predict_all(jaxmr.ChannelDelay(TRUTH, delay), runs)
    for run, force in zip(runs, forces):
        run.force = np.asarray(force)
    return runs


def test_the_force_is_read_delay_earlier_between_samples():
    runs = _runs(0.0)
    undelayed = jaxmr.predict_all(TRUTH, runs)
    for delay in (0.0237, -0.012):  # 2.37 samples late, 1.2 early
        delayed = jaxmr.predict_all(jaxmr.ChannelDelay(TRUTH, delay), runs)
        for run, a, b in zip(runs, undelayed, delayed):
            # Linear interpolation between samples, holding the first (last) sample
            # outside the run, as numpy's interp does: equal to rounding (1e-12 of
            # the peak force, for sums of a few terms).
            expected = np.interp(run.t - delay, run.t, a)
            assert np.max(np.abs(b - expected)) < 1e-12 * np.max(np.abs(a))


def test_a_fit_recovers_the_channel_delay():
    delay = 0.0237
    runs = _runs(delay)
    guess = jaxmr.ChannelDelay(dahl_guess(), jaxmr.Bounded(0.0, -0.05, 0.05))
    result = jaxmr.fit(guess, runs, progress=False)
    fitted = unwrap(result.model)
    # Noise-free data: the delay and the model come back to the solver's tolerance
    # (1e-6 relative is far looser than LM's 1e-8 step test, far tighter than any
    # error a wrong delay would leave).
    assert abs(float(np.asarray(fitted.delay)) / delay - 1) < 1e-6
    assert abs(float(fitted.model.rho) / 5.0 - 1) < 1e-6
    assert result.loss < 1e-20
    # The skew matters: the true model read without it misses each run by an NRMSE
    # of 0.17-0.19.
    assert min(jaxmr.record_nrmse(TRUTH, runs)) > 0.1


@pytest.mark.parametrize("delay", [0.0, INTERVAL, 2.5 * INTERVAL])
def test_gradient_with_respect_to_the_delay_is_finite(delay):
    # 0 and whole sample intervals are the kinks of linear interpolation: the
    # gradient there is one side's slope, finite.
    runs = _runs(0.013)
    data = pack(runs)
    model = jaxmr.ChannelDelay(TRUTH, delay)
    free, static = eqx.partition(model, free_filter(model))

    def loss(d):
        f = eqx.tree_at(lambda m: m.delay, free, d)
        return 0.5 * jnp.sum(residuals(f, static, data) ** 2)

    g = jax.grad(loss)(jnp.asarray(delay))
    assert np.isfinite(float(g)) and float(g) != 0.0


def test_saved_and_loaded(tmp_path):
    model = jaxmr.ChannelDelay(jaxmr.Damper(TRUTH, jaxmr.FirstOrderLag(200.0)), 0.003)
    path = tmp_path / "delayed.json"
    jaxmr.save_model(model, path)
    loaded = jaxmr.load_model(path)
    assert isinstance(loaded, jaxmr.ChannelDelay)
    runs = _runs(0.0)
    for a, b in zip(jaxmr.predict_all(model, runs), jaxmr.predict_all(loaded, runs)):
        np.testing.assert_array_equal(a, b)


def test_readable_errors():
    # What `jaxmr.simulate` and the machines call on their device (in this suite
    # the annotations' run-time check refuses the type first).
    with pytest.raises(TypeError, match="simulate its `.model`"):
        as_damper(jaxmr.ChannelDelay(TRUTH, 0.001))
    with pytest.raises(TypeError, match="hysteresis model or Damper"):
        jaxmr.ChannelDelay(jaxmr.Sine(0.1, 1.0), 0.001)  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="one number"):
        jaxmr.ChannelDelay(TRUTH, jnp.zeros(2))
    with pytest.raises(ValueError, match="finite"):
        jaxmr.ChannelDelay(TRUTH, float("nan"))


def test_jaxmr_fit_channel_delay(tmp_path):
    delay = 0.0237
    paths = []
    for run in _runs(delay):
        e = jaxmr.data.Experiment(run.t, run.x, run.v, 0.0, run.force, name=run.name)
        paths.append(tmp_path / f"{run.name.replace(' ', '_')}.csv")
        jaxmr.data.write_csv(e, paths[-1])
    out = tmp_path / "fit.json"
    assert main(["fit", "--model", "dahl", "--channel-delay", "--out", str(out)]
                + [str(p) for p in paths]) == 0  # fmt: skip
    model = jaxmr.load_model(out)
    assert isinstance(model, jaxmr.ChannelDelay)
    assert isinstance(model.model, jaxmr.Dahl)
    # The data-scaled Dahl start is not the truth: the fit ends at the noise-free
    # optimum all the same, the delay to 1e-4 of itself.
    assert abs(float(np.asarray(model.delay)) / delay - 1) < 1e-4
    report = json.loads(out.read_text())["report"]
    assert report["template"] == "dahl + channel delay"
    assert main(["predict", str(out), str(paths[0]), "--out", str(tmp_path / "p")]) == 0
