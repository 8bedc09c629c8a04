"""The measuring chain: a force channel that lags the motion channels."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp

from ._current_law import _plain, as_parameter
from ._custom_types import Array, Float
from ._damper import Damper
from ._hysteresis import AbstractHysteresis
from ._misc import check_concrete


class ChannelDelay(eqx.Module):
    r"""A damper (brake) model as its force was *measured*: through a force channel
    that lags the motion channels by `delay`,
    $$F_\mathrm{measured}(t) = F_\mathrm{model}(t - \tau).$$

    Load cells, their amplifiers' filters and an acquisition that does not sample
    every channel at once skew the force against the displacement by a few
    milliseconds; fitted without it, a hysteresis model bends its loop to absorb the
    skew. `ChannelDelay` is how identification (`jaxmr.fit`, `predict`,
    `compare_models`, `jaxmr fit --channel-delay`) sees such a record: the model is
    simulated as it is, and its force, at the data's samples, is read $\tau$ earlier
    (linear interpolation between samples; the first sample of an experiment holds
    before its start, the last after its end). The delay belongs to the test rig, not
    to the device: simulate the device itself (`.model`) in a machine or a controller.

    **Arguments:**

    - `model`: a hysteresis law or a `jaxmr.Damper`.
    - `delay`: $\tau$ [s]; positive when the force lags the motion, negative when it
      leads. May be a fitting constraint (e.g. `jaxmr.Bounded(0.0, -0.01, 0.01)`) to
      identify it.
    """

    model: eqx.Module
    delay: Float[Array, ""] | eqx.Module = eqx.field(converter=as_parameter)
    # What `as_damper` says when handed one (it sits below this module and reads
    # this rather than importing it).
    not_a_device: ClassVar[str] = (
        "a ChannelDelay is the device as its force was measured (the rig's channel "
        "delay), not a device: simulate its `.model`."
    )

    def __check_init__(self):
        if not isinstance(self.model, (AbstractHysteresis, Damper)):
            raise TypeError(
                "ChannelDelay: `model` must be a jaxmr hysteresis model or Damper, got "
                f"{type(self.model).__name__}."
            )
        delay = _plain(self.delay)
        if jnp.ndim(delay) != 0:
            raise ValueError(
                f"ChannelDelay: `delay` must be one number [s], got shape "
                f"{jnp.shape(delay)}."
            )
        check_concrete(
            jnp.isfinite(delay),
            f"ChannelDelay: `delay` must be a finite time [s], got {delay}.",
            delay,
        )


def split_channel(model) -> tuple[eqx.Module, Array | None]:
    """(the device model, the force channel's delay [s] or None)."""
    if isinstance(model, ChannelDelay):
        return model.model, _plain(model.delay)
    return model, None


def delayed(force, delay, sample, first, last, interval):
    """The per-sample force series `force` read `delay` [s] earlier: at sample k,
    linear interpolation at the fractional sample k − delay/interval[k], held within
    the samples [first[k], last[k]] of its experiment (`interval`: the local sample
    interval [s])."""
    dtype = interval.dtype
    position = jnp.clip(
        sample.astype(dtype) - delay / interval, first.astype(dtype), last.astype(dtype)
    )
    lower = jnp.floor(position)
    fraction = position - lower
    lower = lower.astype(first.dtype)
    upper = jnp.minimum(lower + 1, last)
    return (1 - fraction) * force[lower] + fraction * force[upper]
