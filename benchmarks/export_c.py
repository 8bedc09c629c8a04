"""The exported C controller's time per sample (issue 29): the 84-weight law
(`ForceFeedback.mlp`, three features, one hidden layer of 16 tanh units, its weights
drawn) with its velocity estimator and its damper observer (the passenger-car
damper's Bouc–Wen model and coil lag, four RK4 substeps per 1 ms sample), exported
by `jaxmr.export_c`, compiled with the system C compiler (`cc -std=c99 -O2 -Wall
-Werror`) and stepped over the readings a realistic closed-loop run recorded.

    python benchmarks/export_c.py --json benchmarks/results/export_c.json
    python benchmarks/export_c.py --json /tmp/export_c.json --quick

Figures: `c_step_microseconds` (the fastest of `repeats` runs of `samples` steps,
divided by the steps; the loop is the driver's `run`, called once through ctypes, so
the call's own cost is spread over the samples), `max_command_difference` [A] between
the C and the JAX controller on the recorded readings (the equality the timing is
valid for), and the samples timed. About 20 s on an idle 2-core machine (`--quick`:
10 s), most of it JAX's compilation of the recording run.
"""

import argparse
import tempfile
import time

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402
from _compile_c import FLAGS, CompiledController  # noqa: E402
from _report import write_figures  # noqa: E402

import jaxmr  # noqa: E402
import jaxmr.metrics  # noqa: E402

FEATURES = ("body_velocity", "body_acceleration", "damper_velocity")


def controller() -> jaxmr.ObserverBasedController:
    law = jaxmr.ForceFeedback.mlp(
        (0.2, 2.0, 0.3),
        1.0,
        features=FEATURES,
        width=16,
        depth=1,
        key=jax.random.key(0),
        temperature=0.0,
    )
    leaves, tree = jax.tree.flatten(eqx.filter(law.network, eqx.is_array))
    keys = jax.random.split(jax.random.key(1), len(leaves))
    drawn = [0.5 * jax.random.normal(k, x.shape, x.dtype) for k, x in zip(keys, leaves)]
    law = eqx.tree_at(
        lambda f: f.network,
        law,
        eqx.combine(jax.tree.unflatten(tree, drawn), law.network),
    )
    weights = sum(int(np.size(w)) for w in jaxmr.ForceFeedback.weights((None, law)))
    assert weights == 84, weights
    return jaxmr.ObserverBasedController(
        law,
        estimator=jaxmr.VelocityEstimator(),
        observer=jaxmr.DamperObserver(jaxmr.passenger_car_mr_damper()),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True)
    parser.add_argument("--quick", action="store_true", help="fewer samples")
    args = parser.parse_args()
    duration, samples, repeats = (
        (1.0, 100_000, 3) if args.quick else (2.0, 1_000_000, 5)
    )

    law = controller()
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    sensors = jaxmr.realistic_sensors(car)
    road = jaxmr.iso8608_road("C", 20.0, duration, jax.random.key(2))
    sol = jaxmr.simulate_system(
        car, road, law, duration, sensors=sensors, key=jax.random.key(3)
    )
    assert sol.measured is not None
    names = sensors.names
    recorded = np.stack([np.asarray(sol.measured[n]) for n in names], axis=1)

    with tempfile.TemporaryDirectory() as folder:
        jaxmr.export_c(law, folder, name="rich", measurements=names)
        c = CompiledController(folder, "rich")
        difference = float(np.max(np.abs(c.run(recorded) - np.asarray(sol.command))))
        inputs = np.tile(recorded, (-(-samples // len(recorded)), 1))[:samples]
        c.run(inputs[:1000])  # warm the caches
        best = np.inf
        for _ in range(repeats):
            start = time.perf_counter()
            c.run(inputs)
            best = min(best, time.perf_counter() - start)

    write_figures(
        {
            "c_step_microseconds": 1e6 * best / samples,
            "max_command_difference": difference,
            "samples": samples,
            "repeats": repeats,
            "weights": 84,
            "compiler_flags": " ".join(FLAGS),
            "command_range": float(np.ptp(np.asarray(sol.command))),
            "comfort": float(jaxmr.metrics.comfort(sol)),
        },
        args.json,
    )


if __name__ == "__main__":
    main()
