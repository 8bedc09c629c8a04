"""Is D-optimality the right default for `jaxmr.design_experiments`? (issue 28)

`experiment_design.py` headlines the default criterion's plan on the UTFSM damper,
where the I-optimal plan predicted the held-out tests better (session 7). Switching the
default on that evidence would choose it on the set the headline reports. This
benchmark asks the question on other dampers: every simulated preset of
`generalisation.py` (`_generalisation_data.SIMULATED`: Spencer 1997, the passenger-car
damper, the review's damper, the UTFSM Spencer model and the SAS brake's Dahl model).

For each preset:

- **The menu.** Sine tests at 3 amplitudes × 3 frequencies (the preset's own sine
  tests in `_generalisation_data`) × its 5 input levels. There are 45 tests of 2.5
  cycles at 100 samples per cycle of the fastest frequency. Each is simulated from
  the preset itself with the adaptive solver.
- **The prior the design sees.** The family's template (`MODEL_TEMPLATES`, the lag
  variant's plain family: the inputs are constant) at the menu's noise-free data
  scales. This is what a user has before any test: no fitted model.
- **The plans.** K = 4 tests chosen by D-optimality (the default) and by
  I-optimality, both with `fit`'s NRMSE weighting; and `RANDOM_PLANS` random plans
  of 4 (`PLAN_SEED`).
- **The score.** Each plan's tests get noise as in `generalisation.py`: 2 % white
  plus 3 % AR(1) of φ = 0.95, relative to each test's force spread. One draw per
  noise seed (`NOISE_SEEDS`). The template is fitted from the prior, with the first
  cycle discarded. It is scored on the menu's other 41 tests: the median NRMSE
  against the noise-free force, first cycle discarded, averaged over the seeds.

Figures: per preset, `D`, `I` and the random plans' median. At the top level:

- `i_over_d_geomean`: the geometric mean over the presets of I's score over D's.
  Below 1, I predicted better.
- `d_over_random_geomean` and `i_over_d_max`.
- `i_over_d_geomean_seed_medians`: the same ratio with each plan scored by its median
  over the seeds instead of the mean (one failed fit moves a mean, not a median).
- `rule_switches_to_i`: the rule, fixed before the run with these seeds (session 17).
  It is true when I beats D on both statistics: `i_over_d_geomean` below 0.95 and
  `i_over_d_geomean_seed_medians` below 1.

History, so that the seeds here are read as fresh. A first look with noise seeds 101
and 202 (session 16, not kept) gave a geometric mean of 1.03. A run with seeds 303,
404 and 505 gave 0.894 by the mean and 1.16 by the median: one stalled D fit (the
review's damper, seed 303) decided the mean, and the rule of that run (the mean alone
below 0.95) was not acted on. The ten seeds here were drawn after it, and the rule
above, which asks both statistics, was fixed before they ran.

    python benchmarks/design_criterion_choice.py --json benchmarks/results/design_criterion_choice.json
    python benchmarks/design_criterion_choice.py --starts 4 --json benchmarks/results/design_criterion_choice_starts4.json
    python benchmarks/design_criterion_choice.py --json /tmp/dcc.json --quick   # smoke test

`--starts 4` fits every plan from 4 starts instead of `fit`'s default one (a check,
added after the ten-seed run: the rule is about the default fit).
"""

import argparse
import time
from pathlib import Path

import jaxmr
import jaxmr.devices

# As `jaxmr fit` does: every CPU core an XLA device (up to 8).
jaxmr.devices.configure_cpu()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import _generalisation_data as gd  # noqa: E402
import numpy as np  # noqa: E402
from _report import write_figures  # noqa: E402

import jaxmr.data as jd  # noqa: E402
from jaxmr.templates import MODEL_TEMPLATES  # noqa: E402

# Every setting, frozen before the run.
K = 4
RANDOM_PLANS = 5
PLAN_SEED = 7
NOISE_SEEDS = tuple(range(1201, 1211))
MAX_STEPS = 60
SAMPLES_PER_CYCLE = 100
CYCLES = 2.5
# I replaces D as the default only where it predicts at least 5 % better over the
# presets (geometric mean of the seeds' means: a smaller gap is within the seeds'
# scatter) and is also better by the seeds' medians (so that no single failed fit
# decides).
SWITCH_BELOW = 0.95
SWITCH_BELOW_MEDIANS = 1.0
# Spencer 1997 and the review's damper take a command voltage.
VOLTAGE = ("spencer_1997", "review_quarter_car_damper")


def _with_force(e, force):
    return jd.Experiment(
        e.t, e.x, e.v, e.current, force, name=e.name, rotary=e.rotary, drive=e.drive
    )


def preset_scores(preset, noise_seeds, random_plans, starts=None) -> dict:
    started = time.perf_counter()
    device = getattr(jaxmr, preset.name)()
    drive = "voltage" if preset.name in VOLTAGE else "current"
    amplitudes = sorted({a for a, _ in preset.train_sines} | {preset.test_sine[0]})
    frequencies = sorted({f for _, f in preset.train_sines} | {preset.test_sine[1]})
    menu = jaxmr.sine_grid(
        amplitudes,
        frequencies,
        preset.levels,
        cycles=CYCLES,
        sample_rate=SAMPLES_PER_CYCLE * max(frequencies),
        rotary=preset.rotary,
        drive=drive,
    )
    # `sine_grid`'s order: amplitude, then frequency, then input level.
    conditions = [
        (a, f, i) for a in amplitudes for f in frequencies for i in preset.levels
    ]
    clean = [
        np.asarray(jaxmr.simulate(device, jaxmr.Sine(a, f), float(i), e.t).force)
        for (a, f, i), e in zip(conditions, menu, strict=True)
    ]
    if not all(np.all(np.isfinite(c)) for c in clean):
        raise RuntimeError(f"{preset.name}: a menu test's simulation diverged")
    truth = [_with_force(e, c) for e, c in zip(menu, clean, strict=True)]
    period = [1.0 / f for _, f, _ in conditions]
    family = preset.family.removesuffix("_lag")
    prior = MODEL_TEMPLATES[family](truth)
    plans = {
        criterion: [
            int(k)
            for k in jaxmr.design_experiments(
                prior, menu, K, criterion=criterion
            ).indices
        ]
        for criterion in ("D", "I")
    }
    rng = np.random.default_rng(PLAN_SEED)
    for r in range(random_plans):
        plans[f"random {r}"] = sorted(
            int(k) for k in rng.choice(len(menu), K, replace=False)
        )
    scores = {}
    for name, plan in plans.items():
        per_seed = []
        for seed in noise_seeds:
            noise = np.random.default_rng(seed)
            data = [_with_force(menu[k], gd._noisy(noise, clean[k])) for k in plan]
            fit = jaxmr.fit(
                prior,
                data,
                discard=[period[k] for k in plan],
                max_steps=MAX_STEPS,
                statistics_refinement=1,
                progress=False,
                starts=starts,
            )
            rest = [k for k in range(len(menu)) if k not in plan]
            nrmse = jaxmr.record_nrmse(
                fit.model, [truth[k] for k in rest], discard=[period[k] for k in rest]
            )
            per_seed.append(float(np.median(nrmse)))
        scores[name] = {
            "plan": [menu[k].name for k in plan],
            "median_nrmse_per_seed": per_seed,
            "median_nrmse": float(np.mean(per_seed)),
        }
        print(
            f"{preset.name:28s} {name:9s} {scores[name]['median_nrmse']:.4f}",
            flush=True,
        )
    random_scores = [
        v["median_nrmse"] for k, v in scores.items() if k.startswith("random")
    ]
    return {
        "family": family,
        "menu": len(menu),
        "D": scores["D"]["median_nrmse"],
        "I": scores["I"]["median_nrmse"],
        "D_median_over_seeds": float(np.median(scores["D"]["median_nrmse_per_seed"])),
        "I_median_over_seeds": float(np.median(scores["I"]["median_nrmse_per_seed"])),
        "random_median": float(np.median(random_scores)),
        "plans": scores,
        "seconds": time.perf_counter() - started,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a smoke run: two presets, one noise seed, two random plans",
    )
    parser.add_argument(
        "--starts",
        type=int,
        default=None,
        help="fit every plan from this many starts (default: one, `fit`'s default, "
        "which the rule is about); a check of how much stalled fits decide",
    )
    args = parser.parse_args()
    presets = gd.SIMULATED[-2:] if args.quick else gd.SIMULATED
    seeds = NOISE_SEEDS[:1] if args.quick else NOISE_SEEDS
    random_plans = 2 if args.quick else RANDOM_PLANS
    started = time.perf_counter()
    per_preset = {
        p.name: preset_scores(p, seeds, random_plans, args.starts) for p in presets
    }
    i_over_d = {n: v["I"] / v["D"] for n, v in per_preset.items()}
    d_over_random = {n: v["D"] / v["random_median"] for n, v in per_preset.items()}
    geomean = lambda xs: float(np.exp(np.mean(np.log(list(xs)))))
    by_medians = geomean(
        v["I_median_over_seeds"] / v["D_median_over_seeds"] for v in per_preset.values()
    )
    figures = {
        "quick": args.quick,
        "starts": args.starts or 1,
        "k": K,
        "noise_seeds": list(seeds),
        "plan_seed": PLAN_SEED,
        "random_plans": random_plans,
        "i_over_d_geomean": geomean(i_over_d.values()),
        "i_over_d_max": max(i_over_d.values()),
        "i_over_d_min": min(i_over_d.values()),
        "i_over_d": i_over_d,
        "d_over_random_geomean": geomean(d_over_random.values()),
        "d_over_random": d_over_random,
        "switch_below": SWITCH_BELOW,
        "switch_below_medians": SWITCH_BELOW_MEDIANS,
        "i_over_d_geomean_seed_medians": by_medians,
        "rule_switches_to_i": geomean(i_over_d.values()) < SWITCH_BELOW
        and by_medians < SWITCH_BELOW_MEDIANS,
        "presets": per_preset,
        "seconds": time.perf_counter() - started,
    }
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
