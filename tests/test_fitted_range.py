"""A model knows where it was fitted (issue 27): the `FittedRange` saved with a
model comes back with `load_model` as the model's static `fitted_range`, survives
the damper and the car built around it, and `simulate` and `simulate_system` warn
beyond it with no extra argument. A model without one keeps its pytree and its
results."""

import json
import warnings

import equinox as eqx
import jax
import numpy as np
import pytest

import jaxmr
import jaxmr.data

from .helpers import FITTED_SPENCER, shared_data

RANGE = jaxmr.FittedRange((-0.005, 0.005), (-0.09, 0.09), (0.0, 1.0))


@pytest.fixture(scope="module")
def params(tmp_path_factory):
    """params.json as `jaxmr fit` writes it: the fitted Spencer and the range of the
    UTFSM files it was fitted on (±0.09 m/s)."""
    files = jaxmr.data.load_utfsm(shared_data("utfsm_mr_damper", "sine"))
    names = ("2mm5Hz0A", "5mm3Hz0x25A", "5mm3Hz1A")
    fitted = jaxmr.FittedRange.from_experiments([e for e in files if e.name in names])
    path = tmp_path_factory.mktemp("fitted") / "params.json"
    jaxmr.save_model(FITTED_SPENCER, path, fitted_range=fitted)
    return path, fitted


def test_the_range_rides_with_the_model_and_changes_no_number(tmp_path):
    """Saved in the file's own entry (not among the model's fields), given back by
    `load_model`, kept through `Damper`, `passenger_car`, `eqx.tree_at` and
    `save_model`; the parameters are the same arrays, and a model without a range
    has the pytree of the model built in code."""
    path = tmp_path / "params.json"
    jaxmr.save_model(FITTED_SPENCER, path, fitted_range=RANGE)
    data = json.loads(path.read_text())
    assert jaxmr.FittedRange.from_dict(data["fitted_range"]) == RANGE
    assert "fitted_range" not in data["model"]["fields"]
    loaded = jaxmr.load_model(path)
    assert loaded.fitted_range == RANGE
    # The range is static: the leaves are the model's, bit for bit.
    for a, b in zip(jax.tree.leaves(loaded), jax.tree.leaves(FITTED_SPENCER)):
        assert np.array_equal(a, b)
    damper = jaxmr.Damper(loaded, jaxmr.FirstOrderLag(50.0))
    assert damper.fitted_range == RANGE
    car = jaxmr.passenger_car(damper)
    assert car.damper.fitted_range == RANGE
    assert eqx.tree_at(lambda c: c.ms, car, 400.0).damper.fitted_range == RANGE
    # `save_model` writes the model's own range (here from inside a car's damper).
    again = tmp_path / "again.json"
    jaxmr.save_model(car.damper, again)
    assert jaxmr.load_fitted_range(again) == RANGE
    # Without a range: None, and the pytree of the model built in code.
    bare = jaxmr.with_fitted_range(loaded, None)
    assert bare.fitted_range is None and loaded.fitted_range == RANGE
    assert jax.tree.structure(bare) == jax.tree.structure(FITTED_SPENCER)
    plain = tmp_path / "plain.json"
    jaxmr.save_model(FITTED_SPENCER, plain)
    assert jaxmr.load_fitted_range(plain) is None
    assert jax.tree.structure(jaxmr.load_model(plain)) == jax.tree.structure(
        FITTED_SPENCER
    )
    # (The suite's runtime type checks refuse it first, naming the parameter.)
    with pytest.raises(TypeError, match="fitted_range"):
        jaxmr.Dahl(k_x=1.0, k_w=1.0, rho=1.0, fitted_range=(0.0, 1.0))  # pyright: ignore[reportArgumentType]
    # A damaged range in the file: named with the file, not a model without one.
    data["fitted_range"]["velocity"] = 0.09
    damaged = tmp_path / "damaged.json"
    damaged.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"damaged.json: fitted_range: `velocity`"):
        jaxmr.load_model(damaged)


def test_a_loaded_damper_warns_in_the_car_with_no_argument(params):
    """The issue's one-liner, `simulate_system(passenger_car(load_model(path)),
    road, law, T)`: on an ISO C road at 20 m/s the car drives the damper at ~2 m/s,
    and the run warns naming the fitted velocity interval, with the numbers of the
    same damper built in code (the range changes no result); on the same road at
    2 % of its height it stays within the range, and nothing warns."""
    path, fitted = params
    car = jaxmr.passenger_car(jaxmr.load_model(path))
    road = jaxmr.iso8608_road("C", 20.0, 1.0, jax.random.key(0))
    with pytest.warns(jaxmr.OutsideFittedRange) as caught:
        solution = jaxmr.simulate_system(car, road, 0.0, 1.0)
    (message,) = [str(w.message) for w in caught]
    low, high = fitted.velocity
    assert f"the fitted range [{low:.4g}, {high:.4g}] m/s" in message, message
    assert message.startswith("jaxmr.simulate_system drove the model beyond")
    assert np.max(np.abs(solution["damper_velocity"])) > 10 * high
    # The same damper built in code holds no range: silent, and the same bits.
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxmr.OutsideFittedRange)
        code = jaxmr.simulate_system(
            jaxmr.passenger_car(FITTED_SPENCER), road, 0.0, 1.0
        )
    assert np.array_equal(code.states, solution.states)
    # Within the range: the road at 2 % of its height (the premise asserted).
    gentle = jax.tree.map(lambda a: 0.02 * a, road)
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxmr.OutsideFittedRange)
        calm = jaxmr.simulate_system(car, gentle, 0.0, 1.0)
    assert np.max(np.abs(calm["damper_velocity"])) < high
    assert not fitted.exceeded(
        calm["damper_displacement"], calm["damper_velocity"], calm.current
    )
    # An explicit `fitted_range=` still overrides the model's own.
    with pytest.warns(jaxmr.OutsideFittedRange, match=r"\[-0\.001, 0\.001\] m/s"):
        jaxmr.simulate_system(
            car,
            gentle,
            0.0,
            1.0,
            fitted_range=jaxmr.FittedRange(
                fitted.displacement, (-1e-3, 1e-3), (0.0, 1.0)
            ),
        )


def test_simulate_warns_beyond_a_loaded_models_range(params):
    """`simulate` of the loaded model at twice the fitted peak velocity warns with
    no argument; within it, it does not."""
    path, fitted = params
    model = jaxmr.load_model(path)
    ts = np.linspace(0.0, 0.5, 501)
    high = fitted.velocity[1]
    frequency = 3.0  # [Hz]; a sine's peak velocity is 2π f amplitude
    step = jaxmr.FixedStep(8)  # fixed steps compile quickly; stable at ~0.2 m/s
    fast = jaxmr.Sine(2 * high / (2 * np.pi * frequency), frequency)
    with pytest.warns(jaxmr.OutsideFittedRange, match=r"jaxmr.simulate .* velocity"):
        jaxmr.simulate(model, fast, 0.5, ts, integrator=step)
    slow = jaxmr.Sine(0.5 * high / (2 * np.pi * frequency), frequency)
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxmr.OutsideFittedRange)
        jaxmr.simulate(model, slow, 0.5, ts, integrator=step)


def test_the_library_refuses_records_of_another_device():
    """A fit of a damper's and a brake's records together (N with N·m), and a damper
    fitted on linear records predicting a brake's: refused, as the command line
    refuses them (the library had fitted and predicted without a word)."""
    t = np.linspace(0.0, 1.0, 501)
    x = 0.01 * np.sin(2 * np.pi * 2 * t)
    v = np.gradient(x, t)
    linear = jaxmr.data.Experiment(t, x, v, 0.5, 1e3 * np.tanh(v / 0.01), name="lin")
    rotary = jaxmr.data.Experiment(
        t, 5 * x, 5 * v, 0.5, 2 * np.tanh(v / 0.05), name="rot", rotary=True
    )
    with pytest.raises(ValueError, match=r"mix devices \(linear, current-driven: lin"):
        jaxmr.fit(jaxmr.sas_brake_bingham(), [linear, rotary], progress=False)
    damper = jaxmr.with_fitted_range(
        jaxmr.passenger_car_mr_damper(), jaxmr.FittedRange.from_experiments([linear])
    )
    with pytest.raises(ValueError, match="fitted on a linear, current-driven device"):
        jaxmr.predict(damper, rotary)
