"""Every benchmark with a headline figure, one after another, then the README's tables.

    python benchmarks/run_all.py                      # all (about an hour, 2 idle cores)
    python benchmarks/run_all.py --only simulate_sweep,calibration
    python benchmarks/run_all.py --quick              # smoke runs, to results/quick/
    python benchmarks/run_all.py --list               # the commands, run nothing

Each benchmark runs as its own process (`python benchmarks/SCRIPT ... --json
results/NAME.json`), one at a time: a speed figure is only worth something on an idle
machine, so nothing else of this command runs beside it. Its output goes to
`results/logs/NAME.log`; its figures to a temporary file that replaces
`results/NAME.json` only when it succeeds (a failed run leaves the last good figures
in place). Every result file gets the machine described (`_report.machine`: CPU,
cores, load average before and after, versions, date, commit) where the script did not
write it itself. A failing benchmark is reported and the others still run; the command
then exits 1. Last, `benchmarks/README.md`'s tables are rewritten from
`results/*.json` (`_tables.py`).

`--quick` gives each script `--quick` where it has that flag and otherwise a small run
of its own options (`Benchmark.quick`), writes to `results/quick/` (never over the
real figures) and leaves the README alone: its tables go to `results/quick/tables.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from importlib.util import find_spec
from pathlib import Path

import _tables
from _report import with_machine

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent  # the commands run here, as the README writes them
BOUCWEN = "../shared/data/boucwen_benchmark"  # the project's data, beside the checkout


@dataclass(frozen=True)
class Benchmark:
    """`script` run with `args` and `--json`; `{results}` in an argument is the
    results folder. `quick`: the arguments of a smoke run where the script has no
    `--quick`. `requires`: modules it needs that jaxmr does not (absent: skipped).
    `accelerator`: it measures an accelerator against the CPU, so it is skipped where
    JAX sees none (its CPU-only figures would say nothing and replace the real ones)."""

    name: str
    script: str
    args: tuple[str, ...] = ()
    quick: tuple[str, ...] = ()
    requires: tuple[str, ...] = ()
    accelerator: bool = False

    def has_quick_flag(self) -> bool:
        """Whether the script defines `--quick` (read from its argument parser)."""
        source = (HERE / self.script).read_text()
        return re.search(r"add_argument\(\s*[\"']--quick[\"']", source) is not None

    def command(self, results: Path, quick: bool) -> list[str]:
        folder = os.path.relpath(results, ROOT)
        args = [a.format(results=folder) for a in self.args]
        if quick:
            args += ["--quick"] if self.has_quick_flag() else list(self.quick)
        return [sys.executable, f"benchmarks/{self.script}", *args]


# In the README's order. The full runs' arguments are the README's commands.
BENCHMARKS = (
    Benchmark("simulate_sweep", "simulate_sweep.py", requires=("numba", "scipy")),
    Benchmark(
        "identify_speed", "identify_speed.py", quick=("--sections", "layouts,boucwen")
    ),
    Benchmark("cpu_flags", "cpu_flags.py"),
    Benchmark(
        "fit_vs_scipy",
        "fit_vs_scipy.py",
        quick=("--samples-per-cycle", "100", "--max-nfev", "40"),
        requires=("scipy",),
    ),
    *(
        Benchmark(
            f"boucwen_{kind}",
            "boucwen_benchmark.py",
            (
                "--train",
                f"{BOUCWEN}/train.h5",
                "--test-input",
                f"{BOUCWEN}/uval_{kind}.mat",
                "--out",
                f"{{results}}/boucwen_{kind}.npy",
            ),
            quick=("--periods", "1", "--substeps", "10", "--max-nfev", "40"),
            requires=("scipy",),
        )
        for kind in ("multisine", "sinesweep")
    ),
    Benchmark("quarter_car_control", "quarter_car_control.py"),
    Benchmark("sas_rig", "sas_rig.py"),
    Benchmark(
        "closed_loop",
        "closed_loop_kernel.py",
        quick=("--duration", "1", "--roads", "2", "--repeats", "1"),
    ),
    Benchmark("opensees_check", "opensees_check.py", requires=("openseespy",)),
    Benchmark("gpu_throughput", "gpu_throughput.py", accelerator=True),
    Benchmark("experiment_design", "experiment_design.py"),
    Benchmark("design_criterion_choice", "design_criterion_choice.py"),
    Benchmark(
        "design_criterion_choice_starts4",
        "design_criterion_choice.py",
        args=("--starts", "4"),
    ),
    Benchmark("realistic_control", "realistic_control.py"),
    Benchmark("export_c", "export_c.py"),
    Benchmark("held_out_currents", "held_out_currents.py"),
    Benchmark("saturation_choice", "saturation_choice.py"),
    Benchmark("screening_folds_choice", "screening_folds_choice.py"),
    Benchmark("screening_choice", "screening_choice.py"),
    Benchmark(
        "starts_choice", "starts_choice.py", quick=("--datasets", "sim_sas_brake_dahl")
    ),
    Benchmark("trust_region_choice", "trust_region_choice.py"),
    Benchmark(
        "fold_choice",
        "fold_choice.py",
        ("--baseline", "b2c039a"),
        quick=("--datasets", "sim_spencer_1997"),
    ),
    Benchmark(
        "fit_each_scaling",
        "fit_each_scaling.py",
        ("--processes", "2"),
        quick=("--records", "16"),
    ),
    Benchmark(
        "calibration",
        "calibration.py",
        # The headline's set-up: the fresh seeds, 100 refits per case.
        ("--fresh", "--refits", "100"),
        quick=("--refits", "3", "--cases", "equal_white"),
    ),
    # The headline's set-up: one process per dataset (`--separate`).
    Benchmark(
        "generalisation",
        "generalisation.py",
        ("--small", "--no-cv", "--max-steps", "100", "--separate"),
    ),
)


def _describe(path: Path, load_at_start, started: float, command: list[str]) -> None:
    """Give the result file a machine block where its script wrote none of its own
    (`_report.write_figures` writes one; scripts that write their JSON themselves do
    not)."""
    figures = json.loads(path.read_text())
    if not isinstance(figures, dict):
        figures = {"figures": figures}
    machine = figures.get("machine")
    if isinstance(machine, dict) and "cpu" in machine:
        described = figures | {"machine": machine | {"command": command}}
    else:
        described = with_machine(
            figures,
            load_average_at_start=load_at_start,
            started=started,
            command=command,
        )
    path.write_text(json.dumps(described, indent=2))


def _tail(path: Path, lines: int = 15) -> str:
    return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])


def _default_backend() -> str:
    """JAX's default backend ("cpu", "gpu", ...), asked of a fresh process so that this
    one starts no backend of its own."""
    command = [sys.executable, "-c", "import jax; print(jax.default_backend())"]
    found = subprocess.run(command, capture_output=True, text=True, check=True)
    return found.stdout.strip()


def run(benchmark: Benchmark, results: Path, quick: bool, prefix: str) -> str:
    """Run one benchmark; 'ok', 'failed' or 'skipped (why)'."""
    missing = [m for m in benchmark.requires if find_spec(m) is None]
    backend = _default_backend() if benchmark.accelerator and not missing else None
    if missing or backend == "cpu":
        why = (
            f"skipped ({', '.join(missing)} not installed)"
            if missing
            else "skipped (no accelerator: JAX sees only the CPU)"
        )
        print(f"{prefix} {benchmark.name}: {why}", flush=True)
        return why
    target = results / f"{benchmark.name}.json"
    partial = results / f"{benchmark.name}.json.part"  # not *.json: never committed
    log = results / "logs" / f"{benchmark.name}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    partial.unlink(missing_ok=True)
    command = benchmark.command(results, quick)
    command += ["--json", os.path.relpath(partial, ROOT)]
    load = os.getloadavg()
    busy = " (machine busy: timings unreliable)" if load[0] > 0.5 else ""
    print(
        f"{prefix} {benchmark.name}: load average {load[0]:.2f}{busy}\n"
        f"    {' '.join(command)}\n    log: {log}",
        flush=True,
    )
    started = time.time()
    with log.open("w") as out:
        code = subprocess.call(command, stdout=out, stderr=subprocess.STDOUT, cwd=ROOT)
    seconds = time.time() - started
    if code != 0 or not partial.exists():
        why = f"exit {code}" if code != 0 else "no JSON written"
        print(f"{prefix} {benchmark.name}: FAILED ({why}) after {seconds:.0f} s; log:")
        print("    " + _tail(log).replace("\n", "\n    "), flush=True)
        partial.unlink(missing_ok=True)
        return "failed"
    shown = ["python", *command[1:-1], os.path.relpath(target, ROOT)]
    _describe(partial, load, started, shown)
    partial.replace(target)
    print(f"{prefix} {benchmark.name}: ok in {seconds:.0f} s -> {target}", flush=True)
    return "ok"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--only",
        help="comma-separated names (default: all): "
        + ", ".join(b.name for b in BENCHMARKS),
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke runs, to results/quick/"
    )
    parser.add_argument(
        "--results",
        type=Path,
        help="the results folder (default: results/, results/quick/ with --quick)",
    )
    parser.add_argument(
        "--list", action="store_true", help="print the commands, run nothing"
    )
    parser.add_argument(
        "--no-tables", action="store_true", help="leave the README's tables alone"
    )
    args = parser.parse_args(argv)
    chosen = list(BENCHMARKS)
    if args.only:
        names = [n.strip() for n in args.only.split(",") if n.strip()]
        known = {b.name for b in BENCHMARKS}
        unknown = [n for n in names if n not in known]
        if unknown:
            parser.error(f"unknown benchmark(s) {unknown}; known: {sorted(known)}")
        chosen = [b for b in BENCHMARKS if b.name in names]
    results = args.results or (
        _tables.RESULTS / "quick" if args.quick else _tables.RESULTS
    )
    if args.list:
        for b in chosen:
            json_path = os.path.relpath(results / f"{b.name}.json", ROOT)
            print(" ".join(["python", *b.command(results, args.quick)[1:]]), end="")
            print(f" --json {json_path}")
        return 0
    results.mkdir(parents=True, exist_ok=True)
    start = time.time()
    outcome = {}
    for i, benchmark in enumerate(chosen, 1):
        outcome[benchmark.name] = run(
            benchmark, results, args.quick, f"[{i}/{len(chosen)}]"
        )
    print(f"\n{len(chosen)} benchmark(s) in {(time.time() - start) / 60:.1f} min:")
    for name, result in outcome.items():
        print(f"  {name}: {result}")
    if args.no_tables:
        pass
    elif args.quick or results != _tables.RESULTS:
        # Smoke figures never reach the README: their tables go beside them.
        tables = results / "tables.md"
        tables.write_text(
            f"# Figures of {results} (smoke runs: not measurements)\n\n"
            + "\n\n".join(
                f"## {name}\n\n{body}" for name, body in _tables.blocks(results).items()
            )
            + "\n"
        )
        print(f"tables of these figures: {tables}")
    else:
        _tables.main(["--results", str(results)])
    failed = [name for name, result in outcome.items() if result == "failed"]
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
