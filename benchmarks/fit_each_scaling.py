"""`fit_each` at scale: 256 independent synthetic brake records in one call (issue 12).

Each record is its own brake: the published Bouc–Wen brake (`sas_brake_bouc_wen()` at
a constant current drawn from 0–1 A) with α, c0, β, n each scaled by a log-uniform
factor within ±30 %, one 1 Hz ±3.5° cycle at 500 Hz from the virgin state, simulated
with a tight adaptive solve, plus 1 % Gaussian noise. Fitted: α, c0, β, γ, n (A fixed
against the Bouc–Wen scaling redundancy; k0, x0, f0 fixed at 0), every record from a
start 2–3x off (each parameter multiplied or divided by a factor in [2, 3]).

Figures:

- `seconds_256_fits`: the `fit_each` call in one process, compilation included (goal
  <= 120 s on 2 cores), and `seconds_256_fits_run` (the same call again, compiled);
- `fraction_recovered`: of the 256 x 5 fitted values, the fraction with a finite
  standard error and within 3 of them of the truth (goal >= 0.95): the standard
  errors are honest when it holds;
- `two_process_over_one`: with `--processes 2`, the time of the call split over 2
  processes (`jax.distributed` on localhost, one CPU device each) over the time in 1
  process on the same cores (goal <= 1.15), and whether the fitted values are equal.

    python benchmarks/fit_each_scaling.py --json benchmarks/results/fit_each_scaling.json
    python benchmarks/fit_each_scaling.py --processes 2 --json OUT   # adds the 2-process run

Every run is a fresh process (`--worker`), so each pays its own compilation.
"""

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

HERE = Path(__file__).resolve()
sys.path.insert(0, str(HERE.parents[1]))  # the repository's jaxmr
from _processes import initialize, launch  # noqa: E402
from _report import write_figures  # noqa: E402

NAMES = ("alpha", "c0", "beta", "gamma", "n")


def records(count: int, seed: int = 0):
    """(experiments, true parameter values (count, 5), starts)."""
    import jax.numpy as jnp
    import numpy as np

    import jaxmr

    rng = np.random.default_rng(seed)
    published = jaxmr.sas_brake_bouc_wen()
    ts = jnp.linspace(0.0, 1.0, 501)
    motion = jaxmr.Sine(jnp.deg2rad(3.5), 1.0)
    currents = rng.uniform(0.0, 1.0, count)
    truths, brakes = [], []
    for i in currents:
        plain = published.at(float(i))
        factor = np.exp(rng.uniform(-np.log(1.3), np.log(1.3), 4))
        values = np.array(
            [
                float(plain.alpha) * factor[0],
                float(plain.c0) * factor[1],
                float(plain.beta) * factor[2],
                float(plain.gamma),
                float(plain.n) * factor[3],
            ]
        )
        truths.append(values)
        brakes.append(constant_brake(values, float(plain.A)))
    sol = jaxmr.sweep(
        brakes, motion, 0.0, ts, grid=False,
        integrator=jaxmr.Adaptive(rtol=1e-10, atol=1e-12),
    )  # fmt: skip
    experiments = []
    for k in range(count):
        force = np.asarray(sol.force[k])
        experiments.append(
            SimpleNamespace(
                t=np.asarray(ts),
                x=np.asarray(sol.displacement[k]),
                v=np.asarray(sol.velocity[k]),
                current=np.full(ts.shape, currents[k]),
                force=force + 0.01 * np.std(force) * rng.standard_normal(force.shape),
                name=f"brake {k}",
            )
        )
    off = rng.uniform(2.0, 3.0, (count, 5)) ** rng.choice([-1.0, 1.0], (count, 5))
    return experiments, np.array(truths), np.array(truths) * off, float(published.A)


def constant_brake(values, A, wrap=None):
    """A Bouc–Wen brake with constant parameters; with `wrap` (e.g. `Positive`) the
    five fitted ones wrapped and the rest `Fixed`, else plain numbers."""
    import jaxmr

    free = (lambda v: v) if wrap is None else wrap
    fixed = (lambda v: v) if wrap is None else jaxmr.Fixed
    alpha, c0, beta, gamma, n = (free(float(v)) for v in values)
    return jaxmr.BoucWen(
        alpha=alpha, c0=c0, A=fixed(A), beta=beta, gamma=gamma, n=n,
        k0=fixed(0.0), x0=fixed(0.0), f0=fixed(0.0),
    )  # fmt: skip


def worker(args):
    """One process of a run: fits every record with one `fit_each` call (twice: the
    first compiles), writes the figures from process 0."""
    initialize(args.processes, args.worker, args.port)
    import jax
    import numpy as np

    import jaxmr

    experiments, truths, starts, A = records(args.records)
    # Every record from its own start (a sequence of models, one per experiment).
    models = [constant_brake(s, A, jaxmr.Positive) for s in starts]
    times = []
    for _ in range(2):
        t0 = time.perf_counter()
        results = jaxmr.fit_each(models, experiments, progress=False)
        times.append(time.perf_counter() - t0)
    values = np.array([r.values for r in results])
    errors = np.array([r.std_errors for r in results])
    names = [n.lstrip(".") for n in results[0].names]
    order = [names.index(name) for name in NAMES]
    values, errors = values[:, order], errors[:, order]
    # An infinite standard error (a parameter the fit reports as undetermined) is
    # not a recovery, however close its value: `inf <= inf` would count it.
    within = np.isfinite(errors) & (np.abs(values - truths) <= 3 * errors)
    if jax.process_index() == 0:
        np.savez(
            args.out,
            values=values,
            errors=errors,
            within=within,
            seconds=np.array(times),
            steps=np.array([r.num_steps for r in results]),
            devices=np.array(len(jax.devices())),
        )


def run(processes: int, count: int, folder: Path, host_devices: int = 1) -> dict:
    out = folder / f"p{processes}d{host_devices}.npz"
    return launch(str(HERE), processes, ["--records", str(count)], out, host_devices)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--records", type=int, default=256)
    parser.add_argument("--processes", type=int, default=1)
    parser.add_argument(
        "--host-devices",
        type=int,
        default=1,
        help="XLA CPU devices of the one-process run (default 1)",
    )
    parser.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--port", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:
        return worker(args)
    import numpy as np

    with tempfile.TemporaryDirectory() as folder:
        # One process on one XLA device by default (XLA's CPU client still spreads
        # large batched operations over the cores: the run kept ~1.5 of 2 busy). Its
        # cores as several devices (`--host-devices`) used to hang in the 256-record
        # fit: jaxlib split each batched LAPACK QR over the thread pool the devices
        # themselves run on. The solver now factorises one matrix at a time
        # (`solver._one_matrix_at_a_time`, 2026-11-25), so `--host-devices` runs.
        one = run(1, args.records, Path(folder), host_devices=args.host_devices)
        figures = {
            "records": args.records,
            "parameters_per_record": len(NAMES),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            "load_average": os.getloadavg(),
            "host_devices": int(one["devices"]),
            "seconds_256_fits": float(one["seconds"][0]),
            "seconds_256_fits_run": float(one["seconds"][1]),
            "median_steps": float(np.median(one["steps"])),
            "fraction_recovered": float(np.mean(one["within"])),
            "fraction_recovered_per_parameter": dict(
                zip(NAMES, np.mean(one["within"], axis=0).tolist())
            ),
            "goals": {
                "seconds_256_fits": "<= 120 s on 2 cores",
                "fraction_recovered": ">= 0.95",
                "two_process_over_one": "<= 1.15, equal results",
            },
        }
        if args.processes > 1:
            many = run(args.processes, args.records, Path(folder))
            figures[f"seconds_{args.processes}_processes"] = float(many["seconds"][0])
            figures[f"seconds_{args.processes}_processes_run"] = float(
                many["seconds"][1]
            )
            figures["two_process_over_one"] = float(
                many["seconds"][0] / one["seconds"][0]
            )
            figures["two_process_over_one_run"] = float(
                many["seconds"][1] / one["seconds"][1]
            )
            figures["equal_results"] = bool(
                np.array_equal(many["values"], one["values"])
            )
            figures["records_differing"] = int(
                np.sum(np.any(many["values"] != one["values"], axis=1))
            )
            figures["largest_relative_difference"] = float(
                np.max(
                    np.abs(many["values"] - one["values"])
                    / np.maximum(np.abs(one["values"]), 1e-300)
                )
            )
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
