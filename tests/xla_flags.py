"""How the test session compiles: faster, into programs that run slower.

The suite is bound by XLA's compilation, most of it spent optimising programs that
then run for milliseconds. Two settings, measured on 2 cores:

- jax's `jax_disable_most_optimizations` (set through its environment variable, so
  that the workers, subprocesses and notebook kernels inherit it): XLA's backend at
  optimisation level 0 and LLVM's expensive passes off. tests/test_models.py took 77 s
  instead of 101 s, the whole suite 657 s instead of 782 s.
- XLA's CPU fusions emitted by its older emitter (`--xla_cpu_use_fusion_emitters=false`):
  tests/test_models.py with tests/test_tune.py then took 99 s instead of 119 s. An XLA
  that does not know the flag would stop the process, so it is added only where a
  probe process accepts it.

The programs compute the same operations: the tests' tolerances hold, and the
bit-for-bit comparisons compare programs compiled alike. Nothing here imports JAX:
tests/conftest.py calls `compile_fast` before JAX starts its backend.
"""

import os
import subprocess
import sys

FAST_COMPILE_VARIABLE = "JAX_DISABLE_MOST_OPTIMIZATIONS"
FAST_COMPILE_XLA_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def compile_fast() -> None:
    """Set both settings in this process's environment, unless the user (or the
    session's first process, whose environment the others inherit) has set the
    variable."""
    if FAST_COMPILE_VARIABLE in os.environ:
        return
    os.environ[FAST_COMPILE_VARIABLE] = "1"
    flags = " ".join([os.environ.get("XLA_FLAGS", ""), *FAST_COMPILE_XLA_FLAGS])
    probe = subprocess.run(
        [sys.executable, "-c", "import jax; jax.devices()"],
        env=dict(os.environ, XLA_FLAGS=flags.strip()),
        capture_output=True,
        timeout=120,
    )
    if probe.returncode == 0:
        os.environ["XLA_FLAGS"] = flags.strip()


def without_fast_compile_flags(flags: str) -> str:
    """`XLA_FLAGS` without `FAST_COMPILE_XLA_FLAGS`: with `FAST_COMPILE_VARIABLE`
    unset, a process compiles as a user's does."""
    return " ".join(f for f in flags.split() if f not in FAST_COMPILE_XLA_FLAGS)
