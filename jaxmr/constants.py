"""Constants: published data that jaxmr's presets are built from, and the names of the
measurements a machine reports.

- `MEASUREMENT_NAMES`: what every machine's `simulate_system` run returns by name
  (`sol["damper_force"]`); a machine adds its own (a quarter car's
  `sol["tyre_force"]`).
- `AISI_12L14_MAJOR_LOOP`: the steel's major-loop data, from which
  `jaxmr.aisi_12l14()` derives Hodgdon's constants.
- `UTFSM_SPENCER_PUBLISHED`: the UTFSM damper's published Spencer parameters, in the
  thesis's units, which `jaxmr.utfsm_spencer()` converts to SI.
"""

from ._magnetic.presets import AISI_12L14_MAJOR_LOOP as AISI_12L14_MAJOR_LOOP
from ._presets import UTFSM_SPENCER_PUBLISHED as UTFSM_SPENCER_PUBLISHED
from ._systems.base import MEASUREMENT_NAMES as MEASUREMENT_NAMES

__all__ = ["AISI_12L14_MAJOR_LOOP", "MEASUREMENT_NAMES", "UTFSM_SPENCER_PUBLISHED"]
