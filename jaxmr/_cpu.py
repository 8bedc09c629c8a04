"""`configure_cpu`: the XLA settings that suit jaxmr's simulations on a CPU.

Both are XLA flags (`XLA_FLAGS`), read once, when JAX starts its CPU backend (its first
computation or `jax.devices()`), so they are set by a call the user makes first, never
on import:

- **One kernel per simulation loop.** XLA's CPU runtime executes a program as a
  sequence of "thunks", one call per fused kernel, and a while loop as one such
  sequence per iteration. A loop whose body touches at most
  `xla_cpu_small_while_loop_byte_threshold` bytes (an XLA CPU backend option, default
  1024) is compiled into a single kernel instead. An RK4 step of a damper is a few
  hundred scalar operations, so the per-kernel overhead decides its cost: a forward-mode
  Jacobian carries p tangents through the step, its body crosses 1024 bytes and falls
  back to thunks. With 100 kB the Bouc–Wen benchmark oscillator's Jacobian (6
  parameters, 819 200 RK4 steps) took 0.18 s instead of 1.02 s and the 30-record
  UTFSM fit's (14 parameters, 8 lanes) 0.71 s instead of 1.49 s
  (`benchmarks/cpu_flags.py`). Bodies above 100 kB (a sweep of hundreds of runs in
  one loop) keep the thunks, which can split large kernels over threads.
- **Every core a device** (`xla_force_host_platform_device_count`): XLA runs one
  device's loop on one core, and `fit` splits its lanes, `sweep` its batch, over the
  devices.
- **XLA's older CPU fusion emitters** (`xla_cpu_use_fusion_emitters=false`): they
  compile jaxmr's programs 20-40 % faster than the newer (MLIR) ones, which run them
  no faster and give the same bits (the 30-file UTFSM residual and Jacobian compiled
  in 0.45 and 1.3 s instead of 0.65 and 1.7 s, and matched to the bit; a cold
  Bouc–Wen benchmark fit reached its target 0.5 s sooner: `benchmarks/cpu_flags.py`).
  The flag is XLA's, and XLA aborts the process on a flag it does not know, so it is
  set only under the jaxlib releases it was measured on (`_FUSION_EMITTERS_TESTED`).
"""

import importlib.metadata
import os
import re

# Per-iteration bytes below which a while loop becomes one compiled kernel.
SMALL_LOOP_BYTES = 100_000
_SMALL_LOOP_OPTION = "xla_cpu_small_while_loop_byte_threshold"
_DEVICE_COUNT = "xla_force_host_platform_device_count"
_EXTRA_OPTIONS = "xla_backend_extra_options"
_FUSION_EMITTERS = "xla_cpu_use_fusion_emitters"
# The jaxlib releases (major, minor) whose XLA has `_FUSION_EMITTERS` and on which
# turning it off was measured (benchmarks/cpu_flags.py).
_FUSION_EMITTERS_TESTED = ((0, 10),)


def usable_cores() -> int:
    """The CPU cores this process may run on: its affinity mask where the platform
    has one (a container or `taskset` limits it; `os.cpu_count()` counts the whole
    machine), else `os.cpu_count()`."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):  # macOS and Windows have no affinity call
        return os.cpu_count() or 1


def configure_cpu(devices: int | None = None) -> str:
    """Set the XLA flags under which jaxmr runs fastest on a CPU; call it first.

    Three settings (details in the module docstring): a simulation loop is compiled
    into one kernel (its forward-mode Jacobian ran 2-5x faster); `devices` CPU
    cores become XLA devices, over which `fit` splits its lanes and `sweep`,
    `fit_each` and `evaluate` their batches; and XLA's older CPU fusion emitters
    compile the programs (20-40 % faster, the same results; only under the jaxlib
    releases this was measured on). A flag the user has set in `XLA_FLAGS` is kept
    as it is. GPUs are unaffected.

    XLA reads its flags when JAX starts its CPU backend: call this before any JAX
    computation (`import jaxmr` does not start it), e.g. on the first line of a
    script or notebook. The `jaxmr` command line calls it itself.

    **Arguments:**

    - `devices`: how many XLA CPU devices to make; `None` (default): one per core this
      process may run on (its CPU affinity), at most 8; `1`: leave the device count alone (a single device).

    **Returns:** the `XLA_FLAGS` now set.

    **Raises:** `RuntimeError` when JAX's CPU backend had already started with another
    device count (the flags came too late: restart the interpreter or kernel and call
    this first); `ValueError` for a `devices` below 1.
    """
    if devices is None:
        devices = min(usable_cores(), 8)
    if not isinstance(devices, int) or isinstance(devices, bool) or devices < 1:
        raise ValueError(f"`devices` must be a positive integer, got {devices!r}.")
    flags = os.environ.get("XLA_FLAGS", "")
    added = []
    if _EXTRA_OPTIONS not in flags:
        added.append(f"--{_EXTRA_OPTIONS}={_SMALL_LOOP_OPTION}={SMALL_LOOP_BYTES}")
    if _FUSION_EMITTERS not in flags and _jaxlib_release() in _FUSION_EMITTERS_TESTED:
        added.append(f"--{_FUSION_EMITTERS}=false")
    count = _flag_value(flags, _DEVICE_COUNT)
    if count is None and devices > 1:
        added.append(f"--{_DEVICE_COUNT}={devices}")
        count = devices
    before = os.environ.get("XLA_FLAGS")
    flags = " ".join([flags, *added]).strip()
    os.environ["XLA_FLAGS"] = flags
    if count is not None and count > 1:
        import jax

        try:
            found = len(jax.devices("cpu"))
        except RuntimeError:  # no CPU platform (JAX_PLATFORMS without it): no check
            return flags
        if found != count:
            # Not left behind for the subprocesses this one may start.
            if before is None:
                del os.environ["XLA_FLAGS"]
            else:
                os.environ["XLA_FLAGS"] = before
            raise RuntimeError(
                f"jaxmr.devices.configure_cpu: JAX's CPU backend had already started (with "
                f"{found} device(s)), so XLA_FLAGS came too late; restart the "
                "interpreter or kernel and call configure_cpu() before any JAX "
                "computation."
            )
    return flags


def _jaxlib_release() -> tuple[int, int] | None:
    """The installed jaxlib's (major, minor) release, or None if it cannot be read
    (read from its metadata: importing jaxlib is not needed)."""
    try:
        major, minor = importlib.metadata.version("jaxlib").split(".")[:2]
        return int(major), int(minor)
    except (importlib.metadata.PackageNotFoundError, ValueError):
        return None


def _flag_value(flags: str, name: str) -> int | None:
    match = re.search(rf"--{name}=(\d+)", flags)
    return None if match is None else int(match.group(1))
