"""Calibration of `FitResult`'s standard errors and of the prediction band (issue 25).

A simulated damper: a Dahl model whose k_x and k_w are `LinearLaw`s of the current
(5 free parameters), driven by a 2 Hz ±10 mm sine at 0, 0.5 and 1 A, sampled at
500 Hz. Each case refits it to `--refits` noise realisations (each from the truth's
values times a factor within ±10 %, so that every refit lands in the truth's minimum:
this measures the statistics, not the optimiser). A nominal 95 % interval is
value ± 1.96 std_error; its coverage is the fraction of (refit, parameter) pairs
whose interval holds the truth. Cases:

- `equal_white`: three 2000-sample records, white noise of 3 % of std(F);
- `unequal_white`: 250, 1000 and 4000 samples (16x), the same white noise in N, so
  that the default weighting 1/(std F·√N) is not 1/σ;
- `equal_ar90`, `unequal_ar90`, `equal_ar98`, `unequal_ar98`: AR(1) noise with lag-1
  autocorrelation 0.9 and 0.98 (the same marginal 3 %);
- `equal_mixed90`, `unequal_mixed90`: white and AR(1) noise (0.9) together, half
  the variance each (the same marginal 3 %): a sensor's noise beside a slow
  disturbance;
- `noise_levels`: equal records, white noise of 1 %, 3 % and 10 % of std(F);
- `richer_model`: the data of a Bouc–Wen model (n = 2, with a stiffness) at 3 %
  white noise, fitted with the Dahl model: coverage of the best-fitting values (the
  pseudo-true ones, from a fit to the noise-free force).

Every estimator `statistics_from` offers is measured on the same refits (its
Jacobian and residual taken again at each fitted point): `pooled` (the former
s² (JᵀJ)⁺), `experiment` (a variance per experiment), `hac` (Newey–West, Andrews'
bandwidth), `prewhitened` (AR(1) prewhitening then Newey–West: the default).
`min_coverage`, `max_coverage` are the default's (goal 0.90-0.98 in every case).

`band_coverage`: the prediction band (`jaxmr.prediction_band`, 95 %) of each refit on
a held-out test (0.25 A, 1.5 Hz, ±12 mm, noise-free): the fraction of its samples
whose band holds the true force, over every refit of the well-specified cases (for
`richer_model`, reported apart, against the pseudo-true model's force).

Seeds: the reported figures use noise seeds 0, 1, ... (`REPORT_SEED`). The default
estimator and its one tuned setting were chosen on the seeds from `TUNING_SEED`
(`--tuning`, 30 refits), a different set: there the AR(1) coefficient's bias
correction (1 + 3ρ)/n in `jaxmr/_identify/result.py` took `unequal_ar98` from 0.887
to 0.960 and `unequal_ar90` from 0.900 to 0.920, the other cases unchanged
(`RHO_MAX` = 0.99 was set beforehand, not tuned). In session 27 the filter's
coefficient became the larger of ρ₁ and ρ₂/ρ₁ (`ar_coefficient`), chosen there too
(the mixed cases 0.81 → 0.97 and 0.67 → 0.94). The headline is scored on fresh seeds
(`--fresh`, `FRESH_SEED`), drawn after every setting was frozen.

    python benchmarks/calibration.py --fresh --refits 100 \
        --json benchmarks/results/calibration.json
    python benchmarks/calibration.py --refits 10 --cases equal_white   # a quick look
"""

import argparse
import os
import platform
import sys
import time
from pathlib import Path
from types import SimpleNamespace

HERE = Path(__file__).resolve()
sys.path.insert(0, str(HERE.parents[1]))  # the repository's jaxmr
from _report import write_figures  # noqa: E402

REPORT_SEED = 0
TUNING_SEED = 100_000
# Drawn on 2026-11-27 (session 27), after the prewhitening coefficient took the
# ARMA(1,1) ratio ρ₂/ρ₁ (`result.ar_coefficient`, chosen on the tuning seeds: the
# mixed cases went from 0.81 and 0.67 to 0.97 and 0.94, every other case within
# 0.90-0.98) and was frozen, for the headline with 100 refits per case (`--fresh`).
# The previous fresh seeds (300000-300099, drawn 2026-11-26) scored the estimator
# before this change.
FRESH_SEED = 400_000
RATE = 500.0  # [Hz]
CURRENTS = (0.0, 0.5, 1.0)
EQUAL = (2000, 2000, 2000)
UNEQUAL = (250, 1000, 4000)
CASES = {
    "equal_white": dict(lengths=EQUAL, rho=0.0),
    "unequal_white": dict(lengths=UNEQUAL, rho=0.0),
    "equal_ar90": dict(lengths=EQUAL, rho=0.9),
    "unequal_ar90": dict(lengths=UNEQUAL, rho=0.9),
    "equal_ar98": dict(lengths=EQUAL, rho=0.98),
    "unequal_ar98": dict(lengths=UNEQUAL, rho=0.98),
    # White and AR(1) noise together, each half the variance: a sensor's white
    # noise beside a slow disturbance (a user's trial, session 27: 2 % white + 2 %
    # AR(1) at 0.9 covered 84 %).
    "equal_mixed90": dict(lengths=EQUAL, rho=0.9, white=0.5),
    "unequal_mixed90": dict(lengths=UNEQUAL, rho=0.9, white=0.5),
    "noise_levels": dict(lengths=EQUAL, rho=0.0, noise=(0.01, 0.03, 0.1)),
    "richer_model": dict(lengths=EQUAL, rho=0.0, truth="bouc_wen"),
}
NOISE = 0.03  # of std(F), per experiment
Z95 = 1.959964


def dahl(values, wrap=None):
    import jaxmr

    w = (lambda v: v) if wrap is None else wrap
    kx_a, kx_b, kw_a, kw_b, rho = values
    return jaxmr.Dahl(
        k_x=jaxmr.LinearLaw(w(kx_a), w(kx_b)),
        k_w=jaxmr.LinearLaw(w(kw_a), w(kw_b)),
        rho=w(rho),
    )


TRUE_DAHL = (800.0, 1500.0, 150.0, 600.0, 800.0)


def bouc_wen():
    import jaxmr

    return jaxmr.BoucWen(
        # z peaks at (A/(β + γ))^(1/n) = 1/40: α z as the Dahl's k_w.
        alpha=jaxmr.LinearLaw(6000.0, 24000.0),
        c0=jaxmr.LinearLaw(800.0, 1500.0),
        A=1.0,
        beta=1000.0,
        gamma=600.0,
        n=2.0,
        k0=500.0,
        x0=0.0,
        f0=0.0,
    )


def motions(lengths, frequency=2.0, amplitude=0.01, currents=CURRENTS):
    import numpy as np

    out = []
    for n, i in zip(lengths, currents):
        t = np.arange(n) / RATE
        w = 2 * np.pi * frequency
        out.append(
            SimpleNamespace(
                t=t,
                x=amplitude * np.sin(w * t),
                v=amplitude * w * np.cos(w * t),
                current=np.full(n, i),
                force=None,
                name=f"{i} A ({n} samples)",
            )
        )
    return out


def ar1(rng, n, rho):
    """Stationary AR(1) noise of unit variance."""
    import numpy as np

    e = rng.standard_normal(n)
    out = np.empty(n)
    out[0] = e[0]
    for k in range(1, n):
        out[k] = rho * out[k - 1] + np.sqrt(1 - rho**2) * e[k]
    return out


def run_case(name, spec, refits, first_seed, policy):
    import equinox as eqx
    import numpy as np

    import jaxmr
    from jaxmr._identify.data import pack
    from jaxmr._identify.residual import residuals
    from jaxmr._identify.result import (
        ERROR_METHODS,
        jacobian_matrix,
        kept_groups,
        statistics_from,
    )
    from jaxmr._parameter import free_filter

    tests = motions(spec["lengths"])
    truth = bouc_wen() if spec.get("truth") == "bouc_wen" else dahl(TRUE_DAHL)
    clean = jaxmr.predict_all(truth, tests, integrator=policy)
    held_out = motions((1500,), 1.5, 0.012, (0.25,))
    P = jaxmr.Positive
    if spec.get("truth") == "bouc_wen":
        # The pseudo-true values: the Dahl model fitted to the noise-free force.
        noiseless = [
            SimpleNamespace(**{**vars(e), "force": f}) for e, f in zip(tests, clean)
        ]
        best = jaxmr.fit(
            dahl(TRUE_DAHL, P), noiseless, integrator=policy, progress=False
        )
        target = np.asarray(best.values)
        held_force = jaxmr.predict_all(best.model, held_out, integrator=policy)[0]
    else:
        target = np.asarray(TRUE_DAHL)
        held_force = jaxmr.predict_all(truth, held_out, integrator=policy)[0]
    levels = np.broadcast_to(np.asarray(spec.get("noise", NOISE)), (len(tests),))
    covered = {m: [] for m in ERROR_METHODS}
    ratios, band, seconds, values_all = [], [], [], []
    for k in range(refits):
        rng = np.random.default_rng(first_seed + k)
        data = []
        for e, f, level in zip(tests, clean, levels):
            noise = (
                ar1(rng, len(f), spec["rho"])
                if spec["rho"]
                else rng.standard_normal(len(f))
            )
            if spec.get("white"):  # unit variance: shares of white and AR(1)
                white = spec["white"]
                noise = np.sqrt(1 - white) * noise + np.sqrt(white) * (
                    rng.standard_normal(len(f))
                )
            data.append(
                SimpleNamespace(**{**vars(e), "force": f + level * np.std(f) * noise})
            )
        start = target * np.exp(rng.uniform(-0.1, 0.1, target.size))
        t0 = time.perf_counter()
        result = jaxmr.fit(dahl(start, P), data, integrator=policy, progress=False)
        seconds.append(time.perf_counter() - t0)
        values = np.asarray(result.values)
        values_all.append(values)
        # Every estimator on the same fitted point and Jacobian (as `fit` takes it).
        free, static = eqx.partition(
            result.constrained, free_filter(result.constrained)
        )
        refined = pack(data, policy.refined(4))
        r, J = jacobian_matrix(residuals, free, static, refined, None)
        groups = kept_groups(refined.kept_counts)
        for method in ERROR_METHODS:
            se = statistics_from(r, J, free, static, groups, method).std
            covered[method].append(np.abs(values - target) <= Z95 * se)
        ratios.append(np.asarray(result.std_errors))
        (b,) = jaxmr.prediction_band(result, held_out, integrator=policy)
        band.append(float(np.mean((b.lower <= held_force) & (held_force <= b.upper))))
    spread = np.std(np.array(values_all), axis=0, ddof=1)
    return {
        "coverage": {m: float(np.mean(c)) for m, c in covered.items()},
        "coverage_per_parameter": np.mean(covered["prewhitened"], axis=0).tolist(),
        "reported_over_actual_spread": (np.median(ratios, axis=0) / spread).tolist(),
        "band_coverage": float(np.mean(band)),
        "median_fit_s": float(np.median(seconds)),
        "refits": refits,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--refits", type=int, default=50)
    parser.add_argument("--cases", nargs="*", default=list(CASES))
    parser.add_argument(
        "--tuning", action="store_true", help="the tuning seeds (TUNING_SEED)"
    )
    parser.add_argument(
        "--fresh", action="store_true", help="the fresh scoring seeds (FRESH_SEED)"
    )
    args = parser.parse_args()
    import jax

    jax.config.update("jax_enable_x64", True)
    import jaxmr

    policy = jaxmr.StepPolicy(substeps=2)
    first = TUNING_SEED if args.tuning else FRESH_SEED if args.fresh else REPORT_SEED
    t0 = time.perf_counter()
    cases = {}
    for name in args.cases:
        cases[name] = run_case(name, CASES[name], args.refits, first, policy)
        print(name, cases[name]["coverage"], cases[name]["band_coverage"], flush=True)
    default = {n: c["coverage"]["prewhitened"] for n, c in cases.items()}
    specified = [c["band_coverage"] for n, c in cases.items() if n != "richer_model"]
    figures = {
        "min_coverage": min(default.values()),
        "max_coverage": max(default.values()),
        "coverage": default,
        "band_coverage": min(specified) if specified else None,
        "band_coverage_per_case": {n: c["band_coverage"] for n, c in cases.items()},
        "estimators": {n: c["coverage"] for n, c in cases.items()},
        "cases": cases,
        "seeds": f"noise seeds {first}..{first + args.refits - 1} per case",
        "seconds": time.perf_counter() - t0,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "goals": {
            "min_coverage, max_coverage": "0.90-0.98 in every case",
            "band_coverage": "0.90-0.98",
        },
    }
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
