"""Identification speed and accuracy on the 30 UTFSM sine tests (issue 9).

Measures, in one run:

- `simulated_steps_per_data_step`: RK4 steps simulated per evaluation over the steps
  the records need at their own step policy, for the packed layout (the default) and
  for the padded one (a lane per record, each as long as the longest);
- `residual_seconds`, `jacobian_seconds` and `jacobian_cost_in_residuals` (the
  residual with its forward-mode Jacobian over the residual alone), compiled first,
  median of 3, for both layouts, with the data-scaled ShearThinningSpencer start;
- `seconds_joint_fit`: that template fitted jointly to all 30 whole records (the
  files' smoothing and discarded first cycle), compilation included, and its median
  NRMSE on the 30 against the published model's (smoothed like the data and raw);
- `seconds_auto`: the whole `jaxmr fit` command (default `--model auto`) on the 30
  files converted to canonical CSV, compilation included, and the chosen model's
  median NRMSE on all 30;
- the NEES record (`nees`): `jaxmr fit` on its first two thirds, and the last
  third's NRMSE (means removed) against Spencer 1997's published parameters; again
  with `--channel-delay`;
- `speedup_vs_scipy_fd` (`boucwen`): on the Bouc–Wen benchmark's training record,
  `fit_system` against scipy's least_squares with finite differences to the same
  loss, compilation included on both sides (`boucwen_benchmark.against_scipy`).

    python benchmarks/identify_speed.py --json benchmarks/results/identify_speed.json

`--sections` picks parts (default all: layouts,joint,auto,nees,boucwen; the command-line runs
take minutes). Reads the data from ../shared/data beside the repository.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _report import write_figures

import jaxmr

# As `jaxmr fit` does: every CPU core an XLA device (up to 8), so that a fit splits its
# lanes over them, and each simulation loop one kernel. Flags of your own are kept.
jaxmr.devices.configure_cpu()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402

import jaxmr.data as jd  # noqa: E402
from jaxmr._identify.data import pack  # noqa: E402
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


def _fit_command(files, out, *options):
    """`jaxmr fit --out OUT [options] FILES` (default: auto) in a fresh process; its
    seconds."""
    start = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, jaxmr._cli; sys.exit(jaxmr._cli.main())",
            "fit",
            "--out",
            str(out),
            *options,
            *map(str, files),
        ],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return time.perf_counter() - start


def _timed(function, repeats=3):
    jax.block_until_ready(function())  # compile
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return statistics.median(times)


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


def joint_fit(experiments, discard, smoothing, published):
    start = time.perf_counter()
    model = jaxmr.templates.MODEL_TEMPLATES["shear_thinning_spencer"](experiments)
    result = jaxmr.fit(
        model, experiments, discard=discard, smoothing=smoothing, progress=False
    )
    seconds = time.perf_counter() - start
    scores = jaxmr.record_nrmse(
        result.model, experiments, discard=discard, smoothing=smoothing
    )
    out = {
        "seconds_joint_fit": seconds,
        "joint_fit_steps": result.num_steps,
        "joint_fit_reason": result.reason,
        "joint_fit_median_nrmse": float(np.median(scores)),
        "joint_fit_better_than_published": int(np.sum(scores < published)),
    }
    print(out, flush=True)
    return out


def auto(experiments, discard, smoothing):
    with tempfile.TemporaryDirectory() as folder:
        files = jd.convert_dataset("utfsm", UTFSM, Path(folder) / "csv")
        out = Path(folder) / "auto.json"
        seconds = _fit_command(files, out)
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
        seconds = _fit_command([path], out)
        model = jaxmr.load_model(out)
        report = json.loads(out.read_text())["report"]
        # The same with the force channel's delay fitted too (`--channel-delay`).
        out = Path(folder) / "nees_delay.json"
        delay_seconds = _fit_command([path], out, "--channel-delay")
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


def boucwen():
    """The Bouc–Wen benchmark oscillator fitted by `fit_system` to the five periods of
    its training record, against scipy's least_squares with finite differences on the
    same residual from the same start (`boucwen_benchmark.against_scipy`)."""
    from boucwen_benchmark import against_scipy

    train = jd.load_boucwen_benchmark_train(BOUCWEN / "train.h5")
    _, _, _, figures = against_scipy(train, periods=5, substeps=20)
    out = {
        "speedup_vs_scipy_fd": figures["speedup_vs_scipy_fd"],
        "speedup_vs_scipy_fd_compiled": figures["speedup_vs_scipy_fd_compiled"],
        "boucwen_fit": {k: v for k, v in figures["fit"].items() if k != "values"},
        "boucwen_scipy": figures["scipy"],
    }
    print(out, flush=True)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument(
        "--sections",
        default="layouts,joint,auto,nees,boucwen",
        help="comma-separated: layouts, joint, auto, nees, boucwen (default: all)",
    )
    args = parser.parse_args()
    sections = set(args.sections.split(","))
    experiments = jd.load_utfsm(UTFSM)
    discard = jd.utfsm_first_cycle(experiments)
    smoothing = jd.utfsm_smoothing(experiments)
    published = jaxmr.record_nrmse(
        jaxmr.utfsm_spencer(), experiments, discard=discard, smoothing=smoothing
    )
    raw = jaxmr.record_nrmse(
        jaxmr.utfsm_spencer(), experiments, discard=discard, smoothing=0.0
    )
    figures = {
        "devices": len(jax.devices()),
        "load_average_at_start": os.getloadavg(),
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
        figures.update(joint_fit(experiments, discard, smoothing, published))
    if "auto" in sections:
        figures.update(auto(experiments, discard, smoothing))
    if "nees" in sections:
        figures.update(nees())
    if "boucwen" in sections:
        figures.update(boucwen())
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
