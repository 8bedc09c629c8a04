"""How a model's force is scored against a measured one: NRMSE = RMSE/std(F) (the figure
every dataset's authors quote), RMSE, the moving average a measured force went through,
the held-out split of `compare_models` and its table of scores.

`jaxmr.record_nrmse` scores a model on whole records with these. NumPy in, NumPy out
(not jit-able), like `jaxmr.data`.
"""

from ._identify.score import (
    moving_average as moving_average,
    nrmse as nrmse,
    rmse as rmse,
)
from ._identify.select import (
    holdout_split as holdout_split,
    score_table as score_table,
)

__all__ = ["holdout_split", "moving_average", "nrmse", "rmse", "score_table"]
