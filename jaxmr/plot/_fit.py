"""Measured against predicted force: how well a fitted model reproduces an experiment."""

import numpy as np

from ._loops import _UNITS, _pyplot

_AGAINST = ("displacement", "velocity", "time")


def _default_units(experiment, units):
    if units is None:
        # Millimetres: a damper's stroke in metres gives unreadable tick labels.
        return "rotary" if getattr(experiment, "rotary", False) else "linear_mm"
    if units not in _UNITS:
        raise ValueError(f"`units` must be one of {sorted(_UNITS)}, got {units!r}.")
    return units


def measured_vs_predicted(
    experiment,
    predicted_force,
    against: str = "displacement",
    *,
    ax=None,
    units: str | None = None,
    measured_kwargs: dict | None = None,
    predicted_kwargs: dict | None = None,
    legend: bool = True,
):
    """Draw an experiment's measured force and a model's predicted force against
    displacement, velocity or time.

    **Arguments:**

    - `experiment`: a `jaxmr.data.Experiment` with its measured force (`None` draws the
      prediction alone).
    - `predicted_force`: the predicted force [N] (torque [N·m]) at its samples, e.g.
      `jaxmr.predict(model, experiment)`.
    - `against`: `"displacement"`, `"velocity"` or `"time"`.
    - `ax`: a matplotlib Axes to draw on (a new figure when `None`).
    - `units`: as `loop`'s (`"linear"`, `"linear_mm"`, `"rotary"`); default
      `"rotary"` for a rotary experiment (degrees, N·m), else `"linear_mm"` (mm, N).
    - `measured_kwargs`, `predicted_kwargs`: extra `Axes.plot` arguments of each line.
    - `legend`: draw the legend.

    **Returns:** the Axes.
    """
    if against not in _AGAINST:
        raise ValueError(f"`against` must be one of {list(_AGAINST)}, got {against!r}.")
    units = _default_units(experiment, units)
    t = np.asarray(experiment.t)
    predicted = np.asarray(predicted_force)
    if predicted.shape != t.shape:
        raise ValueError(
            f"`predicted_force` has shape {predicted.shape}, but the experiment has "
            f"{t.shape[0]} samples: give one predicted value per sample."
        )
    x_label, v_label, force_label, scale = _UNITS[units]
    if against == "time":
        abscissa, label = t, "Time [s]"
    elif against == "displacement":
        abscissa, label = np.asarray(experiment.x) * scale, x_label
    else:
        abscissa, label = np.asarray(experiment.v) * scale, v_label
    plt = _pyplot()
    if ax is None:
        _, ax = plt.subplots(figsize=(5, 4), layout="constrained")
    if getattr(experiment, "force", None) is not None:
        # A wide light band under a thin dark line: where the model follows the data
        # (a good fit) the prediction is still seen, on top of the measurement.
        style = {"color": "0.7", "lw": 2.5, "label": "measured"}
        ax.plot(
            abscissa, np.asarray(experiment.force), **style | (measured_kwargs or {})
        )
    style = {"color": "C3", "lw": 1.0, "label": "predicted"}
    ax.plot(abscissa, predicted, **style | (predicted_kwargs or {}))
    ax.set_xlabel(label)
    ax.set_ylabel(force_label)
    ax.grid(True, alpha=0.3)
    if legend:
        ax.legend(fontsize="small")
    return ax


def measured_vs_predicted_loops(
    experiment, predicted_force, *, units: str | None = None, title: str | None = None
):
    """Three panels of `measured_vs_predicted`: force against displacement, velocity
    and time.

    **Returns:** the matplotlib Figure.
    """
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), layout="constrained")
    for ax, against in zip(axes, _AGAINST):
        measured_vs_predicted(
            experiment,
            predicted_force,
            against,
            ax=ax,
            units=units,
            legend=against == "time",
        )
    if title:
        fig.suptitle(title)
    return fig
