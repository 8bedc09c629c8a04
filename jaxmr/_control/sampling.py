"""The timing of a digital controller (its sample time and delay)."""

import math

import equinox as eqx


class Sampling(eqx.Module):
    """The timing of a digital controller: how often it samples and how late its
    command acts. Taken by `simulate_system`, `free_decay` and the tuners (`tune`,
    `random_search`, `cma_es`, `evaluate`) and held by an `ObserverBasedController`,
    whose filters and observer step at it; how the states are integrated between
    samples is their `integrator` (`FixedStep`).

    **Arguments:**

    - `dt`: the sample time [s], the controller's period; default 1e-3 (1 kHz).
    - `delay`: whole samples between a measurement and the command it leads to acting
      on the damper; default 1 (0: at once).
    """

    dt: float = eqx.field(static=True, default=1e-3)
    delay: int = eqx.field(static=True, default=1)

    def __check_init__(self):
        if isinstance(self.dt, bool) or not isinstance(self.dt, (int, float)):
            raise TypeError(
                f"Sampling: `dt` must be a number of seconds, got {self.dt!r}."
            )
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(
                f"Sampling: `dt` must be a positive number of seconds, got {self.dt!r}."
            )
        if isinstance(self.delay, bool) or not isinstance(self.delay, int):
            raise TypeError(
                f"Sampling: `delay` must be a whole number of samples, got "
                f"{self.delay!r}."
            )
        if self.delay < 0:
            raise ValueError(
                f"Sampling: `delay` must be a whole number of samples >= 0, got "
                f"{self.delay!r}."
            )
