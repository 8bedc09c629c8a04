"""The multi-process half of tests/test_distributed.py: run as
`python distributed_worker.py PROCESS_ID NUM_PROCESSES PORT OUT`, by every process of a
local `jax.distributed` job on the CPU (gloo collectives). Each runs the same calls as
the single-process reference (`cases` below, shared with the test) and process 0 saves
what came back."""

import sys

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")


def cases():
    """{name: array}: a sweep, independent fits, a controller's evaluation and its
    tuning by `tune` and `cma_es`, each over a batch that the devices do not divide
    evenly (3 members over 2 processes): the tuners' losses leave the padded road
    out of their means (also tested alone in tests/test_tune.py)."""
    import jax.numpy as jnp
    import numpy as np

    import jaxmr
    from tests.helpers import dahl_guess, dahl_runs

    # Sizes for compile time (fixed RK4 steps, adaptive ones compile 2-3x longer;
    # one per control sample; short runs): the comparison is of layouts, not physics.
    out = {}
    # A state that depends on the current (a coil lag): one solve per run.
    damper = jaxmr.Damper(jaxmr.sas_brake_bouc_wen(), jaxmr.FirstOrderLag(50.0))
    ts = jnp.linspace(0.0, 0.2, 41)
    sol = jaxmr.sweep(
        damper,
        jaxmr.Sine(0.05, 2.0),
        [0.0, 0.5, 1.0],
        ts,
        integrator=jaxmr.FixedStep(2),
    )
    out["sweep_force"] = np.asarray(sol.force)
    results = jaxmr.fit_each(
        dahl_guess(), dahl_runs((3.0, 5.0, 8.0), (1.0, 2.0, 3.0)), progress=False,
        max_steps=6, statistics_refinement=1,
    )  # fmt: skip
    out["fit_each_values"] = np.stack([np.asarray(r.values) for r in results])
    out["fit_each_loss"] = np.array([r.loss for r in results])
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    keys = jax.vmap(jax.random.key)(jnp.arange(3))
    roads = jax.vmap(lambda k: jaxmr.iso8608_road("C", 20.0, 0.3, k))(keys)
    values = jaxmr.evaluate(
        car,
        jaxmr.Skyhook(2000.0, 1.0),
        roads,
        0.3,
        integrator=jaxmr.FixedStep(1),
        sensors="oracle",  # Skyhook inverts the damper: perfect information
    )
    out["evaluate_comfort"] = np.asarray(values["comfort"])
    # The tuners keep their parameters replicated over every device of every process
    # (`_distribute.replicate`) while their losses spread the roads.
    gain = lambda pair: pair[1].c_sky
    tuners = dict(integrator=jaxmr.FixedStep(1), sensors="oracle")
    tuned = jaxmr.tune(car, jaxmr.Skyhook(2000.0, 1.0), roads, 0.3, parameters=gain,
                       steps=3, check_every=2, temperature=0.1, progress=False,
                       **tuners)  # fmt: skip
    searched = jaxmr.cma_es(car, jaxmr.Skyhook(2000.0, 1.0), roads, 0.3,
                            parameters=gain, population=4, simulations=3 * 9,
                            **tuners)  # fmt: skip
    for name, result in (("tune", tuned), ("cma_es", searched)):
        out[name] = np.array([float(result.controller.c_sky), result.loss])
    return out


def joint_fit():
    """A joint fit whose 2 lanes split over 2 devices where there are 2."""
    import numpy as np

    import jaxmr
    from tests.helpers import dahl_guess, dahl_runs

    runs = dahl_runs((3.0, 5.0, 8.0, 12.0), (1.0, 2.0, 3.0, 4.0))
    result = jaxmr.fit(
        dahl_guess(), runs, lanes=2, progress=False, statistics_refinement=1
    )
    return np.asarray(result.values), np.asarray(result.std_errors)


if __name__ == "__main__" and sys.argv[1] == "lanes":
    # One process, its CPU cores as 2 devices (XLA_FLAGS set by the test).
    import numpy as np

    from jaxmr._identify.data import pack
    from jaxmr._identify.fitting import _lanes_on_devices
    from tests.helpers import dahl_runs

    assert len(jax.devices()) == 2
    packed = _lanes_on_devices(pack(dahl_runs((3.0, 5.0), (1.0, 2.0)), lanes=2))
    assert len(packed.step.sharding.device_set) == 2  # the lanes are split
    np.savez(sys.argv[2], *joint_fit())
elif __name__ == "__main__":
    process_id, processes, port, path = sys.argv[1:5]
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=f"localhost:{port}",
        num_processes=int(processes),
        process_id=int(process_id),
    )
    assert jax.process_count() == int(processes)
    import numpy as np

    figures = cases()
    figures["devices"] = np.array(len(jax.devices()))
    if jax.process_index() == 0:
        np.savez(path, **figures)
    jax.distributed.shutdown()
