"""How many starts per fit should `jaxmr fit --model auto` run? (issue 25, items 1
and 3: "several starts", every default chosen by validation across datasets)

A user's trial (session 26) fitted a simulated damper of the UTFSM Spencer family
with a coil lag: auto chose LuGre at a held-out NRMSE of 0.039, while
`--model shear_thinning_spencer --starts 4` reached 0.0010 (one start: 0.053, a poor
minimum from the data-scaled guess). Starts run as one batch, so they cost less than
their number of fits.

For every choice dataset (`_generalisation_data.dataset_names(CHOICE_DRAWS)` minus
the second draw, to keep the run short: the UTFSM tests, the NEES record and draw 1
of the simulated tests of each preset damper; never the fresh draws that score the
headlines), this runs `select_model` as `jaxmr fit --model auto` runs it
(`generalisation.py --small --no-cv --auto-only --max-steps 100`, one process per
dataset and setting) with `STARTS` starts per fit, and records the chosen model, its
held-out median NRMSE and the wall time.

The decision rule, written down before any run: let r_d be a setting's held-out
median NRMSE over that of one start, on dataset d. The smallest setting k > 1 is
adopted as `AUTO_STARTS` when the geometric mean of r_d is at most 0.95, no r_d
exceeds 1.10, and its total wall time is at most twice one start's; where several
settings qualify, the one with the lowest geometric mean, unless a smaller one is
within 0.02 of it. Otherwise one start stays.

    python benchmarks/starts_choice.py --json benchmarks/results/starts_choice.json
    python benchmarks/starts_choice.py --analyse A.json B.json ... --json OUT
"""

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from _report import write_figures

HERE = Path(__file__).parent
STARTS = (1, 4)
DATASETS = (
    "utfsm",
    "nees",
    "sim_spencer_1997",
    "sim_passenger_car_mr_damper",
    "sim_review_quarter_car_damper",
    "sim_utfsm_spencer",
    "sim_sas_brake_dahl",
)
MAX_GEOMEAN = 0.95
MAX_RATIO = 1.10
MAX_TIME_FACTOR = 2.0
TIE = 0.02


def run(datasets, folder: Path) -> list[Path]:
    parts = []
    for name in datasets:
        for k in STARTS:
            part = folder / f"{name}_{k}.json"
            command = [
                sys.executable, str(HERE / "generalisation.py"), "--small", "--no-cv",
                "--auto-only", "--max-steps", "100", "--starts", str(k),
                "--datasets", name, "--json", str(part),
            ]  # fmt: skip
            subprocess.run(command, check=True)
            parts.append(part)
    return parts


def analyse(parts) -> dict:
    table: dict[str, dict[int, dict]] = {}
    for path in parts:
        figures = json.loads(Path(path).read_text())
        for name, result in figures["datasets"].items():
            auto = result["auto"]
            table.setdefault(name, {})[int(auto["starts"])] = {
                "choice": auto["choice"],
                "held_out": auto["held_out_median_nrmse"],
                "seconds": auto["seconds"],
            }
    names = [n for n in table if all(k in table[n] for k in STARTS)]
    summary = {}
    for k in STARTS[1:]:
        ratios = np.array(
            [table[n][k]["held_out"] / table[n][1]["held_out"] for n in names]
        )
        seconds = sum(table[n][k]["seconds"] for n in names)
        base = sum(table[n][1]["seconds"] for n in names)
        geomean = float(np.exp(np.mean(np.log(ratios))))
        summary[k] = {
            "geomean_ratio": geomean,
            "max_ratio": float(ratios.max()),
            "time_factor": seconds / base,
            "qualifies": bool(
                geomean <= MAX_GEOMEAN
                and ratios.max() <= MAX_RATIO
                and seconds <= MAX_TIME_FACTOR * base
            ),
        }
    qualified = [k for k in STARTS[1:] if summary[k]["qualifies"]]
    chosen = 1
    if qualified:
        best = min(qualified, key=lambda k: summary[k]["geomean_ratio"])
        close = [
            k
            for k in qualified
            if summary[k]["geomean_ratio"] <= summary[best]["geomean_ratio"] + TIE
        ]
        chosen = min(close)
    figures = {
        "datasets": names,
        "table": {n: {str(k): v for k, v in table[n].items()} for n in names},
        "chosen_starts": chosen,
    }
    for k, s in summary.items():
        for key, value in s.items():
            figures[f"starts{k}_{key}"] = value
    return figures


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--analyse", type=Path, nargs="+")
    parser.add_argument("--datasets", help="comma-separated (default: DATASETS)")
    args = parser.parse_args()
    if args.analyse:
        figures = analyse(args.analyse)
    else:
        names = args.datasets.split(",") if args.datasets else DATASETS
        with tempfile.TemporaryDirectory() as folder:
            figures = analyse(run(names, Path(folder)))
    for name, row in figures["table"].items():
        cells = "  ".join(
            f"{k} starts: {v['choice']} {v['held_out']:.4f} ({v['seconds']:.0f} s)"
            for k, v in row.items()
        )
        print(f"{name}: {cells}")
    print("chosen starts:", figures["chosen_starts"])
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
