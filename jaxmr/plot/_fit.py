"""Measured against predicted force: how well a fitted model reproduces an experiment."""

from types import SimpleNamespace

import numpy as np

from ._loops import _UNITS, _pyplot, expect

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
    expect(
        experiment,
        ("t", {"displacement": "x", "velocity": "v"}.get(against, "t")),
        "experiment",
        "a jaxmr.data.Experiment (then the predicted force, e.g. "
        "jaxmr.predict(model, experiment))",
    )
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
    experiment,
    predicted_force,
    *,
    units: str | None = None,
    title: str | None = None,
    band=None,
):
    """Three panels of `measured_vs_predicted`: force against displacement, velocity
    and time.

    **Arguments:** as `measured_vs_predicted`'s, and `title` (the figure's), `band`:
    a `jaxmr.PredictionBand` of the same samples, shaded in each panel as
    `prediction_band` shades it (`None`: no band).

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
            legend=False,
        )
        if band is not None:
            _shade(ax, band, experiment, against, units, None)
        if against == "time":
            ax.legend(fontsize="small")
    if title:
        fig.suptitle(title)
    return fig


def prediction_band(
    band,
    experiment=None,
    against: str = "time",
    *,
    ax=None,
    units: str | None = None,
    band_kwargs: dict | None = None,
    legend: bool = True,
):
    """Draw a prediction band (`jaxmr.prediction_band`): the predicted force and the
    shaded band around it, with the measured force where `experiment` has one.

    **Arguments:**

    - `band`: a `jaxmr.PredictionBand`.
    - `experiment`: the experiment it predicts (needed to draw against displacement
      or velocity, and to draw the measured force); `None`: the band against time.
    - `against`, `ax`, `units`, `legend`: as `measured_vs_predicted`.
    - `band_kwargs`: extra `Axes.fill_between` arguments of the band.

    **Returns:** the Axes.
    """
    expect(
        band,
        ("t", "force", "lower", "upper"),
        "band",
        "a jaxmr.PredictionBand (jaxmr.prediction_band(result, experiments))",
    )
    if experiment is None:
        if against != "time":
            raise ValueError(
                "drawing a band against displacement or velocity needs its "
                "`experiment` (for the motion); give it, or use against='time'."
            )
        experiment = SimpleNamespace(t=band.t, force=None)
    ax = measured_vs_predicted(
        experiment, band.force, against, ax=ax, units=units, legend=False
    )
    _shade(ax, band, experiment, against, units, band_kwargs)
    if legend:
        ax.legend(fontsize="small")
    return ax


def _shade(ax, band, experiment, against: str, units, band_kwargs) -> None:
    """Shade `band` on `ax` against time, displacement or velocity."""
    t = np.asarray(experiment.t)
    if np.shape(band.lower) != t.shape:
        raise ValueError(
            f"the band has {np.size(band.lower)} samples, but the experiment has "
            f"{t.shape[0]}: give the band of the same samples."
        )
    if against == "time":
        abscissa = t
    else:
        units = _default_units(experiment, units)
        scale = _UNITS[units][3]
        key = "x" if against == "displacement" else "v"
        abscissa = np.asarray(getattr(experiment, key)) * scale
    # Against the motion the abscissa turns back at each reversal: shade between
    # the edges as a polygon, not as a function of the abscissa.
    style = {"color": "C3", "alpha": 0.25, "lw": 0, "label": f"{band.level:.0%} band"}
    style |= band_kwargs or {}
    if against == "time":
        ax.fill_between(abscissa, band.lower, band.upper, **style)
    else:
        ax.fill(
            np.concatenate([abscissa, abscissa[::-1]]),
            np.concatenate([band.lower, band.upper[::-1]]),
            **style,
        )
