"""The devices jaxmr computes on: CPU cores as XLA devices, arrays gathered from every
process of a `jax.distributed` run, and where a process keeps the fit's traced
programs for the next one.

```python
import jaxmr.devices

jaxmr.devices.configure_cpu()  # first, before any JAX computation
```

See [Scale-out](../scale-out.md). Importing this module imports JAX but starts no
backend.
"""

from ._cpu import configure_cpu as configure_cpu
from ._distribute import gather as gather
from ._traced import traced_programs_in as traced_programs_in

__all__ = ["configure_cpu", "gather", "traced_programs_in"]
