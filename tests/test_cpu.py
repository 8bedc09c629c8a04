"""`jaxmr.devices.configure_cpu`: the XLA flags it sets take effect, a user's own are kept, and
a call that comes after JAX's backend started says so."""

import os
import subprocess
import sys
import textwrap

import equinox as eqx
import jax
import pytest

import jaxmr
from jaxmr._identify.data import pack
from jaxmr._identify.residual import residuals, value_and_jacobian
from jaxmr._parameter import free_filter

from .helpers import dahl_guess, dahl_runs


def _run(code: str, xla_flags: str | None) -> str:
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    env.pop("XLA_FLAGS", None)
    if xla_flags is not None:
        env["XLA_FLAGS"] = xla_flags
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def test_devices_are_made_and_a_users_own_count_is_kept():
    code = """
        import jaxmr, jax
        flags = jaxmr.devices.configure_cpu(devices=2)
        print(len(jax.devices()), flags)
        """
    count, flags = _run(code, None).split(" ", 1)
    assert count == "2"
    assert "xla_cpu_small_while_loop_byte_threshold=100000" in flags
    # XLA started with it (it aborts on a flag it does not know) on this jaxlib.
    assert "--xla_cpu_use_fusion_emitters=false" in flags
    count, flags = _run(code, "--xla_force_host_platform_device_count=3").split(" ", 1)
    assert count == "3"  # the user's count, not the call's
    assert "xla_cpu_small_while_loop_byte_threshold" in flags


def test_a_call_after_the_backend_started_raises_and_leaves_no_flags():
    code = """
        import os, jax, jax.numpy as jnp, jaxmr
        jnp.zeros(1).block_until_ready()  # the backend starts with one device
        try:
            jaxmr.devices.configure_cpu(devices=2)
        except RuntimeError as e:
            print("too late" in str(e), os.environ.get("XLA_FLAGS"))
        """
    assert _run(code, None).split() == ["True", "None"]


def test_the_default_count_follows_the_cores_the_process_may_use(monkeypatch):
    """Pinned to one core of a larger machine (`taskset`, a container), the default
    is one device, not one per core of the machine; no affinity call (macOS,
    Windows): the machine's count."""
    from jaxmr import _cpu

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 16)
    assert _cpu.usable_cores() == 1
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)
    assert _cpu.usable_cores() == 16
    # The default count (no device flag: nothing to check against a started
    # backend) is the usable cores', here 1: only the loop option is added.
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    monkeypatch.setenv("XLA_FLAGS", "")  # (restored after the test)
    flags = jaxmr.devices.configure_cpu()
    assert "xla_force_host_platform_device_count" not in flags


def test_the_fusion_emitter_flag_is_set_only_where_it_was_measured(monkeypatch):
    # XLA aborts the process on a flag it does not know: a jaxlib release it was not
    # measured on does not get it, and a user's own setting is kept.
    from jaxmr import _cpu

    monkeypatch.setenv("XLA_FLAGS", "")  # (restored after the test)
    monkeypatch.setattr(_cpu, "_jaxlib_release", lambda: (0, 10))
    assert "--xla_cpu_use_fusion_emitters=false" in _cpu.configure_cpu(devices=1)
    for release in [(0, 11), (1, 0), None]:
        monkeypatch.setenv("XLA_FLAGS", "")
        monkeypatch.setattr(_cpu, "_jaxlib_release", lambda r=release: r)
        assert "fusion_emitters" not in _cpu.configure_cpu(devices=1)
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    monkeypatch.setattr(_cpu, "_jaxlib_release", lambda: (0, 10))
    flags = _cpu.configure_cpu(devices=1)
    assert "--xla_cpu_use_fusion_emitters=true" in flags and "=false" not in flags


def test_bad_device_count():
    with pytest.raises(ValueError, match="positive integer"):
        jaxmr.devices.configure_cpu(devices=0)


def test_a_fit_jacobian_loop_is_one_kernel():
    # The session's flags (conftest calls configure_cpu): the forward-mode Jacobian's
    # RK4 loop, p tangents per step, compiles into a single kernel ("small call")
    # instead of one runtime call per fused operation; under XLA's default threshold
    # (1024 bytes) it does not, and ran 2-5x slower.
    assert "xla_cpu_small_while_loop_byte_threshold" in os.environ["XLA_FLAGS"]
    guess = dahl_guess()
    free, static = eqx.partition(guess, free_filter(guess))
    data = pack(dahl_runs([3.0, 8.0], [1.0, 1.5]), lanes=2)
    jacobian = jax.jit(
        lambda f, d: value_and_jacobian(residuals, f, static, d, None)
    ).lower(free, data)
    assert "xla_cpu_small_call" in jacobian.compile().as_text()
