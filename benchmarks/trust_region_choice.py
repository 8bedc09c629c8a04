"""Which first trust region `FastLevenbergMarquardt` starts from (issue 28: on the
Bouc–Wen benchmark jaxmr took 13 steps where MINPACK's lm took 7 Jacobians).

The solver's first damped step has λ = 1/`initial_radius` on columns scaled to unit
norm (`initial_radius` 1 until now). After a step that achieves 75 % of its predicted
reduction the radius grows tenfold, after a rejected one it shrinks fourfold, and a
rejection costs one residual, a tenth to a third of an accepted step (its Jacobian).
A bolder start may save the steps spent relaxing the damping; too bold, it pays a
few rejections.

Chosen on (`CHOICE`): the datasets the selection defaults were chosen on
(`_generalisation_data`: the UTFSM and NEES training records, and draw 1 of every
simulated preset's), each fitted from two templates (its truth's family, or the
family that won there, and one other) with `jaxmr.fit`'s defaults, for every radius
in `RADII`. Per fit: the steps, the steps that lowered the loss (each paid a
Jacobian), the final loss, and the time to the target (the best final loss over the
radii × (1 + 1e-3)), compilation excluded (`_fit_baselines.CompileClock`; each
radius compiles its own program). The rule (`choose`): first safety, the radii
whose worst final loss over the best radius's (over the fits) is within 2 % of the
smallest such (a fit that stops early, or in another local minimum, costs a user far
more than a few steps); among them the smallest geometric mean of time-to-target
over radius 1's, ties (within 2 %) to the smaller radius, the default until now.

Not used in the choice, and so a fresh score of it: the Bouc–Wen benchmark
(`identify_speed.py --sections boucwen`), run after the default was set.

    python benchmarks/trust_region_choice.py --json benchmarks/results/trust_region_choice.json
"""

import argparse
import json
import math
import time
from pathlib import Path

import _generalisation_data as gd
from _fit_baselines import TARGET, CompileClock, LossTrace, timed_figures
from _report import write_figures

import jaxmr
import jaxmr.devices

jaxmr.devices.configure_cpu()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from jaxmr.templates import MODEL_TEMPLATES  # noqa: E402

RADII = (1.0, 10.0, 100.0)
# Each dataset's templates: the family that generated it (simulated) or won there in
# `generalisation.py` (measured), and one other family.
CHOICE = {
    "utfsm": ("shear_thinning_spencer", "lugre"),
    "nees": ("shear_thinning_spencer_lag", "bouc_wen_lag"),
    "sim_passenger_car_mr_damper": ("bouc_wen_lag", "spencer_lag"),
    "sim_review_quarter_car_damper": ("dahl", "spencer"),
    "sim_sas_brake_dahl": ("dahl", "bouc_wen"),
    "sim_spencer_1997": ("spencer_lag", "lugre"),
    "sim_utfsm_spencer": ("shear_thinning_spencer", "bouc_wen"),
}
TIE = 0.02


def one_fit(dataset, template: str, radius: float) -> dict:
    model = MODEL_TEMPLATES[template](dataset.train)
    solver = jaxmr.FastLevenbergMarquardt(initial_radius=radius)
    started = time.time()
    trace = LossTrace(started)
    with CompileClock() as clock:
        result = jaxmr.fit(
            model,
            dataset.train,
            discard=dataset.train_discard,
            smoothing=dataset.train_smoothing,
            solver=solver,
            progress=lambda step, loss: trace.add(loss),
        )
    history = list(result.history)
    improving = sum(1 for a, b in zip([math.inf] + history, history) if b < a)
    return {
        "template": template,
        "radius": radius,
        "steps": int(result.num_steps),
        "improving_steps": improving,
        "loss": float(result.loss),
        "stop": str(result.stop),
        "total_seconds": time.time() - started,
        "trace": trace.points,
        "compile_spans": clock.spans,
        "started": started,
    }


def to_target(fit: dict, target: float) -> dict:
    """The fit's time to `target`, compilation excluded (`timed_figures`)."""
    trace = LossTrace(fit["started"])
    trace.points = fit["trace"]
    clock = CompileClock()
    clock.spans = fit["compile_spans"]
    timed = timed_figures(trace, clock, target, fit["total_seconds"])
    return {
        "reached": timed["reached"],
        "seconds_to_target": timed["seconds_excluding_compile"],
        "compile_seconds": timed["compile_seconds"],
    }


def choose(rows: list[dict]) -> tuple[dict, float]:
    """Per radius: its worst final loss over the best radius's (over the fits), the
    fits that reached the target, the geometric mean and range of its time to the
    target over radius 1's; and the chosen radius (see the module's docstring)."""
    summary = {}
    for r in RADII:
        quality, ratios, reached = [], [], 0
        for row in rows:
            if row["radius"] != r:
                continue
            same = [
                x
                for x in rows
                if x["dataset"] == row["dataset"] and x["template"] == row["template"]
            ]
            base = next(x for x in same if x["radius"] == RADII[0])
            quality.append(row["loss"] / min(x["loss"] for x in same))
            reached += row["reached"]
            ratios.append(row["seconds_to_target"] / base["seconds_to_target"])
        summary[str(r)] = {
            "worst_loss_over_best": max(quality),
            "geomean_loss_over_best": math.exp(
                sum(map(math.log, quality)) / len(quality)
            ),
            "reached": reached,
            "fits": len(ratios),
            "geomean_time_ratio": math.exp(sum(map(math.log, ratios)) / len(ratios)),
            "max_time_ratio": max(ratios),
            "min_time_ratio": min(ratios),
            "steps": sum(x["steps"] for x in rows if x["radius"] == r),
        }
    safest = min(summary[str(r)]["worst_loss_over_best"] for r in RADII)
    eligible = [
        r
        for r in RADII
        if summary[str(r)]["worst_loss_over_best"] <= safest * (1 + TIE)
    ]
    fastest = min(summary[str(r)]["geomean_time_ratio"] for r in eligible)
    chosen = min(
        r
        for r in eligible
        if summary[str(r)]["geomean_time_ratio"] <= fastest * (1 + TIE)
    )
    return summary, chosen


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the figures here")
    parser.add_argument(
        "--datasets", default=",".join(CHOICE), help="comma-separated (default all)"
    )
    parser.add_argument(
        "--analyse", help="only re-run the choice on the fits of this written JSON"
    )
    args = parser.parse_args()
    if args.analyse:
        # The measured run's machine block is kept: it describes the fits.
        figures = json.loads(Path(args.analyse).read_text())
        figures["summary"], figures["chosen_initial_radius"] = choose(figures["fits"])
        text = json.dumps(figures, indent=2)
        print(text)
        if args.json:
            Path(args.json).write_text(text)
        return
    names = args.datasets.split(",")
    rows = []
    for dataset in gd.datasets(names):
        for template in CHOICE[dataset.name]:
            fits = [one_fit(dataset, template, r) for r in RADII]
            target = min(f["loss"] for f in fits) * TARGET
            for f in fits:
                row = {
                    k: v for k, v in f.items() if k not in ("trace", "compile_spans")
                }
                row |= {"dataset": dataset.name, **to_target(f, target)}
                del row["started"]
                rows.append(row)
                print(
                    f"{dataset.name:32s} {template:28s} radius {f['radius']:6g}: "
                    f"{row['steps']:3d} steps ({row['improving_steps']} improving), "
                    f"loss {row['loss']:.6g}, to target "
                    f"{row['seconds_to_target']:.2f} s"
                    + ("" if row["reached"] else " (never)"),
                    flush=True,
                )
    summary, chosen = choose(rows)
    figures = {
        "radii": list(RADII),
        "datasets": names,
        "summary": summary,
        "chosen_initial_radius": chosen,
        "fits": rows,
    }
    print(summary, "chosen", chosen)
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
