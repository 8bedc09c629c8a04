"""Should `select_model`'s two folds hold out different records? (issue 25, item 1:
selection by cross-validation over several folds, every default chosen by
validation across datasets)

Until session 27 the "records" fold held out every third experiment whatever the
"levels" fold held out, so a record could be held out by both: on the UTFSM training
files `5mm3Hz0x5A`, on two simulated presets `sine_0.005_4Hz_1` and
`sine_0.008_5Hz_0.5`, and in a user's trial (session 26) `rand_0.35A`. Such a record
is counted twice in the pooled held-out errors, and the records fold then tests its
motion only at a level that was never fitted. The change: where the levels fold
holds one out, the next experiment it trains on takes its place (`cv_folds`).

For every choice dataset whose folds the change alters (the UTFSM tests and draw 1
of the simulated Spencer 1997 and passenger-car dampers; the others' folds are the
same bits, so are their choices; never the fresh draws that score the headlines),
this runs `select_model` as `jaxmr fit --model auto` runs it
(`generalisation.py --small --no-cv --auto-only --max-steps 100`, one process per
dataset and tree) twice: with the baseline commit's jaxmr (a `git worktree`, its own
benchmark script) and with this tree's. It records each choice, its held-out median
NRMSE and the wall time.

The decision rule, written down before any run: let r_d be the new folds' held-out
median NRMSE over the baseline's on dataset d. The new folds are kept when the
geometric mean of r_d is at most 1.00 and no r_d exceeds 1.10 (a fold design that
counts no record twice is kept unless it chooses worse); otherwise the baseline's
folds are restored.

    python benchmarks/fold_choice.py --baseline COMMIT --json OUT
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from _report import write_figures

HERE = Path(__file__).parent
ROOT = HERE.parent
DATASETS = ("utfsm", "sim_spencer_1997", "sim_passenger_car_mr_damper")
MAX_GEOMEAN = 1.00
MAX_RATIO = 1.10


def _auto(tree: Path, name: str, out: Path) -> dict:
    command = [
        sys.executable, str(tree / "benchmarks" / "generalisation.py"), "--small",
        "--no-cv", "--auto-only", "--max-steps", "100", "--datasets", name,
        "--json", str(out),
    ]  # fmt: skip
    # The tree's own jaxmr before the installed one (an editable install of this
    # checkout): its benchmark script imports it.
    env = {**os.environ, "PYTHONPATH": str(tree)}
    subprocess.run(command, check=True, cwd=tree, env=env)
    return json.loads(out.read_text())["datasets"][name]["auto"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, help="the commit to compare")
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--datasets", help="comma-separated (default: DATASETS)")
    args = parser.parse_args()
    names = args.datasets.split(",") if args.datasets else DATASETS
    commit = subprocess.run(
        ["git", "rev-parse", args.baseline], cwd=ROOT, check=True,
        capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    table = {}
    with tempfile.TemporaryDirectory() as folder:
        base = Path(folder) / "baseline"
        # The data are read from ../shared beside the checkout.
        (Path(folder) / "shared").symlink_to((ROOT.parent / "shared").resolve())
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(base), commit],
            cwd=ROOT, check=True, capture_output=True,
        )  # fmt: skip
        try:
            for name in names:
                old = _auto(base, name, Path(folder) / f"{name}_old.json")
                new = _auto(ROOT, name, Path(folder) / f"{name}_new.json")
                table[name] = {
                    "baseline": {k: old[k] for k in ("choice", "seconds")}
                    | {"held_out": old["held_out_median_nrmse"]},
                    "new": {k: new[k] for k in ("choice", "seconds")}
                    | {"held_out": new["held_out_median_nrmse"]},
                }
                row = table[name]
                print(
                    f"{name}: baseline {row['baseline']['choice']} "
                    f"{row['baseline']['held_out']:.4f}, new {row['new']['choice']} "
                    f"{row['new']['held_out']:.4f}",
                    flush=True,
                )
        finally:
            subprocess.run(
                ["git", "worktree", "remove", "--force", str(base)], cwd=ROOT,
                check=False,
            )  # fmt: skip
    ratios = np.array(
        [t["new"]["held_out"] / t["baseline"]["held_out"] for t in table.values()]
    )
    geomean = float(np.exp(np.mean(np.log(ratios))))
    keep = bool(geomean <= MAX_GEOMEAN and ratios.max() <= MAX_RATIO)
    figures = {
        "baseline_commit": commit,
        "datasets": list(names),
        "table": table,
        "geomean_ratio": geomean,
        "max_ratio": float(ratios.max()),
        "time_factor": sum(t["new"]["seconds"] for t in table.values())
        / sum(t["baseline"]["seconds"] for t in table.values()),
        "keep_new_folds": keep,
    }
    print(
        f"geomean ratio {geomean:.4f}, max {ratios.max():.4f}: keep new folds: {keep}"
    )
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
