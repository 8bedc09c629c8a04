"""Semi-active control of a quarter car on ISO 8608 class C roads: a rich law tuned by
gradients through the closed loop from a generic start, against CMA-ES and random
search at equal road simulations, against constant currents, the classical laws and an
optimal schedule; robust tuning over damper samples; closed-loop speed against a
hand-written scan kernel.

    python benchmarks/quarter_car_control.py --json benchmarks/results/quarter_car_control.json
    python benchmarks/quarter_car_control.py --json /tmp/qc.json --quick   # smoke test
    python benchmarks/quarter_car_control.py --json OUT --all-laws  # tune every law too

The car: ms 350 kg, mu 40 kg, ks 20 kN/m, kt 200 kN/m (`jaxmr.passenger_car`) with
`jaxmr.passenger_car_mr_damper()` (Bouc–Wen, 30 N + 200 N·s/m at 0 A to 1 kN + 2 kN·s/m
at 1 A, 8 ms current lag). Control at 1 kHz with one sample of delay, RK4 at 0.25 ms.
Roads: ISO 8608 class C at 72 km/h (20 m/s), by sum of sinusoids; the laws are tuned on
`--train` seeds and every figure is from `--eval` other seeds.

Comfort is the ISO 2631-1 Wk-weighted RMS body acceleration a_w; road holding the RMS
dynamic tyre load over the static load; travel the RMS suspension deflection.
"""

import argparse
import json

import equinox as eqx
import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxmr  # noqa: E402

I_MAX = 1.0
SPEED = 20.0  # m/s
CONSTANTS = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0)


def metrics_for(car):
    load = float(car.static_load)

    def travel(sol):
        return jaxmr.rms(sol["damper_displacement"])

    def tyre(sol):
        return jaxmr.rms(sol["tyre_force"]) / load

    def unweighted(sol):
        return jaxmr.rms(sol["body_acceleration"])

    def current(sol):
        return jnp.mean(sol.current)

    return {
        "comfort": jaxmr.comfort,
        "rms_acceleration": unweighted,
        "travel": travel,
        "tyre_load": tyre,
        "mean_current": current,
    }


def roads(seeds, duration):
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
    return jax.vmap(lambda k: jaxmr.iso8608_road("C", SPEED, duration, k))(keys)


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


ON_BOUNDS = ((0.01, I_MAX),)
HYBRID_BOUNDS = ((10.0, 1e5), (1e-3, 1.0))


def laws(car):
    """The laws and their tuned parameters (None: nothing to tune, evaluated as is)."""
    A, B, _ = jaxmr.quarter_car_state_space(car, damping=200.0)
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


# The rich law's measurements (a body accelerometer, its integral, and the damper's
# stroke rate: sensors a semi-active car has), its network, and the annealed
# relaxation every tuned law uses. Chosen on the training roads' loss (60-160 steps,
# session 4): with two more features (wheel velocity, damper stroke) the linear law's
# training loss was 4 % higher; the linear law alone reached 0.767, linear + 16 tanh
# units 0.766 (8 units: 0.797); annealing from 0.3 or 0.2 did worse than from 0.1.
# (Sessions 4-8 regularised the band's closing over T F_y, and below T = 0.05 that
# loss turned as rough as the hard one; over sqrt(T) F_y, session 9, the anneal was
# kept as it was.)
RICH_FEATURES = ("body_velocity", "body_acceleration", "damper_velocity")
RICH_WIDTH = 16
TEMPERATURE = (0.1, 0.05)
# Unit-to-unit and temperature spread of the damper for robust tuning: yield force and
# viscous laws scaled by independent log-normal factors (an assumption of this
# benchmark, not a measured spread).
SPREAD = 0.25
# Robust tuning weighs the worst third of the damper samples (CVaR; 2 of 6), on the
# first ROBUST_ROADS training roads (samples x roads runs per step), Adam's rate
# decayed geometrically over the steps.
WORST_SHARE = 1 / 3
ROBUST_ROADS, ROBUST_RATE = 4, (0.05, 0.005)
CONTINUATION_T, CONTINUATION_RATE = (0.02, 0.01), (0.02, 0.002)
# The constrained law by dual ascent on the Lagrangian of the mean tyre load (session
# 8): rounds of `tune` on comfort + lambda (tyre / target - 1) with the multiplier
# raised by RHO x the training roads' excess over the target after each round. A
# round's law counts as feasible when its training tyre load is at most MARGIN x the
# limit: the held-out roads' tyre load ran 2.6 % above the training roads' in a probe,
# so 3 % is kept aside for them; the rounds aim a point lower (TARGET), as they end
# within about 1 % of where they aim.
LAGRANGE_START, RHO, ROUNDS, MARGIN, TARGET = 0.3, 3.0, 4, 0.97, 0.96


def weights(p):
    return jaxmr.ForceFeedback.weights(p)


def first_reaching(history, target, simulations_at):
    """Simulations spent when `history` (best loss per iteration) first reached
    `target`, or None."""
    for k, loss in enumerate(history):
        if loss <= target:
            return simulations_at(k)
    return None


def damper_samples(car, n, key):
    """`n` cars whose damper's yield-force and viscous laws are scaled by log-normal
    factors (`SPREAD`), as one batch of systems."""
    factors = jnp.exp(SPREAD * jax.random.normal(key, (n, 2)))

    def one(f):
        h = car.damper.hysteresis
        return eqx.tree_at(
            lambda s: (
                s.damper.hysteresis.alpha.a,
                s.damper.hysteresis.alpha.b,
                s.damper.hysteresis.c0.a,
                s.damper.hysteresis.c0.b,
            ),
            car,
            (f[0] * h.alpha.a, f[0] * h.alpha.b, f[1] * h.c0.a, f[1] * h.c0.b),
        )

    return jax.vmap(one)(factors), np.asarray(factors)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--duration", type=float, default=8.0)
    parser.add_argument("--train", type=int, default=4)
    parser.add_argument("--eval", type=int, default=12)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--rich-steps", type=int, default=80)
    parser.add_argument("--budget-factor", type=float, default=10.0)
    # The searches' budget: `budget_factor` x the gradient's simulations, and at least
    # this many, so that CMA-ES runs long enough to show where it goes.
    parser.add_argument("--search-budget", type=int, default=4840)
    parser.add_argument("--round-steps", type=int, default=30)
    parser.add_argument("--robust-steps", type=int, default=60)
    parser.add_argument("--samples", type=int, default=6)
    parser.add_argument("--all-laws", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.duration, args.train, args.eval = 2.0, 2, 2
        args.steps, args.rich_steps, args.budget_factor, args.samples = 4, 6, 2.0, 2
        args.search_budget, args.round_steps, args.robust_steps = 0, 4, 4

    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    train = roads(range(args.train), args.duration)
    held = roads(range(1000, 1000 + args.eval), args.duration)
    metrics = metrics_for(car)
    T = args.duration
    out = {"setup": vars(args) | {"speed_m_s": SPEED, "i_max_A": I_MAX}}

    def evaluate(controller, system=car):
        values = jaxmr.evaluate(system, controller, held, T, metrics)
        return {k: float(np.mean(v)) for k, v in values.items()}

    def train_loss(controller):
        return float(np.mean(jaxmr.evaluate(car, controller, train, T)["comfort"]))

    if not args.skip_speed:
        from closed_loop_kernel import closed_loop_speed

        quick = dict(duration=1.0, roads=2, repeats=1) if args.quick else {}
        out["speed"] = closed_loop_speed(**quick)
        print(f"speed: {out['speed']}", flush=True)

    table = {}
    for c in CONSTANTS:
        table[f"constant {c:g} A"] = evaluate(jaxmr.ConstantCurrent(c, I_MAX))
    passive_on = table[f"constant {I_MAX:g} A"]
    tyre_limit = 1.02 * passive_on["tyre_load"]
    constants = {k: v for k, v in table.items() if k.startswith("constant")}
    best_constant = min(constants, key=lambda k: constants[k]["comfort"])
    feasible = {k: v for k, v in constants.items() if v["tyre_load"] <= tyre_limit}
    best_feasible_constant = min(feasible, key=lambda k: feasible[k]["comfort"])

    # The training-set tyre load of passive-on, for the constraint while tuning.
    train_on = jaxmr.evaluate(
        car, jaxmr.ConstantCurrent(I_MAX, I_MAX), train, T, metrics
    )
    train_limit = 1.02 * float(np.mean(train_on["tyre_load"]))

    def constrained(sol):
        ratio = jaxmr.rms(sol["tyre_force"]) / car.static_load
        excess = jax.nn.relu(ratio / train_limit - 1.0)
        return jaxmr.comfort(sol) * (1.0 + 50.0 * excess + 2000.0 * excess**2)

    tuning = {}

    def record(name, result):
        tuning[name] = {
            "values": [np.asarray(v).tolist() for v in result.values],
            "train_loss": result.loss,
            "initial_train_loss": result.initial_loss,
            "held_out_loss": result.held_out_loss,
            "simulations": result.simulations,
            "seconds": result.seconds,
            "reason": result.reason,
        }
        print(
            f"{name:44s} train {result.loss:.4f} ({result.seconds:.0f} s)", flush=True
        )

    for name, (controller, where, bounds) in laws(car).items():
        table[f"{name} (untuned)"] = evaluate(controller)
        if where is None or not args.all_laws:
            continue
        for label, objective in (
            ("comfort", jaxmr.comfort),
            ("constrained", constrained),
        ):
            result = jaxmr.tune(
                car,
                controller,
                train,
                T,
                parameters=where,
                objective=objective,
                temperature=TEMPERATURE,
                steps=args.steps,
                progress=False,
                bounds=bounds,
                validation=held,
            )
            table[f"{name} (tuned, {label})"] = evaluate(result.controller)
            record(f"{name} ({label})", result)

    # Skyhook from a gain ten times too small, against the best gain of a fine grid
    # (both judged on the training loss, the quantity tuning minimises).
    grid = np.geomspace(250.0, 16000.0, 4 if args.quick else 37)
    grid_losses = [train_loss(jaxmr.Skyhook(c, I_MAX)) for c in grid]
    far = jaxmr.tune(
        car,
        jaxmr.Skyhook(200.0, I_MAX),
        train,
        T,
        parameters=c_sky,
        temperature=TEMPERATURE,
        steps=args.steps,
        learning_rate=0.15,
        patience=args.steps,
        validation=held,
        progress=False,
    )
    record("skyhook from 200 N·s/m (comfort)", far)
    table["skyhook (tuned from 200 N·s/m)"] = evaluate(far.controller)
    out["skyhook_far_start"] = {
        "grid_best_gain": float(grid[int(np.argmin(grid_losses))]),
        "grid_best_train_loss": float(min(grid_losses)),
        "tuned_gain": float(far.values[0]),
        "tuned_train_loss": far.loss,
    }

    # The rich law from a generic start (every weight 0: the damper at its softest).
    passive = jax.vmap(
        lambda r: jaxmr.simulate_system(car, r, jaxmr.ConstantCurrent(0.2, I_MAX), T)
    )(train)
    scales = jaxmr.feature_scales(passive, RICH_FEATURES)
    start = jaxmr.ForceFeedback.mlp(
        scales, I_MAX, features=RICH_FEATURES, width=RICH_WIDTH, depth=1
    )
    # The whole annealing schedule is run (`patience` = steps): on the relaxed loss
    # the descent is steady but the hard law's check can pause for a few steps.
    rich_settings = dict(
        parameters=weights,
        log_space=False,
        temperature=TEMPERATURE,
        steps=args.rich_steps,
        learning_rate=0.03,
        patience=args.rich_steps,
        check_every=4,
        validation=held,
        progress=False,
    )
    rich = jaxmr.tune(car, start, train, T, **rich_settings)
    record("rich law (comfort)", rich)
    table["rich law (tuned, comfort)"] = evaluate(rich.controller)

    # The constrained law: dual ascent on the Lagrangian of the mean tyre load over the
    # training roads (a per-road penalty, session 4, held every road under the limit
    # and ended 6.5 % inside it, less comfortable than the best feasible constant).
    # Road holding needs the wheel's motion too (groundhook's signal).
    features_c = RICH_FEATURES + ("wheel_velocity",)
    law_c = jaxmr.ForceFeedback.mlp(
        jaxmr.feature_scales(passive, features_c),
        I_MAX,
        features=features_c,
        width=RICH_WIDTH,
        depth=1,
    )
    multiplier, rounds, spent_c = LAGRANGE_START, [], 0
    target = TARGET * train_limit
    for k in range(1 if args.quick else ROUNDS):

        def lagrangian(sol, multiplier=multiplier):
            ratio = jaxmr.rms(sol["tyre_force"]) / car.static_load
            # The comfort scale (0.9 m/s²) makes the multiplier dimensionless.
            return jaxmr.comfort(sol) + multiplier * 0.9 * (ratio / target - 1.0)

        result = jaxmr.tune(
            car,
            law_c,
            train,
            T,
            **(
                rich_settings
                | dict(
                    objective=lagrangian,
                    steps=args.round_steps,
                    patience=args.round_steps,
                    validation=None,
                )
            ),
        )
        spent_c += result.simulations
        law_c = result.controller
        on_train = jaxmr.evaluate(car, law_c, train, T, metrics)
        row = {
            "multiplier": multiplier,
            "train_comfort": float(np.mean(on_train["comfort"])),
            "train_tyre_over_limit": float(np.mean(on_train["tyre_load"]))
            / train_limit,
            "simulations": result.simulations,
        }
        rounds.append((row, law_c))
        print(f"constrained round {k}: {row}", flush=True)
        over_target = row["train_tyre_over_limit"] * train_limit / target
        multiplier = max(0.0, multiplier + RHO * (over_target - 1))
    ok_rounds = [r for r in rounds if r[0]["train_tyre_over_limit"] <= MARGIN]
    chosen = min(ok_rounds or rounds, key=lambda r: r[0]["train_comfort"])
    rich_c = chosen[1]
    table["rich law (tuned, constrained)"] = evaluate(rich_c)
    out["constrained_rounds"] = [r[0] for r in rounds] + [
        {"chosen_round": rounds.index(chosen), "simulations": spent_c}
    ]

    # Derivative-free searches on the same law, loss and roads, with `budget_factor`
    # times the gradient's simulations (at least `search_budget`): how many they need
    # to reach its loss, and where CMA-ES goes with the rest.
    budget = max(int(args.budget_factor * rich.simulations), args.search_budget)
    runs = args.train
    cma = jaxmr.cma_es(
        car,
        start,
        train,
        T,
        parameters=weights,
        log_space=False,
        sigma=0.2,
        simulations=budget,
        validation=held,
    )
    record("rich law by CMA-ES (comfort)", cma)
    table["rich law (CMA-ES, comfort)"] = evaluate(cma.controller)
    # Simulations per generation, from what CMA-ES spent (its start: one evaluation).
    per_generation = (cma.simulations - runs) // max(len(cma.history) - 1, 1)
    cma_needed = first_reaching(
        cma.history, rich.loss, lambda k: runs + k * per_generation
    )
    search = jaxmr.random_search(
        car,
        start,
        train,
        T,
        parameters=weights,
        log_space=False,
        spread=1.0,
        simulations=budget,
        validation=held,
    )
    record("rich law by random search (comfort)", search)
    search_needed = first_reaching(search.history, rich.loss, lambda k: (k + 1) * runs)

    def at_budget(history, simulations_at):
        spent = [simulations_at(k) for k in range(len(history))]
        ok = [h for h, s in zip(history, spent) if s <= rich.simulations]
        return min(ok) if ok else None

    out["gradient_vs_derivative_free"] = {
        "gradient_simulations": rich.simulations,
        "gradient_train_loss": rich.loss,
        "budget": budget,
        "cmaes_simulations_to_reach": cma_needed,
        "cmaes_train_loss_at_equal_simulations": at_budget(
            cma.history, lambda k: runs + k * per_generation
        ),
        "cmaes_best_train_loss": cma.loss,
        "cmaes_held_out_loss": cma.held_out_loss,
        "cmaes_history": list(cma.history),
        "cmaes_simulations_per_generation": per_generation,
        "random_search_simulations_to_reach": search_needed,
        "random_search_train_loss_at_equal_simulations": at_budget(
            search.history, lambda k: (k + 1) * runs
        ),
        "random_search_best_train_loss": search.loss,
        "random_search_held_out_loss": search.held_out_loss,
        "gradient_held_out_loss": rich.held_out_loss,
        "gradient_history": list(rich.history),
    }

    def ratio(needed):
        # Not reached within the budget: the ratio is at least budget / gradient's.
        return needed / rich.simulations if needed else budget / rich.simulations

    # Robust tuning. The controller inverts the nominal damper (`model=`), as a real
    # one inverts its nominal fit, while the simulated unit is drawn from the spread.
    # The linear law (3 gains) is first tuned from zero on the nominal damper; then
    # two continuations with the same settings differ only in their loss: the robust
    # one over every damper sample, weighing the worst third (`worst_share`), the
    # nominal one on the nominal damper again (equal tuning effort). Both are scored
    # on every sample's held-out roads. The continuations run nearly hard
    # (CONTINUATION_T): the samples' worst-third loss differs between laws by less
    # than the relaxation's bias at T = 0.05 (session 9: at the stage-1 law and at
    # gains 1.5-2 times as large, 0.7762 and 0.7765 relaxed, 0.773 and 0.781 hard). From
    # zero, the robust tune followed that bias to larger gains and ended worse on its
    # own objective; so did the rich law's (session 9: 84 weights, worst held-out
    # sample 0.7454 for both).
    systems, factors = damper_samples(car, args.samples, jax.random.key(7))
    train_r = jax.tree.map(lambda x: x[:ROBUST_ROADS], train)
    linear_start = jaxmr.ForceFeedback.linear(
        scales, I_MAX, features=RICH_FEATURES, model=car.damper
    )
    stage_1 = rich_settings | dict(
        steps=args.robust_steps,
        patience=args.robust_steps,
        learning_rate=ROBUST_RATE,
        validation=None,
    )
    first = jaxmr.tune(car, linear_start, train_r, T, **stage_1)
    record("linear law, nominal damper (stage 1)", first)
    stage_2 = stage_1 | dict(
        steps=args.robust_steps // 2,
        patience=args.robust_steps // 2,
        temperature=CONTINUATION_T,
        learning_rate=CONTINUATION_RATE,
    )
    robust = jaxmr.tune(
        car,
        first.controller,
        train_r,
        T,
        samples=systems,
        worst_share=WORST_SHARE,
        **stage_2,
    )
    record("linear law, robust continuation", robust)
    nominal = jaxmr.tune(car, first.controller, train_r, T, **stage_2)
    record("linear law, nominal continuation", nominal)

    def per_sample(controller, on=held):
        values = []
        for j in range(args.samples):
            system = jax.tree.map(lambda x, j=j: x[j], systems)
            values.append(
                float(np.mean(jaxmr.evaluate(system, controller, on, T)["comfort"]))
            )
        return values

    nominal_scores, robust_scores = (
        per_sample(nominal.controller),
        per_sample(robust.controller),
    )
    first_scores = per_sample(first.controller)
    out["robust"] = {
        "stage_1_law_comfort_per_sample": first_scores,
        "factors_yield_viscous": factors.tolist(),
        "nominal_law_comfort_per_sample": nominal_scores,
        "robust_law_comfort_per_sample": robust_scores,
        "nominal_law_train_per_sample": per_sample(nominal.controller, train_r),
        "robust_law_train_per_sample": per_sample(robust.controller, train_r),
        "nominal_values": [np.asarray(v).tolist() for v in nominal.values],
        "robust_values": [np.asarray(v).tolist() for v in robust.values],
    }

    out["table"] = table
    out["tuning"] = tuning
    semi = {k: v for k, v in table.items() if not k.startswith("constant")}
    best_law = min(semi, key=lambda k: semi[k]["comfort"])
    ok = {k: v for k, v in semi.items() if v["tyre_load"] <= tyre_limit}
    best_ok = min(ok, key=lambda k: ok[k]["comfort"]) if ok else None

    # The ceiling: a current schedule that knows the road, optimised by gradients on
    # the schedule itself, on the first held-out roads.
    n_bound = min(2, args.eval)
    samples = int(round(T / 1e-3))
    bound_ratios = []
    c_best = float(best_constant.split()[1])
    for j in range(n_bound):
        road = jax.tree.map(lambda x, j=j: x[j : j + 1], held)
        schedule = jaxmr.CurrentSchedule.constant(
            min(max(c_best, 0.01), 0.99), samples, I_MAX
        )
        result = jaxmr.tune(
            car,
            schedule,
            road,
            T,
            parameters=lambda p: p[1].logits,
            log_space=False,
            steps=4 * args.steps,
            learning_rate=0.3,
            patience=4 * args.steps,
            progress=False,
        )
        optimal = jaxmr.evaluate(car, result.controller, road, T, metrics)["comfort"][0]
        constant = jaxmr.evaluate(
            car, jaxmr.ConstantCurrent(c_best, I_MAX), road, T, metrics
        )["comfort"][0]
        bound_ratios.append(1 - optimal / constant)

    base = table[best_constant]["comfort"]
    rich_row = table["rich law (tuned, comfort)"]
    rich_c_row = table["rich law (tuned, constrained)"]
    feasible_base = table[best_feasible_constant]["comfort"]
    summary = {
        "best_constant": best_constant,
        "best_law_comfort": best_law,
        "wk_rms_reduction_comfort": 1 - rich_row["comfort"] / base,
        "wk_rms_reduction_comfort_best_law": 1 - table[best_law]["comfort"] / base,
        "wk_rms_reduction_comfort_cmaes": 1
        - table["rich law (CMA-ES, comfort)"]["comfort"] / base,
        "wk_rms_reduction_comfort_vs_passive_on": 1
        - rich_row["comfort"] / passive_on["comfort"],
        "best_constant_constrained": best_feasible_constant,
        "wk_rms_reduction_constrained": (
            1 - rich_c_row["comfort"] / feasible_base
            if rich_c_row["tyre_load"] <= tyre_limit
            else None
        ),
        "tyre_load_ratio": rich_c_row["tyre_load"] / passive_on["tyre_load"],
        "best_law_constrained": best_ok,
        "gradient_vs_cmaes_simulations": ratio(cma_needed),
        "cmaes_reached_gradient_loss": cma_needed is not None,
        "gradient_vs_random_search_simulations": ratio(search_needed),
        "random_search_reached_gradient_loss": search_needed is not None,
        "skyhook_from_far_start": far.loss / min(grid_losses) - 1,
        "robust_worst_case_gain": max(robust_scores) / max(nominal_scores),
        "robust_mean_gain": float(np.mean(robust_scores) / np.mean(nominal_scores)),
        "robust_worst_case_gain_vs_stage_1": max(robust_scores) / max(first_scores),
        "bound_reduction_comfort": float(np.mean(bound_ratios)),
    }
    if "speed" in out:
        for name in (
            "closed_loop_sim_s_per_s",
            "time_ratio_vs_scan_kernel",
            "gradient_time_ratio_vs_scan_kernel",
        ):
            summary[name] = out["speed"].get(name)
    out["summary"] = summary
    out.update(summary)
    print(
        f"\n{'law':44s} {'a_w':>7s} {'a_rms':>7s} {'travel':>8s} {'tyre':>7s} {'i':>6s}"
    )
    for name, row in table.items():
        print(
            f"{name:44s} {row['comfort']:7.4f} {row['rms_acceleration']:7.4f} "
            f"{1e3 * row['travel']:6.2f}mm {row['tyre_load']:7.4f} "
            f"{row['mean_current']:6.3f}"
        )
    print(json.dumps(summary, indent=1))
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1, default=float)


if __name__ == "__main__":
    main()
