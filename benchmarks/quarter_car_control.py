"""Semi-active control of a quarter car on ISO 8608 class C roads: every law, tuned by
gradients through the closed loop, against constant currents and an optimal schedule.

    python benchmarks/quarter_car_control.py --json benchmarks/results/quarter_car.json
    python benchmarks/quarter_car_control.py --json /tmp/qc.json --quick   # smoke test

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
import time

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


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--duration", type=float, default=8.0)
    parser.add_argument("--train", type=int, default=4)
    parser.add_argument("--eval", type=int, default=12)
    parser.add_argument("--steps", type=int, default=25)
    parser.add_argument("--temperature", type=float, default=0.1)
    args = parser.parse_args()
    if args.quick:
        args.duration, args.train, args.eval, args.steps = 2.0, 2, 2, 3

    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    train = roads(range(args.train), args.duration)
    held = roads(range(1000, 1000 + args.eval), args.duration)
    metrics = metrics_for(car)
    T = args.duration
    out = {"setup": vars(args) | {"speed_m_s": SPEED, "i_max_A": I_MAX}}

    def evaluate(controller, system=car):
        values = jaxmr.evaluate(system, controller, held, T, metrics)
        return {k: float(np.mean(v)) for k, v in values.items()}

    # Compile and run timed separately, against the same runs one road at a time.
    t0 = time.perf_counter()
    evaluate(jaxmr.Skyhook(1000.0, I_MAX))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    evaluate(jaxmr.Skyhook(1500.0, I_MAX))
    batched_s = time.perf_counter() - t0
    one = jax.tree.map(lambda x: x[:1], held)
    jaxmr.evaluate(car, jaxmr.Skyhook(1000.0, I_MAX), one, T, metrics)
    t0 = time.perf_counter()
    for j in range(args.eval):
        road = jax.tree.map(lambda x, j=j: x[j : j + 1], held)
        jaxmr.evaluate(car, jaxmr.Skyhook(1500.0, I_MAX), road, T, metrics)
    looped_s = time.perf_counter() - t0
    out["timing"] = {
        "evaluate_compile_s": compile_s - batched_s,
        "evaluate_batched_s": batched_s,
        "evaluate_one_road_at_a_time_s": looped_s,
        "simulated_s_per_wall_s_batched": args.eval * T / batched_s,
    }
    print(f"timing: {out['timing']}")

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
    for name, (controller, where, bounds) in laws(car).items():
        table[f"{name} (untuned)"] = evaluate(controller)
        if where is None:
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
                temperature=args.temperature,
                steps=args.steps,
                progress=False,
                bounds=bounds,
            )
            table[f"{name} (tuned, {label})"] = evaluate(result.controller)
            tuning[f"{name} ({label})"] = {
                "values": [np.asarray(v).tolist() for v in result.values],
                "train_loss": result.loss,
                "initial_train_loss": result.initial_loss,
                "simulations": result.simulations,
                "seconds": result.seconds,
                "reason": result.reason,
            }
            print(
                f"{name:28s} {label:11s} -> {tuning[f'{name} ({label})']['values']} "
                f"({result.seconds:.0f} s)",
                flush=True,
            )
    out["table"] = table
    out["tuning"] = tuning

    # Gradient against derivative-free tuning at an equal number of road simulations.
    versus = {}
    for name in ("skyhook", "hybrid"):
        controller, where, bounds = laws(car)[name]
        grad = jaxmr.tune(
            car,
            controller,
            train,
            T,
            parameters=where,
            bounds=bounds,
            temperature=args.temperature,
            steps=args.steps,
            progress=False,
        )
        search = jaxmr.random_search(
            car,
            controller,
            train,
            T,
            parameters=where,
            bounds=bounds,
            simulations=grad.simulations,
        )
        versus[name] = {
            "simulations": grad.simulations,
            "gradient_train_loss": grad.loss,
            "random_search_train_loss": search.loss,
            "gradient_held_out_comfort": evaluate(grad.controller)["comfort"],
            "random_search_held_out_comfort": evaluate(search.controller)["comfort"],
            "gradient_seconds": grad.seconds,
            "random_search_seconds": search.seconds,
        }
    out["gradient_vs_random_search"] = versus

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
        start = jaxmr.CurrentSchedule.constant(
            min(max(c_best, 0.01), 0.99), samples, I_MAX
        )
        result = jaxmr.tune(
            car,
            start,
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
    out["summary"] = {
        "best_constant": best_constant,
        "best_law_comfort": best_law,
        "wk_rms_reduction_comfort": 1 - table[best_law]["comfort"] / base,
        "wk_rms_reduction_comfort_vs_passive_on": 1
        - table[best_law]["comfort"] / passive_on["comfort"],
        "best_law_constrained": best_ok,
        "best_constant_constrained": best_feasible_constant,
        "wk_rms_reduction_constrained": (
            1 - table[best_ok]["comfort"] / table[best_feasible_constant]["comfort"]
            if best_ok
            else None
        ),
        "tyre_load_ratio": (
            table[best_ok]["tyre_load"] / passive_on["tyre_load"] if best_ok else None
        ),
        "bound_reduction_comfort": float(np.mean(bound_ratios)),
    }
    out.update(out["summary"])
    print(
        f"\n{'law':44s} {'a_w':>7s} {'a_rms':>7s} {'travel':>8s} {'tyre':>7s} {'i':>6s}"
    )
    for name, row in table.items():
        print(
            f"{name:44s} {row['comfort']:7.4f} {row['rms_acceleration']:7.4f} "
            f"{1e3 * row['travel']:6.2f}mm {row['tyre_load']:7.4f} "
            f"{row['mean_current']:6.3f}"
        )
    print(json.dumps(out["summary"], indent=1))
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1, default=float)


if __name__ == "__main__":
    main()
