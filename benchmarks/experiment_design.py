"""Optimal experiment design (issue 13): what a plan of 6 tests chosen by
`jaxmr.design_experiments` buys, on real data and on a synthetic brake.

UTFSM (the 30 constant-current sine tests as the menu):

- the design sees the candidates' motions and currents only (their forces are
  stripped before it is called), at the published model's values: the structure is
  `ShearThinningSpencer` (the one `jaxmr fit` chooses for this damper, 14 parameters)
  started from the published UTFSM model as in notebook 02. It chooses k = 6,
  I-optimal (`criterion="I"`: the smallest predicted variance of the fitted force
  summed over the menu) with the fit's NRMSE weighting; the D-optimal plan (the
  default criterion) is fitted and scored beside it (`d_optimal_*`);
- the model is fitted to the 6 chosen tests only (their forces), and scored on the
  other 24: `designed_nrmse` is the median NRMSE over those 24 (whole records, first
  cycle discarded, smoothed like the data);
- `all_nrmse`: the same model fitted to all 30 tests, scored on the same 24 (which it
  trained on: a floor, not a held-out figure);
- `random_median_nrmse`: 50 random 6-test plans, each fitted and scored on its own 24
  held-out tests; their median, 10th and 90th percentiles.

Every fit is on the first two cycles of each test (the first cycle left out of the
residual), as in notebook 02, by the engine's own Levenberg–Marquardt loop: the 6-test
problems are padded to one shape so that the loop compiles once for all 51 of them
(`jaxmr.fit` would compile each plan's shape anew, 20 s each).

Synthetic brake (known parameters): the SAS brake's Bouc–Wen model
(`jaxmr.sas_brake_bouc_wen()`, 6 free parameters), a menu of 36 sine tests, a
D-optimal plan of 4 for white torque noise of known σ; the plan's data simulated and
noised with `--seeds` seeds and fitted each time: the realised standard errors (the
spread of the estimates over the seeds) against the predicted ones (goal: within a
factor 1.5).

    python benchmarks/experiment_design.py --json benchmarks/results/experiment_design.json

`--random N` (default 50) and `--seeds N` (default 40) set the sizes; `--quick` (4 and
8) is a smoke test. The full run took 20 minutes on 2 shared cores.
"""

import argparse
import json
import platform
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402

import jaxmr  # noqa: E402
import jaxmr.data as jd  # noqa: E402
from jaxmr._identify.data import pack, pad_to, shape_of  # noqa: E402
from jaxmr._identify.fitting import _scaled_residuals, _split_model  # noqa: E402
from jaxmr._identify.residual import residuals  # noqa: E402
from jaxmr._identify.solver import (  # noqa: E402
    FastLevenbergMarquardt,
    column_scale,
    divide,
    iterate,
    multiply,
)
from jaxmr._parameter import unwrap  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
UTFSM = ROOT.parent / "shared" / "data" / "utfsm_mr_damper" / "sine"
K = 6
P = jaxmr.Positive


def utfsm_start():
    """ShearThinningSpencer from the published UTFSM model (notebook 02's start)."""
    published = jaxmr.utfsm_spencer()
    return jaxmr.ShearThinningSpencer(
        alpha=published.alpha,
        c0=jaxmr.LinearLaw(2.5 * published.c0.a, 2.5 * published.c0.b),
        k0=jaxmr.Fixed(published.k0),
        c1=published.c1,
        k1=published.k1,
        x0=published.x0,
        gamma=jaxmr.ExponentialLaw(P(published.gamma.a), published.gamma.b),
        beta=jaxmr.ExponentialLaw(
            jaxmr.Bounded(published.beta.a, -2e7, 2e7), published.beta.b
        ),
        A=jaxmr.Fixed(published.A),
        n=jaxmr.Fixed(published.n),
        e0=P(30.0),
        e1=jaxmr.Fixed(0.0),
    )


class Fitter:
    """`jaxmr.fit`'s loop (FastLevenbergMarquardt, its stopping rules) on problems
    padded to one shape, so that one compilation serves every plan of one size."""

    def __init__(self, start, windows, discard, smoothing, plans):
        self.start, self.windows = start, windows
        self.discard, self.smoothing = discard, smoothing
        shapes = [shape_of(self.pack(plan)) for plan in plans]
        self.shape = tuple(max(s) for s in zip(*shapes))
        self.common = jax.tree.structure(pad_to(self.pack(plans[0]), self.shape))

    def pack(self, plan):
        plan = np.asarray(plan)
        return pack(
            [self.windows[k] for k in plan],
            discard=self.discard[plan],
            smoothing=self.smoothing[plan],
        )

    def __call__(self, plan):
        free, static = _split_model(self.start)
        padded = pad_to(self.pack(plan), self.shape)
        # The static fields (names, offsets) of one plan for all: the simulation
        # reads none of them but the number of tests, the same in every plan.
        data = jax.tree.unflatten(self.common, jax.tree.leaves(padded))
        scale = column_scale(residuals, free, static, data, None)
        ys = jax.tree.map(lambda a: a[None], free)
        best, outcomes = iterate(
            FastLevenbergMarquardt(),
            divide(ys, scale),
            (_scaled_residuals, static, data, scale),
            None,
            200,
            8,
            1e-4,
            lambda step, loss: None,
        )
        free = jax.tree.map(lambda a: a[0], multiply(best, scale))
        return unwrap(eqx.combine(free, static)), outcomes[0]


def utfsm(random_plans: int, seed: int) -> dict:
    experiments = jd.load_utfsm(UTFSM)
    n = len(experiments)
    discard = jd.utfsm_first_cycle(experiments)
    smoothing = jd.utfsm_smoothing(experiments)
    windows = [
        e.window(None, float(e.t[0]) + 2 * p) for e, p in zip(experiments, discard)
    ]
    # What the design may see: motions and currents, no force.
    menu = [
        jd.Experiment(
            w.t, w.x, w.v, w.current, None, name=w.name, velocity_source="measured"
        )
        for w in windows
    ]
    # I-optimal (prediction over the menu) is the plan scored; D-optimal beside it.
    t0 = time.perf_counter()
    design = jaxmr.design_experiments(
        utfsm_start(), menu, K, discard=discard, smoothing=smoothing, criterion="I"
    )
    design_seconds = time.perf_counter() - t0
    print(design, flush=True)
    plan = list(design.indices)
    d_design = jaxmr.design_experiments(
        utfsm_start(), menu, K, discard=discard, smoothing=smoothing
    )
    d_plan = list(d_design.indices)

    rng = np.random.default_rng(seed)
    plans = []
    while len(plans) < random_plans:
        candidate = sorted(rng.choice(n, K, replace=False).tolist())
        if candidate not in plans:
            plans.append(candidate)

    def score(model):
        return jaxmr.record_nrmse(
            model, experiments, discard=discard, smoothing=smoothing
        )

    def held_out(plan):
        return np.setdiff1d(np.arange(n), plan)

    fitter = Fitter(utfsm_start(), windows, discard, smoothing, [plan, d_plan] + plans)
    t0 = time.perf_counter()
    designed_model, outcome = fitter(plan)
    designed_scores = score(designed_model)
    d_model, d_outcome = fitter(d_plan)
    d_scores = score(d_model)
    print(
        f"designed plan fitted in {time.perf_counter() - t0:.0f} s "
        f"({outcome.steps} steps, {outcome.reason})",
        flush=True,
    )
    every = Fitter(utfsm_start(), windows, discard, smoothing, [list(range(n))])
    t0 = time.perf_counter()
    all_model, all_outcome = every(list(range(n)))
    all_scores = score(all_model)
    all_seconds = time.perf_counter() - t0
    print(f"all 30 fitted in {all_seconds:.0f} s ({all_outcome.steps} steps)")
    published = score(jaxmr.utfsm_spencer())
    rest = held_out(plan)

    random_rows = []
    t0 = time.perf_counter()
    for k, p in enumerate(plans):
        model, o = fitter(p)
        s = score(model)
        random_rows.append(
            {
                "plan": p,
                "held_out_median_nrmse": float(np.median(s[held_out(p)])),
                "log_det": design.log_det_of(p),
                "steps": o.steps,
                "reason": o.reason,
            }
        )
        print(
            f"random plan {k + 1}/{len(plans)} {p}: held-out median NRMSE "
            f"{random_rows[-1]['held_out_median_nrmse']:.4f}",
            flush=True,
        )
    random_seconds = time.perf_counter() - t0
    medians = np.array([r["held_out_median_nrmse"] for r in random_rows])
    log_dets = np.array([r["log_det"] for r in random_rows])
    designed = float(np.median(designed_scores[rest]))
    d_designed = float(np.median(d_scores[held_out(d_plan)]))
    everything = float(np.median(all_scores[rest]))
    random_median = float(np.median(medians))
    return {
        "model": "ShearThinningSpencer from the published UTFSM model (14 free)",
        "k": K,
        "criterion": "I (prediction over the menu)",
        "design_seconds": design_seconds,
        "designed_plan": [design.candidate_names[k] for k in plan],
        "designed_indices": plan,
        "designed_swaps": design.swaps,
        "designed_contributions": design.contributions.tolist(),
        "designed_log_det": design.log_det,
        "all_log_det": design.log_det_all,
        "random_log_det_percentiles_10_50_90": np.percentile(
            log_dets, [10, 50, 90]
        ).tolist(),
        "designed_fit_steps": outcome.steps,
        "designed_nrmse": designed,
        "designed_nrmse_per_test": designed_scores[rest].tolist(),
        "d_optimal_plan": [d_design.candidate_names[k] for k in d_plan],
        "d_optimal_nrmse": d_designed,
        "d_optimal_fit_steps": d_outcome.steps,
        "d_optimal_log_det": d_design.log_det,
        "d_optimal_all_nrmse_same_24": float(np.median(all_scores[held_out(d_plan)])),
        "all_nrmse": everything,
        "all_fit_seconds": all_seconds,
        "published_nrmse_same_24": float(np.median(published[rest])),
        "random_median_nrmse": random_median,
        "random_nrmse_p10": float(np.percentile(medians, 10)),
        "random_nrmse_p90": float(np.percentile(medians, 90)),
        "random_plans_beaten_by_designed": float(np.mean(medians > designed)),
        "random_fit_seconds": random_seconds,
        "random": random_rows,
        "goal_designed_within_10_percent_of_all": bool(designed <= 1.1 * everything),
        "goal_designed_below_random_median": bool(designed < random_median),
    }


def brake(seeds: int, seed: int) -> dict:
    """Predicted against realised standard errors of a designed plan."""
    published = jaxmr.sas_brake_bouc_wen()
    truth = jaxmr.BoucWen(
        alpha=jaxmr.LinearLaw(P(published.alpha.a), P(published.alpha.b)),
        c0=jaxmr.LinearLaw(P(published.c0.a), P(published.c0.b)),
        A=jaxmr.Fixed(published.A),
        beta=P(published.beta),
        gamma=jaxmr.Fixed(published.gamma),
        n=P(published.n),
        k0=jaxmr.Fixed(0.0),
        x0=jaxmr.Fixed(0.0),
        f0=jaxmr.Fixed(0.0),
    )
    menu = jaxmr.sine_grid(
        np.radians([1.0, 2.0, 3.5, 5.0]),
        [0.5, 1.0, 2.0],
        [0.0, 0.5, 1.0],
        cycles=2.0,
        sample_rate=250.0,
        rotary=True,
    )
    sigma = 0.02  # N·m, about 2 % of the peak torque
    design = jaxmr.design_experiments(truth, menu, 4, weighting="force", noise=sigma)
    print(design, flush=True)
    clean = jaxmr.predict_all(unwrap(truth), design.plan)
    rng = np.random.default_rng(seed)
    estimates, reported = [], []
    t0 = time.perf_counter()
    for _ in range(seeds):
        data = [
            jd.Experiment(
                e.t,
                e.x,
                e.v,
                e.current,
                f + sigma * rng.normal(size=f.shape),
                name=e.name,
                rotary=True,
            )
            for e, f in zip(design.plan, clean)
        ]
        result = jaxmr.fit(
            truth, data, weighting="force", progress=False, statistics_refinement=1
        )
        estimates.append(result.values)
        reported.append(result.std_errors)
    seconds = time.perf_counter() - t0
    realised = np.std(np.array(estimates), axis=0, ddof=1)
    ratio = realised / design.std_errors
    return {
        "model": "sas_brake_bouc_wen, 6 free (alpha, c0 laws, beta, n)",
        "menu": len(menu),
        "k": 4,
        "noise_Nm": sigma,
        "seeds": seeds,
        "plan": [design.candidate_names[k] for k in design.indices],
        "names": list(design.names),
        "values": design.values.tolist(),
        "predicted_std_errors": design.std_errors.tolist(),
        "realised_std_errors": realised.tolist(),
        "fit_reported_std_errors_mean": np.mean(reported, axis=0).tolist(),
        "bias_over_std_error": (
            (np.mean(estimates, axis=0) - design.values) / design.std_errors
        ).tolist(),
        "ratio_realised_to_predicted": ratio.tolist(),
        "max_factor": float(np.max(np.maximum(ratio, 1 / ratio))),
        "fit_seconds": seconds,
        # The realised spread of `seeds` estimates is itself uncertain by about
        # 1/sqrt(2 (seeds - 1)) (11 % for 40).
        "goal_within_factor_1_5": bool(np.all((ratio < 1.5) & (ratio > 1 / 1.5))),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", required=True, help="where to write the figures")
    parser.add_argument("--random", type=int, default=50)
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.random, args.seeds = 4, 8
    t0 = time.perf_counter()
    figures = {
        "date": time.strftime("%Y-%m-%d"),
        "machine": f"{platform.machine()}, {jax.devices()[0].device_kind}",
        "jax": jax.__version__,
        "brake": brake(args.seeds, args.seed),
    }
    print(json.dumps(figures["brake"], indent=1), flush=True)
    figures["utfsm"] = utfsm(args.random, args.seed)
    figures["seconds"] = time.perf_counter() - t0
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(figures, indent=1))
    summary = {k: v for k, v in figures["utfsm"].items() if k != "random"}
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
