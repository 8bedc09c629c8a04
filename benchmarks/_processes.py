"""Running a benchmark's measurement in fresh processes: N local processes with
`jax.distributed` (CPU, gloo collectives, one device per process), the launcher and
the worker's start; `jaxmr fit` as a user runs it (`fit_command`); and the runs of
`generalisation.py` a choice between options reads (`generalisation_runs`).

A benchmark script that supports `--processes N` re-runs itself as N workers
(`--worker K --port P --out FILE`); process 0 saves its figures to FILE (.npz)."""

import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def fit_command(files, out, *options, quiet: bool = True) -> float:
    """`jaxmr fit --out OUT [options] FILES` (default: auto) in a fresh process, its
    output shown unless `quiet`; its wall time [s]."""
    start = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, jaxmr._cli; sys.exit(jaxmr._cli.main())",
            "fit",
            "--out",
            str(out),
            *options,
            *map(str, files),
        ],
        check=True,
        stdout=subprocess.DEVNULL if quiet else None,
    )
    return time.perf_counter() - start


# The settings of the generalisation headline (and of every choice scored on it).
GENERALISATION_RUN = ("--small", "--no-cv", "--max-steps", "100")


def generalisation_runs(datasets, options: dict, quick: bool = False) -> None:
    """`generalisation.py` on each of `datasets` under each option, one process
    each: `options` maps a folder to the option's extra arguments, and each run
    writes `folder/<dataset>.json` (`quick`: generalisation.py's `--quick`)."""
    script = Path(__file__).resolve().parent / "generalisation.py"
    common = ("--quick", "--no-cv") if quick else GENERALISATION_RUN
    for name in datasets:
        for folder, extra in options.items():
            folder.mkdir(parents=True, exist_ok=True)
            command = [sys.executable, str(script), *common, *extra]
            command += ["--datasets", name, "--json", str(folder / f"{name}.json")]
            subprocess.run(command, check=True)


def option_rule(rows, old: str, new: str, timed=None, suffix: str = "") -> dict:
    """The figures of a choice rule between two options (saturation_choice_rule.md,
    screening_folds_rule.md): each option's worst and median regret over `rows`
    (`<label>_regret` each), its median wall time over the rows `timed` keeps
    (default all), the time factor new / old, the three criteria (the worst regret
    0.02 lower, the median at most 0.01 higher, the time at most 2x) and
    `adopt_<new>`. `suffix` ends the time figures' keys."""
    timed = timed or (lambda row: True)
    figures = {}
    for label in (old, new):
        regrets = [r[f"{label}_regret"] for r in rows]
        figures[f"{label}_max_regret"] = max(regrets)
        figures[f"{label}_median_regret"] = float(np.median(regrets))
        figures[f"{label}_median_seconds{suffix}"] = float(
            np.median([r[f"{label}_seconds"] for r in rows if timed(r)])
        )
    factor = f"time_factor{suffix}"
    figures[factor] = (
        figures[f"{new}_median_seconds{suffix}"]
        / figures[f"{old}_median_seconds{suffix}"]
    )
    criteria = {
        "max_regret_lower_by_0.02": figures[f"{new}_max_regret"]
        <= figures[f"{old}_max_regret"] - 0.02,
        "median_regret_at_most_0.01_higher": figures[f"{new}_median_regret"]
        <= figures[f"{old}_median_regret"] + 0.01,
        "time_at_most_2x": figures[factor] <= 2.0,
    }
    figures["criteria"] = criteria
    figures[f"adopt_{new}"] = all(criteria.values())
    return figures


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def launch(
    script: str, processes: int, arguments: list[str], out, host_devices: int = 1
) -> dict:
    """Run `script` as `processes` workers (fresh processes: each pays its own
    compilation), each with `host_devices` CPU devices, and return what process 0
    saved."""
    import numpy as np

    port = str(free_port())
    import jaxmr

    # Each worker as users are advised to run (each simulation loop one kernel),
    # with `host_devices` CPU devices.
    jaxmr.devices.configure_cpu(devices=1)
    env = dict(os.environ)
    env["XLA_FLAGS"] = re.sub(
        r"--xla_force_host_platform_device_count=\d+", "", env.get("XLA_FLAGS", "")
    )
    if host_devices > 1:
        env["XLA_FLAGS"] += f" --xla_force_host_platform_device_count={host_devices}"
    workers = [
        subprocess.Popen(
            [
                sys.executable,
                script,
                *arguments,
                "--worker",
                str(k),
                "--processes",
                str(processes),
                "--port",
                port,
                "--out",
                str(out),
            ],
            env=env,
        )  # fmt: skip
        for k in range(processes)
    ]
    codes = [w.wait() for w in workers]
    if any(codes):
        raise RuntimeError(f"a worker of the {processes}-process run failed: {codes}")
    return dict(np.load(out))


def initialize(processes: int, worker: int, port) -> None:
    """The worker's start: float64, and `jax.distributed` when there are several."""
    import jax

    jax.config.update("jax_enable_x64", True)
    if processes > 1:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(
            coordinator_address=f"localhost:{port}",
            num_processes=processes,
            process_id=worker,
        )
