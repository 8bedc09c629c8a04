"""Model files for the equinox layers a `ForceFeedback` holds: `equinox.nn.Linear` and
`equinox.nn.MLP`.

A layer is not a jaxmr model: its constructor takes sizes and a key, not its arrays,
and an MLP holds its activation as a function. A file therefore stores a layer's
sizes (`config`), its activation by name and its arrays, and reading builds the layer
from the sizes and then puts the arrays in (shapes checked), so a tuned law is read
back exactly:

    {"layer": "Linear", "config": {"in_features": 5, "out_features": "scalar",
     "use_bias": false}, "weight": [...], "bias": null}
    {"layer": "MLP", "config": {..., "activation": "tanh", "final_activation":
     "identity"}, "layers": [<Linear>, ...]}
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._misc import default_float

# The activations a file may name. A function is named by what it computes on a probe
# (equinox stores the identity as a lambda, and a user may pass `jax.nn.tanh` or
# `jnp.tanh`): the first whose values match to rounding.
_ACTIVATIONS = {
    "identity": lambda x: x,
    "tanh": jnp.tanh,
    "relu": jax.nn.relu,
    "sigmoid": jax.nn.sigmoid,
    "softplus": jax.nn.softplus,
    "silu": jax.nn.silu,
    "gelu": jax.nn.gelu,
    "elu": jax.nn.elu,
}
_PROBE = np.array([-3.0, -1.2, -0.3, 0.0, 0.4, 1.1, 2.7])


def is_layer(value) -> bool:
    """Whether `value` is a layer this module writes."""
    return isinstance(value, (eqx.nn.Linear, eqx.nn.MLP))


def is_layer_entry(value) -> bool:
    """Whether a decoded JSON value is a layer's entry."""
    return isinstance(value, dict) and "layer" in value


def _activation_name(function) -> str | None:
    try:
        values = np.asarray(function(jnp.asarray(_PROBE)))
    except Exception:  # a function of another kind of input: not one of ours
        return None
    for name, known in _ACTIVATIONS.items():
        if values.shape == _PROBE.shape and np.allclose(
            values, np.asarray(known(jnp.asarray(_PROBE))), rtol=1e-6, atol=1e-9
        ):
            return name
    return None


def _array(value):
    return None if value is None else np.asarray(value).tolist()


def encode_layer(value, path: str, unwritable) -> dict:
    """The file entry of a layer; `unwritable(path, what)` is the error to raise for an
    activation the file cannot name."""
    if isinstance(value, eqx.nn.Linear):
        return {
            "layer": "Linear",
            "config": {
                "in_features": value.in_features,
                "out_features": value.out_features,
                "use_bias": value.use_bias,
            },
            "weight": _array(value.weight),
            "bias": _array(value.bias),
        }
    names = {}
    for field in ("activation", "final_activation"):
        name = _activation_name(getattr(value, field))
        if name is None:
            raise unwritable(
                f"{path}.{field}",
                f"an activation other than {', '.join(_ACTIVATIONS)}",
            )
        names[field] = name
    return {
        "layer": "MLP",
        "config": {
            "in_size": value.in_size,
            "out_size": value.out_size,
            "width_size": value.width_size,
            "depth": value.depth,
            "use_bias": value.use_bias,
            "use_final_bias": value.use_final_bias,
            **names,
        },
        "layers": [
            encode_layer(layer, f"{path}.layers[{k}]", unwritable)
            for k, layer in enumerate(value.layers)
        ],
    }


def _numbers(value, where: str, shape) -> jax.Array:
    try:
        array = jnp.asarray(value, dtype=default_float())
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected numbers.") from None
    if array.shape != tuple(shape):
        raise ValueError(
            f"{where}: expected an array of shape {tuple(shape)} for the layer's "
            f"sizes, got {array.shape}."
        )
    return array


def decode_layer(value: dict, where: str):
    """The layer `encode_layer` wrote, with its arrays; `ValueError` naming `where`
    for an entry that does not describe one."""
    kind, config = value.get("layer"), value.get("config")
    if kind not in ("Linear", "MLP") or not isinstance(config, dict):
        raise ValueError(
            f"{where}: a layer entry needs 'layer' ('Linear' or 'MLP') and a "
            "'config' object."
        )
    return (_decode_linear if kind == "Linear" else _decode_mlp)(value, config, where)


def _built(build, kind: str, where: str):
    try:
        return build()
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: cannot build the {kind} layer: {e}.") from e


def _decode_linear(value: dict, config: dict, where: str) -> eqx.nn.Linear:
    # The key only builds the shapes: the arrays are replaced.
    layer = _built(
        lambda: eqx.nn.Linear(**config, key=jax.random.key(0), dtype=default_float()),
        "Linear",
        where,
    )
    weight = _numbers(value.get("weight"), f"{where}.weight", layer.weight.shape)
    if layer.bias is None:
        if value.get("bias") is not None:
            raise ValueError(f"{where}.bias: the layer has no bias (use_bias).")
        return eqx.tree_at(lambda m: m.weight, layer, weight)
    bias = _numbers(value.get("bias"), f"{where}.bias", layer.bias.shape)
    return eqx.tree_at(lambda m: (m.weight, m.bias), layer, (weight, bias))


def _decode_mlp(value: dict, config: dict, where: str) -> eqx.nn.MLP:
    activations = {}
    for field in ("activation", "final_activation"):
        name = config.get(field)
        if name not in _ACTIVATIONS:
            raise ValueError(
                f"{where}: `{field}` must be one of {', '.join(_ACTIVATIONS)}, got "
                f"{name!r}."
            )
        activations[field] = _ACTIVATIONS[name]
    sizes = {k: v for k, v in config.items() if k not in activations}
    layer = _built(
        lambda: eqx.nn.MLP(
            **sizes, **activations, key=jax.random.key(0), dtype=default_float()
        ),
        "MLP",
        where,
    )
    stored = value.get("layers")
    if not isinstance(stored, list) or len(stored) != len(layer.layers):
        got = len(stored) if isinstance(stored, list) else type(stored).__name__
        raise ValueError(
            f"{where}.layers: expected {len(layer.layers)} layers for depth "
            f"{config.get('depth')}, got {got}."
        )
    layers = []
    for k, (entry, built) in enumerate(zip(stored, layer.layers)):
        inner = f"{where}.layers[{k}]"
        if not is_layer_entry(entry) or entry.get("layer") != "Linear":
            raise ValueError(f"{inner}: expected a Linear layer entry.")
        read = _decode_linear(entry, entry.get("config") or {}, inner)
        if read.weight.shape != built.weight.shape:
            raise ValueError(f"{inner}: does not fit the MLP's sizes.")
        layers.append(read)
    return eqx.tree_at(lambda m: m.layers, layer, tuple(layers))
