"""Semi-active control of a quarter car on ISO 8608 class C roads (issues 10 and 28): a
rich law tuned by gradients through the closed loop from a generic start, against
CMA-ES (best of a grid of step sizes and populations) at equal cost, against constant
currents, the classical laws and an optimal schedule; a law under a tyre-load
constraint; robust tuning over damper samples drawn from a fit's uncertainty. Every
headline is scored on road sets and damper samples drawn with fresh seeds after every
setting is frozen.

    python benchmarks/quarter_car_control.py --json benchmarks/results/quarter_car_control.json
    python benchmarks/quarter_car_control.py --json /tmp/qc.json --quick   # smoke test
    python benchmarks/quarter_car_control.py --json OUT --all-laws  # tune every law too
    python benchmarks/quarter_car_control.py --json OUT --speed  # closed-loop speed too

The car: ms 350 kg, mu 40 kg, ks 20 kN/m, kt 200 kN/m (`jaxmr.passenger_car`) with
`jaxmr.passenger_car_mr_damper()` (Bouc–Wen, 30 N + 200 N·s/m at 0 A to 1 kN + 2 kN·s/m
at 1 A, 8 ms current lag). Control at 1 kHz with one sample of delay, RK4 at 0.25 ms.
Roads: ISO 8608 class C at 72 km/h (20 m/s), by sum of sinusoids.

Three kinds of road set (`Settings`): the training roads (tuned on), the development
roads (the former held-out roads, seen while the settings were chosen over several
sessions: they choose the baselines, e.g. the best constant current), and three fresh
sets, drawn only after every law and baseline is frozen (`score_fresh`): every headline
is from those.

Comfort is the ISO 2631-1 Wk-weighted RMS body acceleration a_w [m/s²]; road holding the
RMS dynamic tyre load over the static load; travel the RMS suspension deflection [m].
"""

import argparse
import dataclasses
import functools
import time
from pathlib import Path

import equinox as eqx
import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _generalisation_data import _noisy  # noqa: E402
from _report import write_figures  # noqa: E402
from jax.flatten_util import ravel_pytree  # noqa: E402

import jaxmr  # noqa: E402
import jaxmr.data as jd  # noqa: E402
import jaxmr.linear  # noqa: E402
import jaxmr.metrics  # noqa: E402
from jaxmr._closed_loop import loop_settings  # noqa: E402
from jaxmr._tune.common import prepare, set_temperature  # noqa: E402
from jaxmr._tune.loss import loss_and_grad, losses, population_losses  # noqa: E402

# Every law here runs, is tuned and is scored with perfect information
# (`sensors="oracle"`: the true measurements and, for the laws' inverse models, the
# simulated damper at its true hysteretic state): a study of the laws and the tuners.
# What realistic sensors and an observer cost is `realistic_control.py`'s.
ORACLE = "oracle"
simulate_system = functools.partial(jaxmr.simulate_system, sensors=ORACLE)
tune = functools.partial(jaxmr.tune, sensors=ORACLE)
cma_es = functools.partial(jaxmr.cma_es, sensors=ORACLE)
evaluate = functools.partial(jaxmr.evaluate, sensors=ORACLE)


@dataclasses.dataclass(frozen=True)
class Settings:
    """Every setting of the run, frozen before any fresh road set or damper sample is
    drawn. The values below are the full run's; `QUICK` shrinks the sizes for a
    smoke test (same seeds)."""

    duration: float = 8.0  # s per road
    # Road seeds (`jax.random.key(seed)` per road). Training: tuned on. Development:
    # the held-out roads of sessions 2-9, seen while these settings were chosen; they
    # choose the baselines (best constant, best feasible constant). Fresh: three sets
    # never seen before this script, drawn after everything is frozen (seeds never
    # used before: sessions 2-9 probed 10-13, 20-23, 2000-2011 and 3000-3011).
    # Sessions 11-14 scored on 41000-41011, 42000-42011 and 43000-43011; session 15
    # changed the constrained law's rule after seeing it break the limit on the second
    # of them, so those sets were retired. Session 15-16 scored on 44000-44011,
    # 45000-45011 and 46000-46011; session 17 drew new sets for a change of the
    # constrained law's sensors (`CONSTRAINED_FEATURES`), which it then dropped on the
    # development roads' figure: these sets score the law frozen in session 15.
    train_seeds: tuple = tuple(range(4))
    dev_seeds: tuple = tuple(range(1000, 1012))
    fresh_road_sets: tuple = (
        tuple(range(51000, 51012)),
        tuple(range(52000, 52012)),
        tuple(range(53000, 53012)),
    )
    # The rich law (chosen on the training roads' loss in sessions 4-9): its
    # measurements, 16 tanh units, Adam at 0.03, the relaxation annealed 0.1 -> 0.05,
    # the hard law checked every 4th step, the whole schedule run (patience = steps).
    rich_steps: int = 80
    rich_rate: float = 0.03
    check_every: int = 4
    temperature: tuple = (0.1, 0.05)
    # The MLP's initial hidden layer (`ForceFeedback.mlp(key=jax.random.key(seed))`;
    # the output layer starts at zero whatever the seed): the gradient's seeds. Seed 0
    # is the law of sessions 8-9.
    gradient_seeds: tuple = (0, 1, 2)
    # Timing of one forward simulation and one value_and_grad of tune's loss: the
    # fastest of this many interleaved rounds, after a first call (compilation).
    timing_repeats: int = 5
    # CMA-ES (`jaxmr.cma_es`, evosax): the grid of step sizes (in the weights) and
    # populations (17 is CMA-ES's default 4 + 3 ln 84) is run on a selection seed with
    # `cma_selection_factor` x the gradient's mean cost (forward-simulation
    # equivalents; 1.5, to keep the whole run near 15 min); the best cell (lowest training
    # loss) then runs on each of `cma_seeds` (from the gradient's start of the same
    # seed) with `cma_budget_factor` x that seed's gradient cost (forward-simulation
    # equivalents), and at least what its measured generation time affords in
    # `cma_wall_factor` x the gradient's wall clock (compilation counted on both
    # sides), so that a run that never reaches the gradient's loss still decides the
    # wall-clock goal (3x); it stops early if it reaches the gradient's training loss.
    cma_sigmas: tuple = (0.1, 0.3)
    cma_populations: tuple = (17, 34)
    cma_selection_seed: int = 100
    cma_selection_factor: float = 1.5
    cma_seeds: tuple = (0, 1, 2)
    cma_budget_factor: float = 10.0
    cma_wall_factor: float = 3.2
    # Skyhook from 200 N·s/m (ten times too soft) against a grid of gains.
    sky_steps: int = 40
    sky_rate: float = 0.15
    sky_grid: int = 37
    # The constrained law (session 8): dual ascent on the Lagrangian of the mean tyre
    # load, rounds of `tune` on comfort + lambda (tyre / target - 1), the multiplier
    # raised by RHO x the training excess over the target after each round; the
    # rounds aim at `target` x the limit to start. The limit holds on a road set
    # when the set's mean tyre load is at most `tyre_limit` x passive-on's on the
    # same roads: a statistic of 12 random roads, which varies from set to set.
    # Session 15's rule (sessions 8-14 kept a round whose training tyre load was at
    # most 0.97 x the limit, and a fresh set then broke the limit by 0.7 %): a
    # round's law is kept when, on the development roads resampled as sets of their
    # size (`bootstrap` draws), its tyre load over passive-on's is within the limit
    # with probability `confidence`; the most comfortable such round on the training
    # roads is kept. A round that misses lowers the next rounds' target by its
    # excess. Frozen here; no fresh road set enters its choice.
    tyre_limit: float = 1.02  # x passive-on's RMS dynamic tyre load
    lagrange_start: float = 0.3
    rho: float = 3.0
    rounds: int = 6
    round_steps: int = 30
    target: float = 0.96
    confidence: float = 0.975
    bootstrap: int = 4000
    bootstrap_seed: int = 20261126
    # Robust tuning. The damper is identified from simulated tests of the preset
    # (three 2 Hz ±10 mm sine tests at 0, 0.5, 1 A, 3 cycles at 500 Hz, the first
    # cycle left out; 2 % white + 3 % AR(1) force noise, `_generalisation_data`),
    # fitting α and c0 (each a + b i), β and γ; the controller inverts the fitted
    # (nominal) damper while the simulated unit is drawn from the fit's uncertainty
    # (`FitResult.sample`). The linear law (3 gains) is tuned from zero on the nominal
    # damper (stage 1), then continued twice: over `robust_samples` training samples
    # weighing the worst `worst_share` (CVaR), or on the nominal damper again. The
    # training samples of seed s are drawn with key `robust_sample_seeds[s]`; the
    # fresh samples that score them with `fresh_sample_seed`, on the first fresh road
    # set. The continuations run nearly hard (session 9: the samples' worst-third loss
    # differs between laws by less than the relaxation's bias at T = 0.05).
    id_noise_seed: int = 20261128
    robust_samples: int = 6
    worst_share: float = 1 / 3
    robust_roads: int = 4
    robust_steps: int = 60
    robust_rate: tuple = (0.05, 0.005)
    continuation_temperature: tuple = (0.02, 0.01)
    continuation_rate: tuple = (0.02, 0.002)
    robust_sample_seeds: tuple = (7, 8, 9)
    fresh_sample_seed: int = 71000
    fresh_samples: int = 32
    # The ceiling: a current schedule optimised on each of the first `bound_roads`
    # development roads.
    bound_roads: int = 2
    bound_steps: int = 160
    bound_rate: float = 0.3


FULL = Settings()
# The smoke test: the same seeds, fewer and shorter roads, few steps. Its figures mean
# nothing; it checks that every section runs.
QUICK = dataclasses.replace(
    FULL,
    duration=2.0,
    train_seeds=FULL.train_seeds[:2],
    dev_seeds=FULL.dev_seeds[:2],
    fresh_road_sets=tuple(s[:2] for s in FULL.fresh_road_sets),
    rich_steps=6,
    timing_repeats=1,
    cma_selection_factor=1.0,
    cma_budget_factor=2.0,
    cma_wall_factor=0.0,
    sky_steps=4,
    sky_grid=4,
    rounds=1,
    round_steps=4,
    robust_samples=3,
    robust_roads=2,
    robust_steps=4,
    fresh_samples=3,
    bound_roads=1,
    bound_steps=4,
)

I_MAX = 1.0
SPEED = 20.0  # m/s
CONSTANTS = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0)
RICH_FEATURES = ("body_velocity", "body_acceleration", "damper_velocity")
# The constrained law's sensors: the rich law's and the wheel's velocity (road holding
# needs the wheel's motion). Session 17 tried adding the suspension's deflection,
# chosen on the development roads by a script of its own (kept round 0.127 against the
# best feasible constant, tyre bound 0.9987); in this script's own run its round 1 came
# out at a bound of 1.0017 instead, round 2 was kept, and the development roads gave
# 0.048 (fresh sets 51000-53011: 0.047). On that development figure the deflection
# was dropped again; the fresh sets stay those of the run (benchmarks/README.md).
CONSTRAINED_FEATURES = RICH_FEATURES + ("wheel_velocity",)
RICH_WIDTH = 16


def metrics_for(car):
    load = float(car.static_load)

    def travel(sol):
        return jaxmr.metrics.rms(sol["damper_displacement"])

    def tyre(sol):
        return jaxmr.metrics.rms(sol["tyre_force"]) / load

    def unweighted(sol):
        return jaxmr.metrics.rms(sol["body_acceleration"])

    def current(sol):
        return jnp.mean(sol.current)

    return {
        "comfort": jaxmr.metrics.comfort,
        "rms_acceleration": unweighted,
        "travel": travel,
        "tyre_load": tyre,
        "mean_current": current,
    }


def roads(seeds, duration):
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
    return jax.vmap(lambda k: jaxmr.iso8608_road("C", SPEED, duration, k))(keys)


def first(batch, n):
    """The first `n` roads of a batch."""
    return jax.tree.map(lambda x: x[:n], batch)


# Tuned leaves of (system, controller), module-level so that tune's compiled loss is
# reused across calls; on-levels stay within the damper's range, the hybrid blend in
# (0, 1].
def c_sky(p):
    return p[1].c_sky


def c_gnd(p):
    return p[1].c_gnd


def on_level(p):
    return p[1].i_max


def gain_blend(p):
    return p[1].gain, p[1].alpha


def pdd_gain(p):
    return p[1].ks


def weights(p):
    return jaxmr.ForceFeedback.weights(p)


def schedule_logits(p):
    return p[1].logits


ON_BOUNDS = ((0.01, I_MAX),)
HYBRID_BOUNDS = ((10.0, 1e5), (1e-3, 1.0))


def laws(car):
    """The classical laws and their tuned parameters (None: evaluated as designed)."""
    A, B, _ = jaxmr.linear.quarter_car_state_space(car, damping=200.0)
    Q = jnp.diag(jnp.array([1e4, 1e2, 1e3, 1.0]))
    lqr_law = jaxmr.ContinuousClippedOptimal.design(A, B, Q, jnp.array([[1e-5]]), I_MAX)
    clipped = jaxmr.ClippedOptimal.design(A, B, Q, jnp.array([[1e-5]]), I_MAX)
    lyapunov = jaxmr.LyapunovController.design(A, B[:, 0], jnp.eye(4), I_MAX)
    return {
        "skyhook": (jaxmr.Skyhook(2000.0, I_MAX), c_sky, None),
        "on/off skyhook": (jaxmr.OnOffSkyhook(0.3), on_level, ON_BOUNDS),
        "groundhook": (jaxmr.Groundhook(500.0, I_MAX), c_gnd, None),
        "hybrid": (jaxmr.Hybrid(2000.0, 0.8, I_MAX), gain_blend, HYBRID_BOUNDS),
        "acceleration-driven": (
            jaxmr.AccelerationDrivenDamper(0.3),
            on_level,
            ON_BOUNDS,
        ),
        "power-driven": (jaxmr.PowerDrivenDamper(car.ks, I_MAX), pdd_gain, None),
        "clipped-optimal (LQR)": (clipped, None, None),
        "continuous clipped-optimal": (lqr_law, None, None),
        "lyapunov": (lyapunov, None, None),
    }


def first_reaching(history, target, simulations_at):
    """Simulations spent when `history` (best loss per iteration) first reached
    `target`, or None."""
    for k, loss in enumerate(history):
        if loss <= target:
            return simulations_at(k)
    return None


def best_within(history, simulations_at, limit):
    """The best loss of `history` once at most `limit` simulations were spent (None if
    its first entry already cost more)."""
    ok = [h for k, h in enumerate(history) if simulations_at(k) <= limit]
    return min(ok) if ok else None


def spread(values) -> dict:
    """Mean, sample standard deviation, minimum and maximum of a few seeds' values."""
    v = np.asarray(values, dtype=float)
    return {
        "mean": float(np.mean(v)),
        "std": float(np.std(v, ddof=1)) if v.size > 1 else 0.0,
        "min": float(np.min(v)),
        "max": float(np.max(v)),
        "values": v.tolist(),
    }


def record(tuning, name, result):
    tuning[name] = {
        "train_loss": result.loss,
        "initial_train_loss": result.initial_loss,
        "simulations": result.simulations,
        "seconds": result.seconds,
        "reason": result.reason,
        "history": list(result.history),
    }
    print(f"{name:48s} train {result.loss:.4f} ({result.seconds:.1f} s)", flush=True)


def time_losses(car, start, train, cfg: Settings) -> dict:
    """One forward simulation and one value_and_grad of tune's own loss (the functions
    `tune` and `cma_es` call, on the same pair, roads and settings), and CMA-ES's
    population losses for every population of the grid: the fastest of
    `timing_repeats` interleaved rounds after a first call (which compiles what is not
    compiled yet, so that the tuners' own `seconds` that follow are run time only).

    **Returns:** `{"run_s", "runs_s"}` per call [s], and
    `forward_equivalents_per_gradient`: value_and_grad (relaxed law, as `tune` takes
    it) over the forward simulation of the hard law (what CMA-ES simulates), both
    over the training roads."""
    sampling, integrator = loop_settings("tune", None, None, {})
    _, setup, hard, u0, batch = prepare(
        "tune",
        car,
        start,
        train,
        None,
        weights,
        False,
        None,
        jaxmr.metrics.comfort,
        cfg.duration,
        sampling,
        integrator,
        noise=ORACLE,
    )
    relaxed = (car, set_temperature(start, cfg.temperature[0]))
    flat0, unravel = ravel_pytree(u0)
    one = jax.vmap(unravel)(flat0[None])
    noise = jax.random.normal(jax.random.key(0), (max(cfg.cma_populations), flat0.size))
    candidates = {
        p: jax.vmap(unravel)(flat0 + 0.1 * noise[:p]) for p in cfg.cma_populations
    }
    calls = {
        "forward": lambda: losses(u0, hard, None, batch, setup, ORACLE),
        "relaxed_forward": lambda: losses(u0, relaxed, None, batch, setup, ORACLE),
        "value_and_grad": lambda: loss_and_grad(
            u0, relaxed, None, batch, setup, ORACLE
        ),
        "population_1": lambda: population_losses(
            one, hard, None, batch, setup, ORACLE
        ),
    }
    for p, us in candidates.items():
        calls[f"population_{p}"] = lambda us=us: population_losses(
            us, hard, None, batch, setup, ORACLE
        )
    for call in calls.values():
        jax.block_until_ready(call())
    runs = {name: [] for name in calls}
    for _ in range(cfg.timing_repeats):
        for name, call in calls.items():
            t0 = time.perf_counter()
            jax.block_until_ready(call())
            runs[name].append(time.perf_counter() - t0)
    run_s = {name: min(v) for name, v in runs.items()}
    out = {name: {"run_s": run_s[name], "runs_s": runs[name]} for name in calls}
    n = len(cfg.train_seeds)
    out["roads"] = n
    out["forward_s_per_simulation"] = run_s["forward"] / n
    out["forward_equivalents_per_gradient"] = run_s["value_and_grad"] / run_s["forward"]
    out["relaxed_forward_over_forward"] = run_s["relaxed_forward"] / run_s["forward"]
    for p in cfg.cma_populations:
        out[f"population_{p}_s_per_simulation"] = run_s[f"population_{p}"] / (p * n)
    return out


def first_and_second(call) -> dict:
    """Wall times [s] of a first call from cold caches (`jax.clear_caches`: trace,
    compile, run) and of a second, identical one (run): their difference is the
    compilation."""
    jax.clear_caches()
    times = []
    for _ in range(2):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return {
        "first_s": times[0],
        "second_s": times[1],
        "compile_s": max(times[0] - times[1], 0.0),
    }


def gradient_cost(result, runs: int, ratio: float) -> dict:
    """A `tune` run's cost in forward simulations: each Adam step one value_and_grad
    over the roads (`ratio` forward simulations each), each hard check one forward
    simulation per road."""
    steps = len(result.history)
    checks = result.simulations // runs - steps
    return {
        "steps": steps,
        "checks": checks,
        "forward_equivalents": steps * runs * ratio + checks * runs,
    }


def identified_damper(cfg: Settings):
    """The passenger-car damper identified from simulated sine tests (`Settings`):
    the `FitResult` whose covariance the robust section samples."""
    truth = jaxmr.passenger_car_mr_damper().hysteresis
    tests = jaxmr.sine_grid([0.01], [2.0], [0.0, 0.5, 1.0], cycles=3, sample_rate=500.0)
    clean = jaxmr.predict_all(truth, tests)
    rng = np.random.default_rng(cfg.id_noise_seed)
    data = [
        jd.Experiment(e.t, e.x, e.v, e.current, _noisy(rng, np.asarray(f)), name=e.name)
        for e, f in zip(tests, clean)
    ]
    P, F = jaxmr.Positive, jaxmr.Fixed
    # Started away from the truth (factors 0.7-1.3), as a fit from a template is.
    start = jaxmr.BoucWen(
        alpha=jaxmr.LinearLaw(P(1.3 * truth.alpha.a), P(0.8 * truth.alpha.b)),
        c0=jaxmr.LinearLaw(P(0.7 * truth.c0.a), P(1.2 * truth.c0.b)),
        A=F(truth.A),
        beta=P(1.2 * truth.beta),
        gamma=P(0.8 * truth.gamma),
        n=F(truth.n),
        k0=F(0.0),
        x0=F(0.0),
        f0=F(0.0),
    )
    return jaxmr.fit(start, data, progress=False, discard=0.5)


def with_hysteresis(car, hysteresis):
    return eqx.tree_at(lambda s: s.damper.hysteresis, car, hysteresis)


def sampled_cars(car, fit, n: int, seed: int):
    """`n` cars whose damper's hysteresis is drawn from `fit`'s uncertainty, as one
    batch of systems."""
    draws = fit.sample(n, jax.random.key(seed))
    return jax.vmap(lambda h: with_hysteresis(car, h))(draws)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--quick", action="store_true", help="smoke test (QUICK)")
    parser.add_argument(
        "--all-laws", action="store_true", help="tune every classical law too"
    )
    parser.add_argument(
        "--speed",
        action="store_true",
        help="also time the closed loop against the hand-written kernel "
        "(closed_loop_kernel.py, which writes the same figures itself)",
    )
    parser.add_argument(
        "--xla-defaults",
        action="store_true",
        help="run under XLA's default CPU flags on one device (the set-up of the results "
        "up to session 13) instead of jaxmr.devices.configure_cpu()",
    )
    args = parser.parse_args()
    if not args.xla_defaults:
        # As the documentation sets up a CPU user (and the command line does): every
        # core a device (both tuners spread their roads over them) and each simulation
        # loop one kernel. The gradient gains more from it than the forward runs
        # (closed_loop_kernel.py under the same flags: 2x against 1.4x).
        jaxmr.devices.configure_cpu()
    cfg = QUICK if args.quick else FULL
    wall0 = time.perf_counter()
    T = cfg.duration
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    metrics = metrics_for(car)
    train = roads(cfg.train_seeds, T)
    dev = roads(cfg.dev_seeds, T)
    runs = len(cfg.train_seeds)
    # The machine, versions and load averages are `write_figures`' `machine` block.
    out = {
        "quick": args.quick,
        "xla_setup": "defaults" if args.xla_defaults else "configure_cpu",
        "devices": jax.device_count(),
        "settings": dataclasses.asdict(cfg) | {"speed_m_s": SPEED, "i_max_A": I_MAX},
    }
    tuning = {}

    if args.speed:
        from closed_loop_kernel import closed_loop_speed

        quick = dict(duration=1.0, roads=2, repeats=1) if args.quick else {}
        out["speed"] = closed_loop_speed(**quick)
        print(f"speed: {out['speed']}", flush=True)

    # ---- Phase A: tune and choose, on the training and development roads only. ----

    def mean_metrics(system, controller, batch):
        values = evaluate(system, controller, batch, T, metrics)
        return {k: float(np.mean(v)) for k, v in values.items()}

    # Baselines chosen on the development roads: the most comfortable constant
    # current, and the most comfortable one within the tyre limit.
    dev_constants = {
        c: mean_metrics(car, jaxmr.ConstantCurrent(c, I_MAX), dev) for c in CONSTANTS
    }
    dev_limit = cfg.tyre_limit * dev_constants[I_MAX]["tyre_load"]
    best_constant = min(CONSTANTS, key=lambda c: dev_constants[c]["comfort"])
    best_feasible_constant = min(
        (c for c in CONSTANTS if dev_constants[c]["tyre_load"] <= dev_limit),
        key=lambda c: dev_constants[c]["comfort"],
    )
    print(
        f"chosen on the development roads: best constant {best_constant} A, "
        f"best within the tyre limit {best_feasible_constant} A",
        flush=True,
    )

    # The rich law's feature scales: RMS of each measurement in a 0.2 A run.
    passive = jax.vmap(
        lambda r: simulate_system(car, r, jaxmr.ConstantCurrent(0.2, I_MAX), T)
    )(train)
    scales = jaxmr.feature_scales(passive, RICH_FEATURES)

    def rich_start(seed):
        return jaxmr.ForceFeedback.mlp(
            scales,
            I_MAX,
            features=RICH_FEATURES,
            width=RICH_WIDTH,
            depth=1,
            key=jax.random.key(seed),
        )

    rich_settings = dict(
        parameters=weights,
        log_space=False,
        temperature=cfg.temperature,
        steps=cfg.rich_steps,
        learning_rate=cfg.rich_rate,
        patience=cfg.rich_steps,
        check_every=cfg.check_every,
        progress=False,
    )

    def cma_run(seed_start, key, sigma, population, budget, target=None, law=None):
        # At least one generation, whatever the factor (the smoke test's budgets).
        budget = max(int(np.ceil(budget)), runs * (1 + population))
        return cma_es(
            car,
            rich_start(seed_start) if law is None else law,
            train,
            T,
            parameters=weights,
            log_space=False,
            sigma=sigma,
            population=population,
            simulations=budget,
            target=target,
            key=jax.random.key(key),
        )

    # Compilation, apart: each tuner's first call against its second, from cold
    # caches (a 2-step `tune`; a CMA-ES start and one generation per population).
    # The starting law is built before, outside the timed calls: its random
    # initialisation (compiled anew after `clear_caches`, ~1 s) is an input of
    # both tuners, not part of either's compilation.
    start_0 = cfg.gradient_seeds[0]
    law_0 = rich_start(start_0)
    compilation = {
        f"cma_es population {p}": first_and_second(
            lambda p=p: cma_run(start_0, 0, cfg.cma_sigmas[0], p, 0, law=law_0)
        )
        for p in cfg.cma_populations
    }
    compilation["tune"] = first_and_second(
        lambda: tune(car, law_0, train, T, **(rich_settings | dict(steps=2)))
    )
    gradient_compile = compilation["tune"]["compile_s"]
    out["compilation"] = compilation

    timing = time_losses(car, rich_start(cfg.gradient_seeds[0]), train, cfg)
    ratio = timing["forward_equivalents_per_gradient"]
    out["timing"] = timing
    print(
        f"one value_and_grad = {ratio:.2f} forward simulations "
        f"({timing['value_and_grad']['run_s']:.3f} s against "
        f"{timing['forward']['run_s']:.3f} s over {runs} roads)",
        flush=True,
    )

    # The rich law by gradients, from each seed's generic start (every output weight
    # 0: the damper at its softest).
    rich = {}
    for seed in cfg.gradient_seeds:
        result = tune(car, rich_start(seed), train, T, **rich_settings)
        record(tuning, f"rich law by gradients, seed {seed}", result)
        cost = gradient_cost(result, runs, ratio)
        rich[seed] = {
            "result": result,
            **cost,
            "seconds": result.seconds,
            "seconds_with_compile": result.seconds + gradient_compile,
        }

    # CMA-ES: the grid on the selection seed, then the best cell on every seed.
    mean_cost = float(np.mean([r["forward_equivalents"] for r in rich.values()]))

    grid = []
    for sigma in cfg.cma_sigmas:
        for population in cfg.cma_populations:
            result = cma_run(
                cfg.gradient_seeds[0],
                cfg.cma_selection_seed,
                sigma,
                population,
                cfg.cma_selection_factor * mean_cost,
            )
            grid.append(
                {
                    "sigma": sigma,
                    "population": population,
                    "train_loss": result.loss,
                    "simulations": result.simulations,
                    "seconds": result.seconds,
                }
            )
            print(
                f"CMA-ES grid sigma {sigma:g}, population {population}: "
                f"{result.loss:.4f} after {result.simulations} simulations",
                flush=True,
            )
    chosen = min(grid, key=lambda g: g["train_loss"])
    sigma, population = chosen["sigma"], chosen["population"]
    # What a CMA-ES call costs beyond its simulations: the warm-up's calls ran the
    # start and one generation (`population_1` and `population_{p}` of `time_losses`).
    # Its first call from cold caches adds the compilation, and every call pays a
    # part again (`cma_es` builds a new evosax strategy, a static argument of evosax's
    # jitted ask and tell, so they are traced and compiled anew each call): the
    # run-only times below leave that per-call part out, the with-compile ones count
    # it with the rest, once.
    warm = compilation[f"cma_es population {population}"]
    generation = (
        timing["population_1"]["run_s"] + timing[f"population_{population}"]["run_s"]
    )
    cma_call_overhead = max(warm["second_s"] - generation, 0.0)
    cma_compile = max(warm["first_s"] - generation, 0.0)

    cma = {}
    for seed, g_seed in zip(cfg.cma_seeds, cfg.gradient_seeds):
        g = rich[g_seed]
        target = g["result"].loss
        generations = (
            cfg.cma_wall_factor * g["seconds_with_compile"] - cma_compile
        ) / timing[f"population_{population}"]["run_s"]
        budget = max(
            cfg.cma_budget_factor * g["forward_equivalents"],
            runs + max(int(generations), 1) * population * runs,
        )
        t0 = time.perf_counter()
        result = cma_run(g_seed, seed, sigma, population, budget, target)
        outer = time.perf_counter() - t0
        record(tuning, f"rich law by CMA-ES, seed {seed}", result)
        size = population * runs
        # Not below the time its simulations take alone (the overhead's estimate
        # varies by a second or so from call to call on a loaded machine).
        compute = (
            timing["population_1"]["run_s"]
            + (result.simulations - runs)
            // size
            * timing[f"population_{population}"]["run_s"]
        )
        run_seconds = max(outer - cma_call_overhead, compute)

        def simulations_at(k, size=size):
            return runs + k * size

        needed = first_reaching(result.history, target, simulations_at)
        reached = needed is not None
        spent = needed if reached else result.simulations
        # CMA-ES's generations cost alike: its time at a point is its share of the
        # simulations.
        seconds = run_seconds * spent / result.simulations
        cma[seed] = {
            "result": result,
            "gradient_seed": g_seed,
            "target_train_loss": target,
            "budget": int(np.ceil(budget)),
            "budget_over_gradient_forward_equivalents": budget
            / g["forward_equivalents"],
            "reached": reached,
            "simulations_to_reach": needed,
            "forward_ratio": spent / g["forward_equivalents"],
            "wall_ratio": (seconds + cma_compile) / g["seconds_with_compile"],
            "wall_ratio_without_compile": seconds / g["seconds"],
            "seconds": seconds,
            "seconds_with_compile": seconds + cma_compile,
            "best_train_loss": result.loss,
            "gap_at_budget": None if reached else result.loss / target - 1,
            "train_loss_at_gradient_forward_cost": best_within(
                result.history, simulations_at, g["forward_equivalents"]
            ),
            "train_loss_at_gradient_wall": best_within(
                result.history,
                simulations_at,
                result.simulations * g["seconds"] / max(run_seconds, 1e-9),
            ),
            "run_seconds": run_seconds,
            "call_seconds": outer,
        }

    # The constrained law: dual ascent on the Lagrangian of the mean tyre load over
    # the training roads (a per-road penalty, session 4, held every road under the
    # limit and ended 6.5 % inside it). Road holding needs the wheel's motion too.
    train_on = evaluate(car, jaxmr.ConstantCurrent(I_MAX, I_MAX), train, T, metrics)
    train_limit = cfg.tyre_limit * float(np.mean(train_on["tyre_load"]))
    law_c = jaxmr.ForceFeedback.mlp(
        jaxmr.feature_scales(passive, CONSTRAINED_FEATURES),
        I_MAX,
        features=CONSTRAINED_FEATURES,
        width=RICH_WIDTH,
        depth=1,
    )
    multiplier, rounds, spent_c = cfg.lagrange_start, [], 0
    target_c = cfg.target * train_limit
    dev_on = evaluate(car, jaxmr.ConstantCurrent(I_MAX, I_MAX), dev, T, metrics)
    resample = np.random.default_rng(cfg.bootstrap_seed).integers(
        0, len(cfg.dev_seeds), (cfg.bootstrap, len(cfg.dev_seeds))
    )

    def dev_bound(tyre):
        """The `confidence` quantile, over road sets resampled from the development
        roads, of a set's tyre load over its limit (tyre_limit x passive-on's)."""
        passive = np.asarray(dev_on["tyre_load"])
        ratio = np.asarray(tyre)[resample].mean(axis=1) / passive[resample].mean(axis=1)
        return float(np.quantile(ratio / cfg.tyre_limit, cfg.confidence))

    for k in range(cfg.rounds):

        def lagrangian(sol, multiplier=multiplier, target_c=target_c):
            ratio = jaxmr.metrics.rms(sol["tyre_force"]) / car.static_load
            # The comfort scale (0.9 m/s²) makes the multiplier dimensionless.
            return jaxmr.metrics.comfort(sol) + multiplier * 0.9 * (
                ratio / target_c - 1.0
            )

        result = tune(
            car,
            law_c,
            train,
            T,
            **(
                rich_settings
                | dict(
                    objective=lagrangian,
                    steps=cfg.round_steps,
                    patience=cfg.round_steps,
                )
            ),
        )
        spent_c += result.simulations
        law_c = result.controller
        on_train = evaluate(car, law_c, train, T, metrics)
        on_dev = evaluate(car, law_c, dev, T, metrics)
        row = {
            "multiplier": multiplier,
            "target_over_limit": target_c / train_limit,
            "train_comfort": float(np.mean(on_train["comfort"])),
            "train_tyre_over_limit": float(np.mean(on_train["tyre_load"]))
            / train_limit,
            "dev_tyre_over_limit": float(
                np.mean(on_dev["tyre_load"]) / np.mean(dev_on["tyre_load"])
            )
            / cfg.tyre_limit,
            "dev_tyre_bound": dev_bound(on_dev["tyre_load"]),
            "simulations": result.simulations,
            "seconds": result.seconds,
        }
        rounds.append((row, law_c))
        print(f"constrained round {k}: {row}", flush=True)
        over_target = row["train_tyre_over_limit"] * train_limit / target_c
        multiplier = max(0.0, multiplier + cfg.rho * (over_target - 1))
        if row["dev_tyre_bound"] > 1:
            target_c /= row["dev_tyre_bound"]
    ok_rounds = [r for r in rounds if r[0]["dev_tyre_bound"] <= 1]
    kept = (
        min(ok_rounds, key=lambda r: r[0]["train_comfort"])
        if ok_rounds
        else min(rounds, key=lambda r: r[0]["dev_tyre_bound"])
    )
    rich_c = kept[1]
    out["constrained_rounds"] = [r[0] for r in rounds]
    out["constrained_kept_round"] = rounds.index(kept)
    out["constrained_round_within_bound"] = bool(ok_rounds)
    out["constrained_simulations"] = spent_c

    # Skyhook from a gain ten times too small, against the best gain of a grid (both
    # judged on the training loss, the quantity tuning minimises).
    gains = np.geomspace(250.0, 16000.0, cfg.sky_grid)

    def train_comfort(controller):
        return float(np.mean(evaluate(car, controller, train, T)["comfort"]))

    grid_losses = [train_comfort(jaxmr.Skyhook(c, I_MAX)) for c in gains]
    far = tune(
        car,
        jaxmr.Skyhook(200.0, I_MAX),
        train,
        T,
        parameters=c_sky,
        temperature=cfg.temperature,
        steps=cfg.sky_steps,
        learning_rate=cfg.sky_rate,
        patience=cfg.sky_steps,
        progress=False,
    )
    record(tuning, "skyhook from 200 N·s/m", far)
    out["skyhook_far_start"] = {
        "grid_best_gain": float(gains[int(np.argmin(grid_losses))]),
        "grid_best_train_loss": float(min(grid_losses)),
        "tuned_gain": float(far.values[0]),
        "tuned_train_loss": far.loss,
    }

    # Every classical law as designed, and tuned (`--all-laws`) for comfort and for
    # comfort under the tyre limit (a penalty on the training roads' excess).
    def penalised(sol):
        ratio = jaxmr.metrics.rms(sol["tyre_force"]) / car.static_load
        excess = jax.nn.relu(ratio / train_limit - 1.0)
        return jaxmr.metrics.comfort(sol) * (1.0 + 50.0 * excess + 2000.0 * excess**2)

    classical = {}
    for name, (controller, where, bounds) in laws(car).items():
        classical[f"{name} (as designed)"] = controller
        if where is None or not args.all_laws:
            continue
        for label, objective in (
            ("comfort", jaxmr.metrics.comfort),
            ("tyre", penalised),
        ):
            result = tune(
                car,
                controller,
                train,
                T,
                parameters=where,
                objective=objective,
                temperature=cfg.temperature,
                steps=cfg.sky_steps,
                progress=False,
                bounds=bounds,
            )
            classical[f"{name} (tuned, {label})"] = result.controller
            record(tuning, f"{name} ({label})", result)

    # Robust tuning over damper samples from an identification's uncertainty.
    t0 = time.perf_counter()
    id_fit = identified_damper(cfg)
    id_seconds = time.perf_counter() - t0
    print(id_fit, flush=True)
    nominal_car = with_hysteresis(car, id_fit.model)
    train_r = first(train, cfg.robust_roads)
    passive_n = jax.vmap(
        lambda r: simulate_system(nominal_car, r, jaxmr.ConstantCurrent(0.2, I_MAX), T)
    )(train_r)
    linear_start = jaxmr.ForceFeedback.linear(
        jaxmr.feature_scales(passive_n, RICH_FEATURES),
        I_MAX,
        features=RICH_FEATURES,
        model=nominal_car.damper,
    )
    stage_1 = rich_settings | dict(
        steps=cfg.robust_steps,
        patience=cfg.robust_steps,
        learning_rate=cfg.robust_rate,
    )
    stage_1_law = tune(nominal_car, linear_start, train_r, T, **stage_1)
    record(tuning, "linear law, nominal damper (stage 1)", stage_1_law)
    stage_2 = stage_1 | dict(
        steps=cfg.robust_steps // 2,
        patience=cfg.robust_steps // 2,
        temperature=cfg.continuation_temperature,
        learning_rate=cfg.continuation_rate,
    )
    nominal_law = tune(nominal_car, stage_1_law.controller, train_r, T, **stage_2)
    record(tuning, "linear law, nominal continuation", nominal_law)
    robust_laws = {}
    for seed in cfg.robust_sample_seeds:
        samples = sampled_cars(nominal_car, id_fit, cfg.robust_samples, seed)
        result = tune(
            nominal_car,
            stage_1_law.controller,
            train_r,
            T,
            samples=samples,
            worst_share=cfg.worst_share,
            **stage_2,
        )
        record(tuning, f"linear law, robust continuation, samples seed {seed}", result)
        robust_laws[seed] = result

    # The ceiling: a current schedule that knows the road, optimised by gradients on
    # the schedule itself, against the best constant on the same road.
    samples_per_road = int(round(T / 1e-3))
    bound_ratios = []
    for j in range(cfg.bound_roads):
        road = jax.tree.map(lambda x, j=j: x[j : j + 1], dev)
        schedule = jaxmr.CurrentSchedule.constant(
            min(max(best_constant, 0.01), 0.99), samples_per_road, I_MAX
        )
        result = tune(
            car,
            schedule,
            road,
            T,
            parameters=schedule_logits,
            log_space=False,
            steps=cfg.bound_steps,
            learning_rate=cfg.bound_rate,
            patience=cfg.bound_steps,
            progress=False,
        )
        optimal = evaluate(car, result.controller, road, T)["comfort"][0]
        constant = evaluate(car, jaxmr.ConstantCurrent(best_constant, I_MAX), road, T)[
            "comfort"
        ][0]
        bound_ratios.append(float(1 - optimal / constant))

    # ---- Phase B: everything above is frozen; the fresh sets are drawn now. ----
    scored = score_fresh(
        cfg,
        car,
        metrics,
        dev,
        {
            **{f"constant {c:g} A": jaxmr.ConstantCurrent(c, I_MAX) for c in CONSTANTS},
            **classical,
            "skyhook (tuned from 200 N·s/m)": far.controller,
            **{
                f"rich law, gradients, seed {s}": r["result"].controller
                for s, r in rich.items()
            },
            **{
                f"rich law, CMA-ES, seed {s}": c["result"].controller
                for s, c in cma.items()
            },
            "rich law, constrained": rich_c,
        },
    )
    robust_scores = score_robust(
        cfg, car, nominal_car, id_fit, stage_1_law, nominal_law, robust_laws
    )

    # ---- Figures. ----
    sets = scored["sets"]
    names = list(sets)
    fresh = names[1:]
    table = scored["table"]

    def reduction(law, baseline, where):
        return 1 - table[where][law]["comfort"] / table[where][baseline]["comfort"]

    constant_name = f"constant {best_constant:g} A"
    feasible_name = f"constant {best_feasible_constant:g} A"
    comfort = {
        s: [
            reduction(f"rich law, gradients, seed {s}", constant_name, w) for w in fresh
        ]
        for s in cfg.gradient_seeds
    }
    every = np.array(list(comfort.values()))  # seeds x fresh sets
    hindsight = {
        w: min(
            (f"constant {c:g} A" for c in CONSTANTS),
            key=lambda n, w=w: table[w][n]["comfort"],
        )
        for w in names
    }
    cma_comfort = [
        [reduction(f"rich law, CMA-ES, seed {s}", constant_name, w) for w in fresh]
        for s in cfg.cma_seeds
    ]
    limits = {
        w: cfg.tyre_limit * table[w][f"constant {I_MAX:g} A"]["tyre_load"]
        for w in names
    }
    constrained = [reduction("rich law, constrained", feasible_name, w) for w in fresh]
    feasible = [
        table[w]["rich law, constrained"]["tyre_load"] <= limits[w] for w in fresh
    ]
    cma_forward = spread([c["forward_ratio"] for c in cma.values()])
    cma_wall = spread([c["wall_ratio"] for c in cma.values()])
    cma_wall_run = spread([c["wall_ratio_without_compile"] for c in cma.values()])
    reached_all = all(c["reached"] for c in cma.values())
    reached_any = any(c["reached"] for c in cma.values())
    robust_gain = spread(robust_scores["worst_gain_per_seed"])

    figures = {
        "comfort_fresh_mean": float(np.mean(every)),
        "comfort_fresh_min": float(np.min(every)),
        "comfort_fresh_per_set_seed_mean": np.mean(every, axis=0).tolist(),
        "comfort_fresh_per_seed_set_mean": spread(np.mean(every, axis=1)),
        "comfort_fresh_per_seed_and_set": every.tolist(),
        "comfort_fresh_vs_hindsight_best_constant": [
            [
                reduction(f"rich law, gradients, seed {s}", hindsight[w], w)
                for w in fresh
            ]
            for s in cfg.gradient_seeds
        ],
        "comfort_development_roads": spread(
            [
                reduction(f"rich law, gradients, seed {s}", constant_name, names[0])
                for s in cfg.gradient_seeds
            ]
        ),
        "comfort_fresh_cmaes": spread(np.mean(cma_comfort, axis=1)),
        "best_constant": constant_name,
        "hindsight_best_constant_per_set": hindsight,
        "constrained_fresh": float(np.mean(constrained)),
        "constrained_fresh_min": float(np.min(constrained)),
        "constrained_fresh_per_set": constrained,
        "constrained_fresh_feasible_per_set": feasible,
        "constrained_fresh_tyre_over_limit_per_set": [
            table[w]["rich law, constrained"]["tyre_load"] / limits[w] for w in fresh
        ],
        "best_feasible_constant": feasible_name,
        "best_feasible_constant_fresh_over_limit_per_set": [
            table[w][feasible_name]["tyre_load"] / limits[w] for w in fresh
        ],
        "constrained_development_roads": reduction(
            "rich law, constrained", feasible_name, names[0]
        ),
        "forward_equivalents_per_gradient": ratio,
        "gradient_forward_equivalents": spread(
            [r["forward_equivalents"] for r in rich.values()]
        ),
        "gradient_seconds": spread([r["seconds"] for r in rich.values()]),
        "gradient_seconds_with_compile": spread(
            [r["seconds_with_compile"] for r in rich.values()]
        ),
        "gradient_compile_seconds": gradient_compile,
        "gradient_train_loss": spread([r["result"].loss for r in rich.values()]),
        "cmaes_grid": grid,
        "cmaes_sigma": sigma,
        "cmaes_population": population,
        "cmaes_compile_seconds": cma_compile,
        "cmaes_call_overhead_seconds": cma_call_overhead,
        "cmaes_forward_ratio": cma_forward["mean"],
        "cmaes_forward_ratio_spread": cma_forward,
        "cmaes_wall_ratio": cma_wall["mean"],
        "cmaes_wall_ratio_spread": cma_wall,
        "cmaes_wall_ratio_without_compile": cma_wall_run,
        "cmaes_reached_gradient_loss": [c["reached"] for c in cma.values()],
        # Where CMA-ES never reached the gradient's loss, the ratios are lower bounds
        # (its whole budget over the gradient's cost) and this is how far it stayed.
        "cmaes_gap_at_budget": [c["gap_at_budget"] for c in cma.values()],
        "cmaes_train_loss": spread([c["best_train_loss"] for c in cma.values()]),
        "robust_worst_fresh_gain": robust_gain["mean"],
        "robust_worst_fresh_gain_spread": robust_gain,
        "robust_mean_fresh_gain": spread(robust_scores["mean_gain_per_seed"]),
        "skyhook_from_far_start": far.loss / min(grid_losses) - 1,
        "bound_reduction_comfort": float(np.mean(bound_ratios)),
    }
    lower = "" if reached_all else " (a lower bound: CMA-ES's budget was spent)"
    goals = {
        "comfort_fresh_mean >= 0.16": figures["comfort_fresh_mean"] >= 0.16,
        "comfort_fresh_min >= 0.14": figures["comfort_fresh_min"] >= 0.14,
        "constrained_fresh >= 0.12, feasible on every fresh set": bool(
            figures["constrained_fresh"] >= 0.12 and all(feasible)
        ),
        # Every seed's ratio at least 3 (a lower bound where the budget ran out).
        "cmaes_wall_ratio >= 3" + lower: cma_wall["min"] >= 3,
        "cmaes_forward_ratio >= 3" + lower: cma_forward["min"] >= 3,
        "robust_worst_fresh_gain < 1 (mean over seeds)": robust_gain["mean"] < 1,
        "robust_worst_fresh_gain < 1 on every seed": robust_gain["max"] < 1,
    }
    figures["goals"] = {k: {"met": bool(v)} for k, v in goals.items()}
    figures["cmaes_never_reached"] = not reached_any
    figures["cmaes"] = {
        s: {k: v for k, v in c.items() if k != "result"} for s, c in cma.items()
    }
    figures["gradient"] = {
        s: {k: v for k, v in r.items() if k != "result"}
        | {"train_loss": r["result"].loss}
        for s, r in rich.items()
    }
    figures["robust"] = robust_scores | {
        "identification": {
            "names": list(id_fit.names),
            "values": np.asarray(id_fit.values).tolist(),
            "std_errors": np.asarray(id_fit.std_errors).tolist(),
            "seconds": id_seconds,
        }
    }
    figures["table"] = table
    figures["tuning"] = tuning
    figures["skyhook_far_start"] = out.pop("skyhook_far_start")
    figures["bound_reduction_per_road"] = bound_ratios
    figures["seconds"] = time.perf_counter() - wall0
    out = out | figures
    if "speed" in out:
        for name in (
            "closed_loop_sim_s_per_s",
            "time_ratio_vs_scan_kernel",
            "gradient_time_ratio_vs_scan_kernel",
        ):
            out[name] = out["speed"].get(name)
    print_table(table)
    write_figures(out, args.json)


def score_fresh(cfg: Settings, car, metrics, dev, controllers: dict) -> dict:
    """Every frozen law on the development roads and on the fresh road sets (drawn
    here, once every law and baseline is fixed): the mean of every metric per set."""
    sets = {"development": dev} | {
        f"fresh {k + 1} (seeds {s[0]}-{s[-1]})": roads(s, cfg.duration)
        for k, s in enumerate(cfg.fresh_road_sets)
    }
    # One batch of every set's roads, so each law compiles and runs once.
    batch = jax.tree.map(lambda *x: jnp.concatenate(x), *sets.values())
    sizes = np.cumsum([0] + [len(s) for s in [cfg.dev_seeds, *cfg.fresh_road_sets]])
    table = {name: {} for name in sets}
    for law, controller in controllers.items():
        values = evaluate(car, controller, batch, cfg.duration, metrics)
        for j, name in enumerate(sets):
            table[name][law] = {
                k: float(np.mean(v[sizes[j] : sizes[j + 1]])) for k, v in values.items()
            }
    return {"sets": sets, "table": table}


def score_robust(cfg, car, nominal_car, fit, stage_1, nominal, robust) -> dict:
    """The nominal and robust laws on fresh damper samples drawn from the fit's
    uncertainty (`fresh_sample_seed`), each on the first fresh road set, and on the
    true damper: each sample's mean comfort over the roads."""
    roads_1 = roads(cfg.fresh_road_sets[0], cfg.duration)
    samples = sampled_cars(nominal_car, fit, cfg.fresh_samples, cfg.fresh_sample_seed)

    def per_sample(controller):
        values = []
        for j in range(cfg.fresh_samples):
            system = jax.tree.map(lambda x, j=j: x[j], samples)
            comfort = evaluate(system, controller, roads_1, cfg.duration)
            values.append(float(np.mean(comfort["comfort"])))
        return values

    def on_truth(controller):
        return float(
            np.mean(evaluate(car, controller, roads_1, cfg.duration)["comfort"])
        )

    nominal_scores = per_sample(nominal.controller)
    robust_scores = {s: per_sample(r.controller) for s, r in robust.items()}
    return {
        "fresh_samples": cfg.fresh_samples,
        "stage_1_comfort_per_sample": per_sample(stage_1.controller),
        "nominal_comfort_per_sample": nominal_scores,
        "robust_comfort_per_sample": robust_scores,
        "worst_gain_per_seed": [
            max(v) / max(nominal_scores) for v in robust_scores.values()
        ],
        "mean_gain_per_seed": [
            float(np.mean(v) / np.mean(nominal_scores)) for v in robust_scores.values()
        ],
        "true_damper_nominal_comfort": on_truth(nominal.controller),
        "true_damper_robust_comfort": {
            s: on_truth(r.controller) for s, r in robust.items()
        },
        "nominal_values": [np.asarray(v).tolist() for v in nominal.values],
        "robust_values": {
            s: [np.asarray(v).tolist() for v in r.values] for s, r in robust.items()
        },
    }


def print_table(table):
    for where, rows in table.items():
        print(f"\n{where}")
        print(
            f"{'law':44s} {'a_w':>7s} {'a_rms':>7s} {'travel':>8s} {'tyre':>7s} {'i':>6s}"
        )
        for name, row in rows.items():
            print(
                f"{name:44s} {row['comfort']:7.4f} {row['rms_acceleration']:7.4f} "
                f"{1e3 * row['travel']:6.2f}mm {row['tyre_load']:7.4f} "
                f"{row['mean_current']:6.3f}"
            )


if __name__ == "__main__":
    main()
