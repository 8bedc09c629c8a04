"""How a model's force is scored against a measured one: NRMSE = RMSE/std(F) (the figure
every dataset's authors quote), RMSE, the moving average a measured force went through,
the held-out split of `compare_models`, the cross-validation folds and parsimony rule
of `select_model`, and the table of scores.

`jaxmr.record_nrmse` scores a model on whole records with these. NumPy in, NumPy out
(not jit-able), like `jaxmr.data`.
"""

from ._identify.score import (
    moving_average as moving_average,
    nrmse as nrmse,
    rmse as rmse,
)
from ._identify.select import (
    Fold as Fold,
    Parsimony as Parsimony,
    cv_folds as cv_folds,
    fold_data as fold_data,
    holdout_split as holdout_split,
    parsimony as parsimony,
    score_table as score_table,
)

__all__ = [
    "Fold",
    "Parsimony",
    "cv_folds",
    "fold_data",
    "holdout_split",
    "moving_average",
    "nrmse",
    "parsimony",
    "rmse",
    "score_table",
]
