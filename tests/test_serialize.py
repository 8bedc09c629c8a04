"""Models round-trip through JSON with their type."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr

from .helpers import MODEL_CASES, tree_allclose


@pytest.mark.parametrize("case", MODEL_CASES, ids=repr)
def test_every_model_round_trips(case, tmp_path):
    model = case.device()
    path = tmp_path / "model.json"
    jaxmr.save_model(model, path, note="test")
    loaded = jaxmr.load_model(path)
    assert type(loaded) is type(model)
    assert tree_allclose(loaded, model, rtol=0, atol=0)


def test_constrained_model_round_trips(tmp_path):
    model = jaxmr.BoucWen(
        alpha=jaxmr.LinearLaw(jaxmr.Positive(1.0), jaxmr.Bounded(0.1, 0.0, 1.0)),
        c0=0.01,
        A=jaxmr.Fixed(843.0),
        beta=jaxmr.Positive(737.0),
        gamma=1.0,
        n=0.9,
    )
    path = tmp_path / "m.json"
    jaxmr.save_model(model, path)
    loaded = jaxmr.load_model(path)
    assert tree_allclose(loaded, model, rtol=0, atol=0)
    np.testing.assert_allclose(loaded.beta.value(), 737.0, rtol=1e-12)


def test_unknown_type_and_bad_file(tmp_path):
    path = tmp_path / "m.json"
    path.write_text('{"model": {"type": "Nope", "fields": {}}}')
    with pytest.raises(ValueError, match="unknown model type 'Nope'"):
        jaxmr.load_model(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        jaxmr.load_model(path)


def _edited(tmp_path, edit):
    """A saved Bouc–Wen damper with a TableLaw, its JSON changed by `edit`."""
    model = jaxmr.BoucWen(
        alpha=jaxmr.TableLaw(
            np.array([0.0, 0.5, 1.0]), np.array([100.0, 400.0, 800.0])
        ),
        c0=1000.0,
        A=1.0,
        beta=jaxmr.Positive(100.0),
        gamma=100.0,
        n=2.0,
    )
    path = tmp_path / "m.json"
    jaxmr.save_model(model, path)
    data = json.loads(path.read_text())
    edit(data["model"]["fields"])
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda f: f.pop("c0"), r"model: BoucWen is missing the field\(s\) 'c0'"),
        (
            lambda f: f.update(c_0=f.pop("c0")),
            r"model: BoucWen has no field 'c_0' \(did you mean 'c0'\?\)",
        ),
        (lambda f: f.update(extra=1.0), r"model: BoucWen has no field 'extra'"),
        (lambda f: f.update(n="2"), r"model\.n: expected a number, got \"2\""),
        (lambda f: f.update(gamma=True), r"model\.gamma: expected a number, got true"),
        (
            lambda f: f["alpha"]["fields"].update(currents=[1.0, 0.5, 0.0]),
            r"model\.alpha: .*increasing",
        ),
        (
            lambda f: f["beta"]["fields"].pop("log_value"),
            r"model\.beta: Positive is missing the field\(s\) 'log_value'",
        ),
        (
            lambda f: f["beta"]["fields"].update(log_value=["a"]),
            r"model\.beta\.log_value: expected numbers",
        ),
    ],
)
def test_load_runs_the_checks_of_construction(tmp_path, edit, match):
    """A hand-edited file is refused, naming the file and the field; before, the
    loader fell back to an unchecked object (an uninitialised attribute that crashed
    later, an unsorted table accepted)."""
    path = _edited(tmp_path, edit)
    with pytest.raises(ValueError, match=match) as info:
        jaxmr.load_model(path)
    assert str(path) in str(info.value)


def test_a_controller_and_its_sensors_round_trip(tmp_path):
    """An `ObserverBasedController` (law, estimator, observer with its nominal damper,
    sampling) and a `Sensors` set, saved and loaded: the same objects, static fields
    included (a `Sampling`'s `dt` comes back a number, not an array), and the same
    readings and commands in a closed-loop run, bit for bit (the same program on
    the same numbers)."""
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    sensors = jaxmr.realistic_sensors(car, load_cell=True)
    controller = jaxmr.ObserverBasedController(
        jaxmr.Skyhook(1500.0, 1.0, temperature=0.1),
        estimator=jaxmr.VelocityEstimator(crossover=4.0, position_high_pass=0.05),
        observer=jaxmr.DamperObserver(car.damper, gain=0.2, substeps=8),
        sampling=jaxmr.Sampling(2e-3, 2),
    )
    jaxmr.save_model(controller, tmp_path / "controller.json")
    jaxmr.save_model(sensors, tmp_path / "sensors.json")
    loaded = jaxmr.load_model(tmp_path / "controller.json")
    loaded_sensors = jaxmr.load_model(tmp_path / "sensors.json")
    for new, old in ((loaded, controller), (loaded_sensors, sensors)):
        assert type(new) is type(old)
        # Equal static fields and structure: the same tree definition.
        assert jax.tree.structure(new) == jax.tree.structure(old)
        assert tree_allclose(new, old, rtol=0, atol=0)
    assert loaded.sampling == jaxmr.Sampling(2e-3, 2)
    assert isinstance(loaded.sampling.dt, float) and loaded.observer.substeps == 8
    assert float(loaded.estimator.position_high_pass) == 0.05  # [Hz], not the default
    assert loaded_sensors.names == sensors.names

    T = 0.3  # [s]
    road = jaxmr.iso8608_road("C", 20.0, T, jax.random.key(0))
    runs = [
        jaxmr.simulate_system(car, road, c, T, sensors=s, key=jax.random.key(1))
        for c, s in ((controller, sensors), (loaded, loaded_sensors))
    ]
    assert runs[0].measured is not None and runs[1].measured is not None
    for name in sensors.names:
        np.testing.assert_array_equal(runs[1].measured[name], runs[0].measured[name])
    np.testing.assert_array_equal(runs[1].command, runs[0].command)
    assert np.ptp(np.asarray(runs[0].command)) > 0.1  # the law acts


def test_a_mapping_is_told_from_a_model(tmp_path):
    path = tmp_path / "m.json"
    sensors = jaxmr.Sensors({"body_acceleration": jaxmr.Sensor(noise=0.05)})
    jaxmr.save_model(sensors, path)
    data = json.loads(path.read_text())
    mapping = data["model"]["fields"]["sensors"]
    assert set(mapping) == {"dict"}
    # A model's object mistyped is refused, not read as a mapping.
    data["model"]["fields"]["sensors"] = {"tpye": "Sensor", "fields": {}}
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"model\.sensors: expected a number, a model"):
        jaxmr.load_model(path)


def test_a_tuned_force_feedback_law_round_trips(tmp_path):
    """A ForceFeedback's network (equinox Linear and MLP layers, which construction
    builds from sizes and a key) is written with its arrays and read back to the
    bit, inside an observer-based controller (`save_model` had refused it)."""
    law = jaxmr.ForceFeedback.mlp(
        [1.0] * 5, 1.0, width=4, depth=2, key=jax.random.key(3)
    )
    # Tuned weights: every layer's arrays away from construction's.
    law = jax.tree.map(
        lambda a: (
            a + 0.01 * jnp.arange(a.size, dtype=a.dtype).reshape(a.shape)
            if eqx.is_inexact_array(a) and a.ndim > 0
            else a
        ),
        law,
    )
    controller = jaxmr.ObserverBasedController(law, estimator=jaxmr.VelocityEstimator())
    path = tmp_path / "controller.json"
    jaxmr.save_model(controller, path)
    back = jaxmr.load_model(path)
    assert jax.tree.structure(back) == jax.tree.structure(controller)
    arrays = [jax.tree.leaves(eqx.filter(m, eqx.is_array)) for m in (controller, back)]
    assert len(arrays[0]) == len(arrays[1]) == 14  # the estimator's and 5 layers'
    for a, b in zip(*arrays):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    phi = jnp.linspace(-2.0, 2.0, 5)
    assert float(back.law.network(phi)) == float(law.network(phi))
    assert float(law.network(phi)) != 0.0  # the check sees the tuned weights

    linear = jaxmr.ForceFeedback.linear([1.0] * 5, 1.0)
    jaxmr.save_model(linear, tmp_path / "linear.json")
    assert jaxmr.load_model(tmp_path / "linear.json").network.weight.shape == (1, 5)


def test_a_field_that_cannot_be_saved_is_named_by_its_path(tmp_path):
    """A network with an activation a file cannot name: the error names the path of
    fields down to it and what to do instead, and no file is left."""
    law = jaxmr.ForceFeedback.mlp([1.0] * 5, 1.0, width=4, depth=1)
    law = eqx.tree_at(lambda m: m.network.mlp.activation, law, lambda x: x**3)
    controller = jaxmr.ObserverBasedController(law, estimator=jaxmr.VelocityEstimator())
    path = tmp_path / "controller.json"
    with pytest.raises(
        TypeError, match=r"cannot write law\.network\.mlp\.activation \(an activation"
    ):
        jaxmr.save_model(controller, path)
    assert not path.exists()


def test_a_layer_whose_arrays_do_not_fit_its_sizes_is_refused(tmp_path):
    path = tmp_path / "law.json"
    jaxmr.save_model(jaxmr.ForceFeedback.linear([1.0] * 5, 1.0), path)
    data = json.loads(path.read_text())
    data["model"]["fields"]["network"]["weight"] = [[1.0, 2.0]]
    path.write_text(json.dumps(data))
    with pytest.raises(
        ValueError, match=r"network\.weight: expected an array of shape \(1, 5\)"
    ):
        jaxmr.load_model(path)


def test_save_model_never_replaces_a_file_unless_told(tmp_path):
    path = tmp_path / "model.json"
    jaxmr.save_model(jaxmr.sas_brake_dahl(), path)
    before = path.read_text()
    with pytest.raises(FileExistsError, match="pass overwrite=True"):
        jaxmr.save_model(jaxmr.sas_brake_bouc_wen(), path)
    assert path.read_text() == before
    jaxmr.save_model(jaxmr.sas_brake_bouc_wen(), path, overwrite=True)
    assert type(jaxmr.load_model(path)).__name__ == "BoucWen"
