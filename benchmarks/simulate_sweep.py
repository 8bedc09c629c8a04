"""Benchmark: a sweep of 1024 brake simulations with `jaxmr.sweep`, against baselines.

Simulates the published Bouc–Wen brake (`jaxmr.sas_brake_bouc_wen()`) over a grid of
currents × sine amplitudes × sine frequencies, 10 s each with output at 1 kHz, and
measures, every method held to the same accuracy (torque error ≤ 1e-3 of the peak
torque against a tight reference, Dopri8 at rtol 1e-10, atol 1e-12, checked in the same
run on every motion at the lowest and highest current):

- jaxmr's fast mode, `FixedStep(substeps=k)` under `sweep` (compile and run timed
  apart), with `k` the fewest substeps that meet the target; with its shared-state path
  (z solved once per motion, the torque evaluated at every current: the brake's current
  laws act only on its output gains) and without it (`*_no_sharing`, one solve per run);
- the SciPy/NumPy user's vectorised code, with and without state sharing: one
  `solve_ivp` over the whole batch with a NumPy right-hand side (the method and rtol,
  from RK45/DOP853 ladders, that meets the target fastest), and a fixed-step NumPy RK4
  loop over the whole batch (fewest substeps meeting the target); the faster of the two
  is `speedup_vs_scipy_vectorised`'s baseline;
- the performance-minded user's numba code: an RK4 loop per run, `@njit(parallel=True)`
  with `prange` over the runs (or motions, when sharing), `--numba-threads` threads,
  fewest substeps meeting the target; its compile time reported apart and counted in
  the `*_with_compile` figures;
- the old baseline: a `solve_ivp` loop, one run at a time with a plain-Python right-hand
  side (timed on a few runs and extrapolated per simulated second; `*_scipy_loop`);
- a minimal hand-written `jax.lax.scan` RK4 kernel (jit + vmap) with jaxmr's step,
  per run and with z shared per motion (`time_ratio_vs_scan_kernel*`: jaxmr's overhead);
- the adaptive default `Adaptive()` with `batching="vmap"` and `"map"` (several
  `batch_size`), on a subset: the figures behind `sweep`'s `"auto"` batching rule.

Speedups are throughput ratios, simulated seconds per wall second: compilation excluded
(`speedup_vs_*`) and included (`*_with_compile`: compile + one run). The headline ones
compare like with like: jaxmr's shared-state path with the baselines' shared forms;
`*_no_sharing` compares every method solving every run. jaxmr runs as its documentation
sets up a CPU user, `jaxmr.devices.configure_cpu()`: one XLA device per core (`sweep`
splits its batch over them; `--host-devices` to change) against numba on as many
threads (`--numba-threads`, default 2). Reported apart: jaxmr on one device (a fresh
process, `jaxmr_fixedstep_one_device`) against numba on one thread
(`speedup_vs_numba_one_device`), and its torque against the devices' (bit for bit,
`one_device_equal_bitwise`). The NumPy/SciPy baselines run on one core (NumPy does not
thread these element-wise operations): their CPU-time ratios (`*_cpu_time`, process
CPU time of all threads) are in the JSON beside the wall-time ones.

Run from the repository root (numba: `pip install -e .[bench]`):

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
# The vectorised solve_ivp (one solve over the batch): per method, rtol tightened from
# loose until the target is met; the passing setting of the faster method is the
# baseline (the search's wall times decide, as a user would). Its step
# is the batch's (RMS error norm over the components), so it may need a tighter rtol
# than a run alone.
VECTORISED_CANDIDATES = {
    "RK45": (1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11),
    "DOP853": (1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12),
}


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
        default=None,
        help="XLA CPU devices for jaxmr, over which sweep splits its batch (default: "
        "one per core, as jaxmr.devices.configure_cpu() sets up a CPU user; 1: one "
        "device). A one-device run is measured apart in a fresh process either way",
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
    p.add_argument(
        "--numba-threads",
        type=int,
        default=2,
        help="threads of the numba baseline (default 2, the cores of the reference "
        "machine)",
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's jaxmr
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _processes import initialize, launch  # noqa: E402

import jaxmr  # noqa: E402  (does not start JAX's backend)

if ARGS.worker is not None:  # before anything touches a JAX backend
    # Its XLA flags (devices, the small-loop option) come from `launch`.
    initialize(ARGS.processes, ARGS.worker, ARGS.port)
elif ARGS.processes == 1:
    # jaxmr as its documentation sets up a CPU user: one XLA device per core (sweep
    # splits its batch over them) and each simulation loop one kernel.
    jaxmr.devices.configure_cpu(devices=ARGS.host_devices)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

# The baselines, and the model's numbers written out for them.
import _sweep_baselines as baselines  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
from _report import write_figures  # noqa: E402
from jax.sharding import Mesh, NamedSharding, PartitionSpec  # noqa: E402


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
    want = (
        baselines.ALPHA_A,
        baselines.ALPHA_B,
        baselines.C0_A,
        baselines.C0_B,
        baselines.DELTA,
        baselines.BETA,
        baselines.GAMMA,
        baselines.N_EXP,
    )
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


def fewest(candidates, error_of, label):
    """The first of `candidates` (fewest steps first) whose `error_of` meets the target
    -> (candidate, {str(candidate): error} of those tried)."""
    errors = {}
    for c in candidates:
        errors[str(c)] = err = error_of(c)
        print(f"{label} {c}: max error {err:.2e} of peak")
        if err <= PEAK_ERROR_TARGET:
            return c, errors
    raise SystemExit(f"{label}: no candidate met the accuracy target")


def method_entry(times, simulated_s, error, compile_s=0.0, **details):
    """One method's figures from its `interleaved` times: throughput [simulated s per
    wall s] without and with compilation (`compile_s` [s], 0 where nothing compiles)."""
    return {
        "throughput_sim_s_per_s": simulated_s / times["min_s"],
        "throughput_with_compile_sim_s_per_s": simulated_s
        / (compile_s + times["min_s"]),
        "max_torque_error_rel": error,
        "compile_s": compile_s,
        "run_s": times["min_s"],
        "run_s_median": times["median_s"],
        "run_s_all": times["all_s"],
        "run_cpu_s": times["cpu_s"],
        "simulated_s": simulated_s,
        **details,
    }


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
# A hand-written lax.scan RK4 kernel: what jaxmr's fixed-step path costs over bare JAX


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
            p = jnp.where(az > 0, jnp.where(az > 0, az, 1.0) ** baselines.N_EXP, 0.0)
            return (
                baselines.DELTA * v
                - baselines.GAMMA * jnp.abs(v) * jnp.sign(z) * p
                - baselines.BETA * v * p
            )

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
        return (baselines.ALPHA_A + baselines.ALPHA_B * i) * zs + (
            baselines.C0_A + baselines.C0_B * i
        ) * v

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
    """One process of the process comparison, or the one-device run of the main
    benchmark: the fixed-step grid (torque only), compiled then timed `repeats` times
    (median, min and the CPU time of the fastest), every process getting every run's
    torque."""
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
    force = call()
    first = time.perf_counter() - t0
    runs, cpus = [], []
    for _ in range(args.repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        force = call()
        runs.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    if jax.process_index() == 0:
        best = int(np.argmin(runs))
        np.savez(
            args.out,
            first_s=first,
            run_s=statistics.median(runs),
            run_min_s=runs[best],
            run_all_s=np.array(runs),
            run_cpu_s=cpus[best],
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


def one_device_run(args, substeps: int) -> dict:
    """The timed jaxmr sweep (torque only) in a fresh process with one XLA device and
    the same flags otherwise: what the figures were before sweeps used every core."""
    import tempfile

    passed = ["--json", args.json, "--runs", str(args.runs), "--repeats",
              str(args.repeats), "--substeps", str(substeps)] + (
        ["--quick"] if args.quick else [])  # fmt: skip
    with tempfile.TemporaryDirectory() as folder:
        return launch(
            str(Path(__file__).resolve()), 1, passed, Path(folder) / "one.npz"
        )


def main():
    args = ARGS
    if args.worker is not None:
        return process_worker(args)
    if args.processes > 1:
        return process_comparison(args)
    check_preset_numbers()
    try:
        import numba  # the numba baseline (its kernels are in _sweep_baselines)
    except ImportError:
        raise SystemExit(
            "simulate_sweep.py needs numba for its baseline: pip install -e .[bench]"
        ) from None
    load_start = os.getloadavg()
    t_start = time.perf_counter()
    brake = jaxmr.sas_brake_bouc_wen()

    # --- grid ----------------------------------------------------------------------------
    duration = 2.0 if args.quick else 10.0
    n_times = int(round(duration * 1000)) + 1
    ts = jnp.linspace(0.0, duration, n_times)
    ts_np = np.array(ts)  # a writable copy: numba's signatures take writable arrays
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
        torque, _ = baselines.scipy_loop_torque(a, f, i, ts_np, "DOP853", 1e-12)
        cross.append(rel_error(torque, t_ref[m, c]))
    reference_crosscheck = max(cross)

    def fixed(k, cur):
        return jaxmr.sweep(
            brake, motions, jnp.asarray(cur), ts, integrator=jaxmr.FixedStep(substeps=k)
        )

    # --- choose substeps -----------------------------------------------------------------
    substep_errors = {}
    if args.substeps is None:
        substeps, substep_errors = fewest(
            SUBSTEP_CANDIDATES,
            lambda k: rel_error(fixed(k, ref_currents).force, t_ref),
            "jaxmr FixedStep substeps",
        )
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
            torque, n = baselines.scipy_loop_torque(a, f, i, ts_np, method, rtol)
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

    # Every method below returns the torque of the whole grid; its error is taken on the
    # reference runs, as jaxmr's.
    mot_a = np.array([a for a, _ in motion_params])
    mot_f = np.array([f for _, f in motion_params])

    def grid_error(torque):
        """Error of a (motions, currents, times) or (runs, times) torque."""
        torque = np.asarray(torque).reshape(n_mot, n_cur, -1)
        return rel_error(torque[:, ref_cur_index], t_ref)

    # --- vectorised solve_ivp: the fastest setting of equal accuracy ----------------------
    def ivp_shared(method, rtol):
        return baselines.solve_ivp_shared(mot_a, mot_f, currents, ts_np, method, rtol)

    def ivp_runs(method, rtol):
        return baselines.solve_ivp_runs(run_a, run_f, run_i, ts_np, method, rtol)

    ivp_tries = []

    def ladder(solve, method, rtols, variant):
        """Tighten rtol until the target is met -> that try, or None."""
        for rtol in rtols:
            (torque, nfev), seconds = wall(solve, method, rtol)
            err = grid_error(torque)
            del torque
            ivp_tries.append(
                {
                    "variant": variant,
                    "method": method,
                    "rtol": rtol,
                    "atol": rtol * 1e-2,
                    "max_torque_error_rel": err,
                    "wall_s": seconds,
                    "nfev": nfev,
                }
            )
            print(
                f"vectorised solve_ivp ({variant}) {method} rtol={rtol:g}: error "
                f"{err:.2e} ({seconds:.1f} s, {nfev} calls)"
            )
            if err <= PEAK_ERROR_TARGET:
                return ivp_tries[-1]
        return None

    passing = [
        t
        for m, rtols in VECTORISED_CANDIDATES.items()
        if (t := ladder(ivp_shared, m, rtols, "shared")) is not None
    ]
    if not passing:
        raise SystemExit("no vectorised solve_ivp setting met the accuracy target")
    ivp_best = min(passing, key=lambda t: t["wall_s"])  # the fastest that passes
    # Without sharing: the same method, from the same rtol (its step follows the batch's
    # RMS error, which the repeated motions leave about the same).
    rtols = VECTORISED_CANDIDATES[ivp_best["method"]]
    ivp_best_ns = ladder(
        ivp_runs,
        ivp_best["method"],
        rtols[rtols.index(ivp_best["rtol"]) :],
        "no_sharing",
    )
    if ivp_best_ns is None:
        raise SystemExit("no vectorised solve_ivp setting met the target per run")

    # --- NumPy RK4 over the batch: fewest substeps of equal accuracy ----------------------
    def np_shared(k):
        return baselines.numpy_rk4_shared(mot_a, mot_f, currents, ts_np, k)

    def np_runs(k):
        return baselines.numpy_rk4_runs(run_a, run_f, run_i, ts_np, k)

    np_k, np_errors = fewest(
        SUBSTEP_CANDIDATES, lambda k: grid_error(np_shared(k)), "NumPy RK4 substeps"
    )
    np_k_ns, np_errors_ns = fewest(
        SUBSTEP_CANDIDATES[SUBSTEP_CANDIDATES.index(np_k) :],
        lambda k: grid_error(np_runs(k)),
        "NumPy RK4 substeps (no sharing)",
    )

    # --- numba RK4, parallel over runs: compiled, then fewest substeps --------------------
    numba_warm_up_s = baselines.numba_warm_up(args.numba_threads)
    nb_shared, nb_shared_compile_s = baselines.numba_kernel(True, args.numba_threads)
    nb_runs, nb_runs_compile_s = baselines.numba_kernel(False, args.numba_threads)
    print(
        f"numba compile: {nb_shared_compile_s:.2f} s (shared), {nb_runs_compile_s:.2f} "
        f"s (per run), after {numba_warm_up_s:.2f} s of first use; "
        f"{args.numba_threads} threads"
    )
    nb_k, nb_errors = fewest(
        SUBSTEP_CANDIDATES,
        lambda k: grid_error(nb_shared(mot_a, mot_f, currents, ts_np, k)),
        "numba RK4 substeps",
    )
    nb_k_ns, nb_errors_ns = fewest(
        SUBSTEP_CANDIDATES[SUBSTEP_CANDIDATES.index(nb_k) :],
        lambda k: grid_error(nb_runs(run_a, run_f, run_i, ts_np, k)),
        "numba RK4 substeps (no sharing)",
    )

    # --- compile: jaxmr fast mode and the scan kernels -----------------------------------
    cur_all = jnp.asarray(currents)

    # Like the baselines, the timed sweeps return the torque alone (`keep`); the whole
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
    # Where the torque lives: split over the devices along the motions when sweep
    # shards its batch (each device solving its own motions).
    force_sharding = {
        "devices": len(sol.force.sharding.device_set),
        "spec": str(getattr(sol.force.sharding, "spec", None)),
        "shard_shapes": sorted(
            {tuple(s.data.shape) for s in sol.force.addressable_shards}
        ),
    }
    del sol
    err_jaxmr = grid_error(jaxmr_force)
    _, first_nothrow_s = wall(jaxmr_fast, False)
    sol, first_full_s = wall(jaxmr_full)
    full_vs_force_only = float(np.abs(np.asarray(sol.force) - jaxmr_force).max())
    del sol
    sol, first_no_sharing_s = wall(jaxmr_no_sharing)
    err_jaxmr_ns = grid_error(sol.force)
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
    err_kernel = grid_error(kernel_torque)
    kernel_vs_jaxmr = float(np.abs(kernel_torque - jaxmr_force).max())
    shared_kernel = make_kernel(ts, substeps, shared=True)
    m_args = [jnp.asarray(mot_a), jnp.asarray(mot_f), cur_all]
    if jax.device_count() > 1 and n_mot % jax.device_count() == 0:
        m_args[:2] = [jax.device_put(x, sharding) for x in m_args[:2]]
    t0 = time.perf_counter()
    shared_kernel_compiled = shared_kernel.lower(*m_args).compile()
    shared_kernel_compile_s = time.perf_counter() - t0
    shared_kernel_torque = np.asarray(shared_kernel_compiled(*m_args))
    err_shared_kernel = grid_error(shared_kernel_torque)
    shared_kernel_vs_kernel = float(np.abs(shared_kernel_torque - kernel_torque).max())
    del kernel_torque, shared_kernel_torque

    def numba_one_thread(kernel, *kernel_args):
        """The numba kernel on one thread: the figure beside jaxmr on one device."""
        numba.set_num_threads(1)
        try:
            return kernel(*kernel_args)
        finally:
            numba.set_num_threads(args.numba_threads)

    # --- timing: interleaved rounds, so that load from elsewhere hits all alike ----------
    timing = interleaved(
        {
            "jaxmr": jaxmr_fast,
            "jaxmr_throw_false": lambda: jaxmr_fast(False),
            "jaxmr_full_solution": jaxmr_full,
            "jaxmr_no_sharing": jaxmr_no_sharing,
            "kernel": lambda: kernel_compiled(*k_args),
            "shared_kernel": lambda: shared_kernel_compiled(*m_args),
            "numba": lambda: nb_shared(mot_a, mot_f, currents, ts_np, nb_k),
            "numba_one_thread": lambda: numba_one_thread(
                nb_shared, mot_a, mot_f, currents, ts_np, nb_k
            ),
            "numba_no_sharing": lambda: nb_runs(run_a, run_f, run_i, ts_np, nb_k_ns),
            "numpy_rk4": lambda: np_shared(np_k),
            "numpy_rk4_no_sharing": lambda: np_runs(np_k_ns),
            "solve_ivp": lambda: ivp_shared(ivp_best["method"], ivp_best["rtol"]),
            "solve_ivp_no_sharing": lambda: ivp_runs(
                ivp_best_ns["method"], ivp_best_ns["rtol"]
            ),
            "scipy_loop": lambda: scipy_loop(scipy_best["method"], scipy_best["rtol"]),
        },
        args.repeats,
    )

    # --- jaxmr on one XLA device: a fresh process (the device count is fixed at start) --
    one_device = one_device_run(args, substeps)
    one_vs_devices = float(np.abs(one_device["force"] - jaxmr_force).max())
    print(
        f"jaxmr on one device: {one_device['run_min_s']:.2f} s (cpu "
        f"{one_device['run_cpu_s']:.2f} s); torque vs {jax.device_count()} devices: "
        f"{one_vs_devices:.1e} N·m"
    )

    # --- figures per method ----------------------------------------------------------------
    def ivp_details(best):
        return {k: best[k] for k in ("method", "rtol", "atol", "nfev")}

    jaxmr_details = {"substeps": substeps, "step_s": dt_step}
    methods = {
        "jaxmr_fixedstep": method_entry(
            timing["jaxmr"],
            sim_seconds,
            err_jaxmr,
            first_s - timing["jaxmr"]["median_s"],
            first_call_s=first_s,
            shares_states=shared_states,
            **jaxmr_details,
        ),
        "jaxmr_fixedstep_throw_false": method_entry(
            timing["jaxmr_throw_false"],
            sim_seconds,
            err_jaxmr,
            first_nothrow_s - timing["jaxmr_throw_false"]["median_s"],
            first_call_s=first_nothrow_s,
            shares_states=shared_states,
            **jaxmr_details,
        ),
        "jaxmr_fixedstep_full_solution": method_entry(
            timing["jaxmr_full_solution"],
            sim_seconds,
            err_jaxmr,
            first_full_s - timing["jaxmr_full_solution"]["median_s"],
            first_call_s=first_full_s,
            shares_states=shared_states,
            **jaxmr_details,
        ),
        "jaxmr_fixedstep_no_sharing": method_entry(
            timing["jaxmr_no_sharing"],
            sim_seconds,
            err_jaxmr_ns,
            first_no_sharing_s - timing["jaxmr_no_sharing"]["median_s"],
            first_call_s=first_no_sharing_s,
            shares_states=False,
            **jaxmr_details,
        ),
        "jaxmr_fixedstep_one_device": method_entry(
            {
                "min_s": float(one_device["run_min_s"]),
                "median_s": float(one_device["run_s"]),
                "all_s": [float(t) for t in one_device["run_all_s"]],
                "cpu_s": float(one_device["run_cpu_s"]),
            },
            sim_seconds,
            grid_error(one_device["force"]),
            float(one_device["first_s"] - one_device["run_s"]),
            first_call_s=float(one_device["first_s"]),
            shares_states=shared_states,
            devices=int(one_device["devices"]),
            **jaxmr_details,
        ),
        "scan_kernel_shared": method_entry(
            timing["shared_kernel"],
            sim_seconds,
            err_shared_kernel,
            shared_kernel_compile_s,
            shares_states=True,
            substeps=substeps,
        ),
        "scan_kernel": method_entry(
            timing["kernel"],
            sim_seconds,
            err_kernel,
            kernel_compile_s,
            first_call_s=kernel_first_s,
            shares_states=False,
            substeps=substeps,
        ),
        "numba": method_entry(
            timing["numba"],
            sim_seconds,
            nb_errors[str(nb_k)],
            nb_shared_compile_s,
            shares_states=True,
            substeps=nb_k,
            threads=args.numba_threads,
        ),
        "numba_one_thread": method_entry(
            timing["numba_one_thread"],
            sim_seconds,
            nb_errors[str(nb_k)],
            nb_shared_compile_s,
            shares_states=True,
            substeps=nb_k,
            threads=1,
        ),
        "numba_no_sharing": method_entry(
            timing["numba_no_sharing"],
            sim_seconds,
            nb_errors_ns[str(nb_k_ns)],
            nb_runs_compile_s,
            shares_states=False,
            substeps=nb_k_ns,
            threads=args.numba_threads,
        ),
        "numpy_rk4": method_entry(
            timing["numpy_rk4"],
            sim_seconds,
            np_errors[str(np_k)],
            shares_states=True,
            substeps=np_k,
        ),
        "numpy_rk4_no_sharing": method_entry(
            timing["numpy_rk4_no_sharing"],
            sim_seconds,
            np_errors_ns[str(np_k_ns)],
            shares_states=False,
            substeps=np_k_ns,
        ),
        "solve_ivp_vectorised": method_entry(
            timing["solve_ivp"],
            sim_seconds,
            ivp_best["max_torque_error_rel"],
            shares_states=True,
            **ivp_details(ivp_best),
        ),
        "solve_ivp_vectorised_no_sharing": method_entry(
            timing["solve_ivp_no_sharing"],
            sim_seconds,
            ivp_best_ns["max_torque_error_rel"],
            shares_states=False,
            **ivp_details(ivp_best_ns),
        ),
        # Timed on a few runs (`runs_timed`), extrapolated per simulated second.
        "scipy_loop": method_entry(
            timing["scipy_loop"],
            len(scipy_runs) * duration,
            scipy_best["max_torque_error_rel"],
            shares_states=False,
            method=scipy_best["method"],
            rtol=scipy_best["rtol"],
            atol=scipy_best["atol"],
            runs_timed=len(scipy_runs),
        ),
    }
    # jaxmr's default path against the baselines doing the same work: their shared forms
    # where jaxmr shares the states.
    same = "" if shared_states else "_no_sharing"

    def speedup(jaxmr_name, baseline, with_compile=False):
        key = (
            "throughput_with_compile_sim_s_per_s"
            if with_compile
            else "throughput_sim_s_per_s"
        )
        return methods[jaxmr_name][key] / methods[baseline][key]

    def fastest(*names):
        return max(names, key=lambda n: methods[n]["throughput_sim_s_per_s"])

    vectorised = fastest(f"numpy_rk4{same}", f"solve_ivp_vectorised{same}")
    vectorised_ns = fastest("numpy_rk4_no_sharing", "solve_ivp_vectorised_no_sharing")
    default, no_sharing = "jaxmr_fixedstep", "jaxmr_fixedstep_no_sharing"
    headline = {
        "speedup_vs_scipy_vectorised": speedup(default, vectorised),
        "speedup_vs_numba": speedup(default, f"numba{same}"),
        "speedup_vs_scipy_vectorised_with_compile": speedup(default, vectorised, True),
        "speedup_vs_numba_with_compile": speedup(default, f"numba{same}", True),
        "speedup_vs_scipy_vectorised_no_sharing": speedup(no_sharing, vectorised_ns),
        "speedup_vs_numba_no_sharing": speedup(no_sharing, "numba_no_sharing"),
        "speedup_vs_scipy_vectorised_no_sharing_with_compile": speedup(
            no_sharing, vectorised_ns, True
        ),
        "speedup_vs_numba_no_sharing_with_compile": speedup(
            no_sharing, "numba_no_sharing", True
        ),
        "scipy_vectorised_baseline": vectorised,
        "scipy_vectorised_baseline_no_sharing": vectorised_ns,
        "speedup_vs_solve_ivp_vectorised": speedup(
            default, f"solve_ivp_vectorised{same}"
        ),
        "speedup_vs_numpy_rk4": speedup(default, f"numpy_rk4{same}"),
        "speedup_vs_solve_ivp_vectorised_no_sharing": speedup(
            no_sharing, "solve_ivp_vectorised_no_sharing"
        ),
        "speedup_vs_numpy_rk4_no_sharing": speedup(no_sharing, "numpy_rk4_no_sharing"),
        # CPU time: XLA and numba use every core, NumPy one.
        "speedup_vs_scipy_vectorised_cpu_time": methods[vectorised]["run_cpu_s"]
        / methods[default]["run_cpu_s"],
        "speedup_vs_numba_cpu_time": methods[f"numba{same}"]["run_cpu_s"]
        / methods[default]["run_cpu_s"],
        # Reported apart: jaxmr on one XLA device (a fresh process) against numba on
        # one thread, and against numba on its threads (the pairing before sweeps
        # used every core); the gain from the devices; the two torques compared.
        "jaxmr_devices": jax.device_count(),
        "speedup_vs_numba_one_device": speedup(
            "jaxmr_fixedstep_one_device", "numba_one_thread"
        ),
        "speedup_vs_numba_one_device_cpu_time": methods["numba_one_thread"]["run_cpu_s"]
        / methods["jaxmr_fixedstep_one_device"]["run_cpu_s"],
        "speedup_vs_numba_jaxmr_one_device": speedup(
            "jaxmr_fixedstep_one_device", f"numba{same}"
        ),
        "speedup_devices_over_one_device": speedup(
            default, "jaxmr_fixedstep_one_device"
        ),
        "one_device_vs_devices_max_abs_Nm": one_vs_devices,
        "one_device_equal_bitwise": bool(
            np.array_equal(one_device["force"], jaxmr_force)
        ),
        "jaxmr_output_sharding": force_sharding,
        # The old baseline, one run at a time with a Python right-hand side.
        "speedup_vs_scipy_loop": speedup(default, "scipy_loop"),
        "speedup_vs_scipy_loop_no_sharing": speedup(no_sharing, "scipy_loop"),
    }
    kernel_like = f"scan_kernel{'_shared' if shared_states else ''}"
    results = {
        "benchmark": "simulate_sweep",
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "model": "jaxmr.sas_brake_bouc_wen()",
        "runs": args.runs,
        "quick": args.quick,
        **headline,
        "all_within_target": all(
            m["max_torque_error_rel"] <= PEAK_ERROR_TARGET for m in methods.values()
        ),
        "throughput_sim_s_per_s": methods[default]["throughput_sim_s_per_s"],
        "throughput_sim_s_per_s_no_sharing": methods[no_sharing][
            "throughput_sim_s_per_s"
        ],
        "throughput_sim_s_per_s_by_method": {
            k: m["throughput_sim_s_per_s"] for k, m in methods.items()
        },
        "max_torque_error_rel_by_method": {
            k: m["max_torque_error_rel"] for k, m in methods.items()
        },
        "time_ratio_vs_scan_kernel": methods[default]["run_s"]
        / methods[kernel_like]["run_s"],
        "cpu_time_ratio_vs_scan_kernel": methods[default]["run_cpu_s"]
        / methods[kernel_like]["run_cpu_s"],
        "time_ratio_vs_scan_kernel_no_sharing": methods[no_sharing]["run_s"]
        / methods["scan_kernel"]["run_s"],
        "time_ratio_vs_scan_kernel_full_solution": methods[
            "jaxmr_fixedstep_full_solution"
        ]["run_s"]
        / methods[kernel_like]["run_s"],
        "substeps": substeps,
        "step_s": dt_step,
        "shared_states": shared_states,
        "numba_threads": args.numba_threads,
        # numba's one-time costs in the process (a trivial parallel function compiled
        # and run first), not counted in its kernels' compile_s: JAX's fall on the
        # reference and substep search the same way.
        "numba_first_use_s": numba_warm_up_s,
        "methods": methods,
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
            "substep_search": {
                "jaxmr_fixedstep": substep_errors,
                "numpy_rk4": np_errors,
                "numpy_rk4_no_sharing": np_errors_ns,
                "numba": nb_errors,
                "numba_no_sharing": nb_errors_ns,
            },
            "solve_ivp_vectorised_tried": ivp_tries,
            "scipy_loop_tried": scipy_tries,
            "scan_kernel_vs_jaxmr_abs_Nm": kernel_vs_jaxmr,
            "jaxmr_no_sharing_vs_shared_abs_Nm": no_sharing_vs_shared,
            "jaxmr_full_solution_vs_force_only_abs_Nm": full_vs_force_only,
            "shared_scan_kernel_vs_scan_kernel_abs_Nm": shared_kernel_vs_kernel,
        },
        "timing": f"run times are the min of {args.repeats} calls after the first "
        "(compile) call, timed in interleaved rounds (every method once per round; then "
        "the batching configurations; jaxmr_fixedstep_one_device in a fresh process "
        "after them), jax outputs with block_until_ready; "
        "throughput = simulated s / run s; with compile = simulated s / (compile s + "
        "run s), compile s = first call - median run for jaxmr, lower().compile() for "
        "the scan kernels, the eager compilation from the signature for numba, 0 for "
        "NumPy/SciPy; speedup_vs_X = throughput ratio, the headline ones jaxmr's default "
        "(shared-state when `shared_states`) path against X's same form, *_no_sharing "
        "one solve per run on both sides; every method returns the torque of every run "
        "(jaxmr: keep=('force',); *_full_solution: the whole Solution); scipy_loop is "
        "timed on `runs_timed` runs and extrapolated per simulated second",
        "versions": {
            "jax": jax.__version__,
            "jaxlib": __import__("jaxlib").__version__,
            "diffrax": __import__("diffrax").__version__,
            "equinox": __import__("equinox").__version__,
            "scipy": scipy.__version__,
            "numpy": np.__version__,
            "numba": __import__("numba").__version__,
            "jaxmr": jaxmr.__version__,
        },
        "device": device_description(),
        "git": git_state(),
        "host_devices": jax.device_count(),
        "loadavg_start": load_start,
    }
    print(
        f"jaxmr FixedStep({substeps}): "
        f"{results['throughput_sim_s_per_s']:.0f} sim s/s; numba "
        f"{methods[f'numba{same}']['throughput_sim_s_per_s']:.0f}; vectorised "
        f"{vectorised} {methods[vectorised]['throughput_sim_s_per_s']:.0f}"
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
    results["adaptive_batching"] = {
        "subset_runs": n_sub,
        "throughput_sim_s_per_s": {
            k: v["throughput_sim_s_per_s"] for k, v in adaptive.items()
        },
        "max_torque_error_rel_default": adaptive["map_bsNone"]["max_torque_error_rel"],
    }
    results["batching_details"] = batching_results
    results["loadavg_end"] = os.getloadavg()
    results["total_wall_s"] = time.perf_counter() - t_start
    out = Path(args.json)
    write_figures(results, out)

    # --- summary -------------------------------------------------------------------------
    labels = {
        "jaxmr_fixedstep": f"jaxmr sweep FixedStep({substeps})"
        + (", shared z" if shared_states else ""),
        "jaxmr_fixedstep_throw_false": f"jaxmr sweep FixedStep({substeps}), throw=False",
        "jaxmr_fixedstep_full_solution": f"jaxmr sweep FixedStep({substeps}), Solution",
        "jaxmr_fixedstep_no_sharing": f"jaxmr sweep FixedStep({substeps}), per run",
        "jaxmr_fixedstep_one_device": f"jaxmr sweep FixedStep({substeps}), 1 device",
        "scan_kernel_shared": "lax.scan RK4 kernel, shared z",
        "scan_kernel": "lax.scan RK4 kernel, per run",
        "numba": f"numba RK4({nb_k}), shared z",
        "numba_one_thread": f"numba RK4({nb_k}), shared z, 1 thread",
        "numba_no_sharing": f"numba RK4({nb_k_ns}), per run",
        "numpy_rk4": f"NumPy RK4({np_k}) over the batch, shared z",
        "numpy_rk4_no_sharing": f"NumPy RK4({np_k_ns}) over the batch, per run",
        "solve_ivp_vectorised": f"solve_ivp {ivp_best['method']} "
        f"rtol={ivp_best['rtol']:g} over the batch, shared z",
        "solve_ivp_vectorised_no_sharing": f"solve_ivp {ivp_best_ns['method']} "
        f"rtol={ivp_best_ns['rtol']:g} over the batch, per run",
        "scipy_loop": f"solve_ivp {scipy_best['method']} rtol={scipy_best['rtol']:g} "
        f"loop ({len(scipy_runs)} runs)",
    }
    rows = [
        (
            labels[k],
            m["compile_s"],
            m["run_s"],
            m["run_cpu_s"],
            m["throughput_sim_s_per_s"],
            m["max_torque_error_rel"],
        )
        for k, m in methods.items()
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
        f"{'mode':<52}{'compile s':>10}{'run s':>8}{'cpu s':>8}{'sim s/s':>9}"
        f"{'err/peak':>10}"
    )
    for name, comp, r, cpu, thr, err in rows:
        print(f"{name:<52}{comp:>10.2f}{r:>8.2f}{cpu:>8.2f}{thr:>9.0f}{err:>10.1e}")
    print()
    r = results
    print(
        f"speedup_vs_scipy_vectorised {r['speedup_vs_scipy_vectorised']:.1f} (goal >= "
        f"10; against {vectorised}; with compile "
        f"{r['speedup_vs_scipy_vectorised_with_compile']:.1f}; without sharing "
        f"{r['speedup_vs_scipy_vectorised_no_sharing']:.1f}, with compile "
        f"{r['speedup_vs_scipy_vectorised_no_sharing_with_compile']:.1f})"
    )
    print(
        f"speedup_vs_numba            {r['speedup_vs_numba']:.2f} (goal >= 1; "
        f"{r['jaxmr_devices']} XLA devices, numba {args.numba_threads} threads; with "
        f"compile {r['speedup_vs_numba_with_compile']:.2f}; without sharing "
        f"{r['speedup_vs_numba_no_sharing']:.2f}, with compile "
        f"{r['speedup_vs_numba_no_sharing_with_compile']:.2f}; CPU time ratio "
        f"{r['speedup_vs_numba_cpu_time']:.2f})"
    )
    print(
        f"one device                  {r['speedup_vs_numba_one_device']:.2f} against "
        f"numba on 1 thread (CPU time ratio "
        f"{r['speedup_vs_numba_one_device_cpu_time']:.2f}), "
        f"{r['speedup_vs_numba_jaxmr_one_device']:.2f} against numba on "
        f"{args.numba_threads}; the devices ran {r['speedup_devices_over_one_device']:.2f}x "
        f"faster; torque equal bit for bit: {r['one_device_equal_bitwise']} (max "
        f"{r['one_device_vs_devices_max_abs_Nm']:.1e} N·m); output split as "
        f"{r['jaxmr_output_sharding']}"
    )
    print(
        f"speedup_vs_scipy_loop       {r['speedup_vs_scipy_loop']:.0f} (one run at a "
        f"time, Python right-hand side; without sharing "
        f"{r['speedup_vs_scipy_loop_no_sharing']:.0f})"
    )
    print(
        f"time_ratio_vs_scan_kernel   {r['time_ratio_vs_scan_kernel']:.2f} "
        f"(goal <= 2, against the kernel doing the same work; CPU time ratio "
        f"{r['cpu_time_ratio_vs_scan_kernel']:.2f}; without sharing "
        f"{r['time_ratio_vs_scan_kernel_no_sharing']:.2f}; whole Solution "
        f"{r['time_ratio_vs_scan_kernel_full_solution']:.2f})"
    )
    print(
        f"every method within {PEAK_ERROR_TARGET:g} of peak: {r['all_within_target']}; "
        f"reference vs scipy DOP853 rtol 1e-12: {reference_crosscheck:.1e} of peak"
    )
    print(f"load average {load_start} -> {r['loadavg_end']}; wrote {out}")


if __name__ == "__main__":
    main()
