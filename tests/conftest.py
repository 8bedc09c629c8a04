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

import gc
import os
import shutil
import tempfile
from pathlib import Path

import pytest

_OWN_CACHE = "JAX_COMPILATION_CACHE_DIR" not in os.environ
if _OWN_CACHE:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(
        prefix="jaxmr-tests-xla-"
    )
    # Every program gets a file (default: those over 1 s), as the command line's cache
    # does: the processes share thousands of small ones (an eager operation, a short
    # simulation) at ~50 ms each to compile and a few ms to read; with them in the
    # cache a second run of tests/test_models.py took 42 s instead of 59 s.
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import jax  # noqa: E402 - after the environment above, which jax reads on import

import jaxmr  # noqa: E402
from tests.xla_flags import FAST_COMPILE_VARIABLE, compile_fast  # noqa: E402

# As a user is advised to (and the command line does): each simulation loop compiled
# as one kernel; one CPU device (the tests that need two start their own processes).
# Set before JAX's backend starts, and inherited by those processes and the kernels.
jaxmr.devices.configure_cpu(devices=1)
# Faster compilation into slower programs (tests/xla_flags.py); the notebooks whose
# fits run longer than they compile go back to the user's settings
# (tests/test_notebooks.py).
compile_fast()

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
# Where jax was imported before this file (by a plugin), the environment came too late.
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update(
    "jax_disable_most_optimizations",
    os.environ[FAST_COMPILE_VARIABLE].lower() in ("1", "true"),
)
jax.config.update(
    "jax_persistent_cache_min_compile_time_secs",
    float(os.environ.get("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1.0")),
)


# Each compiled XLA CPU program holds a few memory mappings of its own (its code and
# data), and a worker that runs half the suite holding every program it compiled
# reached 63 000 of them, against Linux's default limit of 65 530
# (`vm.max_map_count`). Past the limit LLVM's next mapping fails and the worker dies
# in compilation: a segmentation fault in test_tune.py in CI (2026-11-27), after
# which xdist waited for it forever. So a worker over half the limit drops JAX's
# in-memory caches at the end of a module; a program it needs again is traced anew
# and read back from the session's persistent cache.
_MAPS = Path("/proc/self/maps")
_MAP_LIMIT = Path("/proc/sys/vm/max_map_count")


def _mappings() -> int:
    with _MAPS.open() as maps:
        return sum(1 for _ in maps)


@pytest.fixture(autouse=True, scope="module")
def _within_the_mapping_limit():
    yield
    if _MAPS.exists() and _MAP_LIMIT.exists():
        if 2 * _mappings() > int(_MAP_LIMIT.read_text()):
            jax.clear_caches()
            gc.collect()


def pytest_unconfigure(config):
    # The process that made the cache (the xdist controller, or the only process)
    # removes it; the workers, which inherited it, leave it.
    if _OWN_CACHE and not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)


# Under `pytest -n 2` (pyproject.toml: `--dist loadgroup --no-loadscope-reorder`)
# xdist hands out the tests in this order, each worker holding at most three: the
# longest first (about half a minute or more each), so that they start early and the
# short tests fill in around them.
_SLOW_FIRST = (
    "test_two_processes_equal_one",
    "06_",
    "02_",
    "04_",
    "control.md",
    "test_host_devices",
    "01_",
    "05_",
    "07_",
    "03_",
    "your-rigs-data.md",
    "08_",
)
# Modules whose module-scoped fixtures take seconds (a tuning run, a fit through the
# command line, simulated data): each runs whole on one worker, which builds each
# fixture once (split over both workers, the tuning fixture alone was built twice, 35 s
# each). Handed out after the longest single tests, the largest first.
_ONE_WORKER = (
    "test_select.py",
    "test_tune_sensors.py",
    "test_cli_fit.py",
    "test_identify_engine.py",
    "test_sas_rig.py",
    "test_magnetic.py",
    "test_observer.py",
    "test_uncertainty.py",
)


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups
def pytest_collection_modifyitems(config, items):
    def rank(item):
        for k, part in enumerate(_SLOW_FIRST + _ONE_WORKER):
            if part in item.nodeid:
                return k
        return len(_SLOW_FIRST) + len(_ONE_WORKER)

    for item in items:
        module = item.nodeid.split("::")[0].rsplit("/", 1)[-1]
        if module in _ONE_WORKER:
            item.add_marker(pytest.mark.xdist_group(module))
    items.sort(key=rank)  # stable: the rest keep their order
