"""Figures of merit of a run: what a damper, a controller or a tuning is judged by.

- Comfort: `comfort` (a closed-loop run's ISO 2631-1 Wk-weighted RMS body
  acceleration [m/s²]), `wk_rms`, `wk_weighted`, `wk_response`, `wk_state_space` (the
  Wk weighting), `vdv`, `rms`, `peak`, `crest_factor`.
- Energy: `energy_per_cycle` (of a `simulate`/`sweep` solution), `dissipated_work` (of
  a `simulate_system` solution), `dissipated_energy` (of sampled force and velocity).
- Settling: `settling_time`, `decay_settling_time` (a free decay of the SAS rig).
- Control effort: `mean_current`, `rms_current`.

```python
import jaxmr.metrics

a_w = jaxmr.metrics.comfort(sol)  # [m/s²]
```

All are JAX functions of arrays: jit-able, vmap-able and differentiable. Importing
this module imports JAX, as `import jaxmr` does on first use.
"""

from ._analysis import energy_per_cycle as energy_per_cycle
from ._closed_loop import dissipated_work as dissipated_work
from ._metrics import (
    crest_factor as crest_factor,
    dissipated_energy as dissipated_energy,
    mean_current as mean_current,
    peak as peak,
    rms as rms,
    rms_current as rms_current,
    settling_time as settling_time,
    vdv as vdv,
    wk_response as wk_response,
    wk_rms as wk_rms,
    wk_state_space as wk_state_space,
    wk_weighted as wk_weighted,
)
from ._systems import decay_settling_time as decay_settling_time
from ._tune import comfort as comfort

__all__ = [
    "comfort",
    "crest_factor",
    "decay_settling_time",
    "dissipated_energy",
    "dissipated_work",
    "energy_per_cycle",
    "mean_current",
    "peak",
    "rms",
    "rms_current",
    "settling_time",
    "vdv",
    "wk_response",
    "wk_rms",
    "wk_state_space",
    "wk_weighted",
]
