"""Identification speed: `jaxmr.fit` against `scipy.optimize.least_squares` with
finite-difference Jacobians, on the same problem in the same run.

Problem (issue 3's synthetic case): the published Bouc–Wen brake
(`jaxmr.sas_brake_bouc_wen()`), 5 currents, one 1 Hz ±3.5° cycle at 500 Hz each, 1 %
noise; 7 parameters (A fixed against the scaling redundancy) started 2–3x off.

jaxmr: Levenberg–Marquardt with exact forward-mode Jacobians through a fixed-step
simulation; timed twice (the first call compiles). scipy: `least_squares` (trf, 2-point
finite differences) on log-parameters, its residual the same jitted jaxmr simulation
with the same fixed-step integrator (identification has integrated with fixed RK4
steps only since issue 9: the adaptive baseline of 2026-11-21 is gone). Written: times,
final losses, parameter errors, and whether scipy converged.

    python benchmarks/fit_vs_scipy.py --json benchmarks/results/fit_vs_scipy.json
"""

import argparse
import json
import os
import platform
import sys
import time
from types import SimpleNamespace

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import jaxmr  # noqa: E402

CURRENTS = (0.0, 0.25, 0.5, 0.75, 1.0)
TRUE = {"alpha.a": 1.0, "alpha.b": 0.07, "c0.a": 0.0015, "c0.b": 0.07,
        "beta": 737.0, "gamma": 1.0, "n": 0.9}  # fmt: skip
START = {"alpha.a": 2.5, "alpha.b": 0.2, "c0.a": 0.004, "c0.b": 0.15,
         "beta": 737.0 * 2.5, "gamma": 2.5, "n": 0.9 * 1.3}  # fmt: skip


def make_data(samples_per_cycle: int):
    ts = jnp.linspace(0.0, 1.0, samples_per_cycle + 1)
    sol = jaxmr.sweep(
        jaxmr.sas_brake_bouc_wen(),
        jaxmr.Sine(jnp.deg2rad(3.5), 1.0),
        jnp.array(CURRENTS),
        ts,
        integrator=jaxmr.Adaptive(rtol=1e-11, atol=1e-13),
    )
    rng = np.random.default_rng(0)
    experiments = []
    for k, c in enumerate(CURRENTS):
        force = np.asarray(sol.force[k])
        experiments.append(
            SimpleNamespace(
                t=np.asarray(ts),
                x=np.asarray(sol.displacement[k]),
                v=np.asarray(sol.velocity[k]),
                current=np.full(ts.shape, c),
                force=force + 0.01 * np.std(force) * rng.standard_normal(force.shape),
                name=f"{c} A",
            )
        )
    return experiments


def model_from(p):
    P, zero = jaxmr.Positive, jaxmr.Fixed(0.0)
    return jaxmr.BoucWen(
        alpha=jaxmr.LinearLaw(P(p["alpha.a"]), P(p["alpha.b"])),
        c0=jaxmr.LinearLaw(P(p["c0.a"]), P(p["c0.b"])),
        A=jaxmr.Fixed(843.0),
        beta=P(p["beta"]),
        gamma=P(p["gamma"]),
        n=P(p["n"]),
        k0=zero,
        x0=zero,
        f0=zero,
    )


def errors(values: dict) -> dict:
    return {k: float(values[k] / TRUE[k] - 1) for k in TRUE}


def run_jaxmr(experiments):
    out = {}
    for label in ("first_call_s", "run_s"):
        t0 = time.perf_counter()
        result = jaxmr.fit(model_from(START), experiments, progress=False)
        out[label] = time.perf_counter() - t0
    values = {name.lstrip("."): v for name, v in zip(result.names, result.values)}
    out.update(
        steps=result.num_steps,
        reason=result.reason,
        loss=result.loss,
        median_nrmse=float(np.median(result.nrmse)),
        relative_errors=errors(values),
    )
    return out


def run_scipy(experiments, integrator, max_nfev):
    from jaxmr._identify.data import as_step_policy, pack
    from jaxmr._identify.residual import residuals as _residuals
    from jaxmr._parameter import free_filter

    template = model_from(START)
    free, static = eqx.partition(template, free_filter(template))
    leaves, treedef = jax.tree.flatten(free)
    data = pack(experiments, as_step_policy(integrator))

    @jax.jit
    def residual(flat):
        f = jax.tree.unflatten(treedef, list(flat))
        return _residuals(f, static, data)

    x0 = np.array([float(v) for v in leaves])
    residual(jnp.asarray(x0)).block_until_ready()  # compile outside the timing
    calls = [0]

    def fun(x):
        calls[0] += 1
        return np.asarray(residual(jnp.asarray(x)))

    t0 = time.perf_counter()
    sol = scipy.optimize.least_squares(
        fun, x0, jac="2-point", method="trf", max_nfev=max_nfev, x_scale="jac"
    )
    elapsed = time.perf_counter() - t0
    fitted = jax.tree.unflatten(treedef, [jnp.asarray(v) for v in sol.x])
    model = jaxmr._parameter.unwrap(eqx.combine(fitted, static))
    values = {
        "alpha.a": model.alpha.a, "alpha.b": model.alpha.b, "c0.a": model.c0.a,
        "c0.b": model.c0.b, "beta": model.beta, "gamma": model.gamma, "n": model.n,
    }  # fmt: skip
    rel = errors({k: float(v) for k, v in values.items()})
    return {
        "run_s": elapsed,
        "residual_evaluations": calls[0],
        "status": int(sol.status),
        "message": str(sol.message),
        "loss": float(sol.cost),
        "relative_errors": rel,
        "converged_to_truth_2pct": bool(
            all(abs(rel[k]) < 0.02 for k in ("alpha.a", "alpha.b", "beta", "n"))
        ),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True, help="output JSON path")
    parser.add_argument("--samples-per-cycle", type=int, default=500)
    parser.add_argument("--max-nfev", type=int, default=400)
    args = parser.parse_args(argv)

    experiments = make_data(args.samples_per_cycle)
    result = {
        "benchmark": "fit_vs_scipy",
        "problem": "SAS brake Bouc-Wen, 5 currents, 1 cycle, 1 % noise, 7 params, "
        "start 2-3x off",
        "samples_per_cycle": args.samples_per_cycle,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"{jax.devices()[0].platform}",
        "load_average": os.getloadavg(),
        "jax": jax.__version__,
    }
    print("jaxmr.fit ...", flush=True)
    result["jaxmr"] = run_jaxmr(experiments)
    # The same fixed steps as `fit` chooses: at most 0.5 ms.
    steps = max(1, int(np.ceil((1.0 / args.samples_per_cycle) / 5e-4)))
    # No adaptive baseline any more: since issue 9 identification integrates with
    # fixed RK4 steps only (an `Adaptive` integrator is refused by name).
    print("scipy_fd_fixedstep ...", flush=True)
    result["scipy_fd_fixedstep"] = run_scipy(
        experiments, jaxmr.FixedStep(substeps=steps), args.max_nfev
    )
    result["speedup_vs_scipy_fixedstep"] = (
        result["scipy_fd_fixedstep"]["run_s"] / result["jaxmr"]["run_s"]
    )
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    with open(args.json, "w") as f:
        json.dump(result, f, indent=2)
    j = result["jaxmr"]
    print(f"jaxmr: {j['run_s']:.2f} s after compile ({j['first_call_s']:.1f} s first), "
          f"{j['steps']} steps, {j['reason']}")  # fmt: skip
    for name in ("scipy_fd_fixedstep",):
        r = result[name]
        print(f"{name}: {r['run_s']:.2f} s, {r['residual_evaluations']} evaluations, "
              f"status {r['status']}, within 2 %: {r['converged_to_truth_2pct']}")  # fmt: skip
    print("errors (jaxmr):", {k: f"{v:+.2%}" for k, v in j["relative_errors"].items()})
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
