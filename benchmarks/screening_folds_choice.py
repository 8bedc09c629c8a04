"""Should `jaxmr fit --model auto` screen its candidates on every cross-validation
fold, or on the first alone? The rule of `screening_folds_rule.md` (written before
the runs), applied to runs of `generalisation.py` on its 16 choice datasets (issue 25,
item 1).

Each dataset is run under both options, each in a process of its own:

    python benchmarks/generalisation.py --small --no-cv --max-steps 100 \
        --screen-folds first --datasets D --json FIRST/D.json
    python benchmarks/generalisation.py --small --no-cv --max-steps 100 \
        --auto-only --screen-folds every --datasets D --json EVERY/D.json

(the first also fits every plain candidate, the yardstick: every family, lag and
saturating variant), for D in `DATASETS`. Without `--first` and `--every` this script
runs them itself, one after the other in a temporary folder (about 2.5 hours on 2
idle cores; `--quick`: one dataset with generalisation.py's `--quick`), then writes
the rule's figures; with them it reads earlier runs (files or folders of
`generalisation.py` JSON, merged by dataset; `--yardstick` where the plain fits are
in other files than `--first`'s):

    python benchmarks/screening_folds_choice.py --json results/screening_folds_choice.json
    python benchmarks/screening_folds_choice.py --first F... --yardstick Y... \
        --every E --json benchmarks/results/screening_folds_choice.json

The figures of results/screening_folds_choice.json are from the second form: `first`
from session 29's runs (the same code and defaults: the rule's check that today's
`cv_folds` gives each dataset the folds those runs record held on all 16), `every`
from session 30's, two processes at a time.
"""

import argparse
import json
import tempfile
from pathlib import Path

from _processes import generalisation_runs, option_rule
from _report import write_figures

# The rule (screening_folds_rule.md; its thresholds: _processes.option_rule).
PRESETS = (
    "sim_spencer_1997",
    "sim_passenger_car_mr_damper",
    "sim_review_quarter_car_damper",
    "sim_utfsm_spencer",
    "sim_sas_brake_dahl",
    "sim_review_quarter_car_damper_saturating",
    "sim_spencer_1997_saturating",
)
DRAWS = (2, 4)
DATASETS = ("utfsm", "nees", *(f"{p}@{d}" for d in DRAWS for p in PRESETS))


def _datasets(paths) -> dict:
    """Every dataset of the `generalisation.py` JSON files in `paths` (files or
    folders), by name."""
    out = {}
    for path in paths:
        files = sorted(path.glob("*.json")) if path.is_dir() else [path]
        for f in files:
            out.update(json.loads(f.read_text())["datasets"])
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--first", type=Path, nargs="+", help="the `first` runs")
    parser.add_argument("--every", type=Path, nargs="+", help="the `every` runs")
    parser.add_argument(
        "--yardstick", type=Path, nargs="+", help="the plain fits (default: --first)"
    )
    parser.add_argument("--quick", action="store_true", help="a smoke run")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if (args.first is None) != (args.every is None):
        parser.error("give both --first and --every, or neither (to run them)")
    names = DATASETS
    if args.first is None:
        names = ("sim_sas_brake_dahl",) if args.quick else DATASETS
        folder = Path(tempfile.mkdtemp(prefix="screening_folds_choice_"))
        first, every = folder / "first", folder / "every"
        generalisation_runs(
            names,
            {
                first: ("--screen-folds", "first"),
                every: ("--auto-only", "--screen-folds", "every"),
            },
            args.quick,
        )
        args.first, args.every = [first], [every]
    first, every = _datasets(args.first), _datasets(args.every)
    yardstick = _datasets(args.yardstick) if args.yardstick else first
    table = {}
    for name in names:
        plain = yardstick[name]
        best = plain["best_held_out_median_nrmse"]
        table[name] = {
            "best": plain["best"],
            "best_held_out": best,
            **{
                f"{label}_{key}": value
                for label, auto in (
                    ("first", first[name]["auto"]),
                    ("every", every[name]["auto"]),
                )
                for key, value in (
                    ("choice", auto["choice"]),
                    ("held_out", auto["held_out_median_nrmse"]),
                    ("regret", auto["held_out_median_nrmse"] / best - 1),
                    ("seconds", auto["seconds"]),
                    ("holdout", auto["holdout"]),
                )
            },
        }
        if table[name]["first_holdout"] != table[name]["every_holdout"]:
            raise SystemExit(f"{name}: the two runs have different folds")
    rows = list(table.values())
    figures = {"datasets": table, "num_datasets": len(rows)}
    figures.update(option_rule(rows, "first", "every"))
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
