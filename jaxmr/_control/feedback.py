"""A semi-active law with many parameters: a desired force from a learned map of the
measurements, projected onto what the damper can deliver."""

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Float
from .._damper import Damper
from .._misc import as_float_array, check_concrete
from .base import AbstractController
from .smooth import check_range_and_temperature, clip_command, command_for_force

# Sensors a production semi-active suspension has (or integrates): no road profile.
DEFAULT_FEATURES = (
    "body_velocity",
    "body_acceleration",
    "wheel_velocity",
    "damper_displacement",
    "damper_velocity",
)


def _as_scales(scales: Any) -> Array:
    return as_float_array(np.asarray(scales, dtype=float))


def _zero_linear(features: int, dtype) -> eqx.nn.Linear:
    # An `equinox.nn.Linear` to a scalar, without bias, every gain 0.
    linear = eqx.nn.Linear(
        features, "scalar", use_bias=False, dtype=dtype, key=jax.random.key(0)
    )
    return eqx.tree_at(lambda m: m.weight, linear, jnp.zeros_like(linear.weight))


class LinearAndMLP(eqx.Module):
    # A linear law plus a nonlinear correction: never worse than the linear law it
    # contains, and tuned from zero the gradient moves the linear part first.
    linear: eqx.nn.Linear
    mlp: eqx.nn.MLP

    def __call__(self, phi):
        return self.linear(phi) + self.mlp(phi)


class ForceFeedback(AbstractController):
    r"""A desired damper force from a learned map $g$ of the scaled measurements,
    $$\varphi_k = m_k / s_k,\qquad F^* = F_y\, g(\varphi),\qquad i = \Pi(F^*),$$
    where $m_k$ are the measurements named in `features`, $s_k$ their typical sizes,
    $F_y$ the damper's yield force at $I_\max$ (`AbstractHysteresis.yield_force`, read
    from the device at every sample) and $\Pi$ the semi-active projection onto the
    damper's force band (`DamperPlant.current_for_force`).

    $g$ is linear (`ForceFeedback.linear`: one dimensionless gain per feature, which
    spans skyhook, groundhook, their hybrids and acceleration-driven damping, and any
    blend of them) or a small multilayer perceptron (`ForceFeedback.mlp`). Both start
    at $g = 0$ (the damper at its lowest force: a generic start that favours no law)
    and are meant to be shaped by `jaxmr.tune` with `log_space=False` and
    `parameters=ForceFeedback.weights`.

    Relaxed ($T > 0$): the band clip becomes the soft clip of every force law.

    **Arguments:**

    - `network`: the map $g$ from the feature vector to a dimensionless force.
    - `features`: measurement names (`jaxmr.constants.MEASUREMENT_NAMES` or the system's own).
    - `scales`: $s_k$, one per feature, in the feature's unit (e.g. m/s), > 0.
    - `i_max`: the top of the current range $I_\max$ [A].
    - `temperature`: $T \ge 0$; 0 (default) is the hard law.
    - `model`: the damper the law inverts (its $F_y$ and its band, read at the
      state of the plant it is handed: `DamperPlant.with_model`), e.g. the nominal
      fit while the simulated unit is a sample drawn around it; `None` (default)
      inverts the plant's own damper. A bare law is handed the simulated device
      (and its true state) only with `simulate_system(..., sensors="oracle")`;
      inside an `ObserverBasedController` it is handed the observer's nominal model
      at its observed state.
    """

    network: eqx.Module
    scales: Float[Array, " features"] = eqx.field(converter=_as_scales)
    i_max: Float[Array, ""] = eqx.field(converter=as_float_array)
    temperature: Float[Array, ""] = eqx.field(converter=as_float_array, default=0.0)
    features: tuple[str, ...] = eqx.field(static=True, default=DEFAULT_FEATURES)
    model: Damper | None = None

    def __check_init__(self):
        if self.model is not None and not isinstance(self.model, Damper):
            raise TypeError(
                "ForceFeedback: `model` must be a jaxmr Damper (the damper the law "
                f"inverts) or None, got {type(self.model).__name__}."
            )
        if self.scales.shape != (len(self.features),):
            raise ValueError(
                f"ForceFeedback: `scales` must hold one size per feature "
                f"({len(self.features)}: {self.features}), got shape "
                f"{self.scales.shape}."
            )
        check_concrete(
            jnp.all(self.scales > 0),
            f"ForceFeedback: every scale must be > 0, got {self.scales}.",
            self.scales,
        )
        check_range_and_temperature("ForceFeedback", self.i_max, self.temperature)

    @classmethod
    def linear(
        cls,
        scales,
        i_max,
        *,
        features: tuple[str, ...] = DEFAULT_FEATURES,
        temperature=0.0,
        model: Damper | None = None,
    ) -> "ForceFeedback":
        """$g(\\varphi) = w \\cdot \\varphi$, every gain $w_k$ zero."""
        return cls(
            network=_zero_linear(len(features), jnp.result_type(float)),
            scales=scales,
            i_max=as_float_array(i_max),
            temperature=as_float_array(temperature),
            features=tuple(features),
            model=model,
        )

    @classmethod
    def mlp(
        cls,
        scales,
        i_max,
        *,
        features: tuple[str, ...] = DEFAULT_FEATURES,
        width: int = 16,
        depth: int = 2,
        key: jax.Array | None = None,
        temperature=0.0,
        model: Damper | None = None,
    ) -> "ForceFeedback":
        """$g(\\varphi) = w \\cdot \\varphi + \\mathrm{MLP}(\\varphi)$: the linear law plus an
        `equinox.nn.MLP` with `depth` hidden layers of `width` tanh units, $w$ and the
        output layer zero (so $g = 0$ at the start, with a nonzero gradient)."""
        key = jax.random.key(0) if key is None else key
        dtype = jnp.result_type(float)
        net = eqx.nn.MLP(
            len(features),
            "scalar",
            width,
            depth,
            activation=jnp.tanh,
            key=key,
            dtype=dtype,
        )
        last = net.layers[-1]
        assert last.bias is not None  # an MLP's output layer has a bias by default
        net = eqx.tree_at(
            lambda n: (n.layers[-1].weight, n.layers[-1].bias),
            net,
            (jnp.zeros_like(last.weight), jnp.zeros_like(last.bias)),
        )
        net = LinearAndMLP(_zero_linear(len(features), dtype), net)
        return cls(
            network=net,
            scales=scales,
            i_max=as_float_array(i_max),
            temperature=as_float_array(temperature),
            features=tuple(features),
            model=model,
        )

    @staticmethod
    def weights(pair) -> list:
        """Every weight of the map, for `tune(..., parameters=ForceFeedback.weights)`
        on a `(system, ForceFeedback)` pair (selected by structure, as `eqx.tree_at`
        requires); for an `ObserverBasedController` around one, its law's."""
        law = pair[1]
        # An observer-based controller holds the law (its `.law`, as `.tunable`
        # selects): the weights are there.
        law = getattr(law, "law", law)
        network = getattr(law, "network", None)
        if network is None:
            raise TypeError(
                "ForceFeedback.weights selects the weights of a ForceFeedback (or of "
                "an ObserverBasedController around one), got a "
                f"{type(pair[1]).__name__}."
            )
        if isinstance(network, eqx.nn.Linear) and not network.use_bias:
            return [network.weight]
        if isinstance(network, LinearAndMLP):
            return [network.linear.weight] + [
                w for layer in network.mlp.layers for w in (layer.weight, layer.bias)
            ]
        raise TypeError(
            "ForceFeedback.weights knows the maps of `linear` and `mlp`; for your own "
            f"{type(network).__name__}, select its arrays in your `parameters`."
        )

    def desired_force(self, measurement, yield_force):
        """$F^*$ [N] from the measurements and the damper's yield force [N]."""
        phi = jnp.stack([measurement[name] for name in self.features]) / self.scales
        # `network` is typed as a Module (a pytree to tune); every map is callable.
        return yield_force * self.network(phi)  # pyright: ignore[reportCallIssue]

    def __call__(self, measurement, state, plant):
        plant = plant.with_model(self.model)
        yield_force = plant.yield_force(self.i_max)
        if yield_force is None:
            raise TypeError(
                "ForceFeedback needs the damper's force scale: its hysteresis model "
                f"({type(plant.damper.hysteresis).__name__}) has no `yield_force`."
            )
        target = self.desired_force(measurement, yield_force)
        command = command_for_force(plant, target, self.i_max, self.temperature)
        return clip_command(command, self.i_max), state


def feature_scales(solution, features: tuple[str, ...] = DEFAULT_FEATURES):
    """Typical sizes $s_k$ of the features: their RMS over a (batch of) runs, e.g. of
    the passive system on the training roads (units of each feature)."""
    return tuple(
        float(np.sqrt(np.mean(np.square(np.asarray(solution[name])))))
        for name in features
    )
