"""Save and load models as JSON: the model type and its parameters, nested.

    {"jaxmr": "0.1.0", "model": {"type": "BoucWen", "fields": {"alpha": {"type":
    "LinearLaw", "fields": {"a": 1.0, "b": 0.07}}, "A": 843.0, ...}}}

Every jaxmr model, law, dynamics, constraint wrapper and `Damper` can be written; a
user's own class can be read back when it is passed in `classes`.
"""

import dataclasses
import json
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._misc import default_float


def _registry() -> dict[str, type]:
    import jaxmr

    return {
        name: obj
        for name, obj in vars(jaxmr).items()
        if isinstance(obj, type) and issubclass(obj, eqx.Module)
    }


def _encode(value):
    if isinstance(value, eqx.Module):
        fields = {}
        for field in dataclasses.fields(value):
            if field.name.startswith("_"):
                continue
            fields[field.name] = _encode(getattr(value, field.name))
        return {"type": type(value).__name__, "fields": fields}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    array = np.asarray(value)
    if array.dtype.kind in "fiu":
        return array.tolist()
    raise TypeError(f"cannot write a value of type {type(value).__name__} to JSON.")


def _decode(value, classes):
    if isinstance(value, dict) and "type" in value and "fields" in value:
        name = value["type"]
        if name not in classes:
            raise ValueError(
                f"unknown model type {name!r} in the file; pass your class in "
                "`classes={...}` to load it."
            )
        cls = classes[name]
        fields = {k: _decode(v, classes) for k, v in value["fields"].items()}
        return _construct(cls, fields)
    if isinstance(value, list):
        return jnp.asarray(value, dtype=default_float())
    if isinstance(value, float):
        return jnp.asarray(value, dtype=default_float())
    return value


def _construct(cls, fields):
    # Constraint wrappers store a transformed variable (log, logit); rebuild them from
    # the stored variable rather than through their value-taking constructors.
    try:
        return cls(**fields)
    except TypeError:
        obj = object.__new__(cls)
        for name, v in fields.items():
            object.__setattr__(obj, name, v)
        return obj


def model_to_dict(model: eqx.Module) -> dict:
    """The JSON-ready description of `model` (type and parameters)."""
    from . import __version__

    return {"jaxmr": __version__, "model": _encode(model)}


def model_from_dict(data: dict, classes: dict[str, type] | None = None) -> eqx.Module:
    """Rebuild a model from `model_to_dict`'s output."""
    if "model" not in data:
        raise ValueError("not a jaxmr model file: no 'model' entry.")
    registry = _registry()
    registry.update(classes or {})
    return _decode(data["model"], registry)


def save_model(model: eqx.Module, path, **extra) -> None:
    """Write `model` to a JSON file (with its type), plus any JSON-able `extra`
    entries (e.g. the fit report)."""
    data = model_to_dict(model)
    data.update(extra)
    Path(path).write_text(json.dumps(data, indent=2))


def load_model(path, classes: dict[str, type] | None = None) -> eqx.Module:
    """Read a model written by `save_model`."""
    try:
        data = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e}).") from e
    return model_from_dict(data, classes)
