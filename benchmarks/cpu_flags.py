"""`jaxmr.devices.configure_cpu`'s loop and emitter settings against XLA's defaults, same machine, same run.

    python benchmarks/cpu_flags.py --json benchmarks/results/cpu_flags.json

XLA reads its flags once per process, so each setting runs in its own fresh process
(one XLA CPU device each, nothing else changed):

- `default`: XLA's own threshold (a while loop becomes one kernel when its body
  touches at most 1024 bytes) and XLA's own (newer, MLIR) CPU fusion emitters;
- `configured`: what `jaxmr.devices.configure_cpu` sets: the threshold 100 kB and,
  on the jaxlib releases it was measured on, XLA's older fusion emitters
  (`--xla_cpu_use_fusion_emitters=false`);
- `newer_emitters`: `configured` with the newer emitters kept (the user's own
  `--xla_cpu_use_fusion_emitters=true`, which `configure_cpu` keeps).

Figures: `*_speedup` (run time, `default` over `configured`: the loop setting);
`*_compile_speedup_older_emitters` (compile time, `newer_emitters` over
`configured`) and `*_run_ratio_older_emitters` (run time, the same ratio: 1 means
no change); `*_same_bits_older_emitters`: whether the two emitters' outputs are
equal to the bit.

Each times, compilation and run separately (run: median of 3 after the compiling
call), the residual and the residual with its forward-mode Jacobian of:

- `utfsm`: the 30 UTFSM sine tests packed in 8 lanes, data-scaled
  ShearThinningSpencer (14 parameters), the files' smoothing, first cycle discarded;
- `boucwen`: `fit_system`'s residual of the Bouc–Wen benchmark oscillator (6
  parameters) on the five training periods, 20 RK4 steps per sample (819 200 steps);
- `sweep`: `jaxmr.sweep` of the published brake, 16 motions × 16 currents × 2 s,
  `FixedStep(4)` (a wide batch in one loop).
"""

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _report import write_figures

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
SETTINGS = ("default", "configured", "newer_emitters")


def _timed(function, repeats=3):
    import jax
    import numpy as np

    start = time.perf_counter()
    value = jax.block_until_ready(function())
    first = time.perf_counter() - start
    # A fingerprint of the output's bits, to compare settings without storing it.
    leaves = [np.asarray(a) for a in jax.tree.leaves(value)]
    digest = hashlib.sha256(b"".join(a.tobytes() for a in leaves)).hexdigest()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    run = statistics.median(times)
    return {"compile_s": first - run, "run_s": run, "sha256": digest}


def _pair(residual, jacobian) -> dict:
    out = {"residual": _timed(residual), "jacobian": _timed(jacobian)}
    out["jacobian_cost_in_residuals"] = (
        out["jacobian"]["run_s"] / out["residual"]["run_s"]
    )
    return out


def utfsm():
    import equinox as eqx

    import jaxmr
    import jaxmr.data as jd
    from jaxmr._identify.data import pack
    from jaxmr._identify.residual import (
        residuals,
        residuals_jit,
        value_and_jacobian_jit,
    )
    from jaxmr._parameter import free_filter

    experiments = jd.load_utfsm(SHARED / "utfsm_mr_damper" / "sine")
    data = pack(
        experiments,
        discard=jd.utfsm_first_cycle(experiments),
        smoothing=jd.utfsm_smoothing(experiments),
    )
    model = jaxmr.templates.MODEL_TEMPLATES["shear_thinning_spencer"](experiments)
    free, static = eqx.partition(model, free_filter(model))
    return _pair(
        lambda: residuals_jit(free, static, data),
        lambda: value_and_jacobian_jit(residuals, free, static, data, None),
    )


def boucwen():
    import boucwen_benchmark as bw
    import jax
    import jax.numpy as jnp

    from jaxmr._identify.system import SystemRecord
    from jaxmr.data import load_boucwen_benchmark_train

    train = load_boucwen_benchmark_train(SHARED / "boucwen_benchmark" / "train.h5")
    n = 5 * bw.PERIOD
    signal = bw.excitation(train.u[: bw.PERIOD], "multisine", 20, 5)
    record = SystemRecord(train.t[:n], train.y[:n], signal)
    start = bw.start_system(*bw.linear_fit(train.u, train.y))
    residual, x0, _, _ = bw.flat_residual(start, record, substeps=20)
    x0 = jnp.asarray(x0)
    residual_jit = jax.jit(residual)
    jacobian_jit = jax.jit(jax.jacfwd(residual))
    return _pair(lambda: residual_jit(x0), lambda: jacobian_jit(x0))


def sweep():
    import jax.numpy as jnp

    import jaxmr

    ts = jnp.linspace(0.0, 2.0, 2001)
    motions = [jaxmr.Sine(jnp.deg2rad(a), 1.0) for a in jnp.linspace(1.0, 6.0, 16)]
    currents = jnp.linspace(0.0, 1.0, 16)
    brake = jaxmr.sas_brake_bouc_wen()

    def run():
        return jaxmr.sweep(
            brake, motions, currents, ts, integrator=jaxmr.FixedStep(substeps=4)
        ).force

    return {"sweep": _timed(run)}


def worker(setting: str, out: Path) -> None:
    import jaxmr

    if setting == "newer_emitters":
        os.environ["XLA_FLAGS"] = "--xla_cpu_use_fusion_emitters=true"
    if setting in ("configured", "newer_emitters"):
        jaxmr.devices.configure_cpu(devices=1)
    import jax

    jax.config.update("jax_enable_x64", True)
    figures = {"setting": setting, "XLA_FLAGS": os.environ.get("XLA_FLAGS", "")}
    for name, case in (("utfsm", utfsm), ("boucwen", boucwen), ("sweep", sweep)):
        figures[name] = case()
        print(setting, name, figures[name], flush=True)
    out.write_text(json.dumps(figures))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--worker", choices=SETTINGS, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.out)
        return
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    figures = {"machine": f"{os.cpu_count()} cores", "load_average": os.getloadavg()}
    with tempfile.TemporaryDirectory() as folder:
        for setting in SETTINGS:
            out = Path(folder) / f"{setting}.json"
            subprocess.run(
                [sys.executable, __file__, "--worker", setting, "--out", str(out)],
                env=env,
                check=True,
            )
            figures[setting] = json.loads(out.read_text())
    for name in ("utfsm", "boucwen"):
        for part in ("residual", "jacobian"):
            figures[f"{name}_{part}_speedup"] = (
                figures["default"][name][part]["run_s"]
                / figures["configured"][name][part]["run_s"]
            )
    figures["sweep_speedup"] = (
        figures["default"]["sweep"]["sweep"]["run_s"]
        / figures["configured"]["sweep"]["sweep"]["run_s"]
    )
    older, newer = figures["configured"], figures["newer_emitters"]
    for name, parts in (
        ("utfsm", ("residual", "jacobian")),
        ("boucwen", ("residual", "jacobian")),
        ("sweep", ("sweep",)),
    ):
        for part in parts:
            key = name if part == "sweep" else f"{name}_{part}"
            a, b = older[name][part], newer[name][part]
            figures[f"{key}_compile_speedup_older_emitters"] = (
                b["compile_s"] / a["compile_s"]
            )
            figures[f"{key}_run_ratio_older_emitters"] = b["run_s"] / a["run_s"]
            figures[f"{key}_same_bits_older_emitters"] = a["sha256"] == b["sha256"]
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
