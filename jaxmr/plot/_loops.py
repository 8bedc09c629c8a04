"""Hysteresis loops of a sweep and energy per cycle against current."""

from collections.abc import Sequence

import numpy as np

_AXES = {"displacement": "displacement", "velocity": "velocity", "time": "ts"}
_UNITS = {
    # (x label, v label, force label, scale of x and v shown)
    "linear": ("Displacement [m]", "Velocity [m/s]", "Force [N]", 1.0),
    "linear_mm": ("Displacement [mm]", "Velocity [mm/s]", "Force [N]", 1e3),
    "rotary": ("Angle [deg]", "Angular velocity [deg/s]", "Torque [N·m]", 180 / np.pi),
}


def _pyplot():
    # Imported on use: `import jaxmr` must not pull in matplotlib. Without a display
    # matplotlib picks the Agg backend by itself.
    import matplotlib.pyplot as plt

    return plt


LOOP_HINT = (
    "a Solution from jaxmr.simulate or jaxmr.sweep; for a measured experiment draw "
    "jaxmr.plot.measured_vs_predicted(experiment, predicted_force)"
)


def expect(value, attributes: Sequence[str], name: str, what: str) -> None:
    """A clear `TypeError` when `value` lacks what a plot reads from it (an
    `AttributeError` deep in the drawing named neither the argument nor the fix)."""
    missing = [a for a in attributes if not hasattr(value, a)]
    if missing:
        raise TypeError(f"`{name}` must be {what}; got {type(value).__name__}.")


def loop(
    solution,
    against: str = "displacement",
    *,
    ax=None,
    units: str = "linear",
    labels: Sequence[str] | None = None,
    last_cycles_from: float | None = None,
    legend: bool | str = True,
    **line_kwargs,
):
    """Draw force (torque) against displacement, velocity or time for every run.

    **Arguments:**

    - `solution`: a `Solution` from `simulate` or a 1-axis `sweep` (or a flattened one).
    - `against`: `"displacement"`, `"velocity"` or `"time"`.
    - `ax`: a matplotlib Axes to draw on (a new figure when `None`).
    - `units`: `"linear"` (m, N), `"linear_mm"` (mm, N) or `"rotary"` (deg, N·m: angles
      in rad are shown in degrees).
    - `labels`: one legend label per run.
    - `last_cycles_from`: draw only samples with t ≥ this time [s] (drop the transient).
    - `legend`: with `labels`, where the legend goes: `True` (matplotlib's best place
      inside the axes), `"outside"` (to the right of the axes, clear of loops that fill
      them, e.g. Dahl's ellipses), any other matplotlib `loc`, or `False` (none).
    - `line_kwargs`: further `Axes.plot` arguments (`linestyle`, `color`, ...).

    **Returns:** the Axes.
    """
    if against not in _AXES:
        raise ValueError(f"`against` must be one of {sorted(_AXES)}, got {against!r}.")
    if units not in _UNITS:
        raise ValueError(f"`units` must be one of {sorted(_UNITS)}, got {units!r}.")
    expect(solution, ("ts", "force", "displacement"), "solution", LOOP_HINT)
    if isinstance(labels, str):
        raise TypeError(
            f"`labels` must be one label per run (a list of strings), got the string "
            f"{labels!r}; for one run give [{labels!r}]."
        )
    plt = _pyplot()
    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4), layout="constrained")
    field = _AXES[against]
    dropped = [n for n in ("ts", "force", field) if getattr(solution, n) is None]
    if dropped:
        raise ValueError(
            f"plot.loop needs the solution's {', '.join(dropped)}, which the sweep "
            f"did not keep: pass them in `sweep(..., keep=)`."
        )
    x_label, v_label, force_label, scale = _UNITS[units]
    xs = np.asarray(getattr(solution, field))
    ts = np.asarray(solution.ts)
    force = np.asarray(solution.force)
    xs, ts, force = (a.reshape(-1, a.shape[-1]) for a in (xs, ts, force))
    if against != "time":
        xs = xs * scale
    if labels is not None and len(labels) != force.shape[0]:
        raise ValueError(
            f"`labels` has {len(labels)} entries for {force.shape[0]} runs."
        )
    keep = np.ones(ts.shape, dtype=bool)
    if last_cycles_from is not None:
        keep = ts >= last_cycles_from
        if not np.all(np.any(keep, axis=-1)):
            raise ValueError(
                f"`last_cycles_from` = {last_cycles_from} s leaves no samples to draw: "
                f"a run ends at t = {float(np.min(ts[:, -1]))} s."
            )
    for k in range(force.shape[0]):
        label = None if labels is None else labels[k]
        ax.plot(xs[k][keep[k]], force[k][keep[k]], label=label, **line_kwargs)
    ax.set_xlabel(
        {"displacement": x_label, "velocity": v_label, "time": "Time [s]"}[against]
    )
    ax.set_ylabel(force_label)
    ax.grid(True, alpha=0.3)
    if labels is not None and legend is not False:
        _legend(ax, legend)
    return ax


def _legend(ax, where: bool | str) -> None:
    if where == "outside":
        ax.legend(
            fontsize="small",
            loc="center left",
            bbox_to_anchor=(1.01, 0.5),
            frameon=False,
        )
    else:
        ax.legend(fontsize="small", loc="best" if where is True else where)


def loops(
    solution,
    *,
    units: str = "linear",
    labels: Sequence[str] | None = None,
    last_cycles_from: float | None = None,
    title: str | None = None,
):
    """Three panels for a sweep: force against displacement, velocity and time (the
    legend, with `labels`, to the right of the last).

    **Arguments:** as `loop`: `units` (`"linear"`: m, m/s, N; `"linear_mm"`: mm,
    mm/s, N; `"rotary"`: deg, deg/s, N·m), `labels` (one per run),
    `last_cycles_from` (draw only samples with t ≥ this time [s]); `title`, the
    figure's title.

    **Returns:** the matplotlib Figure.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), layout="constrained")
    for ax, against in zip(axes, ("displacement", "velocity", "time")):
        loop(
            solution,
            against,
            ax=ax,
            units=units,
            labels=labels,
            last_cycles_from=last_cycles_from,
            legend="outside" if against == "time" else False,
        )
    if title:
        fig.suptitle(title)
    return fig


def energy_vs_current(
    currents, energies, *, ax=None, label: str | None = None, current_unit: str = "A"
):
    """Energy dissipated per cycle [J] against current (or voltage).

    The energy axis starts at 0 (energies are never negative): a change is seen at its
    true scale, not magnified by an axis that starts near the smallest value (the SAS
    brake's 9 % from 0 to 1 A would fill the figure).

    **Arguments:**

    - `currents`: the inputs, one per point (the axis's values, in `current_unit`).
    - `energies`: [J], one per current, or one row per device of a sweep over
      devices and currents (its last axis the currents).
    - `ax`, `label`: the Axes to draw on (default: a new figure), the legend's text.
    - `current_unit`: the unit `currents` are in, for the axis label only (e.g.
      `"V"` for a device driven by voltage).

    **Returns:** the Axes.
    """
    plt = _pyplot()
    currents, energies = np.asarray(currents), np.asarray(energies)
    if currents.ndim != 1 or energies.ndim not in (1, 2):
        raise ValueError(
            "`currents` must be 1-D and `energies` 1-D or 2-D (one row per device), "
            f"got shapes {currents.shape} and {energies.shape}."
        )
    if currents.size == 0:
        raise ValueError("`currents` and `energies` are empty: nothing to draw.")
    if energies.shape[-1] != currents.size:
        raise ValueError(
            f"`energies` must have one value per current along its last axis: "
            f"{currents.size} currents, energies of shape {energies.shape}."
        )
    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4), layout="constrained")
    # matplotlib draws the columns of a 2-D y: the rows (devices) are the lines here.
    ax.plot(currents, energies.T, "o-", label=label)
    ax.set_xlabel(f"Current [{current_unit}]")
    ax.set_ylabel("Energy dissipated per cycle [J]")
    if np.all(energies >= 0):
        ax.set_ylim(bottom=0.0, top=max(ax.get_ylim()[1], 1.05 * energies.max()))
    ax.grid(True, alpha=0.3)
    if label:
        ax.legend()
    return ax
