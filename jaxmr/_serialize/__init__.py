"""Save and load models as JSON: the model type and its parameters, nested.

    {"jaxmr": "0.1.0", "model": {"type": "BoucWen", "fields": {"alpha": {"type":
    "LinearLaw", "fields": {"a": 1.0, "b": 0.07}}, "A": 843.0, ...}}}

Every jaxmr model, law, dynamics, constraint wrapper and `Damper` can be written, and
so can a machine, a controller (an `ObserverBasedController` with its estimator,
observer and `Sampling`; a `ForceFeedback` with its network, whose equinox layers are
written by `layers`) and a `Sensors` set, whose mapping is written
`{"dict": {name: ...}}`; a user's own class can be read back when it is passed in
`classes`.
"""

import dataclasses
import difflib
import inspect
import json
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import (
    _channel,
    _control,
    _current_dynamics,
    _current_law,
    _damper,
    _hysteresis,
    _magnetic,
    _parameter,
    _ramp,
    _road,
    _signal,
    _systems,
)
from .._control import feedback
from .._damper import fitted_range_in, with_fitted_range
from .._fitted_range import FittedRange
from .._hysteresis import AbstractHysteresis
from .._misc import default_float
from .._version import __version__
from .layers import decode_layer, encode_layer, is_layer, is_layer_entry

# The modules whose public classes a file may name: what a model is made of
# (hysteresis models, current laws and dynamics, constraint wrappers, the damper, the
# measuring channel, the magnetic stage and brake) and what it is used in (signals,
# roads, machines, controllers).
_MODULES = (
    _channel,
    _control,
    feedback,  # the map of `ForceFeedback.mlp` (`LinearAndMLP`)
    _current_dynamics,
    _current_law,
    _damper,
    _hysteresis,
    _magnetic,
    _parameter,
    _ramp,
    _road,
    _signal,
    _systems,
)


def _registry() -> dict[str, type]:
    return {
        name: obj
        for module in _MODULES
        for name, obj in vars(module).items()
        if not name.startswith("_")
        and isinstance(obj, type)
        and issubclass(obj, eqx.Module)
        and obj.__module__.startswith("jaxmr.")
    }


def _stored(cls, field) -> bool:
    """Whether a model file holds `field` of `cls`: not a private field, nor a
    hysteresis model's `fitted_range` (the file's own `fitted_range` entry)."""
    if field.name.startswith("_"):
        return False
    return not (issubclass(cls, AbstractHysteresis) and field.name == "fitted_range")


class _Unwritable(TypeError):
    """A value `save_model` cannot store, with the path of fields down to it."""

    def __init__(self, path: str, what: str):
        super().__init__(
            f"cannot write {path} ({what}) to a model file: `save_model` stores jaxmr "
            "models, their numbers and arrays, and equinox's Linear and MLP layers, "
            "not a field of another kind (a user's object or network): keep such a "
            "model in Python (e.g. equinox.tree_serialise_leaves), and export a "
            "controller from there (jaxmr.export_c)."
        )
        self.path, self.what = path, what


def _encode(value, path: str = "the model"):
    if is_layer(value):
        return encode_layer(value, path, _Unwritable)
    if isinstance(value, eqx.Module):
        fields = {}
        for field in dataclasses.fields(value):
            if not _stored(type(value), field):
                continue
            inner = f"{path}.{field.name}" if path != "the model" else field.name
            fields[field.name] = _encode(getattr(value, field.name), inner)
        return {"type": type(value).__name__, "fields": fields}
    if isinstance(value, dict):
        # Models by name (a `Sensors` set), marked so that the mapping is never read
        # as a model, nor a mistyped model as a mapping.
        if not all(isinstance(k, str) for k in value):
            raise TypeError("cannot write a dict whose keys are not strings to JSON.")
        return {"dict": {k: _encode(v, f"{path}[{k!r}]") for k, v in value.items()}}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, tuple) and value and all(isinstance(v, str) for v in value):
        return list(
            value
        )  # names (a law's `features`): a static field, read as a tuple
    array = np.asarray(value)
    if array.dtype.kind in "fiu":
        return array.tolist()
    raise _Unwritable(path, f"a {type(value).__name__}")


def _decode(value, classes, where="model", static=False):
    """The value `_encode` wrote. `static`: the value of a static field, which keeps
    JSON's Python numbers (a `Sampling`'s `dt` sets the compiled loop's step, and an
    array there is refused) and makes its lists tuples (hashable)."""
    if is_layer_entry(value):
        return decode_layer(value, where)
    if isinstance(value, dict) and "type" in value and "fields" in value:
        name = value["type"]
        if not isinstance(name, str) or name not in classes:
            raise ValueError(
                f"{where}: unknown model type {name!r} in the file; pass your class in "
                "`classes={...}` to load it."
            )
        cls = classes[name]
        if not isinstance(value["fields"], dict):
            raise ValueError(f"{where}: the fields of {name} must be a JSON object.")
        statics = {
            f.name for f in dataclasses.fields(cls) if f.metadata.get("static", False)
        }
        fields = {
            k: _decode(v, classes, f"{where}.{k}", k in statics)
            for k, v in value["fields"].items()
        }
        return _construct(cls, fields, where)
    if isinstance(value, dict) and set(value) == {"dict"}:
        if not isinstance(value["dict"], dict):
            raise ValueError(f"{where}: a mapping's 'dict' must be a JSON object.")
        return {
            k: _decode(v, classes, f"{where}.{k}", static)
            for k, v in value["dict"].items()
        }
    if static and isinstance(value, list):
        return tuple(_decode(v, classes, where, static) for v in value)
    if static and not isinstance(value, dict):
        return value
    if isinstance(value, list):
        try:
            return jnp.asarray(value, dtype=default_float())
        except (TypeError, ValueError):
            raise ValueError(
                f"{where}: expected numbers (a number or nested lists of them), got "
                f"{json.dumps(value)[:80]}."
            ) from None
    if isinstance(value, float):
        return jnp.asarray(value, dtype=default_float())
    if isinstance(value, dict):  # `_encode` writes dicts only for models and mappings
        raise ValueError(
            f"{where}: expected a number, a model (an object with 'type' and "
            f"'fields') or a mapping (an object with 'dict' alone), got "
            f"{json.dumps(value)[:80]}."
        )
    return value


def _construct(cls, fields, where):
    """`cls` from its stored fields, with the checks construction makes: every field
    named and known, numbers where the model holds arrays, and `__check_init__`."""
    declared = {f.name: f for f in dataclasses.fields(cls) if _stored(cls, f)}
    unknown = [k for k in fields if k not in declared]
    if unknown:
        hints = []
        for k in unknown:
            close = difflib.get_close_matches(k, list(declared), n=1)
            hints.append(f"{k!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise ValueError(
            f"{where}: {cls.__name__} has no field {', '.join(hints)}; its fields are "
            f"{', '.join(declared)}."
        )
    for k, v in fields.items():
        static = declared[k].metadata.get("static", False)
        if not static and isinstance(v, (str, bool)):
            raise ValueError(
                f"{where}.{k}: expected a number, got {json.dumps(v)} (a "
                f"{'string' if isinstance(v, str) else 'boolean'})."
            )
    try:
        inspect.signature(cls).bind(**fields)
    except TypeError:
        # A constraint wrapper stores its transformed variable (log, logit), which its
        # value-taking constructor does not accept: set the stored fields, then run
        # the class's own checks.
        missing = [
            k
            for k, f in declared.items()
            if k not in fields
            and f.default is dataclasses.MISSING
            and f.default_factory is dataclasses.MISSING
        ]
        if missing:
            raise ValueError(
                f"{where}: {cls.__name__} is missing the field(s) "
                f"{', '.join(map(repr, missing))}."
            ) from None
        obj = object.__new__(cls)
        for name, v in fields.items():
            object.__setattr__(obj, name, v)
        check = getattr(obj, "__check_init__", None)
        if check is not None:
            _checked(check, where)
        return obj
    return _checked(lambda: cls(**fields), where)


def _checked(build, where):
    try:
        return build()
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {e}") from e


def model_to_dict(model: eqx.Module) -> dict:
    """The JSON-ready description of `model` (type and parameters)."""
    return {"jaxmr": __version__, "model": _encode(model)}


def model_from_dict(data: dict, classes: dict[str, type] | None = None) -> eqx.Module:
    """Rebuild a model from `model_to_dict`'s output."""
    if "model" not in data:
        raise ValueError("not a jaxmr model file: no 'model' entry.")
    registry = _registry()
    registry.update(classes or {})
    model = _decode(data["model"], registry)
    if not isinstance(model, eqx.Module):
        raise ValueError(
            "not a jaxmr model file: its 'model' entry is not a model (an object "
            f"with a 'type' field), got {type(model).__name__}."
        )
    return model


def save_model(
    model: eqx.Module,
    path,
    *,
    fitted_range: FittedRange | None = None,
    overwrite: bool = False,
    **extra,
) -> None:
    """Write `model` to a JSON file (with its type), plus any JSON-able `extra`
    entries (e.g. the fit report).

    `overwrite`: write over an existing file (default False: `FileExistsError`, as
    `save_fit`, `export_c` and the command line refuse to replace a file).

    `fitted_range`: the displacements [m], velocities [m/s] and inputs [A or V] the
    model was fitted on (`FittedRange.from_experiments`), written as the file's
    `fitted_range` entry; default: the range the model holds (its hysteresis
    model's `fitted_range`, as `load_model` sets it), if any. `load_model` gives it
    back to the model (and `load_fitted_range` reads it alone), and `simulate`,
    `sweep` and `simulate_system` warn beyond it.
    """
    if fitted_range is not None and not isinstance(fitted_range, FittedRange):
        raise TypeError(
            "`fitted_range` must be a jaxmr.FittedRange, got "
            f"{type(fitted_range).__name__}."
        )
    # Refused here rather than written into a file that `load_model` cannot read.
    cls = type(model)
    if not isinstance(model, eqx.Module):
        raise TypeError(
            f"`model` must be a jaxmr model (an equinox Module), got {cls.__name__}."
        )
    if cls.__module__.startswith("jaxmr.") and cls.__name__ not in _registry():
        hint = (
            ": an experiment is data, written by jaxmr.data.write_csv"
            if cls.__name__ == "Experiment"
            else ""
        )
        raise TypeError(
            f"`model` is of type {cls.__name__}, which `load_model` cannot read "
            f"back{hint}."
        )
    if fitted_range is None:
        fitted_range = fitted_range_in(model)
    data = model_to_dict(model)
    if Path(path).exists() and not overwrite:
        raise FileExistsError(
            f"save_model: {str(path)!r} exists; pass overwrite=True to replace it."
        )
    data.update(extra)
    if fitted_range is not None:
        data["fitted_range"] = fitted_range.to_dict()
    Path(path).write_text(json.dumps(data, indent=2))


def _read_json(path) -> dict:
    try:
        data = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e}).") from e
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a text file ({e}).") from e
    if not isinstance(data, dict):
        raise ValueError(
            f"{path}: not a jaxmr model file: expected a JSON object with a 'type' "
            f"field (as `save_model` writes), got {type(data).__name__}."
        )
    return data


def _fitted_range(data: dict, path) -> FittedRange | None:
    if data.get("fitted_range") is None:
        return None
    try:
        return FittedRange.from_dict(data["fitted_range"])
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e


def load_fitted_range(path) -> FittedRange | None:
    """The `FittedRange` saved with a model (`save_model`, as `jaxmr fit` writes
    it), or None when the file has none. `load_model` already gives it to the
    model it reads (its `fitted_range`); pass it as `fitted_range=` to check a
    model that does not carry it."""
    return _fitted_range(_read_json(path), path)


def load_model(path, classes: dict[str, type] | None = None) -> eqx.Module:
    """Read a model written by `save_model`.

    Loading runs the checks construction runs: a missing, misspelled or extra field,
    a string or boolean where a number belongs, or a value the class refuses (an
    unsorted `TableLaw`) raises `ValueError` naming the file and the field (e.g.
    `model.hysteresis.alpha.currents`).

    When the file holds a `fitted_range` (as `jaxmr fit` writes it), every hysteresis
    model read gets it as its `fitted_range` (`with_fitted_range`): in a `Damper`
    or a system too (`passenger_car(load_model(path))`), `simulate`, `sweep` and
    `simulate_system` then warn (`OutsideFittedRange`) when they drive it beyond
    the displacements, velocities and currents it was fitted on.
    """
    data = _read_json(path)
    try:
        model = model_from_dict(data, classes)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e
    return with_fitted_range(model, _fitted_range(data, path))
