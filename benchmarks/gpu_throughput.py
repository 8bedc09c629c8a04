"""Throughput on an accelerator against the same machine's CPU cores: `jaxmr.sweep` of
many damper simulations and `jaxmr.evaluate` of a controller over many roads.

    python benchmarks/gpu_throughput.py --json benchmarks/results/gpu_throughput.json
    python benchmarks/gpu_throughput.py --json /tmp/gpu.json --quick   # smoke test

Run where JAX sees an accelerator (a GPU). The script times the same work twice, in
the same run: on JAX's default backend (the accelerator) in this process, and on the
machine's CPU in a fresh process (`JAX_PLATFORMS=cpu`, set up as the documentation
sets up a CPU user, `jaxmr.devices.configure_cpu()`: every core a device, over which
`sweep` and `evaluate` spread their batches, and each simulation loop one kernel).
On a machine without an accelerator both columns are the CPU's, and the ratios say
nothing.

- **Sweep:** `jaxmr.passenger_car_mr_damper()` (Bouc–Wen with per-current laws and an
  8 ms current lag: its state depends on the current, so every run is solved; no
  shared-state path) under N / 8 sine motions (amplitudes 5–25 mm, frequencies
  0.5–5 Hz) × 8 constant currents 0–1 A, 2 s each, output at 1 kHz, `FixedStep(substeps=3)`,
  the force only (`keep=("force",)`).
- **Closed loop:** `passenger_car(passenger_car_mr_damper())` under `Skyhook(2000,
  1)`, 1 kHz with one sample of delay, on ISO 8608 class C roads at 20 m/s, 4 s each,
  perfect information (`sensors="oracle"`), the comfort a_w of every road.

Each size is compiled (first call), then run 3 times; run time is the fastest of the
3, compile time the first call minus it. Throughput is simulated seconds per wall
second. The CPU's results are checked against the accelerator's (relative difference
of the forces and the comfort figures: both run in float64).

Figures (top-level keys, at the largest size): `gpu_sweep_sim_s_per_s`,
`cpu_sweep_sim_s_per_s`, `gpu_speedup_sweep`; `gpu_closed_loop_sim_s_per_s`,
`cpu_closed_loop_sim_s_per_s`, `gpu_speedup_closed_loop`; the same with compilation
included (`*_with_compile`); every size in `sizes`.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
FULL = {"sweep": (1024, 8192, 65536), "closed_loop": (64, 1024, 8192)}
QUICK = {"sweep": (64, 256), "closed_loop": (4, 16)}
SWEEP_SECONDS, ROAD_SECONDS = 2.0, 4.0  # [s] simulated per run


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, required=True, help="write the figures here")
    p.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument(
        "--no-cpu", action="store_true", help="skip the CPU comparison process"
    )
    return p.parse_args(argv)


def timed(call, repeats: int = 3) -> dict:
    """First call (compilation included) and the fastest of `repeats` later calls [s]."""
    t0 = time.perf_counter()
    out = call()
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = call()
        runs.append(time.perf_counter() - t0)
    run = min(runs)
    return {"first_s": first, "run_s": run, "compile_s": max(first - run, 0.0)}, out


def measure(quick: bool) -> dict:
    """Every size of both cases on JAX's default backend."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import jaxmr

    sizes = QUICK if quick else FULL
    damper = jaxmr.passenger_car_mr_damper()
    ts = jnp.linspace(0.0, SWEEP_SECONDS, int(round(SWEEP_SECONDS * 1000)) + 1)
    results = {"sweep": {}, "closed_loop": {}}
    outputs = {"sweep": {}, "closed_loop": {}}
    for runs in sizes["sweep"]:
        # runs / 8 motions x 8 currents; the motions' frequencies spread over the
        # band by the golden ratio, their amplitudes evenly.
        k = np.arange(runs // 8)
        amplitudes = np.linspace(5e-3, 25e-3, k.size)  # [m]
        frequencies = 0.5 + 4.5 * ((k * 0.6180339887) % 1.0)  # [Hz]
        motions = [jaxmr.Sine(a, f) for a, f in zip(amplitudes, frequencies)]
        currents = jnp.linspace(0.0, 1.0, 8)
        n = len(motions) * 8

        def call(motions=motions, currents=currents):
            sol = jaxmr.sweep(
                damper,
                motions,
                currents,
                ts,
                integrator=jaxmr.FixedStep(substeps=3),
                keep=("force",),
            )
            return jax.block_until_ready(sol.force)

        times, force = timed(call)
        times["runs"] = n
        times["sim_s_per_s"] = n * SWEEP_SECONDS / times["run_s"]
        times["sim_s_per_s_with_compile"] = n * SWEEP_SECONDS / times["first_s"]
        results["sweep"][str(n)] = times
        # Every 64th run's force for the cross-check against the CPU.
        outputs["sweep"][str(n)] = np.asarray(force).reshape(n, -1)[:: max(n // 64, 1)]
        print(f"sweep {n} runs: {times}", flush=True)
    car = jaxmr.passenger_car(damper)
    law = jaxmr.Skyhook(2000.0, 1.0)
    for n in sizes["closed_loop"]:
        keys = jax.vmap(jax.random.key)(jnp.arange(n))
        roads = jax.vmap(lambda k: jaxmr.iso8608_road("C", 20.0, ROAD_SECONDS, k))(keys)

        def run(roads=roads):
            return jaxmr.evaluate(car, law, roads, ROAD_SECONDS, sensors="oracle")[
                "comfort"
            ]

        times, comfort = timed(run)
        times["roads"] = n
        times["sim_s_per_s"] = n * ROAD_SECONDS / times["run_s"]
        times["sim_s_per_s_with_compile"] = n * ROAD_SECONDS / times["first_s"]
        results["closed_loop"][str(n)] = times
        outputs["closed_loop"][str(n)] = np.asarray(comfort)
        print(f"closed loop {n} roads: {times}", flush=True)
    results["backend"] = jax.default_backend()
    results["devices"] = [str(d) for d in jax.devices()]
    return results, outputs


def cpu_process(quick: bool) -> tuple[dict, dict]:
    """`measure` in a fresh process on the CPU (`configure_cpu()`): its figures and
    outputs."""
    import numpy as np

    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "cpu.json"
        env = os.environ | {"JAX_PLATFORMS": "cpu"}
        command = [sys.executable, __file__, "--worker", "--json", str(out)]
        subprocess.run(command + (["--quick"] if quick else []), env=env, check=True)
        figures = json.loads(out.read_text())
        arrays = np.load(out.with_suffix(".npz"))
        outputs = {"sweep": {}, "closed_loop": {}}
        for name in arrays.files:
            case, size = name.rsplit("_", 1)
            outputs[case][size] = arrays[name]
    return figures, outputs


def worker(args) -> None:
    import numpy as np

    import jaxmr

    jaxmr.devices.configure_cpu()
    figures, outputs = measure(args.quick)
    args.json.write_text(json.dumps(figures))
    np.savez(
        args.json.with_suffix(".npz"),
        **{f"{case}_{n}": v for case in outputs for n, v in outputs[case].items()},
    )


def main(argv=None) -> None:
    args = parse_args(argv)
    if args.worker:
        worker(args)
        return
    sys.path.insert(0, str(HERE))
    import numpy as np
    from _report import write_figures

    started = time.time()
    accelerator, acc_out = measure(args.quick)
    figures = {"quick": args.quick, "accelerator": accelerator}
    if not args.no_cpu:
        cpu, cpu_out = cpu_process(args.quick)
        figures["cpu"] = cpu
        agreement = {}
        for case in ("sweep", "closed_loop"):
            diffs = []
            for size, a in acc_out[case].items():
                b = cpu_out[case][size]
                diffs.append(float(np.max(np.abs(a - b)) / np.max(np.abs(b))))
            agreement[case] = max(diffs)
        figures["max_relative_difference_cpu"] = agreement
        for case in ("sweep", "closed_loop"):
            largest = max(accelerator[case], key=int)
            acc, ref = accelerator[case][largest], cpu[case][largest]
            figures[f"gpu_{case}_sim_s_per_s"] = acc["sim_s_per_s"]
            figures[f"cpu_{case}_sim_s_per_s"] = ref["sim_s_per_s"]
            figures[f"gpu_speedup_{case}"] = acc["sim_s_per_s"] / ref["sim_s_per_s"]
            figures[f"gpu_speedup_{case}_with_compile"] = (
                acc["sim_s_per_s_with_compile"] / ref["sim_s_per_s_with_compile"]
            )
            figures[f"{case}_largest_batch"] = int(largest)
    figures["seconds"] = time.time() - started
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
