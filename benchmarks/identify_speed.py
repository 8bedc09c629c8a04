"""Identification speed and accuracy on the 30 UTFSM sine tests (issues 9 and 28).

Measures, in one run:

- `simulated_steps_per_data_step`: RK4 steps simulated per evaluation over the steps
  the records need at their own step policy, for the packed layout (the default) and
  for the padded one (a lane per record, each as long as the longest);
- `residual_seconds`, `jacobian_seconds` and `jacobian_cost_in_residuals` (the
  residual with its forward-mode Jacobian over the residual alone), compiled first,
  median of 3, for both layouts, with the data-scaled ShearThinningSpencer start;
- `joint`: that template (14 parameters) fitted jointly to all 30 whole records (the
  files' smoothing and discarded first cycle) by `jaxmr.fit`, `seconds_joint_fit`
  compilation included, its median NRMSE on the 30 against the published model's
  (smoothed like the data and raw); against it, from the same start and on the same
  residual (`residual.residuals` of the same packed data, split over the same
  devices, jitted: jaxmr has no public residual, so the baselines use its private
  one), scipy's `least_squares` with "trf" and with "lm" (MINPACK: the free
  variables are unbounded), each with 2-point finite differences and with the exact
  Jacobian (`jax.jacfwd` of that residual, jitted). `speedup_joint_vs_scipy_fd` and
  `speedup_joint_vs_scipy_exact_jacobian`: the fastest of each kind over jaxmr, at
  equal accuracy, compilation included, each with `_excluding_compile`;
- `cold`: `jaxmr fit --model shear_thinning_spencer` on the 30 files converted to
  canonical CSV, once with a fresh persistent compilation cache
  (`--compilation-cache`) and then `SECOND_FITS` times more reading it back, each in
  a fresh process: `first_fit_seconds`, `second_fit_seconds` (the command's own
  wall time, from its `main` to its exit status: the interpreter's start and
  imports are not in it) and `second_fit_compile_seconds` (the tracing, lowering
  and compilation, compiled programs read from the cache included), the second
  fit's figures the medians of its runs;
- `auto`: the whole `jaxmr fit` command (default `--model auto`) on those files,
  compilation included, and the chosen model's median NRMSE on all 30;
- the NEES record (`nees`): `jaxmr fit` on its first two thirds, and the last
  third's NRMSE (means removed) against Spencer 1997's published parameters; again
  with `--channel-delay`;
- `boucwen`: the Bouc–Wen benchmark's training record, `fit_system` against scipy's
  least_squares the same way (`boucwen_benchmark.against_scipy`):
  `speedup_vs_scipy_fd`, `speedup_vs_scipy_exact_jacobian` and their
  `_excluding_compile` and `_cpu_time` (`fit_system` splits its Jacobian over the
  cores, scipy's loop is serial: the same baseline's CPU time, every thread's, over
  jaxmr's).

The rule of the speed comparisons (`_fit_baselines`): each fit runs in a fresh
process with JAX's persistent cache off; jaxmr's final loss × (1 + 1e-3) is the
target, and each fit's time is its wall time from its call to its first point at
or below the target; a baseline stops there or after `--budget-factor` × jaxmr's
time (then marked `reached: false`, the speedup `_lower_bound`). Compilation is the
union of JAX's tracing, lowering and XLA compilation intervals within that time
(`jax.monitoring`); excluding compilation, it is subtracted. The command-line runs
(`cold`, `auto`, `nees`) run in processes of their own; `auto` and `nees` with the
compilation cache off (cold starts).

    python benchmarks/identify_speed.py --json benchmarks/results/identify_speed.json

`--sections` picks parts (default all: layouts,joint,cold,auto,nees,boucwen; the
command-line runs take minutes); `--quick` is a smoke run (6 of the records, the
Bouc–Wen fit on one period at 10 RK4 steps per sample, no `auto` or `nees`, a budget
of 3x). Reads the data from ../shared/data beside the repository.
"""

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from _fit_baselines import (
    COMPILE_EVENTS,
    TARGET,
    CompileClock,
    LossTrace,
    cold_jax,
    in_fresh_process,
    scipy_to_target,
    speedups,
    timed_figures,
)
from _processes import fit_command
from _report import write_figures

import jaxmr

# As `jaxmr fit` does: every CPU core an XLA device (up to 8), so that a fit splits its
# lanes over them, and each simulation loop one kernel. Flags of your own are kept.
# (The fresh processes of the comparisons, which import this module, too.)
jaxmr.devices.configure_cpu()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402
from jax.flatten_util import ravel_pytree  # noqa: E402

import jaxmr.data as jd  # noqa: E402
from jaxmr._identify.data import pack  # noqa: E402
from jaxmr._identify.fitting import _lanes_on_devices  # noqa: E402
from jaxmr._identify.residual import (  # noqa: E402
    residuals,
    residuals_jit,
    value_and_jacobian_jit,
)
from jaxmr._parameter import free_filter  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
UTFSM = ROOT.parent / "shared" / "data" / "utfsm_mr_damper" / "sine"
NEES = ROOT.parent / "shared" / "data" / "nees_dyke_mr_damper" / "ranran_50.csv"
BOUCWEN = ROOT.parent / "shared" / "data" / "boucwen_benchmark"


TEMPLATE = "shear_thinning_spencer"
# Every how manieth record `--quick` keeps (6 of the 30, at every current).
QUICK_STRIDE = 5


def _timed(function, repeats=3):
    jax.block_until_ready(function())  # compile
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _utfsm(stride: int = 1):
    """The UTFSM records (every `stride`-th), their discarded first cycles and
    smoothing widths."""
    experiments = jd.load_utfsm(UTFSM)[::stride]
    return (
        experiments,
        jd.utfsm_first_cycle(experiments),
        jd.utfsm_smoothing(experiments),
    )


def layouts(experiments, discard, smoothing):
    model = jaxmr.templates.MODEL_TEMPLATES["shear_thinning_spencer"](experiments)
    free, static = eqx.partition(model, free_filter(model))
    out = {"num_parameters": int(sum(np.size(x) for x in jax.tree.leaves(free)))}
    for name, lanes in (("packed", None), ("padded", len(experiments))):
        data = pack(experiments, discard=discard, smoothing=smoothing, lanes=lanes)
        residual = _timed(lambda d=data: residuals_jit(free, static, d))
        jacobian = _timed(
            lambda d=data: value_and_jacobian_jit(residuals, free, static, d, None)
        )
        out[name] = {
            "lanes": int(data.step.shape[0]),
            "simulated_steps": data.num_steps,
            "data_steps": data.data_steps,
            "simulated_steps_per_data_step": data.num_steps / data.data_steps,
            "residual_seconds": residual,
            "jacobian_seconds": jacobian,
            "jacobian_cost_in_residuals": jacobian / residual,
        }
        print(name, out[name], flush=True)
    return out


def _joint_jaxmr(stride: int, published) -> dict:
    """`jaxmr.fit` of the template to the records jointly, in a fresh process: its
    time to the target (its own final loss × (1 + 1e-3)) and in all, the
    compilation in each, and the fit's scores."""
    cold_jax()
    experiments, discard, smoothing = _utfsm(stride)
    with CompileClock() as clock:
        started = time.time()
        trace = LossTrace(started)
        model = jaxmr.templates.MODEL_TEMPLATES[TEMPLATE](experiments)
        result = jaxmr.fit(
            model,
            experiments,
            discard=discard,
            smoothing=smoothing,
            progress=lambda step, loss: trace.add(loss),
        )
        total = time.time() - started
    scores = jaxmr.record_nrmse(
        result.model, experiments, discard=discard, smoothing=smoothing
    )
    return {
        **timed_figures(trace, clock, result.loss * TARGET, total),
        "loss": result.loss,
        "steps": result.num_steps,
        "reason": result.reason,
        "median_nrmse": float(np.median(scores)),
        "better_than_published": int(np.sum(scores < np.asarray(published))),
    }


def _joint_scipy(stride: int, method: str, exact: bool, target: float, budget: float):
    """scipy's least_squares on the joint fit's residual, in a fresh process
    (`_fit_baselines.scipy_to_target`)."""
    cold_jax()
    experiments, discard, smoothing = _utfsm(stride)

    def build():
        # As `fit` builds it: the template's start, the packed data split over the
        # devices, the data passed to the jitted residual as arguments.
        model = jaxmr.templates.MODEL_TEMPLATES[TEMPLATE](experiments)
        free, static = eqx.partition(model, free_filter(model))
        data = pack(experiments, discard=discard, smoothing=smoothing)
        data = _lanes_on_devices(data)
        x0, unravel = ravel_pytree(free)
        return (
            (lambda x, static, data: residuals(unravel(x), static, data)),
            x0,
            (
                static,
                data,
            ),
        )

    figures = scipy_to_target(
        build, method=method, exact=exact, target=target, budget=budget
    )
    figures.pop("x")
    return figures


def joint(stride: int, published, budget_factor: float) -> dict:
    """jaxmr's joint fit, then scipy's least_squares ("trf", "lm"; finite
    differences, exact Jacobian) to its loss, each in a fresh process."""
    fit = in_fresh_process(_joint_jaxmr, stride, published)
    print("jaxmr.fit", fit, flush=True)
    target = fit["loss"] * TARGET
    budget = max(60.0, budget_factor * fit["seconds"])
    baselines = {}
    for method in ("trf", "lm"):
        for exact in (False, True):
            name = f"{method}_{'exact' if exact else 'fd'}"
            baselines[name] = in_fresh_process(
                _joint_scipy, stride, method, exact, target, budget
            )
            print(f"scipy {name}", baselines[name], flush=True)
    return {
        "seconds_joint_fit": fit["total_seconds"],
        "joint_fit_steps": fit["steps"],
        "joint_fit_reason": fit["reason"],
        "joint_fit_median_nrmse": fit["median_nrmse"],
        "joint_fit_better_than_published": fit["better_than_published"],
        **speedups(fit, baselines, "joint_vs_scipy"),
        "joint": {
            "target_loss": target,
            "budget_seconds": budget,
            "jaxmr": fit,
            "scipy": baselines,
        },
    }


def _command_with_events(argv: list[str]) -> dict:
    """`jaxmr fit ...` (the command's `main`) in this process, a fresh one: its wall
    time, and its tracing, lowering and compilation (the union of JAX's intervals;
    a cached program's read is its compilation) with the persistent cache's hits."""
    from jaxmr._cli import main

    hits, by_function = [], {}

    def duration(event, seconds, fun_name="", **kwargs):
        if event in COMPILE_EVENTS:
            key = f"{event.rsplit('/', 1)[-1].removesuffix('_duration')} {fun_name}"
            by_function[key] = by_function.get(key, 0.0) + seconds

    jax.monitoring.register_event_listener(
        lambda event, **kwargs: (
            hits.append(event) if event == "/jax/compilation_cache/cache_hits" else None
        )
    )
    jax.monitoring.register_event_duration_secs_listener(duration)
    trace_clock = CompileClock()
    with CompileClock() as clock:
        jax.monitoring.register_event_time_span_listener(
            lambda event, start, end, **kwargs: (
                trace_clock.spans.append((start, end))
                if event == COMPILE_EVENTS[0]
                else None
            )
        )
        started = time.time()
        status = main(argv)
        seconds = time.time() - started
    if status != 0:
        raise RuntimeError(f"jaxmr {' '.join(argv)} exited with {status}")
    return {
        "seconds": seconds,
        "compile_seconds": clock.seconds(),
        "trace_seconds": trace_clock.seconds(),
        "cache_hits": len(hits),
        # Where it went: each event's seconds by function (nested traces counted in
        # each), the largest ten.
        "largest": dict(sorted(by_function.items(), key=lambda kv: -kv[1])[:10]),
    }


# Second fits timed, each in its own fresh process: the figure is their median. One
# alone moved by a third with this host's load (1.09 s and 1.30 s for the same code,
# session 33).
SECOND_FITS = 3


def cold(stride: int) -> dict:
    """`jaxmr fit --model TEMPLATE` on the records' CSV files, each run in a fresh
    process, with a new compilation cache: the first compiles and stores, each of
    `SECOND_FITS` more reads back (the second fit's figures: their medians)."""
    with tempfile.TemporaryDirectory() as folder:
        files = jd.convert_dataset("utfsm", UTFSM, Path(folder) / "csv")
        files = sorted(files)[::stride]
        cache = Path(folder) / "cache"
        runs = []
        for k in range(1 + SECOND_FITS):
            argv = ["fit", "--model", TEMPLATE, "--compilation-cache", str(cache)]
            argv += ["--out", str(Path(folder) / f"fit{k}.json"), *map(str, files)]
            runs.append(in_fresh_process(_command_with_events, argv))
            if k == 0:
                entries = sum(1 for p in cache.iterdir() if p.name.endswith("-cache"))
            print(f"jaxmr fit, run {k + 1}", runs[-1], flush=True)
    first, seconds = runs[0], runs[1:]

    def median(key: str) -> float:
        return float(np.median([run[key] for run in seconds]))

    return {
        "first_fit_seconds": first["seconds"],
        "first_fit_compile_seconds": first["compile_seconds"],
        "second_fit_seconds": median("seconds"),
        "second_fit_compile_seconds": median("compile_seconds"),
        "second_fit_trace_seconds": median("trace_seconds"),
        "cold": {
            "first": first,
            "seconds": seconds,
            "second_fits": SECOND_FITS,
            "second_fit_compile_seconds_all": [r["compile_seconds"] for r in seconds],
            "cache_entries_after_first": entries,
        },
    }


def auto(experiments, discard, smoothing):
    with tempfile.TemporaryDirectory() as folder:
        files = jd.convert_dataset("utfsm", UTFSM, Path(folder) / "csv")
        out = Path(folder) / "auto.json"
        seconds = fit_command(files, out, "--compilation-cache", "off")
        model = jaxmr.load_model(out)
        report = json.loads(out.read_text())["report"]
    scores = jaxmr.record_nrmse(
        model, experiments, discard=discard, smoothing=smoothing
    )
    result = {
        "seconds_auto": seconds,
        "auto_choice": report["template"],
        "auto_median_nrmse_all_30": float(np.median(scores)),
        "auto_ranking": report["selection"]["ranking"],
    }
    print(result, flush=True)
    return result


def nees():
    """`jaxmr fit` on the first two thirds of the NEES record (written as its own
    CSV: the command never sees the rest), scored on the last third, simulated from
    the record's start, against Spencer 1997's parameters (means removed, the data
    README's protocol). The command itself holds out the last third of its file to
    choose the model, then refits the choice on the whole file."""
    record = jd.load_nees(NEES, trim=True)
    t = np.asarray(record.t)
    split = float((t[-1] - t[0]) * 2 / 3)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "ranran_50_first_two_thirds.csv"
        jd.write_csv(record.window(None, t[0] + split), path, discard=0.2)
        out = Path(folder) / "nees.json"
        seconds = fit_command([path], out, "--compilation-cache", "off")
        model = jaxmr.load_model(out)
        report = json.loads(out.read_text())["report"]
        # The same with the force channel's delay fitted too (`--channel-delay`).
        out = Path(folder) / "nees_delay.json"
        delay_seconds = fit_command(
            [path], out, "--channel-delay", "--compilation-cache", "off"
        )
        delayed = jaxmr.load_model(out)
        delay_report = json.loads(out.read_text())["report"]
    score = lambda m: float(
        jaxmr.record_nrmse(m, [record], discard=split, remove_mean=True)[0]
    )
    fitted, published = score(model), score(jaxmr.spencer_1997())
    result = {
        "nees_channel_delay_seconds": delay_seconds,
        "nees_channel_delay_choice": delay_report["template"],
        "nees_channel_delay_s": float(np.asarray(delayed.delay)),
        "nees_channel_delay_held_out_nrmse": score(delayed),
        "nees_seconds": seconds,
        "nees_choice": report["template"],
        "nees_held_out_nrmse": fitted,
        "nees_spencer_1997_held_out_nrmse": published,
        "nees_improvement_over_spencer_1997": 1 - fitted / published,
        "nees_ranking": report["selection"]["ranking"],
    }
    print(result, flush=True)
    return result


def boucwen(quick: bool, budget_factor: float) -> dict:
    """The Bouc–Wen benchmark oscillator fitted by `fit_system` to the five periods of
    its training record, against scipy's least_squares on the same residual from the
    same start (`boucwen_benchmark.against_scipy`)."""
    from boucwen_benchmark import against_scipy

    train = jd.load_boucwen_benchmark_train(BOUCWEN / "train.h5")
    periods, substeps = (1, 10) if quick else (5, 20)
    *_, figures = against_scipy(
        train, periods=periods, substeps=substeps, budget_factor=budget_factor
    )
    keys = [k for k in figures if k.startswith("speedup_vs_scipy")]
    out = {k: figures[k] for k in keys}
    out["boucwen"] = {
        "periods": periods,
        "substeps": substeps,
        "target_loss": figures["target_loss"],
        "budget_seconds": figures["budget_seconds"],
        "jaxmr": {k: v for k, v in figures["fit"].items() if k != "values"},
        "scipy": figures["scipy"],
    }
    print({k: out[k] for k in keys}, flush=True)
    return out


SECTIONS = ("layouts", "joint", "cold", "auto", "nees", "boucwen")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument(
        "--sections",
        default=None,
        help=f"comma-separated: {', '.join(SECTIONS)} (default: all; with --quick "
        "all but auto and nees)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a smoke run: 6 records, the Bouc–Wen fit on one period, budget 3x",
    )
    parser.add_argument(
        "--budget-factor",
        type=float,
        default=None,
        help="a scipy baseline stops after this many times jaxmr's time to the "
        "target if it has not reached it (default 10; --quick 3)",
    )
    args = parser.parse_args()
    quick = args.quick
    default = [s for s in SECTIONS if not (quick and s in ("auto", "nees"))]
    sections = set(args.sections.split(",") if args.sections else default)
    unknown = sections - set(SECTIONS)
    if unknown:
        parser.error(f"unknown sections {sorted(unknown)}; choose from {SECTIONS}")
    budget_factor = args.budget_factor or (3.0 if quick else 10.0)
    stride = QUICK_STRIDE if quick else 1
    experiments, discard, smoothing = _utfsm(stride)
    published = jaxmr.record_nrmse(
        jaxmr.utfsm_spencer(), experiments, discard=discard, smoothing=smoothing
    )
    raw = jaxmr.record_nrmse(
        jaxmr.utfsm_spencer(), experiments, discard=discard, smoothing=0.0
    )
    figures = {
        "devices": len(jax.devices()),
        "records": len(experiments),
        "quick": quick,
        "published_median_nrmse_smoothed": float(np.median(published)),
        "published_median_nrmse_raw": float(np.median(raw)),
    }
    if "layouts" in sections:
        figures["layouts"] = layouts(experiments, discard, smoothing)
        packed = figures["layouts"]["packed"]
        figures["simulated_steps_per_data_step"] = packed[
            "simulated_steps_per_data_step"
        ]
        figures["jacobian_cost_in_residuals"] = packed["jacobian_cost_in_residuals"]
    if "joint" in sections:
        figures.update(joint(stride, np.asarray(published), budget_factor))
    if "cold" in sections:
        figures.update(cold(stride))
    if "auto" in sections:
        figures.update(auto(experiments, discard, smoothing))
    if "nees" in sections:
        figures.update(nees())
    if "boucwen" in sections:
        figures.update(boucwen(quick, budget_factor))
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
