"""`sweep`, `fit_each` and `evaluate` across 2 processes (`jax.distributed` on
localhost, CPU gloo collectives) give exactly the single-process results (issue 12).

Each process owns one device, so a batch of 3 is padded to 4 and each process runs
half of it; every process gets the whole result back."""

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np

from .distributed_worker import cases, joint_fit

HERE = Path(__file__).parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_equal_one(tmp_path):
    out = tmp_path / "two.npz"
    port = str(_free_port())
    env = dict(os.environ, PYTHONPATH=str(HERE.parent))
    # Each process sees one CPU device (as one process per GPU would): the session's
    # flags (conftest: jaxmr.devices.configure_cpu) set no device count.
    workers = [
        subprocess.Popen(
            [
                sys.executable,
                str(HERE / "distributed_worker.py"),
                str(k),
                "2",
                port,
                str(out),
            ],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for k in range(2)
    ]
    # The single-process reference, computed while the workers run.
    one = cases()
    logs = [w.communicate(timeout=600)[0] for w in workers]
    for w, log in zip(workers, logs):
        assert w.returncode == 0, log[-3000:]
    two = dict(np.load(out))
    assert int(two.pop("devices")) == 2
    assert set(one) == set(two)
    for name in one:
        # Exactly: each member is computed by the same program on either layout.
        np.testing.assert_array_equal(two[name], one[name], err_msg=name)


def test_a_fit_splits_its_lanes_over_devices_with_one_device_s_results(tmp_path):
    # `jaxmr fit` makes every core a device; the packed lanes then scan side by
    # side on them. Same program per lane, so the same numbers exactly.
    out = tmp_path / "lanes.npz"
    env = dict(os.environ, PYTHONPATH=str(HERE.parent))
    # The session's flags (conftest: jaxmr.devices.configure_cpu) and 2 CPU devices.
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    )
    subprocess.run(
        [sys.executable, str(HERE / "distributed_worker.py"), "lanes", str(out)],
        env=env,
        check=True,
        timeout=600,
    )
    two = np.load(out)
    values, errors = joint_fit()
    np.testing.assert_array_equal(two["arr_0"], values)
    np.testing.assert_array_equal(two["arr_1"], errors)
