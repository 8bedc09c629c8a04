"""Benchmark: a sweep of 1024 brake simulations with `jaxmr.sweep`, against baselines.

Simulates the published Bouc–Wen brake (`jaxmr.sas_brake_bouc_wen()`) over a grid of
currents × sine amplitudes × sine frequencies, 10 s each with output at 1 kHz, and
measures

- jaxmr's fast mode, `FixedStep(substeps=k)` under `sweep` (compile and run timed
  apart), with `k` the fewest substeps whose torque error is ≤ 1e-3 of the peak torque
  against a tight reference (Dopri8, rtol 1e-10, atol 1e-12);
- the adaptive default `Adaptive()` with `batching="vmap"` and `"map"` (several
  `batch_size`), on a subset: the figures behind `sweep`'s `"auto"` batching rule;
- baseline A: a scipy `solve_ivp` loop of equal accuracy (timed on a few runs and
  extrapolated per simulated second);
- baseline B: a minimal hand-written `jax.lax.scan` RK4 kernel (jit + vmap) with the
  same step size, timed the same way, one solve per run and (like-for-like with
  `sweep`'s shared-state path) z solved once per motion.

The brake's current laws act only on its output gains, so `sweep` solves z once per
motion and evaluates the torque at every current; the figures without that shortcut
(`*_no_sharing`, `sweep` forced down its full path) are reported beside them.

Run from the repository root:

    python benchmarks/simulate_sweep.py --json benchmarks/results/simulate_sweep.json
    python benchmarks/simulate_sweep.py --json /tmp/smoke.json --quick   # smoke test

Errors are `max_t |T - T_ref| / max_t |T_ref|` per run, maximised over the runs checked.
"""

import argparse
import contextlib
import datetime
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

PEAK_ERROR_TARGET = 1e-3  # max torque error / peak torque, for every mode compared
SUBSTEP_CANDIDATES = (2, 3, 4, 5, 6, 8, 10, 12, 16)  # 1 (1 ms) fails: NUMERICS.md
# scipy settings tried in order (roughly fastest first); the first of equal accuracy is
# the baseline. Its error is erratic in rtol (LSODA is wrong on this model: NUMERICS.md).
SCIPY_CANDIDATES = (
    ("RK45", 1e-7),
    ("RK45", 1e-8),
    ("DOP853", 1e-9),
    ("RK45", 1e-9),
    ("DOP853", 1e-10),
    ("RK45", 1e-10),
)


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--json", required=True, metavar="OUT", help="write results here")
    p.add_argument(
        "--runs",
        type=int,
        default=None,
        help="number of runs, a power of two >= 8 (default 1024; 64 with --quick)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="smoke test: 64 runs of 2 s, one timing repeat, few baselines",
    )
    p.add_argument(
        "--substeps",
        type=int,
        default=None,
        help="FixedStep substeps (default: the fewest meeting the accuracy target)",
    )
    p.add_argument(
        "--repeats", type=int, default=None, help="timed repeats (default 3; 1 quick)"
    )
    p.add_argument(
        "--host-devices",
        type=int,
        default=1,
        help="XLA host devices (>1 lets sweep shard across CPU cores; default 1)",
    )
    p.add_argument(
        "--full-reference",
        action="store_true",
        help="reference solve for every run (default: every motion at the lowest and "
        "highest current)",
    )
    p.add_argument(
        "--processes",
        type=int,
        default=1,
        help="N > 1: only the process comparison: the fixed-step grid in N local "
        "processes (jax.distributed, one CPU device each) against 1",
    )
    p.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    p.add_argument("--port", help=argparse.SUPPRESS)
    p.add_argument("--out", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.runs is None:
        args.runs = 64 if args.quick else 1024
    if args.runs < 8 or args.runs & (args.runs - 1):
        p.error(f"--runs must be a power of two >= 8, got {args.runs}")
    if args.repeats is None:
        args.repeats = 1 if args.quick else 3
    return args


ARGS = parse_args()
if ARGS.host_devices > 1:  # must happen before jax is imported
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "")
        + f" --xla_force_host_platform_device_count={ARGS.host_devices}"
    )

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's jaxmr
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _processes import initialize, launch  # noqa: E402

if ARGS.worker is not None:  # before anything touches a JAX backend
    initialize(ARGS.processes, ARGS.worker, ARGS.port)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
from jax.sharding import Mesh, NamedSharding, PartitionSpec  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

import jaxmr  # noqa: E402

# ---------------------------------------------------------------------------------------
# The model, written out for the baselines (the numbers of jaxmr.sas_brake_bouc_wen()).

ALPHA_A, ALPHA_B = 1.0, 0.07  # alpha(i) = ALPHA_A + ALPHA_B i   [N·m]
C0_A, C0_B = 0.0015, 0.07  # C(i) = C0_A + C0_B i               [N·m·s/rad]
DELTA, BETA, GAMMA, N_EXP = 843.0, 737.0, 1.0, 0.9


def check_preset_numbers():
    """Fail loudly if the preset changed and the baselines no longer match it."""
    b = jaxmr.sas_brake_bouc_wen()
    got = (
        float(b.alpha(0.0)),
        float(b.alpha(1.0) - b.alpha(0.0)),
        float(b.c0(0.0)),
        float(b.c0(1.0) - b.c0(0.0)),
        float(b.A),
        float(b.beta),
        float(b.gamma),
        float(b.n),
    )
    want = (ALPHA_A, ALPHA_B, C0_A, C0_B, DELTA, BETA, GAMMA, N_EXP)
    if not np.allclose(got, want, rtol=1e-12, atol=1e-15):
        raise SystemExit(f"preset changed: {got} != {want}; update the baselines")


# ---------------------------------------------------------------------------------------
# Helpers


def wall(fn, *args):
    """(result, seconds) of fn(*args) with every output array ready."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t0


def interleaved(fns, repeats):
    """Time each of `fns` (already compiled) `repeats` times, in rounds that call each
    once, so that load from other processes on a shared machine hits them alike. Per
    function: the min wall time (the figure used), median, all, and the process CPU time
    (all threads) of the fastest call."""
    walls = {k: [] for k in fns}
    cpus = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            c0 = time.process_time()
            walls[k].append(wall(fn)[1])
            cpus[k].append(time.process_time() - c0)
    out = {}
    for k, times in walls.items():
        best = int(np.argmin(times))
        out[k] = {
            "min_s": times[best],
            "median_s": statistics.median(times),
            "all_s": times,
            "cpu_s": cpus[k][best],
        }
    return out


def rel_error(torque, reference):
    """max over runs of max_t |T - T_ref| / max_t |T_ref| (last axis is time)."""
    torque, reference = np.asarray(torque), np.asarray(reference)
    peak = np.abs(reference).max(axis=-1)
    return float((np.abs(torque - reference).max(axis=-1) / peak).max())


def git_state():
    """The checkout measured: commit and the files changed since (others edit too)."""
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "jaxmr"],
            cwd=root,
            capture_output=True,
            text=True,
        ).stdout.split("\n")
    except OSError:
        return None
    return {"commit": head, "changed": [line.strip() for line in dirty if line]}


def device_description():
    d = jax.devices()[0]
    return {
        "jax_platform": d.platform,
        "jax_device_kind": d.device_kind,
        "jax_device_count": jax.device_count(),
        "cpu_count": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "machine": "2-core CPU"
        if os.cpu_count() == 2
        else f"{os.cpu_count()}-core CPU",
        "python": platform.python_version(),
    }


# ---------------------------------------------------------------------------------------
# Baseline B: a hand-written lax.scan RK4 kernel


def make_kernel(ts, substeps, shared=False):
    """jit(vmap(kernel)): (amplitude, frequency, current) per run -> torque (runs, t).

    With `shared`: (amplitude, frequency) per motion and all the currents -> torque
    (motions, currents, t), z solved once per motion (it does not depend on the current
    in this model): the work `jaxmr.sweep`'s shared-state path does.
    """
    dt = ts[1] - ts[0]  # ts is uniform
    h = dt / substeps

    def solve(a, f):
        w = 2 * jnp.pi * f

        def velocity(t):
            return a * w * jnp.cos(w * t)

        def rate(z, t):
            v = velocity(t)
            az = jnp.abs(z)
            p = jnp.where(az > 0, jnp.where(az > 0, az, 1.0) ** N_EXP, 0.0)
            return DELTA * v - GAMMA * jnp.abs(v) * jnp.sign(z) * p - BETA * v * p

        def interval(z, t0):
            def step(k, z):
                t = t0 + k * h
                k1 = rate(z, t)
                k2 = rate(z + 0.5 * h * k1, t + 0.5 * h)
                k3 = rate(z + 0.5 * h * k2, t + 0.5 * h)
                k4 = rate(z + h * k3, t + h)
                return z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

            z = jax.lax.fori_loop(0, substeps, step, z)
            return z, z

        z0 = jnp.zeros((), dtype=ts.dtype)
        _, zs = jax.lax.scan(interval, z0, ts[:-1])
        return jnp.concatenate([z0[None], zs]), velocity(ts)

    def torque(i, zs, v):
        return (ALPHA_A + ALPHA_B * i) * zs + (C0_A + C0_B * i) * v

    def one(a, f, i):
        return torque(i, *solve(a, f))

    def one_shared(a, f, currents):
        zs, v = solve(a, f)
        return jax.vmap(torque, in_axes=(0, None, None))(currents, zs, v)

    if shared:
        return jax.jit(jax.vmap(one_shared, in_axes=(0, 0, None)))
    return jax.jit(jax.vmap(one))


@contextlib.contextmanager
def no_state_sharing():
    """`jaxmr.sweep` forced down its full path (one solve per current), for the figure
    without the shared-state shortcut."""
    decide = jaxmr._simulate._state_ignores_current
    jaxmr._simulate._state_ignores_current = lambda *_: False
    try:
        yield
    finally:
        jaxmr._simulate._state_ignores_current = decide


# ---------------------------------------------------------------------------------------
# Baseline A: scipy solve_ivp, one run at a time


def scipy_torque(a, f, i, ts, method, rtol):
    w = 2 * math.pi * f
    aw = a * w

    def rhs(t, y):
        z = y[0]
        v = aw * math.cos(w * t)
        p = abs(z) ** N_EXP
        return [DELTA * v - GAMMA * abs(v) * math.copysign(p, z) - BETA * v * p]

    sol = solve_ivp(
        rhs,
        (float(ts[0]), float(ts[-1])),
        [0.0],
        method=method,
        t_eval=ts,
        rtol=rtol,
        atol=rtol * 1e-2,
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp {method} rtol={rtol}: {sol.message}")
    torque = (ALPHA_A + ALPHA_B * i) * sol.y[0] + (C0_A + C0_B * i) * aw * np.cos(
        w * ts
    )
    return torque, sol.nfev


# ---------------------------------------------------------------------------------------


def grid(runs: int, duration: float):
    """The sweep's motions and currents: amplitudes x frequencies x currents."""
    e = int(math.log2(runs))
    n_amp = n_freq = 2 ** (e // 3)
    n_cur = runs // (n_amp * n_freq)
    amps_deg = np.linspace(1.0, 5.0, n_amp)
    freqs = np.linspace(0.5, 2.0, n_freq)
    currents = np.linspace(0.0, 1.0, n_cur)
    motion_params = [(np.deg2rad(a), f) for a in amps_deg for f in freqs]
    return motion_params, currents, n_amp, n_freq, n_cur


def process_worker(args):
    """One process of the process comparison: the fixed-step grid, compiled then
    timed (median of `repeats`), every process getting every run's torque."""
    duration = 2.0 if args.quick else 10.0
    ts = jnp.linspace(0.0, duration, int(round(duration * 1000)) + 1)
    motion_params, currents, *_ = grid(args.runs, duration)
    motions = [jaxmr.Sine(a, f) for a, f in motion_params]
    integrator = jaxmr.FixedStep(substeps=args.substeps or 3)

    def call():
        sol = jaxmr.sweep(
            jaxmr.sas_brake_bouc_wen(), motions, jnp.asarray(currents), ts,
            integrator=integrator, keep=("force",),
        )  # fmt: skip
        return jax.block_until_ready(sol.force)

    t0 = time.perf_counter()
    call()
    first = time.perf_counter() - t0
    runs = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        force = call()
        runs.append(time.perf_counter() - t0)
    if jax.process_index() == 0:
        np.savez(
            args.out,
            first_s=first,
            run_s=statistics.median(runs),
            force=np.asarray(force),
            devices=len(jax.devices()),
        )


def process_comparison(args):
    """`--processes N`: the same sweep in 1 and in N processes, fresh each."""
    import tempfile

    script = str(Path(__file__).resolve())
    passed = ["--json", args.json, "--runs", str(args.runs), "--repeats",
              str(args.repeats)] + (["--quick"] if args.quick else []) + (
        ["--substeps", str(args.substeps)] if args.substeps else [])  # fmt: skip
    with tempfile.TemporaryDirectory() as folder:
        # One process with the same cores as devices (the sweep split over them).
        one = launch(script, 1, passed, Path(folder) / "one.npz", os.cpu_count() or 1)
        many = launch(script, args.processes, passed, Path(folder) / "many.npz")
    duration = 2.0 if args.quick else 10.0
    n = args.processes
    figures = {
        "runs": args.runs,
        "duration_s": duration,
        "substeps": args.substeps or 3,
        "machine": device_description(),
        "load_average": os.getloadavg(),
        "one_process": {
            "first_call_s": float(one["first_s"]),
            "run_s": float(one["run_s"]),
            "devices": int(one["devices"]),
        },  # fmt: skip
        f"{n}_processes": {
            "first_call_s": float(many["first_s"]),
            "run_s": float(many["run_s"]),
        },  # fmt: skip
        f"simulated_s_per_wall_s_{n}_processes": args.runs
        * duration
        / float(many["run_s"]),
        "simulated_s_per_wall_s_one_process": args.runs
        * duration
        / float(one["run_s"]),
        "processes_over_one_run": float(many["run_s"] / one["run_s"]),
        "equal_results": bool(np.array_equal(one["force"], many["force"])),
    }
    text = json.dumps(figures, indent=2)
    print(text)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(text)


def main():
    args = ARGS
    if args.worker is not None:
        return process_worker(args)
    if args.processes > 1:
        return process_comparison(args)
    check_preset_numbers()
    load_start = os.getloadavg()
    t_start = time.perf_counter()
    brake = jaxmr.sas_brake_bouc_wen()

    # --- grid ----------------------------------------------------------------------------
    duration = 2.0 if args.quick else 10.0
    n_times = int(round(duration * 1000)) + 1
    ts = jnp.linspace(0.0, duration, n_times)
    ts_np = np.asarray(ts)
    motion_params, currents, n_amp, n_freq, n_cur = grid(args.runs, duration)
    motions = [jaxmr.Sine(a, f) for a, f in motion_params]
    n_mot = len(motions)
    sim_seconds = args.runs * duration
    # Runs flattened in sweep order: motion-major (amplitude, frequency), current inner.
    run_a = np.repeat([a for a, _ in motion_params], n_cur)
    run_f = np.repeat([f for _, f in motion_params], n_cur)
    run_i = np.tile(currents, n_mot)
    print(
        f"grid: {n_cur} currents x {n_amp} amplitudes x {n_freq} frequencies = "
        f"{args.runs} runs of {duration:g} s at 1 kHz ({jax.devices()[0]}, "
        f"{jax.device_count()} device(s))"
    )

    # --- reference -----------------------------------------------------------------------
    ref_currents = currents if args.full_reference else currents[[0, -1]]
    ref_cur_index = (
        np.arange(n_cur) if args.full_reference else np.array([0, n_cur - 1])
    )
    reference_integrator = jaxmr.Adaptive(rtol=1e-10, atol=1e-12)
    ref, ref_s = wall(
        lambda: jaxmr.sweep(
            brake,
            motions,
            jnp.asarray(ref_currents),
            ts,
            integrator=reference_integrator,
        )
    )
    t_ref = np.asarray(ref.force)  # (motions, ref currents, times)
    print(f"reference: {t_ref.shape[0] * t_ref.shape[1]} runs in {ref_s:.1f} s")

    # Independent check of the reference: scipy DOP853 at rtol 1e-12 on the hardest and
    # the easiest motion.
    cross = []
    for m, c in ((n_mot - 1, len(ref_currents) - 1), (0, 0)):
        (a, f), i = motion_params[m], ref_currents[c]
        torque, _ = scipy_torque(a, f, i, ts_np, "DOP853", 1e-12)
        cross.append(rel_error(torque, t_ref[m, c]))
    reference_crosscheck = max(cross)

    def fixed(k, cur):
        return jaxmr.sweep(
            brake, motions, jnp.asarray(cur), ts, integrator=jaxmr.FixedStep(substeps=k)
        )

    # --- choose substeps -----------------------------------------------------------------
    substep_errors = {}
    if args.substeps is None:
        for k in SUBSTEP_CANDIDATES:
            err = rel_error(fixed(k, ref_currents).force, t_ref)
            substep_errors[k] = err
            print(f"FixedStep(substeps={k}): max error {err:.2e} of peak")
            if err <= PEAK_ERROR_TARGET:
                break
        else:
            raise SystemExit("no substeps candidate met the accuracy target")
        substeps = k
    else:
        substeps = args.substeps
    dt_step = float(ts[1] - ts[0]) / substeps

    # --- scipy: choose the setting of equal accuracy (baseline A) ------------------------
    # The corners of the grid: lowest/highest amplitude x frequency x current.
    corner_m = [0, n_freq - 1, n_mot - n_freq, n_mot - 1]
    corner_c = [0, len(ref_currents) - 1]
    scipy_runs = [(m, c) for m in corner_m for c in corner_c]
    if args.quick:
        scipy_runs = [(n_mot - 1, len(ref_currents) - 1), (0, 0)]

    def scipy_loop(method, rtol):
        errs, nfev = [], 0
        for m, c in scipy_runs:
            (a, f), i = motion_params[m], ref_currents[c]
            torque, n = scipy_torque(a, f, i, ts_np, method, rtol)
            nfev += n
            errs.append(rel_error(torque, t_ref[m, c]))
        return max(errs), nfev

    scipy_tries = []
    for method, rtol in SCIPY_CANDIDATES:
        (err, nfev), scipy_s = wall(scipy_loop, method, rtol)
        scipy_tries.append(
            {
                "method": method,
                "rtol": rtol,
                "atol": rtol * 1e-2,
                "max_torque_error_rel": err,
                "wall_s": scipy_s,
                "nfev": nfev,
            }
        )
        print(f"scipy {method} rtol={rtol:g}: error {err:.2e} ({scipy_s:.1f} s)")
        if err <= PEAK_ERROR_TARGET:
            break
    else:
        raise SystemExit("no scipy setting met the accuracy target")
    scipy_best = scipy_tries[-1]

    # --- compile: jaxmr fast mode and the scan kernel (baseline B) -----------------------
    cur_all = jnp.asarray(currents)

    # Like the kernels, the timed sweeps return the torque alone (`keep`); the whole
    # `Solution` (7 arrays per run) is timed beside them.
    def jaxmr_fast(throw=True, keep=("force",)):
        return jaxmr.sweep(
            brake,
            motions,
            cur_all,
            ts,
            integrator=jaxmr.FixedStep(substeps=substeps),
            throw=throw,
            keep=keep,
        )

    def jaxmr_full():
        return jaxmr_fast(keep=None)

    def jaxmr_no_sharing():
        with no_state_sharing():
            return jaxmr_fast()

    # Whether `sweep` solves z once per motion (the default, decided from the model).
    shared_states = bool(
        jaxmr._simulate._state_ignores_current(jaxmr.Damper(brake), ts.dtype)
    )
    sol, first_s = wall(jaxmr_fast)
    jaxmr_force = np.asarray(sol.force)  # (motions, currents, times)
    del sol
    err_jaxmr = rel_error(jaxmr_force[:, ref_cur_index], t_ref)
    _, first_nothrow_s = wall(jaxmr_fast, False)
    sol, first_full_s = wall(jaxmr_full)
    full_vs_force_only = float(np.abs(np.asarray(sol.force) - jaxmr_force).max())
    del sol
    sol, first_no_sharing_s = wall(jaxmr_no_sharing)
    no_sharing_vs_shared = float(np.abs(np.asarray(sol.force) - jaxmr_force).max())
    del sol

    kernel = make_kernel(ts, substeps)
    k_args = [jnp.asarray(x) for x in (run_a, run_f, run_i)]
    if jax.device_count() > 1 and args.runs % jax.device_count() == 0:
        sharding = NamedSharding(
            Mesh(np.array(jax.devices()), ("b",)), PartitionSpec("b")
        )
        k_args = [jax.device_put(x, sharding) for x in k_args]
    t0 = time.perf_counter()
    kernel_compiled = kernel.lower(*k_args).compile()
    kernel_compile_s = time.perf_counter() - t0
    kernel_torque, kernel_first_s = wall(kernel_compiled, *k_args)
    kernel_torque = np.asarray(kernel_torque).reshape(n_mot, n_cur, -1)
    err_kernel = rel_error(kernel_torque[:, ref_cur_index], t_ref)
    kernel_vs_jaxmr = float(np.abs(kernel_torque - jaxmr_force).max())
    shared_kernel = make_kernel(ts, substeps, shared=True)
    m_args = [jnp.asarray([a for a, _ in motion_params])]
    m_args += [jnp.asarray([f for _, f in motion_params]), cur_all]
    if jax.device_count() > 1 and n_mot % jax.device_count() == 0:
        m_args[:2] = [jax.device_put(x, sharding) for x in m_args[:2]]
    t0 = time.perf_counter()
    shared_kernel_compiled = shared_kernel.lower(*m_args).compile()
    shared_kernel_compile_s = time.perf_counter() - t0
    shared_kernel_torque = np.asarray(shared_kernel_compiled(*m_args))
    shared_kernel_vs_kernel = float(np.abs(shared_kernel_torque - kernel_torque).max())

    # --- timing: interleaved rounds, so that load from elsewhere hits all alike ----------
    timing = interleaved(
        {
            "jaxmr": jaxmr_fast,
            "jaxmr_throw_false": lambda: jaxmr_fast(False),
            "jaxmr_full_solution": jaxmr_full,
            "jaxmr_no_sharing": jaxmr_no_sharing,
            "kernel": lambda: kernel_compiled(*k_args),
            "shared_kernel": lambda: shared_kernel_compiled(*m_args),
            "scipy": lambda: scipy_loop(scipy_best["method"], scipy_best["rtol"]),
        },
        args.repeats,
    )
    run, kernel_run = timing["jaxmr"], timing["kernel"]
    no_sharing_run, shared_kernel_run = (
        timing["jaxmr_no_sharing"],
        timing["shared_kernel"],
    )
    # The kernel that does the same work as jaxmr's default path.
    like_kernel_run = shared_kernel_run if shared_states else kernel_run
    throughput = sim_seconds / run["min_s"]
    throughput_no_sharing = sim_seconds / no_sharing_run["min_s"]
    full_run = timing["jaxmr_full_solution"]
    throughput_full = sim_seconds / full_run["min_s"]
    scipy_throughput = len(scipy_runs) * duration / timing["scipy"]["min_s"]
    print(
        f"jaxmr FixedStep({substeps}): first call {first_s:.2f} s, run "
        f"{run['min_s']:.2f} s -> {throughput:.0f} sim s/s; scan kernel: compile "
        f"{kernel_compile_s:.2f} s, run {kernel_run['min_s']:.2f} s; scipy "
        f"{scipy_throughput:.1f} sim s/s"
    )

    # --- adaptive default: vmap vs map, and fixed-step map, on the reference subset -------
    n_sub = n_mot * len(ref_currents)
    configs = [
        ("Adaptive", "vmap", None),
        ("Adaptive", "map", None),
        ("Adaptive", "map", 8),
        ("Adaptive", "map", 64),
        ("FixedStep", "vmap", None),
        ("FixedStep", "map", 64),
    ]
    calls, entries = {}, {}
    for name, batching, batch_size in configs:
        integrator = (
            jaxmr.Adaptive() if name == "Adaptive" else jaxmr.FixedStep(substeps)
        )

        def call(integrator=integrator, batching=batching, batch_size=batch_size):
            return jaxmr.sweep(
                brake,
                motions,
                jnp.asarray(ref_currents),
                ts,
                integrator=integrator,
                batching=batching,
                batch_size=batch_size,
            )

        key = f"{name}_{batching}" + (f"_bs{batch_size}" if batching == "map" else "")
        out, first = wall(call)
        calls[key] = call
        entries[key] = {
            "integrator": name if name == "Adaptive" else f"FixedStep({substeps})",
            "batching": batching,
            "batch_size": batch_size,
            "runs": n_sub,
            "first_call_s": first,
            "max_torque_error_rel": rel_error(out.force, t_ref),
            "mean_num_steps": float(np.mean(np.asarray(out.num_steps))),
        }
    for key, times in interleaved(calls, args.repeats).items():
        entry = entries[key]
        entry.update(
            run_s=times["min_s"],
            run_s_all=times["all_s"],
            run_cpu_s=times["cpu_s"],
            throughput_sim_s_per_s=n_sub * duration / times["min_s"],
        )
        print(
            f"{entry['integrator']:>12} {entry['batching']:>4} batch_size="
            f"{entry['batch_size']}: {entry['throughput_sim_s_per_s']:.0f} sim s/s"
        )
    batching_results = list(entries.values())

    # --- results -------------------------------------------------------------------------
    adaptive = {
        k.removeprefix("Adaptive_"): e
        for k, e in entries.items()
        if e["integrator"] == "Adaptive"
    }
    results = {
        "benchmark": "simulate_sweep",
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "model": "jaxmr.sas_brake_bouc_wen()",
        "runs": args.runs,
        "quick": args.quick,
        "grid": {
            "currents_A": currents.tolist(),
            "amplitudes_deg": sorted(
                {round(float(np.rad2deg(a)), 12) for a, _ in motion_params}
            ),
            "frequencies_Hz": sorted({float(f) for _, f in motion_params}),
            "order": "motion-major (amplitude, frequency), current inner",
            "duration_s": duration,
            "output_rate_Hz": 1000,
            "samples_per_run": n_times,
            "simulated_seconds": sim_seconds,
        },
        "accuracy": {
            "target_max_torque_error_rel": PEAK_ERROR_TARGET,
            "definition": "max over runs of max_t|T - T_ref| / max_t|T_ref|",
            "reference": "Adaptive(Dopri8, rtol=1e-10, atol=1e-12)",
            "reference_runs": "all runs"
            if args.full_reference
            else "every motion at the lowest and highest current "
            "(z does not depend on the current in this preset)",
            "reference_num_runs": int(t_ref.shape[0] * t_ref.shape[1]),
            "reference_wall_s": ref_s,
            "reference_vs_scipy_DOP853_rtol1e-12": reference_crosscheck,
            "substep_search": {str(k): v for k, v in substep_errors.items()},
        },
        "substeps": substeps,
        "step_s": dt_step,
        "throughput_sim_s_per_s": throughput,
        "shared_states": shared_states,
        "speedup_vs_scipy": throughput / scipy_throughput,
        "speedup_vs_scipy_no_sharing": throughput_no_sharing / scipy_throughput,
        "speedup_vs_scipy_full_solution": throughput_full / scipy_throughput,
        "throughput_sim_s_per_s_no_sharing": throughput_no_sharing,
        "shared_scan_kernel_speedup_vs_scipy": sim_seconds
        / shared_kernel_run["min_s"]
        / scipy_throughput,
        "scan_kernel_speedup_vs_scipy": sim_seconds
        / kernel_run["min_s"]
        / scipy_throughput,
        "speedup_vs_scipy_cpu_time": (
            timing["scipy"]["cpu_s"] / (len(scipy_runs) * duration)
        )
        / (run["cpu_s"] / sim_seconds),
        "time_ratio_vs_scan_kernel": run["min_s"] / like_kernel_run["min_s"],
        "cpu_time_ratio_vs_scan_kernel": run["cpu_s"] / like_kernel_run["cpu_s"],
        "time_ratio_vs_scan_kernel_no_sharing": no_sharing_run["min_s"]
        / kernel_run["min_s"],
        "time_ratio_vs_scan_kernel_full_solution": full_run["min_s"]
        / like_kernel_run["min_s"],
        "max_torque_error_rel": {
            "jaxmr_fixedstep": err_jaxmr,
            "scipy": scipy_best["max_torque_error_rel"],
            "scan_kernel": err_kernel,
            "jaxmr_adaptive_default_subset": entries["Adaptive_map_bsNone"][
                "max_torque_error_rel"
            ],
            "scan_kernel_vs_jaxmr_abs_Nm": kernel_vs_jaxmr,
            "jaxmr_no_sharing_vs_shared_abs_Nm": no_sharing_vs_shared,
            "jaxmr_full_solution_vs_force_only_abs_Nm": full_vs_force_only,
            "shared_scan_kernel_vs_scan_kernel_abs_Nm": shared_kernel_vs_kernel,
        },
        "jaxmr_fixedstep": {
            "first_call_s": first_s,
            "compile_s": first_s - run["median_s"],
            "run_s": run["min_s"],
            "run_s_median": run["median_s"],
            "run_s_all": run["all_s"],
            "run_cpu_s": run["cpu_s"],
            "run_s_throw_false": timing["jaxmr_throw_false"]["min_s"],
        },
        "jaxmr_fixedstep_full_solution": {
            "first_call_s": first_full_s,
            "compile_s": first_full_s - full_run["median_s"],
            "run_s": full_run["min_s"],
            "run_s_all": full_run["all_s"],
            "run_cpu_s": full_run["cpu_s"],
            "throughput_sim_s_per_s": throughput_full,
        },
        "jaxmr_fixedstep_no_sharing": {
            "first_call_s": first_no_sharing_s,
            "compile_s": first_no_sharing_s - no_sharing_run["median_s"],
            "run_s": no_sharing_run["min_s"],
            "run_s_all": no_sharing_run["all_s"],
            "run_cpu_s": no_sharing_run["cpu_s"],
        },
        "scan_kernel": {
            "compile_s": kernel_compile_s,
            "first_call_s": kernel_first_s,
            "run_s": kernel_run["min_s"],
            "run_s_median": kernel_run["median_s"],
            "run_s_all": kernel_run["all_s"],
            "run_cpu_s": kernel_run["cpu_s"],
            "throughput_sim_s_per_s": sim_seconds / kernel_run["min_s"],
        },
        "shared_scan_kernel": {
            "compile_s": shared_kernel_compile_s,
            "run_s": shared_kernel_run["min_s"],
            "run_s_all": shared_kernel_run["all_s"],
            "run_cpu_s": shared_kernel_run["cpu_s"],
            "throughput_sim_s_per_s": sim_seconds / shared_kernel_run["min_s"],
        },
        "scipy": {
            "method": scipy_best["method"],
            "rtol": scipy_best["rtol"],
            "atol": scipy_best["atol"],
            "runs_timed": len(scipy_runs),
            "wall_s": timing["scipy"]["min_s"],
            "wall_s_all": timing["scipy"]["all_s"],
            "cpu_s": timing["scipy"]["cpu_s"],
            "throughput_sim_s_per_s": scipy_throughput,
            "extrapolated_wall_s_for_all_runs": sim_seconds / scipy_throughput,
            "tried": scipy_tries,
        },
        "adaptive_batching": {
            "subset_runs": n_sub,
            "throughput_sim_s_per_s": {
                k: v["throughput_sim_s_per_s"] for k, v in adaptive.items()
            },
        },
        "batching_details": batching_results,
        "timing": f"run times are the min of {args.repeats} calls after the first "
        "(compile) call, each with block_until_ready, timed in interleaved rounds "
        "(jaxmr, jaxmr throw=False, jaxmr full Solution, jaxmr without state "
        "sharing, kernel, shared kernel, scipy; then the batching configurations); "
        "compile_s = first call - median run; the jaxmr figures use the shared-state "
        "path when `shared_states` (z solved once per motion), the *_no_sharing ones "
        "one solve per run; they keep the torque alone (keep=('force',)), as the "
        "kernels do, the *_full_solution ones the whole Solution",
        "versions": {
            "jax": jax.__version__,
            "jaxlib": __import__("jaxlib").__version__,
            "diffrax": __import__("diffrax").__version__,
            "equinox": __import__("equinox").__version__,
            "scipy": scipy.__version__,
            "numpy": np.__version__,
            "jaxmr": jaxmr.__version__,
        },
        "device": device_description(),
        "git": git_state(),
        "host_devices": args.host_devices,
        "loadavg_start": load_start,
        "loadavg_end": os.getloadavg(),
        "total_wall_s": time.perf_counter() - t_start,
    }
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")

    # --- summary -------------------------------------------------------------------------
    rows = [
        (
            f"jaxmr sweep FixedStep({substeps})"
            + (" shared z" if shared_states else ""),
            first_s - run["median_s"],
            run["min_s"],
            run["cpu_s"],
            throughput,
            err_jaxmr,
        ),
        (
            f"jaxmr sweep FixedStep({substeps}), whole Solution",
            first_full_s - full_run["median_s"],
            full_run["min_s"],
            full_run["cpu_s"],
            throughput_full,
            err_jaxmr,
        ),
        (
            f"jaxmr sweep FixedStep({substeps}) no sharing",
            first_no_sharing_s - no_sharing_run["median_s"],
            no_sharing_run["min_s"],
            no_sharing_run["cpu_s"],
            throughput_no_sharing,
            err_jaxmr,
        ),
        (
            "lax.scan RK4 kernel",
            kernel_compile_s,
            kernel_run["min_s"],
            kernel_run["cpu_s"],
            sim_seconds / kernel_run["min_s"],
            err_kernel,
        ),
        (
            "lax.scan RK4 kernel, shared z",
            shared_kernel_compile_s,
            shared_kernel_run["min_s"],
            shared_kernel_run["cpu_s"],
            sim_seconds / shared_kernel_run["min_s"],
            err_kernel,
        ),
        (
            f"scipy {scipy_best['method']} rtol={scipy_best['rtol']:g} "
            f"({len(scipy_runs)} runs)",
            0.0,
            timing["scipy"]["min_s"],
            timing["scipy"]["cpu_s"],
            scipy_throughput,
            scipy_best["max_torque_error_rel"],
        ),
    ]
    rows += [
        (
            f"{e['integrator']} {e['batching']} bs={e['batch_size']} ({n_sub} runs)",
            e["first_call_s"] - e["run_s"],
            e["run_s"],
            e["run_cpu_s"],
            e["throughput_sim_s_per_s"],
            e["max_torque_error_rel"],
        )
        for e in batching_results
    ]
    print()
    print(
        f"{'mode':<42}{'compile s':>10}{'run s':>8}{'cpu s':>8}{'sim s/s':>9}"
        f"{'err/peak':>10}"
    )
    for name, comp, r, cpu, thr, err in rows:
        print(f"{name:<42}{comp:>10.2f}{r:>8.2f}{cpu:>8.2f}{thr:>9.0f}{err:>10.1e}")
    print()
    print(
        f"speedup_vs_scipy          {results['speedup_vs_scipy']:.0f}  (goal >= 250; "
        f"shared z: {shared_states}; without sharing "
        f"{results['speedup_vs_scipy_no_sharing']:.0f}; whole Solution "
        f"{results['speedup_vs_scipy_full_solution']:.0f}; scan kernel "
        f"{results['scan_kernel_speedup_vs_scipy']:.0f}, shared z "
        f"{results['shared_scan_kernel_speedup_vs_scipy']:.0f}; in CPU time "
        f"{results['speedup_vs_scipy_cpu_time']:.0f})"
    )
    print(
        f"time_ratio_vs_scan_kernel {results['time_ratio_vs_scan_kernel']:.2f} "
        f"(goal <= 2, against the kernel doing the same work; CPU time ratio "
        f"{results['cpu_time_ratio_vs_scan_kernel']:.2f}; without sharing "
        f"{results['time_ratio_vs_scan_kernel_no_sharing']:.2f}; whole Solution "
        f"{results['time_ratio_vs_scan_kernel_full_solution']:.2f})"
    )
    print(f"reference vs scipy DOP853 rtol 1e-12: {reference_crosscheck:.1e} of peak")
    print(f"load average {load_start} -> {results['loadavg_end']}; wrote {out}")


if __name__ == "__main__":
    main()
