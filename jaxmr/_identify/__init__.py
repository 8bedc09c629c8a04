"""Identification: models fitted to measured records, one stage per file.

- `data.py`: the data a fit sees (experiments packed into lanes of RK4 steps; the
  step policy);
- `residual.py`: the simulation, the residual and its Jacobian;
- `solver.py`: the Levenberg–Marquardt loop, starts and scaling;
- `result.py`: the result and its statistics;
- `band.py`: the prediction band from the parameters' uncertainty;
- `fitting.py`: `fit` and `fit_each`;
- `system.py`: `fit_system` (a whole machine from its response, the same engine);
- `templates.py`: data-scaled initial models;
- `select.py`: model selection on held-out data;
- `design.py`: optimal experiment design (which tests to run) from the same Jacobian;
- `score.py`: prediction and scores;
- `saved.py`: a fit written to a parameter file, with its report.
"""

from .band import (
    PredictionBand as PredictionBand,
    prediction_band as prediction_band,
    prediction_band_from_covariance as prediction_band_from_covariance,
)
from .data import FitData as FitData, StepPolicy as StepPolicy, pack as pack
from .design import (
    Design as Design,
    design_experiments as design_experiments,
    planned_test as planned_test,
    sine_grid as sine_grid,
)
from .fitting import fit as fit, fit_each as fit_each
from .result import FitResult as FitResult, StopReason as StopReason
from .saved import (
    fit_report as fit_report,
    save_fit as save_fit,
)
from .score import (
    StepsRefined as StepsRefined,
    moving_average as moving_average,
    nrmse as nrmse,
    predict as predict,
    predict_all as predict_all,
    record_nrmse as record_nrmse,
)
from .select import (
    FitEnded as FitEnded,
    FitStarted as FitStarted,
    ModelScore as ModelScore,
    Selection as Selection,
    compare_models as compare_models,
    holdout_split as holdout_split,
    score_table as score_table,
    select_model as select_model,
)
from .solver import (
    FastLevenbergMarquardt as FastLevenbergMarquardt,
    ProgressPrinter as ProgressPrinter,
)
from .system import SystemRecord as SystemRecord, fit_system as fit_system
from .templates import (
    MODEL_TEMPLATES as MODEL_TEMPLATES,
    DataScales as DataScales,
    data_scales as data_scales,
)
