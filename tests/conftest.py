"""Tests run in float64 with strict dtype promotion: identification and the tolerances
stated in the tests need double precision, and strict promotion catches silent
float32/int mixing in the models.

The session shares one persistent compilation cache between its processes: the two
`pytest -n 2` workers and the notebooks' kernels. Most of the suite's time is XLA
compilation, and a program compiled in one process (a module fixture that both workers
build, a notebook's fit that a test repeats) is then loaded by the others instead of
compiled again. The directory is made for the session (inherited by the workers and
kernels through the environment) and removed at its end, so nothing carries over
between runs; a `JAX_COMPILATION_CACHE_DIR` set by the user is used as it is."""

import os
import shutil
import tempfile

_OWN_CACHE = "JAX_COMPILATION_CACHE_DIR" not in os.environ
if _OWN_CACHE:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(
        prefix="jaxmr-tests-xla-"
    )
    # Programs that take half a second to compile are worth a file (default: 1 s).
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")

import jax  # noqa: E402 - after the environment above, which jax reads on import

import jaxmr  # noqa: E402

# As a user is advised to (and the command line does): each simulation loop compiled
# as one kernel; one CPU device (the tests that need two start their own processes).
# Set before JAX's backend starts, and inherited by those processes and the kernels.
jaxmr.devices.configure_cpu(devices=1)

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
# Where jax was imported before this file (by a plugin), the environment came too late.
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update(
    "jax_persistent_cache_min_compile_time_secs",
    float(os.environ.get("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1.0")),
)


def pytest_unconfigure(config):
    # The process that made the cache (the xdist controller, or the only process)
    # removes it; the workers, which inherited it, leave it.
    if _OWN_CACHE and not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)


# Longest first (about a minute or more each), so that under `pytest -n 2` they start
# early and the short tests fill in around them; with `--maxschedchunk=2`
# (pyproject.toml) xdist hands tests out two at a time, so the long ones alternate
# between the workers instead of all landing in the first worker's initial chunk.
_SLOW_FIRST = (
    "test_two_processes_equal_one",
    "02_",
    "06_",
    "04_",
    "07_",
    "05_",
    "01_",
    "03_",
    "08_controller_to_c",
    "test_brake_parameters_identified_from_a_free_decay",
)


def pytest_collection_modifyitems(config, items):
    def rank(item):
        for k, part in enumerate(_SLOW_FIRST):
            if part in item.nodeid:
                return k
        return len(_SLOW_FIRST)

    items.sort(key=rank)  # stable: the rest keep their order
