"""Figures of merit of a simulated or measured loop."""

import jax.numpy as jnp
import numpy as np

from ._custom_types import ArrayLike, Float
from ._metrics import dissipated_energy
from ._misc import is_concrete
from ._solution import Solution


def energy_per_cycle(
    solution: Solution, period: float | Float[ArrayLike, "..."]
) -> Float[ArrayLike, "..."]:
    r"""Energy dissipated in the last full cycle, $\oint F\,dx = \int_{t_1-P}^{t_1}
    F\,v\,dt$ [J] (for a brake, torque × angle: [J] too).

    Integrates $F v$ by the trapezoidal rule over the samples of the final period $P$,
    so give a solution that covers at least one whole period after the initial transient,
    sampled finely (≥ 100 samples per period for < 0.1 % error). Works on sweeps: the
    result has the solution's leading axes. Positive for a passive device.

    **Arguments:**

    - `solution`: a `Solution` from `simulate` or `sweep`.
    - `period`: the excitation period $P$ [s] (1/frequency), scalar or per run.
    """
    ts, force, velocity = solution.ts, solution.force, solution.velocity
    if ts is None or force is None or velocity is None:
        raise ValueError(
            "energy_per_cycle needs the solution's ts, force and velocity: pass them "
            "in `sweep(..., keep=)`."
        )
    if is_concrete(period, ts):
        # A frequency passed for the period, or a period longer than the record,
        # would integrate some other stretch and still return a plausible energy.
        p = np.asarray(period, dtype=float)
        host = np.asarray(ts, dtype=float)
        span = float(np.min(host[..., -1] - host[..., 0]))
        step = float(np.max(host[..., -1] - host[..., -2])) if host.shape[-1] > 1 else 0
        if not np.all(np.isfinite(p) & (p > 0)):
            raise ValueError(f"`period` must be > 0 [s], got {period!r}.")
        if np.max(p) > span + 0.5 * step:
            raise ValueError(
                f"`period` = {np.max(p):g} s is longer than the solution "
                f"({span:g} s): give the excitation period 1/f [s], and a solution "
                "that spans at least one whole period."
            )
    t_end = ts[..., -1:]
    period = jnp.asarray(period)[..., None]
    # Within half a sample interval: the period's first sample, rounded off its
    # time (by float32's 1.2e-7 at 2 s), still counts.
    half_step = 0.5 * (ts[..., -1:] - ts[..., -2:-1])
    inside = ts >= t_end - period - half_step
    # `dissipated_energy` over the last period's samples: the clock is held at the
    # first of them before it, so the earlier segments span no time and add exactly 0.
    t_first = jnp.min(jnp.where(inside, ts, jnp.inf), axis=-1, keepdims=True)
    return dissipated_energy(jnp.maximum(ts, t_first), force, velocity)
