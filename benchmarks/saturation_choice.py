"""Should `jaxmr fit --model auto` try saturating current laws? The rule of
`saturation_choice_rule.md` (written before the runs), applied to the runs of
`generalisation.py` on its 16 choice datasets (issue 25, item 1).

Each dataset was run twice, each in a process of its own:

    python benchmarks/generalisation.py --small --no-cv --max-steps 100 \
        --auto-candidates today --datasets D --json TODAY/D.json
    python benchmarks/generalisation.py --small --no-cv --max-steps 100 \
        --auto-only --auto-candidates saturating --datasets D --json SAT/D.json

(the first also fits every plain candidate, the yardstick: every family, lag and
saturating variant), for D in `_generalisation_data.dataset_names(CHOICE_DRAWS)`.
Without `--today` and `--saturating` this script runs them itself, one after the
other in a temporary folder (about 1.5 hours on 2 idle cores; `--quick`: one dataset
with generalisation.py's `--quick`), then writes the rule's figures; with them it
reads the two folders of an earlier run:

    python benchmarks/saturation_choice.py --json benchmarks/results/saturation_choice.json
    python benchmarks/saturation_choice.py --today TODAY --saturating SAT \
        --json benchmarks/results/saturation_choice.json

The figures of results/saturation_choice.json are from the second form: session 29's
runs, two processes at a time for most of them (see `--alone`).

`--alone` names the datasets whose wall times were measured under unequal load (the
rule's addendum), left out of criterion 3.
"""

import argparse
import json
import tempfile
from pathlib import Path

from _processes import generalisation_runs, option_rule
from _report import write_figures


def _auto(path: Path, name: str) -> dict:
    return json.loads(path.read_text())["datasets"][name]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--today", type=Path, help="the `today` runs' folder")
    parser.add_argument("--saturating", type=Path, help="the `saturating` runs'")
    parser.add_argument("--alone", default="", help="comma-separated dataset names")
    parser.add_argument("--quick", action="store_true", help="a smoke run")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    alone = set(filter(None, args.alone.split(",")))
    if (args.today is None) != (args.saturating is None):
        parser.error("give both --today and --saturating, or neither (to run them)")
    if args.today is None:
        import _generalisation_data as gd

        names = (
            ["sim_sas_brake_dahl"] if args.quick else gd.dataset_names(gd.CHOICE_DRAWS)
        )
        folder = Path(tempfile.mkdtemp(prefix="saturation_choice_"))
        args.today, args.saturating = folder / "today", folder / "saturating"
        generalisation_runs(
            names,
            {
                args.today: ("--auto-candidates", "today"),
                args.saturating: ("--auto-only", "--auto-candidates", "saturating"),
            },
            args.quick,
        )
    table = {}
    for path in sorted(args.today.glob("*.json")):
        name = path.stem
        today = _auto(path, name)
        saturating = _auto(args.saturating / path.name, name)["auto"]
        best = today["best_held_out_median_nrmse"]
        table[name] = {
            "best": today["best"],
            "best_held_out": best,
            "plain": {c: p["held_out_median_nrmse"] for c, p in today["plain"].items()},
            **{
                f"{label}_{key}": value
                for label, auto in (
                    ("today", today["auto"]),
                    ("saturating", saturating),
                )
                for key, value in (
                    ("choice", auto["choice"]),
                    ("held_out", auto["held_out_median_nrmse"]),
                    ("regret", auto["held_out_median_nrmse"] / best - 1),
                    ("seconds", auto["seconds"]),
                )
            },
            "equal_load": name not in alone,
        }
    rows = list(table.values())
    figures = {"datasets": table, "num_datasets": len(rows)}
    figures.update(
        option_rule(
            rows,
            "today",
            "saturating",
            timed=lambda r: r["equal_load"],
            suffix="_equal_load",
        )
    )
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
