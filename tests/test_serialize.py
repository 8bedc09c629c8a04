"""Models round-trip through JSON with their type."""

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
