"""The devices jaxmr computes on: CPU cores as XLA devices, and arrays gathered from
every process of a `jax.distributed` run.

```python
import jaxmr.devices

jaxmr.devices.configure_cpu()  # first, before any JAX computation
```

See [Scale-out](../scale-out.md). Importing this module imports JAX but starts no
backend.
"""

from ._cpu import configure_cpu as configure_cpu
from ._distribute import gather as gather

__all__ = ["configure_cpu", "gather"]
