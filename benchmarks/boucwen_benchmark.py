"""The Bouc–Wen hysteretic benchmark (Noël & Schoukens 2016): fit on the training
record, predict an official test input.

    python benchmarks/boucwen_benchmark.py \\
        --train ../shared/data/boucwen_benchmark/train.h5 \\
        --test-input ../shared/data/boucwen_benchmark/uval_multisine.mat \\
        --out benchmarks/results/boucwen_multisine.npy \\
        --json benchmarks/results/boucwen_multisine.json

What it does (SYSTEMS.md §4):

1. Linear model $m\\ddot y + c\\dot y + k y = u$ by least squares in the frequency
   domain: the training record's periods 2–5 (steady state) averaged, $U = (k - m\\omega^2
   + i c\\omega) Y$ at the excited lines. It is the published 1.5e-4 m baseline and the
   start of the nonlinear fit.
2. The oscillator with a Bouc–Wen force (`hysteretic_benchmark_oscillator`, jaxmr's
   `alpha` fixed at 1 so that z is a force and the set is not redundant, n = 1 as the
   benchmark states), fitted by `fit_system` on the first `--periods` periods of the
   training record, simulated from rest as the record was made (its first period
   fits as well as the others). Start: m, c from the linear fit, k and A each half the
   linear stiffness, and the shape parameters βγ, βδ at 2000 and −500 (2.5x and 0.45x
   the true ones). Free: m, c, k, A, βγ, βδ.
3. The test input: a multisine period (8192 samples) is a steady-state record: three
   periods are simulated from rest and the last is kept (the second already agrees
   with the third to 1e-15 m); the sweep (153 000 samples) is simulated from rest. The
   kind is told by the length.

Inputs are made continuous by band-limited interpolation (`band_limited_input`): the
multisine by FFT zero-padding of one period (exact for a periodic band-limited
signal), the sweep by a Kaiser-windowed sinc (±32 samples) with the record continued by
point reflection beyond its ends, both to 2 × `--substeps` points per sample and then
linearly, so that every RK4 stage of the `--substeps` steps per 1/750 s lands on an
upsampled point. Linear interpolation of the 750 Hz samples instead errs by up to 1 N
on the sweep.

The test outputs are scored outside the project. The script reports e_RMS of each
prediction against the true model's simulation of the same input (which reproduces the
official multisine output to ~1e-7 m, SYSTEMS.md §4), and against `--test-output`
if one is given (.npy or .mat). Alternatives timed in the same run: the linear model,
and `scipy.optimize.least_squares` on the same jitted residual from the same start
(`against_scipy`; `--no-scipy` to skip): "trf" and "lm", each with 2-point finite
differences and with the exact Jacobian (a jitted `jax.jacfwd` of that residual), at
equal accuracy (each to `fit_system`'s final loss × (1 + 1e-3), or for at most
`--budget-factor` × its time), each fit in a fresh process with its compilation
measured (`_fit_baselines.py`): `speedup_vs_scipy_fd` and
`speedup_vs_scipy_exact_jacobian` (the fastest of each kind over `fit_system`,
compilation included) and their `_excluding_compile` and `_cpu_time` (the
process's CPU time to the target, every thread's: `fit_system` splits its Jacobian's
columns over the cores, scipy's finite differences run one after another).
"""

import argparse
import json
import os
import platform
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import jaxmr  # noqa: E402

if __name__ == "__main__":
    # As users are advised to: each simulation loop one XLA kernel (the residual's
    # forward-mode Jacobian ran 5x faster), every core a device; before JAX's backend
    # starts. Not when the tests import this file: theirs has started.
    jaxmr.devices.configure_cpu()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
import scipy.io  # noqa: E402

from jaxmr._identify.system import (  # noqa: E402
    SystemRecord,
    _system_residuals,
    _SystemData,
    fit_system,
)
from jaxmr._systems.oscillator import (  # noqa: E402
    band_limited_input,
    hysteretic_benchmark_oscillator,
)
from jaxmr.data import (  # noqa: E402
    load_boucwen_benchmark_input,
    load_boucwen_benchmark_train,
)

FS = 750.0
PERIOD = 8192
KINDS = {PERIOD: "multisine", 153_000: "sinesweep"}
TRUE = {"mass": 2.0, "damping": 10.0, "stiffness": 5e4, "A": 5e4, "beta": -1100.0,
        "gamma": 800.0}  # fmt: skip
FREE = {
    "mass": lambda s: s.mass,
    "damping": lambda s: s.damping,
    "stiffness": lambda s: s.stiffness,
    "A": lambda s: s.damper.hysteresis.A,
    "beta": lambda s: s.damper.hysteresis.beta,
    "gamma": lambda s: s.damper.hysteresis.gamma,
}
POSITIVE = ("mass", "damping", "stiffness", "A", "gamma")


def input_kind(u) -> str:
    """`"multisine"` (one steady-state period, 8192 samples) or `"sinesweep"` (from
    rest, 153 000 samples), told by the length."""
    n = np.size(u)
    if n not in KINDS:
        raise ValueError(
            f"a benchmark test input has 8192 (multisine) or 153000 (sine sweep) "
            f"samples, got {n}."
        )
    return KINDS[n]


def load_input(path) -> np.ndarray:
    """A test input from the official .mat file or a .npy array (1-D, 750 Hz)."""
    if str(path).endswith(".mat"):
        return load_boucwen_benchmark_input(path).u
    return np.asarray(np.load(path), dtype=float).reshape(-1)


def load_output(path) -> np.ndarray:
    if str(path).endswith(".mat"):
        content = scipy.io.loadmat(path)
        arrays = [v for k, v in content.items() if not k.startswith("__")]
        if len(arrays) != 1:
            raise ValueError(f"{path}: expected one variable, found {len(arrays)}.")
        return np.asarray(arrays[0], dtype=float).reshape(-1)
    return np.asarray(np.load(path), dtype=float).reshape(-1)


def excitation(u, kind: str, substeps: int, periods: int = 1) -> jaxmr.Sampled:
    """The force signal of a record: `periods` copies of a multisine period, or the
    sweep once; upsampled to 2·substeps points per sample."""
    factor = 2 * substeps
    if kind == "multisine":
        one = np.asarray(band_limited_input(u, FS, factor, periodic=True).values)
        values = np.tile(one, periods)
    else:
        values = np.asarray(band_limited_input(u, FS, factor, periodic=False).values)
    return jaxmr.Sampled(np.arange(values.size) / (FS * factor), values, uniform=True)


def from_rest(system, signal, samples: int, substeps: int) -> np.ndarray:
    """The displacement at `samples` samples (750 Hz), from rest, open loop."""
    solution = jaxmr.simulate_system(
        system,
        signal,
        0.0,
        samples / FS,
        sampling=jaxmr.Sampling(dt=1 / FS),
        integrator=jaxmr.FixedStep(substeps),
    )
    return np.asarray(solution.outputs["body_position"])


def simulate(system, u, kind: str, substeps: int):
    """The benchmark's output for input `u`: the steady state for a multisine period
    (the last of three simulated from rest), the response from rest for a sweep.
    Returns (y, how far the last two periods differ [m rms] or None)."""
    n = np.size(u)
    periods = 3 if kind == "multisine" else 1
    y = from_rest(system, excitation(u, kind, substeps, periods), periods * n, substeps)
    if kind == "multisine":
        last, before = y[-n:], y[-2 * n : -n]
        return last, float(np.sqrt(np.mean((last - before) ** 2)))
    return y, None


def rms(e) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def linear_fit(u, y):
    """(m, c, k) from the steady-state periods 2–5 in the frequency domain."""
    periods = u.size // PERIOD
    U = np.fft.rfft(u.reshape(periods, PERIOD)[1:], axis=1).mean(0)
    Y = np.fft.rfft(y.reshape(periods, PERIOD)[1:], axis=1).mean(0)
    w = 2 * np.pi * np.fft.rfftfreq(PERIOD, 1 / FS)
    lines = np.abs(U) > 1e-3 * np.abs(U).max()
    w, U, Y = w[lines], U[lines], Y[lines]
    # U = (k - m w² + i c w) Y, split into real and imaginary parts.
    rows = np.concatenate(
        [
            np.stack([-(w**2) * Y.real, -w * Y.imag, Y.real], axis=1),
            np.stack([-(w**2) * Y.imag, w * Y.real, Y.imag], axis=1),
        ]
    )
    m, c, k = np.linalg.lstsq(rows, np.concatenate([U.real, U.imag]), rcond=None)[0]
    return float(m), float(c), float(k)


def linear_system(m, c, k):
    # A Bouc–Wen with no force (alpha = 0): the same simulation path, a linear model.
    zero = jaxmr.BoucWen(alpha=0.0, c0=0.0, A=1.0, beta=0.0, gamma=0.0, n=1.0)
    return jaxmr.SingleDegreeOfFreedom(m, zero, damping=c, stiffness=k)


def start_system(m, c, k):
    """The fit's start, its free parameters wrapped (the rest `Fixed`)."""
    start = hysteretic_benchmark_oscillator(
        mass=m, damping=c, stiffness=k / 2, alpha=k / 2, beta=1.0, gamma=2000.0,
        delta=-500.0,
    )  # fmt: skip
    start = jaxmr.fit_only(start, lambda s: tuple(f(s) for f in FREE.values()))
    positive = [FREE[name] for name in POSITIVE]
    return eqx.tree_at(
        lambda s: tuple(f(s) for f in positive),
        start,
        tuple(jaxmr.Positive(f(start)) for f in positive),
    )


def values_of(system) -> dict:
    return {name: float(f(system)) for name, f in FREE.items()}


def relative_errors(values: dict) -> dict:
    return {k: values[k] / TRUE[k] - 1 for k in TRUE}


def training_record(train, periods: int, substeps: int):
    """The record `fit_system` fits (the training record's first `periods` periods,
    from rest) and the fit's start (from the linear model)."""
    m, c, k = linear_fit(train.u, train.y)
    n = periods * PERIOD
    record = SystemRecord(
        train.t[:n],
        train.y[:n],
        excitation(train.u[:PERIOD], "multisine", substeps, periods),
        name=f"train, periods 1-{periods}",
    )
    return record, start_system(m, c, k)


def with_values(start, values: dict):
    """The start's system, unconstrained, with the free parameters' `values`."""
    from jaxmr._parameter import unwrap

    return eqx.tree_at(
        lambda s: tuple(f(s) for f in FREE.values()),
        unwrap(start),
        tuple(jnp.asarray(values[name], dtype=float) for name in FREE),
    )


def jaxmr_fit(train, periods: int, substeps: int, solver: str) -> dict:
    """`fit_system` from the start, in a fresh process (`_fit_baselines`): its time
    to the target of the equal-accuracy rule (its own final loss × (1 + 1e-3)) and in
    all, the compilation within each, and the fit."""
    from _fit_baselines import TARGET, CompileClock, LossTrace, cold_jax, timed_figures

    cold_jax()
    record, start = training_record(train, periods, substeps)
    # "lm": optimistix's LevenbergMarquardt, fit_system's alternative to its default.
    lm = None if solver == "fast" else optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10)
    with CompileClock() as clock:
        started = time.time()
        trace = LossTrace(started)
        result = fit_system(
            start,
            record,
            substeps=substeps,
            solver=lm,
            progress=lambda step, loss: trace.add(loss),
        )
        total = time.time() - started
    print(result, flush=True)
    values = values_of(result.model)
    return {
        **timed_figures(trace, clock, result.loss * TARGET, total),
        "steps": result.num_steps,
        "reason": result.reason,
        "loss": result.loss,
        "values": values,
        "std_errors": {
            name.rsplit(".", 1)[-1]: float(se)
            for name, se in zip(result.names, result.std_errors)
        },
        "relative_errors": relative_errors(values),
        "train_rmse_m": float(result.rmse[0]),
        "train_nrmse": float(result.nrmse[0]),
        "unidentified": list(result.unidentified),
    }


def flat_residual(start, record, substeps):
    """`fit_system`'s residual of `record` as a function of the free parameters as
    one flat vector (the layout finite differences need), and their start values:
    (residual, x0, treedef, static). Built from `fit_system`'s private pieces (there
    is no public residual): the same simulation, closing over the data and the fixed
    parameters as `fit_system`'s own residual does (`_closed_residuals`)."""
    from jaxmr._closed_loop import _as_controller
    from jaxmr._identify.system import _Simulation, _stack_records
    from jaxmr._parameter import free_filter, unwrap

    free, static = eqx.partition(start, free_filter(start))
    leaves, treedef = jax.tree.flatten(free)
    data: _SystemData = _stack_records([record], start, None, None)
    sim = _Simulation(
        controller=_as_controller(0.0),
        reference=unwrap(start),
        output="body_position",
        substeps=substeps,
        delay=1,
    )

    def residual(flat):
        f = jax.tree.unflatten(treedef, list(flat))
        return _system_residuals(f, static, data, sim)

    x0 = np.array([float(v) for v in leaves])
    return residual, x0, treedef, static


def scipy_fit(
    train, periods, substeps, method, exact, target, budget, max_nfev=None
) -> dict:
    """scipy's least_squares (`method`, finite differences or, `exact`, a jitted
    `jax.jacfwd`) on `fit_system`'s residual (`flat_residual`, jitted) from the same
    start, in a fresh process, until `target` or `budget` [s]
    (`_fit_baselines.scipy_to_target`); with the parameters it ended at."""
    from _fit_baselines import cold_jax, scipy_to_target

    cold_jax()
    record, start = training_record(train, periods, substeps)
    built = {}

    def build():
        residual, x0, treedef, static = flat_residual(start, record, substeps)
        built.update(treedef=treedef, static=static)
        return residual, x0, ()

    figures = scipy_to_target(
        build,
        method=method,
        exact=exact,
        target=target,
        budget=budget,
        max_nfev=max_nfev,
    )
    from jaxmr._parameter import unwrap

    leaves = [jnp.asarray(v) for v in figures.pop("x")]
    model = unwrap(
        eqx.combine(jax.tree.unflatten(built["treedef"], leaves), built["static"])
    )
    values = values_of(model)
    return figures | {"values": values, "relative_errors": relative_errors(values)}


def timed_simulations(systems: dict, u, kind, substeps):
    """Predictions of several systems of one structure: the first call compiles, the
    others reuse it (their parameters are traced arrays)."""
    out, timing = {}, {}
    for name, system in systems.items():
        t0 = time.perf_counter()
        out[name] = simulate(system, u, kind, substeps)
        timing[name] = time.perf_counter() - t0
    return out, timing


# scipy's methods, each with finite differences and with the exact Jacobian; "lm"
# (MINPACK) where there are no bounds, as here (the free variables are unbounded).
SCIPY_METHODS = ("trf", "lm")


def against_scipy(
    train,
    periods,
    substeps,
    solver="fast",
    max_nfev=None,
    no_scipy=False,
    budget_factor=10.0,
):
    """`fit_system` on the training record's first `periods` periods, and scipy's
    least_squares on the same residual from the same start (unless `no_scipy`), each
    in a fresh process, at equal accuracy (`_fit_baselines`): scipy's "trf" and "lm",
    each with finite differences and with the exact Jacobian, until jaxmr's final
    loss × (1 + 1e-3) or `budget_factor` × jaxmr's time to it (at least 30 s).

    **Returns:** (jaxmr's fitted system, the start, the fastest finite-difference
    baseline's system or None, figures): `fit` and `scipy` (one entry per baseline),
    and `speedup_vs_scipy_fd`, `speedup_vs_scipy_exact_jacobian` (the fastest
    baseline of each kind over jaxmr, compilation included) with their
    `_excluding_compile`.
    """
    from _fit_baselines import TARGET, in_fresh_process, speedups

    print(f"fit_system on {periods} period(s), 6 parameters ...", flush=True)
    fit = in_fresh_process(jaxmr_fit, train, periods, substeps, solver)
    print(f"  {fit['total_seconds']:.1f} s in all ({fit['compile_seconds']:.1f} s "
          f"compiling), {fit['steps']} steps, loss {fit['loss']:.6g}; the target in "
          f"{fit['seconds']:.1f} s")  # fmt: skip
    _, start = training_record(train, periods, substeps)
    figures = {"fit": fit}
    if no_scipy:
        return with_values(start, fit["values"]), start, None, figures
    target = fit["loss"] * TARGET
    budget = max(30.0, budget_factor * fit["seconds"])
    baselines = {}
    for method in SCIPY_METHODS:
        for exact in (False, True):
            name = f"{method}_{'exact' if exact else 'fd'}"
            print(f"scipy least_squares {name} ...", flush=True)
            baselines[name] = b = in_fresh_process(
                scipy_fit, train, periods, substeps, method, exact, target, budget,
                max_nfev,
            )  # fmt: skip
            print(f"  {b['seconds']:.1f} s ({b['compile_seconds']:.1f} s compiling), "
                  f"{b['residual_evaluations']} residuals, {b['stop']}")  # fmt: skip
    figures["scipy"] = baselines
    figures["target_loss"] = target
    figures["budget_seconds"] = budget
    figures |= speedups(fit, baselines, "vs_scipy")
    print(f"  speedup_vs_scipy_fd {figures['speedup_vs_scipy_fd']:.2f} "
          f"({figures['speedup_vs_scipy_fd_excluding_compile']:.2f} without "
          "compiling)")  # fmt: skip
    fd = min(
        (b for b in baselines.values() if not b["exact"]), key=lambda b: b["seconds"]
    )
    return (
        with_values(start, fit["values"]),
        start,
        with_values(start, fd["values"]),
        figures,
    )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", required=True, help="train.h5")
    parser.add_argument("--test-input", required=True, help="uval_*.mat or .npy")
    parser.add_argument("--out", required=True, help="predicted output (.npy)")
    parser.add_argument("--json", help="figures (JSON)")
    parser.add_argument("--test-output", help="the official output (.mat or .npy)")
    parser.add_argument(
        "--periods", type=int, default=5, help="training periods used (1-5)"
    )
    parser.add_argument(
        "--solver",
        choices=("fast", "lm"),
        default="fast",
        help="jaxmr.FastLevenbergMarquardt (default) or optimistix's LM",
    )
    parser.add_argument("--substeps", type=int, default=20, help="RK4 steps / sample")
    parser.add_argument("--no-scipy", action="store_true")
    parser.add_argument(
        "--max-nfev",
        type=int,
        default=None,
        help="scipy's max_nfev (default scipy's own); a smoke run caps it",
    )
    parser.add_argument(
        "--budget-factor",
        type=float,
        default=10.0,
        help="each scipy baseline stops after this many times jaxmr's time to the "
        "target (at least 30 s) if it has not reached it (default 10)",
    )
    args = parser.parse_args(argv)

    u_test = load_input(args.test_input)
    kind = input_kind(u_test)
    train = load_boucwen_benchmark_train(args.train)
    true = hysteretic_benchmark_oscillator()
    figures = {
        "benchmark": "boucwen_benchmark",
        "test_input": os.path.basename(args.test_input),
        "kind": kind,
        "periods": args.periods,
        "solver": args.solver,
        "substeps": args.substeps,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"{jax.devices()[0].platform}",
        "load_average": os.getloadavg(),
        "jax": jax.__version__,
    }

    # The true model on the whole training record (five periods from rest): the noise.
    periods = train.u.size // PERIOD
    train_signal = excitation(train.u[:PERIOD], "multisine", args.substeps, periods)
    y_true_train = from_rest(true, train_signal, train.u.size, args.substeps)
    figures["true_model_train_rmse_m"] = rms(y_true_train - train.y)
    print(f"true model on the training record: rms error "
          f"{figures['true_model_train_rmse_m']:.3g} m (the noise)")  # fmt: skip

    t0 = time.perf_counter()
    m, c, k = linear_fit(train.u, train.y)
    figures["linear"] = {"m": m, "c": c, "k": k, "time_s": time.perf_counter() - t0}
    print(f"linear model: m = {m:.4g} kg, c = {c:.4g} N s/m, k = {k:.4g} N/m")

    fitted, _, scipy_model, fit_figures = against_scipy(
        train,
        args.periods,
        args.substeps,
        args.solver,
        args.max_nfev,
        args.no_scipy,
        args.budget_factor,
    )
    figures.update(fit_figures)
    # The first is timed with its compilation, the others reuse it.
    systems = {"fitted": fitted, "true": true, "linear": linear_system(m, c, k)}
    if scipy_model is not None:
        systems["scipy"] = scipy_model

    # The fitted model on the whole training record (all five periods).
    y_fit_train = from_rest(fitted, train_signal, train.u.size, args.substeps)
    figures["fitted_train_rmse_m"] = rms(y_fit_train - train.y)
    figures["fitted_vs_true_train_rmse_m"] = rms(y_fit_train - y_true_train)

    predictions, timing = timed_simulations(systems, u_test, kind, args.substeps)
    first = next(iter(timing))
    figures["prediction"] = {
        "first_call_s": timing[first],
        "run_s": timing["true"],
        "compile_s_estimate": timing[first] - timing["true"],
    }
    reference = predictions["true"][0]
    figures["e_rms_vs_true_model_m"] = {
        name: rms(y - reference) for name, (y, _) in predictions.items()
    }
    if kind == "multisine":
        figures["steady_state_last_two_periods_m"] = predictions["fitted"][1]
    np.save(args.out, predictions["fitted"][0])
    print(f"wrote {args.out} ({kind}, {u_test.size} samples)")
    for name, e in figures["e_rms_vs_true_model_m"].items():
        if name != "true":
            print(f"  e_RMS {name} vs the true model: {e:.3g} m")
    if args.test_output:
        y_test = load_output(args.test_output)
        figures["e_rms_m"] = {
            name: rms(y - y_test) for name, (y, _) in predictions.items()
        }
        for name, e in figures["e_rms_m"].items():
            print(f"  e_RMS {name} vs {os.path.basename(args.test_output)}: {e:.3g} m")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as file:
            json.dump(figures, file, indent=2)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
