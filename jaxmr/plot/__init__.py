"""Figures of simulated (and measured) loops. The only jaxmr module that imports
matplotlib; it imports it when called, so `import jaxmr` stays light."""

from ._fit import (
    measured_vs_predicted as measured_vs_predicted,
    measured_vs_predicted_loops as measured_vs_predicted_loops,
    prediction_band as prediction_band,
)
from ._loops import (
    energy_vs_current as energy_vs_current,
    loop as loop,
    loops as loops,
)
