"""`fit` with several starts and `fit_each` on two host devices of one process (as
`jaxmr fit` makes every core a device) finish, with the one-device results.

Both used to hang with the CPU idle: jaxlib splits a batched LAPACK factorisation
(then the LM step's QR of the tall Jacobian, batched over starts or problems) over
XLA's CPU thread pool and blocks the pool thread it runs on, and with every pool
thread running a device's program none was left to do the pieces. The step now
factorises the small p × p matrix JᵀJ, still one matrix at a time
(`solver._one_matrix_at_a_time`), so the QR that hung is gone; this test keeps the
guarantee the issue asks for (starts and lanes on every device of a multi-core
machine finish, under a timeout), whatever factorisation a later step uses. The data
(12 000 residuals, 3 parameters; 2 starts, or 2 of the 4 problems on each device)
are those that made the batched QR hang."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent

# Seconds the two-device subprocess may take: it compiles two fits (~15 s on 2
# loaded cores); a hang is stopped here and fails the test.
TIMEOUT = 120


def _runs(samples: int, rhos, k_ws):
    """`dahl_runs` with `samples` samples over one period, one RK4 step each
    (≤ 0.17 ms), read as a linear damper's: the data that made the batched QR hang."""
    from .helpers import dahl_runs

    return dahl_runs(rhos, k_ws, samples=samples, substeps=1, rotary=False)


def fits() -> dict:
    """{name: array}: a joint fit with 2 starts (its 2 lanes one per device) and
    `fit_each` of 4 problems (2 per device)."""
    import jaxmr

    P = jaxmr.Positive
    guess = jaxmr.Dahl(k_x=P(0.02), k_w=P(2.0), rho=P(8.0))
    options = dict(progress=False, statistics_refinement=1, max_steps=5)
    joint = jaxmr.fit(
        guess,
        _runs(6000, (3.0, 5.0), (1.0, 2.0)),
        starts=2,
        lanes=2,
        **options,
    )
    each = jaxmr.fit_each(
        guess, _runs(12000, (3.0, 5.0, 8.0, 12.0), (1.0, 2.0, 3.0, 4.0)), **options
    )
    return {
        "joint": np.asarray(joint.values),
        "joint_loss": np.array(joint.loss),
        "each": np.stack([np.asarray(r.values) for r in each]),
    }


def test_starts_and_fit_each_on_two_host_devices_finish_with_one_device_s_results(
    tmp_path,
):
    out = tmp_path / "two.npz"
    env = dict(os.environ, PYTHONPATH=str(HERE.parent))
    # The session's flags (conftest: configure_cpu) and 2 CPU devices.
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    )
    code = (
        "import jax, numpy as np\n"
        "jax.config.update('jax_enable_x64', True)\n"
        "assert len(jax.devices()) == 2\n"
        "from tests.test_host_devices import fits\n"
        f"np.savez({str(out)!r}, **fits())\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        timeout=TIMEOUT,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    two, one = dict(np.load(out)), fits()
    for name in one:
        # Exactly: each lane and each problem is computed by the same program in
        # either layout, and the QR one matrix at a time as it was batched.
        np.testing.assert_array_equal(two[name], one[name], err_msg=name)
