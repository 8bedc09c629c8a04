"""`FittedRange`: the displacements, velocities and inputs a model was fitted on, and
the warning `simulate`, `sweep` and `simulate_system` give beyond them.

A model carries it as a static field (`AbstractHysteresis.fitted_range`, None by
default): not an array, so it is never fitted, differentiated or batched, and a model
without one keeps the pytree and the results it always had. `load_model` gives a model
the range saved with it (`save_model` writes the model's own, or the one given), so
`simulate_system(passenger_car(load_model(path)), ...)` warns with no extra argument;
the simulations' `fitted_range=` checks a model against another range. `jaxmr.fit`
does not set it (a refit's data are not the start's): give the fitted model its
range with `with_fitted_range(result.model, FittedRange.from_experiments(...))`.
"""

import dataclasses
import math
import warnings
from collections.abc import Sequence

import numpy as np

from ._misc import is_concrete

# How far past an interval a simulation may go before it warns, as a share of the
# interval's width: a test repeated at the fitted amplitude meets its own noise and
# the simulation's rounding, which are not extrapolation.
SLACK = 0.02


class OutsideFittedRange(UserWarning):
    """A simulation drove a model beyond the displacements, velocities or inputs it
    was fitted on (its `FittedRange`): its forces there are extrapolation. Filter it
    with `warnings.filterwarnings("ignore", category=jaxmr.OutsideFittedRange)`."""


@dataclasses.dataclass(frozen=True)
class FittedRange:
    """The operating range a model was fitted on: the smallest and largest
    displacement, velocity and input over the fitted experiments' samples.

    **Attributes:** each an interval `(low, high)`:

    - `displacement`: [m] (a brake's angle [rad] when `rotary`).
    - `velocity`: [m/s] ([rad/s] when `rotary`).
    - `input`: the current [A] (the voltage [V] when `drive == "voltage"`).
    - `rotary`: whether the device is a brake (angle and angular velocity).
    - `drive`: `"current"` or `"voltage"`.

    Build it with `FittedRange.from_experiments(experiments)`; `jaxmr fit` saves it
    with the model (`save_model(..., fitted_range=)`), and `load_model` gives it
    back to the model (its `fitted_range`; `load_fitted_range` reads it alone).
    """

    displacement: tuple[float, float]
    velocity: tuple[float, float]
    input: tuple[float, float]
    rotary: bool = False
    drive: str = "current"

    def __post_init__(self):
        for name in ("displacement", "velocity", "input"):
            interval = getattr(self, name)
            try:
                low, high = (float(x) for x in interval)
            except (TypeError, ValueError):
                raise ValueError(
                    f"FittedRange: `{name}` must be an interval (low, high) of "
                    f"numbers, got {interval!r}."
                ) from None
            if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                raise ValueError(
                    f"FittedRange: `{name}` must be a finite interval with low <= "
                    f"high, got ({low}, {high})."
                )
            object.__setattr__(self, name, (low, high))
        if self.drive not in ("current", "voltage"):
            raise ValueError(
                f"FittedRange: `drive` must be 'current' or 'voltage', got "
                f"{self.drive!r}."
            )

    @classmethod
    def from_experiments(cls, experiments: Sequence) -> "FittedRange":
        """The range of `jaxmr.data.Experiment`s: the extremes of their `x`, `v` and
        `current` columns over every sample (the discarded start included: the model
        ran through it)."""
        experiments = list(experiments)
        if not experiments:
            raise ValueError("FittedRange.from_experiments: no experiment given.")

        def interval(name):
            values = np.concatenate(
                [np.ravel(np.asarray(getattr(e, name))) for e in experiments]
            )
            return float(np.min(values)), float(np.max(values))

        first = experiments[0]
        return cls(
            displacement=interval("x"),
            velocity=interval("v"),
            input=interval("current"),
            rotary=bool(first.rotary),
            drive=str(first.drive),
        )

    def units(self) -> dict[str, str]:
        """The unit of each interval, by name."""
        return {
            "displacement": "rad" if self.rotary else "m",
            "velocity": "rad/s" if self.rotary else "m/s",
            "input": "V" if self.drive == "voltage" else "A",
        }

    def to_dict(self) -> dict:
        """The JSON-ready record (with the units), as `save_model` writes it."""
        return {
            "displacement": list(self.displacement),
            "velocity": list(self.velocity),
            "input": list(self.input),
            "rotary": self.rotary,
            "drive": self.drive,
            "units": self.units(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "FittedRange":
        """Read `to_dict`'s record back (its `units` are derived, not read)."""
        if not isinstance(data, dict):
            raise ValueError(
                f"fitted_range: expected a JSON object, got {type(data).__name__}."
            )
        missing = [k for k in ("displacement", "velocity", "input") if k not in data]
        if missing:
            raise ValueError(f"fitted_range: missing {', '.join(missing)}.")
        intervals = {}
        for name in ("displacement", "velocity", "input"):
            value = data[name]
            if not isinstance(value, (list, tuple)):
                raise ValueError(
                    f"fitted_range: `{name}` must be an interval [low, high], got "
                    f"{value!r}."
                )
            intervals[name] = tuple(value)
        return cls(
            **intervals,
            rotary=bool(data.get("rotary", False)),
            drive=str(data.get("drive", "current")),
        )

    def exceeded(self, displacement=None, velocity=None, input=None) -> list[str]:
        """What leaves the range, one sentence per interval exceeded (by more than
        `SLACK` of its width): the values reached, the interval and by how much.
        Any argument may be None (not checked); arrays of any shape."""
        found = []
        units = self.units()
        for name, values in (
            ("displacement", displacement),
            ("velocity", velocity),
            ("input", input),
        ):
            if values is None:
                continue
            values = np.asarray(values, dtype=float)
            values = values[np.isfinite(values)]
            if values.size == 0:
                continue
            low, high = getattr(self, name)
            slack = SLACK * (high - low)
            reached_low, reached_high = float(values.min()), float(values.max())
            beyond = max(low - reached_low, reached_high - high)
            if beyond <= slack:
                continue
            label = self.drive if name == "input" else name
            unit = units[name]
            width = high - low
            share = f" ({beyond / width:.0%} of its width)" if width > 0 else ""
            found.append(
                f"{label} spans [{reached_low:.4g}, {reached_high:.4g}] {unit}, the "
                f"fitted range [{low:.4g}, {high:.4g}] {unit}: beyond it by "
                f"{beyond:.4g} {unit}{share}"
            )
        return found

    def warn(
        self, who: str, displacement=None, velocity=None, input=None, stacklevel=3
    ) -> bool:
        """Warn once (`OutsideFittedRange`) naming every interval exceeded; nothing
        when the values are traced (under jit, vmap or grad: their values are not
        known). **Returns:** whether it warned."""
        if not is_concrete(displacement, velocity, input):
            return False
        found = self.exceeded(displacement, velocity, input)
        if found:
            warnings.warn(
                f"{who} drove the model beyond the range it was fitted on: "
                + "; ".join(found)
                + ". Its forces there are extrapolation.",
                OutsideFittedRange,
                stacklevel=stacklevel,
            )
        return bool(found)


def check_fitted_range(fitted_range) -> FittedRange | None:
    """`fitted_range` checked as a keyword of the simulations (None: no check)."""
    if fitted_range is None or isinstance(fitted_range, FittedRange):
        return fitted_range
    raise TypeError(
        "`fitted_range` must be a jaxmr.FittedRange (e.g. "
        f"jaxmr.load_fitted_range(path)) or None, got {type(fitted_range).__name__}."
    )
