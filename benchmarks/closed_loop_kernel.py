"""Closed-loop speed: jaxmr's `simulate_system` against a hand-written `lax.scan` kernel
of the same quarter car, damper, skyhook law, lag, delay and RK4 substeps (issue 10).

    python benchmarks/closed_loop_kernel.py --json benchmarks/results/closed_loop.json
    python benchmarks/closed_loop_kernel.py --json /tmp/cl.json --duration 1 --roads 2

The kernel is the limit to beat: the equations jaxmr evaluates for this configuration,
written out by hand with nothing general left in the code. The car is
`jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())` (ms 350 kg, mu 40 kg, ks 20 kN/m,
kt 200 kN/m; Bouc–Wen with alpha = 3e4 + 9.7e5 u N/m, c0 = 200 + 1800 u N·s/m, A = 1,
beta = gamma = 500 1/m, n = 1; coil lag du/dt = -125 (u - i)) under the continuous
skyhook law with its inverse model (hard law, T = 0): every 1 ms the desired force is
c_sky times the body velocity, and the command is the current in [0, 1] A whose force is
nearest to it in the damper's present state; it acts one sample later (delay 1), held
over four RK4 steps of 0.25 ms. The road is an ISO 8608 class C profile at 20 m/s on a
1 ms grid, interpolated by cubic Hermite at every RK4 stage. Comfort is
`jaxmr.metrics.wk_rms` of the body acceleration at the controller's samples (what
`jaxmr.metrics.comfort` reads).

Two kernels:

- the kernel (`time_ratio_vs_scan_kernel`, `gradient_time_ratio_vs_scan_kernel`) takes
  the car's and damper's numbers as runtime arrays, as jaxmr does (one compilation
  serves any parameter values, as fitting and robust tuning need), so it evaluates the
  same terms: the power |z|^n, and the tyre damping c_t (v_u - v_r) with the road's
  velocity, both there although n = 1 and c_t = 0 here;
- the specialised kernel (`specialised_*`) has the numbers folded into its code: |z| for
  |z|^1, no tyre damping or other zero terms. No simulator that takes the parameters as
  values can do that; it shows what the generic terms cost.

Each is written in two layouts: the state as one array (rates by `jnp.stack`), or as a
tuple of scalars. On 2 cores XLA ran the generic forward pass fastest with the array
(2x), the specialised one (3x) and every reverse pass (4-25x) with the tuple; each
figure uses the faster layout (benchmarks/README.md).

`closed_loop_speed()` times the forward batch (12 roads x 8 s under `vmap`) through
`jaxmr.evaluate`'s compiled function and through the kernels, and the reverse-mode
gradient of the mean comfort with respect to the skyhook gain: jaxmr's is `tune`'s own
compiled loss-and-gradient (`jaxmr._tune.loss.loss_and_grad`, in log space, NaN-safe,
per road under `vmap`), the kernels' checkpoint every sample (`jax.checkpoint` around
the scan body, as `simulate_system` does). Compilation is timed apart
(`lower().compile()`); runs are the fastest of `repeats` interleaved rounds, because the
machine is shared.
"""

import argparse
import json
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxmr  # noqa: E402
import jaxmr.metrics  # noqa: E402
from jaxmr._tune.batch import road_batch  # noqa: E402
from jaxmr._tune.evaluate import _evaluate  # noqa: E402
from jaxmr._tune.loss import Setup, loss_and_grad  # noqa: E402
from jaxmr._tune.space import as_tuple_where  # noqa: E402

# The laws' inverse model reads the simulated damper's true state, as the kernels do.
ORACLE = "oracle"

SPEED = 20.0  # m/s
I_MAX = 1.0  # A
C_SKY = 2000.0  # N·s/m
DT = 1e-3  # controller sample time [s]
SUBSTEPS = 4
DELAY = 1

# The presets' numbers, folded into the specialised kernel (`preset_car` checks them).
PRESET = dict(
    ms=350.0,  # kg
    mu=40.0,  # kg
    ks=20e3,  # N/m
    kt=200e3,  # N/m
    cs=0.0,  # N·s/m
    ct=0.0,  # N·s/m
    alpha_a=3e4,  # alpha = alpha_a + alpha_b u [N/m]
    alpha_b=9.7e5,
    c0_a=200.0,  # c0 = c0_a + c0_b u [N·s/m]
    c0_b=1800.0,
    A=1.0,
    beta=500.0,  # 1/m
    gamma=500.0,  # 1/m
    n=1.0,
    k0=0.0,  # N/m
    x0=0.0,  # m
    f0=0.0,  # N
    eta=125.0,  # coil lag rate [1/s]
)


def car_parameters(car) -> dict:
    """The numbers of a `passenger_car` with a Bouc–Wen `Damper` with linear laws and a
    `FirstOrderLag`, as the kernel's arrays."""
    bw = car.damper.hysteresis
    return dict(
        ms=car.ms,
        mu=car.mu,
        ks=car.ks,
        kt=car.kt,
        cs=car.cs,
        ct=car.ct,
        alpha_a=bw.alpha.a,
        alpha_b=bw.alpha.b,
        c0_a=bw.c0.a,
        c0_b=bw.c0.b,
        A=bw.A,
        beta=bw.beta,
        gamma=bw.gamma,
        n=bw.n,
        k0=bw.k0,
        x0=bw.x0,
        f0=bw.f0,
        eta=car.damper.dynamics.rate,
    )


def preset_car():
    """`passenger_car(passenger_car_mr_damper())`, after checking that its numbers are
    still those the specialised kernel has folded in."""
    car = jaxmr.passenger_car(jaxmr.passenger_car_mr_damper())
    for name, value in car_parameters(car).items():
        if float(value) != PRESET[name]:
            raise AssertionError(
                f"preset's {name} is {value}, the kernel's {PRESET[name]}"
            )
    return car


def kernel_acceleration(
    c_sky, values, derivatives, road_dt, duration, parameters=None, *, layout, remat
):
    """Body acceleration [m/s²] at the controller's samples $t_k = k\\,dt$, for one road
    of heights `values` [m] and velocities `derivatives` [m/s] on the grid
    $j\\,\\Delta t_r$ (`road_dt` [s], a number; start 0).

    **Arguments:** `parameters`: the car's numbers as arrays (`car_parameters`), or
    `None` for the specialised kernel (the presets' numbers folded in); `layout`:
    `"array"` or `"tuple"`, how the state is carried; `remat`: checkpoint every sample
    for reverse mode. Differentiable in `c_sky`.
    """
    generic = parameters is not None
    p = parameters if generic else PRESET
    samples = int(round(duration / DT))
    last = values.shape[0] - 2
    h = DT / SUBSTEPS

    def road(t):
        # Height (and for the generic kernel the velocity) of the cubic Hermite
        # interpolant, as `jaxmr.RandomRoad` evaluates them.
        r = t / road_dt
        j = jnp.clip(jnp.floor(r), 0, last)
        s = jnp.clip(r - j, 0.0, 1.0)
        inside = (r >= 0) & (r <= last + 1)
        j = j.astype(int)
        y0, y1 = values[j], values[j + 1]
        d0, d1 = derivatives[j] * road_dt, derivatives[j + 1] * road_dt
        height = (
            (2 * s**3 - 3 * s**2 + 1) * y0
            + (s**3 - 2 * s**2 + s) * d0
            + (-2 * s**3 + 3 * s**2) * y1
            + (s**3 - s**2) * d1
        )
        if not generic:
            return height, None
        slope = (
            (6 * s**2 - 6 * s) * y0
            + (3 * s**2 - 4 * s + 1) * d0
            + (-6 * s**2 + 6 * s) * y1
            + (3 * s**2 - 2 * s) * d1
        )
        return height, jnp.where(inside, slope / road_dt, 0.0)

    def damper_force(z, u, x, v, current=None):
        current = u if current is None else current
        alpha = p["alpha_a"] + p["alpha_b"] * current
        c0 = p["c0_a"] + p["c0_b"] * current
        if not generic:
            return alpha * z + c0 * v
        return alpha * z + c0 * v + p["k0"] * (x - p["x0"]) + p["f0"]

    def suspension_force(y):
        zs, vs, zu, vu, z, u = y
        x, v = zs - zu, vs - vu
        force = damper_force(z, u, x, v)
        if not generic:
            return p["ks"] * x + force
        return p["ks"] * x + p["cs"] * v + force

    def power(z):
        a = jnp.abs(z)
        if not generic:
            return a  # n = 1
        positive = a > 0  # jaxmr's `abs_pow`
        return jnp.where(positive, jnp.where(positive, a, 1.0) ** p["n"], 0.0)

    def rates(t, y, applied):
        zs, vs, zu, vu, z, u = y
        v = vs - vu
        suspension = suspension_force(y)
        height, velocity = road(t)
        tyre = -p["kt"] * (zu - height)
        if generic:
            tyre = tyre - p["ct"] * (vu - velocity)
        sign = jnp.sign(z)
        dz = p["A"] * v - (p["gamma"] * jnp.abs(v) * sign + p["beta"] * v) * power(z)
        du = -p["eta"] * (u - applied)
        return (vs, -suspension / p["ms"], vu, (suspension + tyre) / p["mu"], dz, du)

    if layout == "tuple":
        pack, unpack = tuple, tuple
    elif layout == "array":
        pack, unpack = jnp.stack, lambda y: tuple(y)
    else:
        raise ValueError(f"layout must be 'tuple' or 'array', got {layout!r}")

    def rk4(t, y, applied):
        def f(t, y):
            return pack(rates(t, unpack(y), applied))

        def axpy(a, k, y):
            return jax.tree.map(lambda y_, k_: y_ + a * k_, y, k)

        k1 = f(t, y)
        k2 = f(t + h / 2, axpy(h / 2, k1, y))
        k3 = f(t + h / 2, axpy(h / 2, k2, y))
        k4 = f(t + h, axpy(h, k3, y))
        return jax.tree.map(
            lambda y_, a, b, c, d: y_ + (h / 6) * (a + 2 * b + 2 * c + d),
            y,
            k1,
            k2,
            k3,
            k4,
        )

    def skyhook(y):
        # The band [f0, f1] the damper can reach now (state held, lag bypassed) and
        # the position of c_sky vs in it, clipped: the current whose force is nearest.
        zs, vs, zu, vu, z, u = y
        x, v = zs - zu, vs - vu
        f0 = damper_force(z, u, x, v, 0.0)
        f1 = damper_force(z, u, x, v, I_MAX)
        span = f1 - f0
        tiny = jnp.abs(span) < 1e-12 * (1 + jnp.abs(f0) + jnp.abs(f1))
        fraction = jnp.where(tiny, 0.0, (c_sky * vs - f0) / jnp.where(tiny, 1.0, span))
        return I_MAX * jnp.clip(fraction, 0.0, 1.0)

    def sample(carry, k):
        y, applied = carry
        state = unpack(y)
        command = skyhook(state)
        acceleration = -suspension_force(state) / p["ms"]
        t = k * DT
        for j in range(SUBSTEPS):
            y = rk4(t + j * h, y, applied)
        return (y, command), acceleration  # delay 1: `command` acts from t + dt on

    if remat:
        sample = jax.checkpoint(sample, prevent_cse=False)
    zero = jnp.zeros((), values.dtype)
    first = skyhook((zero,) * 6)  # at rest, virgin damper, lag at zero current
    carry = (pack((zero,) * 5 + (first,)), first)
    ks = jnp.arange(samples, dtype=values.dtype)
    _, acceleration = jax.lax.scan(sample, carry, ks)
    return acceleration


def make_roads(n, duration, first_seed=1000):
    """`n` ISO 8608 class C roads at 20 m/s, one per seed, as one batched `RandomRoad`."""
    keys = jax.vmap(jax.random.key)(jnp.arange(first_seed, first_seed + n))
    return jax.vmap(lambda k: jaxmr.iso8608_road("C", SPEED, duration, k))(keys)


def road_grid(roads) -> float:
    """The grid step [s] the batch's roads share (the kernel needs one grid from 0)."""
    dt, start = np.unique(np.asarray(roads.dt)), np.unique(np.asarray(roads.start))
    if dt.size != 1 or start.size != 1 or start[0] != 0.0:
        raise ValueError("the kernel needs roads on one grid starting at t = 0")
    return float(dt[0])


def _c_sky(pair):
    return pair[1].c_sky


def _compiled(jitted, *args):
    t0 = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    return compiled, time.perf_counter() - t0


def _kernels(car, road_dt, duration, specialised):
    """The kernels' jitted forward (comfort of every road) and value-and-gradient (of
    the mean comfort, with respect to log c_sky), as functions of (x, values,
    derivatives, parameters)."""

    def comfort(c_sky, v, d, parameters, layout, remat):
        a = kernel_acceleration(
            c_sky, v, d, road_dt, duration, parameters, layout=layout, remat=remat
        )
        return jaxmr.metrics.wk_rms(a, DT)

    def forward(c_sky, values, derivatives, parameters, layout):
        return jax.vmap(lambda v, d: comfort(c_sky, v, d, parameters, layout, False))(
            values, derivatives
        )

    def loss(log_c, values, derivatives, parameters, layout):
        c_sky = jnp.exp(log_c)
        return jnp.mean(
            jax.vmap(lambda v, d: comfort(c_sky, v, d, parameters, layout, True))(
                values, derivatives
            )
        )

    parameters = None if specialised else car_parameters(car)
    return (
        # The faster layout of each (module docstring).
        jax.jit(
            lambda c, v, d, p: forward(c, v, d, p, "tuple" if specialised else "array")
        ),
        jax.jit(jax.value_and_grad(lambda c, v, d, p: loss(c, v, d, p, "tuple"))),
        parameters,
    )


def closed_loop_speed(duration=8.0, roads=12, repeats=3, specialised=True) -> dict:
    """Time jaxmr's closed loop against the hand-written kernels (module docstring).

    **Arguments:** `duration` [s] per road, `roads` (ISO 8608 class C seeds 1000, 1001,
    ...), `repeats` (timed rounds; the fastest counts), `specialised` (also time the
    kernel with the presets' numbers folded in).

    **Returns:** a dict: simulated seconds per wall second (`closed_loop_sim_s_per_s`
    and `kernel_sim_s_per_s` forward, `gradient_sim_s_per_s` and
    `kernel_gradient_sim_s_per_s` for tuning's value and gradient), the ratios
    `time_ratio_vs_scan_kernel` and `gradient_time_ratio_vs_scan_kernel` (jaxmr's time
    over the kernel's), the same against the specialised kernel (`specialised_...`),
    compile times [s], the largest relative differences between jaxmr and the kernel
    (body acceleration over each road's peak, comfort, loss, gradient), every timed run
    [s] and the load average.
    """
    car = preset_car()
    batch = make_roads(roads, duration)
    road_dt = road_grid(batch)
    values, derivatives = batch.values, batch.derivatives
    law = jaxmr.Skyhook(C_SKY, I_MAX)
    c_sky = jnp.asarray(C_SKY)
    log_c = jnp.log(c_sky)

    # jaxmr's forward: `evaluate`'s compiled function; its gradient: `tune`'s.
    runs, compile_s = {}, {}

    def add(name, jitted, *args):
        runs[name] = (*_compiled(jitted, *args), args)
        compile_s[name] = runs[name][1]

    metrics = (("comfort", jaxmr.metrics.comfort),)
    steps = (jaxmr.Sampling(dt=DT, delay=DELAY), jaxmr.FixedStep(SUBSTEPS))
    # Skyhook inverts the damper: perfect information, as the kernels have it.
    indexed = (batch, jnp.arange(roads))  # each road with its index, as `evaluate`
    # steps=False: the substeps are given, so nothing is read to choose them.
    add(
        "jaxmr_forward",
        _evaluate,
        car,
        law,
        indexed,
        duration,
        metrics,
        *steps,
        ORACLE,
        False,
    )
    setup = Setup(True, as_tuple_where(_c_sky), jaxmr.metrics.comfort, duration, *steps)
    padded = road_batch(batch)
    pair = (car, law)
    add("jaxmr_gradient", loss_and_grad, (log_c,), pair, None, padded, setup, ORACLE)
    kinds = ("kernel", "specialised_kernel") if specialised else ("kernel",)
    for kind in kinds:
        forward, gradient, parameters = _kernels(
            car, road_dt, duration, kind != "kernel"
        )
        add(f"{kind}_forward", forward, c_sky, values, derivatives, parameters)
        add(f"{kind}_gradient", gradient, log_c, values, derivatives, parameters)

    def call(name):
        compiled, _, args = runs[name]
        return compiled(*args)

    # Agreement: body accelerations of every road, and the figures timed.
    @jax.jit
    def accelerations(batch, parameters):
        def one(road):
            jaxmr_run = jaxmr.simulate_system(
                car, road, law, duration, sampling=jaxmr.Sampling(dt=DT), sensors=ORACLE
            )
            kernel_run = kernel_acceleration(
                c_sky,
                road.values,
                road.derivatives,
                road_dt,
                duration,
                parameters,
                layout="tuple",
                remat=False,
            )
            return jaxmr_run["body_acceleration"], kernel_run

        return jax.vmap(one)(batch)

    def largest(a, b):
        a, b = np.asarray(a), np.asarray(b)
        return float(np.max(np.abs(a - b) / np.abs(b)))

    agreement = {}
    comfort = np.asarray(call("jaxmr_forward")[0]["comfort"])  # (values, result)
    loss, (gradient,), _ = call("jaxmr_gradient")
    for kind in kinds:
        parameters = runs[f"{kind}_forward"][2][-1]
        a_jaxmr, a_kernel = (np.asarray(a) for a in accelerations(batch, parameters))
        peak = np.max(np.abs(a_jaxmr), axis=-1, keepdims=True)
        kernel_loss, kernel_gradient = call(f"{kind}_gradient")
        agreement[kind] = {
            "body_acceleration": float(np.max(np.abs(a_jaxmr - a_kernel) / peak)),
            "comfort": largest(comfort, call(f"{kind}_forward")),
            "loss": largest(loss, kernel_loss),
            "gradient": largest(gradient, kernel_gradient),
        }

    times = {name: [] for name in runs}
    cpu0 = time.process_time()
    for _ in range(repeats):
        for name in runs:
            t0 = time.perf_counter()
            jax.block_until_ready(call(name))
            times[name].append(time.perf_counter() - t0)
    best = {name: min(t) for name, t in times.items()}
    simulated = roads * duration
    figures = {
        "closed_loop_sim_s_per_s": simulated / best["jaxmr_forward"],
        "gradient_sim_s_per_s": simulated / best["jaxmr_gradient"],
    }
    for kind in kinds:
        figures |= {
            f"{kind}_sim_s_per_s": simulated / best[f"{kind}_forward"],
            f"{kind}_gradient_sim_s_per_s": simulated / best[f"{kind}_gradient"],
        }
    prefix = {"kernel": "", "specialised_kernel": "specialised_"}
    for kind in kinds:
        figures[f"{prefix[kind]}time_ratio_vs_scan_kernel"] = (
            best["jaxmr_forward"] / best[f"{kind}_forward"]
        )
        figures[f"{prefix[kind]}gradient_time_ratio_vs_scan_kernel"] = (
            best["jaxmr_gradient"] / best[f"{kind}_gradient"]
        )
    return figures | {
        "compile_s": compile_s,
        "max_rel_diff": agreement,
        "setup": {
            "roads": roads,
            "duration_s": duration,
            "repeats": repeats,
            "road": f"ISO 8608 class C at {SPEED} m/s, dt {road_dt} s",
            "c_sky": C_SKY,
            "dt_s": DT,
            "substeps": SUBSTEPS,
            "delay": DELAY,
            "cpu_count": os.cpu_count(),
            "jax": jax.__version__,
        },
        "run_s": times,
        "timed_cpu_s": time.process_time() - cpu0,
        "load_average": os.getloadavg(),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True)
    parser.add_argument("--duration", type=float, default=8.0)
    parser.add_argument("--roads", type=int, default=12)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--no-specialised",
        dest="specialised",
        action="store_false",
        help="skip the kernel with the presets' numbers folded in",
    )
    args = parser.parse_args()
    figures = closed_loop_speed(
        args.duration, args.roads, args.repeats, specialised=args.specialised
    )
    print(json.dumps(figures, indent=1))
    with open(args.json, "w") as f:
        json.dump(figures, f, indent=1)


if __name__ == "__main__":
    main()
