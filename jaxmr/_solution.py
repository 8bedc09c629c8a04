"""What a simulation returns: time series and a result code."""

import dataclasses
from collections.abc import Sequence
from typing import ClassVar

import diffrax as dfx
import equinox as eqx

from ._custom_types import Array, Float, Int


class RESULTS(dfx.RESULTS):  # pyright: ignore[reportGeneralTypeIssues]
    """Outcome codes of jaxmr's solves: diffrax's, and those jaxmr adds."""

    state_out_of_bounds = (
        "An internal state left its theoretical bound (e.g. |z| > z0 of Bouc-Wen): the "
        "integration diverged. With FixedStep use more substeps, or use Adaptive()."
    )
    nonfinite_force = (
        "The simulated force is not finite: check the parameters (and, with FixedStep, "
        "use more substeps or an adaptive integrator)."
    )

    command_out_of_range = (
        "The controller commanded a current outside [0, i_max]: clip its output (the "
        "built-in laws do) or raise its `i_max`."
    )

    max_steps_float32 = (
        "The maximum number of solver steps was reached in float32: tolerances below "
        "what float32 resolves (rtol under ~1e-6, atol under ~1e-8 of the states' size) "
        "shrink the steps without end. Simulate in float64 (call "
        "jax.config.update('jax_enable_x64', True) before creating arrays), or loosen "
        "rtol and atol, or increase `max_steps`."
    )
    current_outside_table = (
        "The current leaves the current range of a TableLaw in the model (laws are not "
        "extrapolated): extend the table or keep the current inside it; with "
        "throw=True, simulate and sweep quote the ranges."
    )


class Solution(eqx.Module):
    """The result of `simulate` (or `sweep`: every array then has the sweep's leading
    axes).

    **Attributes:**

    - `ts`: output times [s].
    - `displacement`, `velocity`: the prescribed motion [m, m/s] (or [rad, rad/s]).
    - `current`: the commanded current [A] (or voltage [V]).
    - `effective_current`: what the model saw after the current dynamics [A or V].
    - `force`: force [N] (or torque [N·m]).
    - `states`: internal states, last axis named by `state_names`.
    - `result`: a `jaxmr.RESULTS` code per run.
    - `num_steps`: integrator steps taken per run.
    - `state_names`: names of the internal states.

    A field is `None` when `sweep(..., keep=)` did not ask for it.
    """

    ts: Float[Array, "*batch times"] | None
    displacement: Float[Array, "*batch times"] | None
    velocity: Float[Array, "*batch times"] | None
    current: Float[Array, "*batch times"] | None
    effective_current: Float[Array, "*batch times"] | None
    force: Float[Array, "*batch times"] | None
    states: Float[Array, "*batch times states"] | None
    result: RESULTS
    num_steps: Int[Array, "*batch"]
    state_names: tuple[str, ...] = eqx.field(static=True)

    # The fields `sweep(..., keep=)` may drop; `result` and `num_steps` always stay.
    OPTIONAL: ClassVar[tuple[str, ...]] = (
        "ts",
        "displacement",
        "velocity",
        "current",
        "effective_current",
        "force",
        "states",
    )

    @classmethod
    def check_fields(cls, keep: str | Sequence[str] | None) -> tuple[str, ...] | None:
        """`keep` as a sorted tuple of field names (hashable, one compilation per
        set), or a readable error."""
        if keep is None:
            return None
        if isinstance(keep, str):
            keep = (keep,)
        unknown = [name for name in keep if name not in cls.OPTIONAL]
        if unknown:
            raise ValueError(
                f"`keep` names Solution fields; unknown: {unknown}. Choose from "
                f"{cls.OPTIONAL} (result and num_steps are always kept)."
            )
        return tuple(sorted(set(keep)))

    def only(self, keep: Sequence[str]) -> "Solution":
        """This solution with the fields not in `keep` set to None."""
        dropped = {name: None for name in self.OPTIONAL if name not in keep}
        return dataclasses.replace(self, **dropped)

    def state(self, name: str) -> Float[Array, "*batch times"]:
        """One internal state by name (e.g. `"z"`)."""
        if self.states is None:
            raise ValueError(
                "this solution was computed without its states (`keep` did not name "
                "'states')."
            )
        if name not in self.state_names:
            raise KeyError(
                f"no state named {name!r}; this model's states are {self.state_names}."
            )
        return self.states[..., self.state_names.index(name)]
