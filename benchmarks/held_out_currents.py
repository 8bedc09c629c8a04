"""`jaxmr fit` with its defaults on the UTFSM damper's 0, 0.5 and 1 A tests, scored on
the 0.25 and 0.75 A tests it never saw (issue 25: "on the 30 UTFSM files the chosen
model's median NRMSE stays ≤ 0.07 and it beats the published model on its own
held-out currents").

The 30 sine tests (5 amplitude/frequency pairs × 6 currents) are written as canonical
CSV files (`jaxmr.data.convert_dataset`, which records each file's discarded first
cycle and force smoothing), and `jaxmr fit` (default `--model auto`, every other
option at its default) runs in a fresh process on the 18 files at 0, 0.5 and 1 A.
Its model is then scored on all 30 files and on the 12 held-out ones (0.25 and
0.75 A: currents between the fitted ones), each file's NRMSE after its discarded first
cycle, with the force smoothed like the data, against the published UTFSM Spencer
model (`jaxmr.utfsm_spencer`, fitted by its authors to all 30).

Figures: `held_out_median_nrmse` (goal: below `published_held_out_median_nrmse`),
`all_30_median_nrmse` (goal ≤ 0.07), `held_out_better_than_published` (files),
`choice`, `seconds` (the whole command, compilation included).

    python benchmarks/held_out_currents.py --json benchmarks/results/held_out_currents.json

Takes about 5–10 minutes on an idle 2-core machine. The held-out currents were looked
at while the defaults were developed (the UTFSM files are in the leave-one-dataset-out
table of generalisation.py, as a subset): this checks a goal, it is not an unseen-data
score; the unseen-data evidence is generalisation.py's left-out datasets.
"""

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from _processes import fit_command
from _report import write_figures

import jaxmr
import jaxmr.data as jd

ROOT = Path(__file__).resolve().parents[1]
UTFSM = ROOT.parent / "shared" / "data" / "utfsm_mr_damper" / "sine"
TRAIN_CURRENTS = (0.0, 0.5, 1.0)  # A
HELD_OUT_CURRENTS = (0.25, 0.75)  # A


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()
    experiments = jd.load_utfsm(UTFSM)
    levels = [jd.utfsm_test_conditions(e).current for e in experiments]
    discard = jd.utfsm_first_cycle(experiments)
    smoothing = jd.utfsm_smoothing(experiments)
    with tempfile.TemporaryDirectory() as folder:
        files = jd.convert_dataset("utfsm", UTFSM, Path(folder) / "csv")
        by_name = {Path(f).stem: f for f in files}
        train_files = [
            by_name[e.name]
            for e, level in zip(experiments, levels)
            if level in TRAIN_CURRENTS
        ]
        out = Path(folder) / "fit.json"
        seconds = fit_command(train_files, out, quiet=False)
        model = jaxmr.load_model(out)
        report = json.loads(out.read_text())["report"]
    fitted = np.asarray(
        jaxmr.record_nrmse(model, experiments, discard=discard, smoothing=smoothing)
    )
    published = np.asarray(
        jaxmr.record_nrmse(
            jaxmr.utfsm_spencer(), experiments, discard=discard, smoothing=smoothing
        )
    )
    held = np.array([level in HELD_OUT_CURRENTS for level in levels])
    figures = {
        "choice": report.get("template"),
        "seconds": seconds,
        "train_files": len(train_files),
        "held_out_files": int(held.sum()),
        "held_out_median_nrmse": float(np.median(fitted[held])),
        "published_held_out_median_nrmse": float(np.median(published[held])),
        "held_out_better_than_published": int(np.sum(fitted[held] < published[held])),
        "all_30_median_nrmse": float(np.median(fitted)),
        "published_all_30_median_nrmse": float(np.median(published)),
        "per_file": {
            e.name: {"current": level, "fitted": float(f), "published": float(p)}
            for e, level, f, p in zip(experiments, levels, fitted, published)
        },
        "ranking": report.get("selection", {}).get("ranking"),
    }
    figures["goals"] = {
        "all_30_median_nrmse <= 0.07": figures["all_30_median_nrmse"] <= 0.07,
        "held_out beats published": figures["held_out_median_nrmse"]
        < figures["published_held_out_median_nrmse"],
    }
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
