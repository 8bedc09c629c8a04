"""Export of a tuned controller for a real-time target: C99 (`c.py`) and StableHLO
(`stablehlo.py`)."""

from .c import export_c as export_c
from .stablehlo import export_stablehlo as export_stablehlo
