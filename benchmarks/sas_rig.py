"""Benchmark: the SAS rig (SYSTEMS.md §2) under constant currents and semi-active laws.

1. Free decay, the source's experiment: the body released 16° above rest, the cam still,
   15 s at 1 kHz (control and sampling), one sample of delay. Settling time: the body
   stays within 0.5° of where it comes to rest (`jaxmr.metrics.decay_settling_time`).
   Writes `settling_s` for 0, 0.2 and 1 A (the source: ≈ 11 s and ≈ 6 s, falling
   with current) and the same for every constant current and controller.
2. The controllers against the fastest constant current: `controller_settling_ratio`
   (the best controller's settling time over that current's; goal ≤ 1.1) and
   `controller_current_ratio` (the best controller's mean current over that constant
   current, over the 15 s; goal ≤ 0.5). "Best": the shortest settling time, ties
   (within 1 %) broken by the lower mean current.
3. Cam excitation at the body's resonance (`jaxmr.Cam`, 4 mm eccentricity, the
   undamped body-mode frequency), 20 s from rest: RMS body angle about rest over the
   last 10 s, for every constant current and every controller.

Controllers: every jaxmr law that applies to the rig (the quarter-car laws run on it
unchanged: its brake's orientation is the quarter car's, `damper_displacement` = body
minus wheel arm): backstepping (source doc 001 §7.1; `jaxmr.Backstepping` with
$g = -1/J_2$), on/off and continuous skyhook, and the acceleration-driven damper. If
jaxmr has no `Backstepping`, the script's own rig law (same equations) stands in.
Every law runs with perfect information (`sensors="oracle"`: the inverse brake model
reads the simulated brake's true state), as the source's simulations do.

Compile and run are timed apart (first call minus the best of the repeated calls).

Run from the repository root:

    python benchmarks/sas_rig.py --json benchmarks/results/sas_rig.json
    python benchmarks/sas_rig.py --json /tmp/smoke.json --quick   # fewer laws, shorter
"""

import argparse
import datetime
import json
import platform
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import jaxmr  # noqa: E402
from jaxmr._closed_loop import free_decay  # noqa: E402
from jaxmr._systems.sas_rig import (  # noqa: E402
    SASRig,
    decay_settling_time,
    sas_rig,
)

I_MAX = 1.5  # A, the RD-2087-01's maximum current
CURRENTS = (0.0, 0.2, 0.5, 1.0, 1.5)
DECAY_S = 15.0
CAM_S, CAM_KEEP_S = 20.0, 10.0
ECCENTRICITY = 0.004  # m
RELEASE_DEG = 16.0


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--json", required=True, metavar="OUT", help="write results here")
    p.add_argument("--repeats", type=int, default=2, help="timed runs after the first")
    p.add_argument(
        "--quick", action="store_true", help="smoke test: two laws, one repeat"
    )
    return p.parse_args()


def controllers(rig: SASRig, rest, f_body: float, quick: bool) -> dict:
    """The laws compared. Backstepping's gains: $1 + h_1 h_2 = \\omega_0^2$ (the body
    mode's, so that $T^*$ asks for no stiffness the brake cannot give) and a large
    $h_1 + h_2$ (damping that saturates the brake while the body moves)."""
    j2 = float(rig.J2)
    h1 = 3.0
    h2 = ((2 * np.pi * f_body) ** 2 - 1) / h1
    laws = {
        "backstepping": jaxmr.Backstepping(
            h1, h2, g=-1 / j2, i_max=I_MAX, y_ref=float(rest)
        ),
        "on/off skyhook": jaxmr.OnOffSkyhook(I_MAX),
    }
    if quick:
        return laws
    # c_sky [N·m·s/rad]: 20 asks for ~8 N·m at the first swing (saturating) and lets
    # the current fall as the body slows.
    laws["skyhook (c=20)"] = jaxmr.Skyhook(20.0, I_MAX)
    laws["acceleration-driven"] = jaxmr.AccelerationDrivenDamper(
        I_MAX, reference_frequency=f_body
    )
    return laws


def timed(fn, *args, repeats):
    """(result, compile seconds, run seconds): compile = first call - best run."""
    start = time.perf_counter()
    result = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - start)
    run = min(runs) if runs else first
    return result, max(first - run, 0.0), run


@eqx.filter_jit
def decay_summary(rig, controller):
    solution = free_decay(
        rig,
        controller,
        release_angle_deg=RELEASE_DEG,
        duration=DECAY_S,
        sensors="oracle",
    )
    settle = decay_settling_time(solution.ts, solution["body_position"])
    return (
        settle,
        jnp.mean(solution.current),
        jnp.max(jnp.abs(solution["damper_force"])),
    )


@eqx.filter_jit
def cam_summary(rig, controller, cam, rest):
    solution = jaxmr.simulate_system(rig, cam, controller, CAM_S, sensors="oracle")
    keep = solution.ts >= CAM_S - CAM_KEEP_S
    angle = solution["body_position"] - rest
    rms = jnp.sqrt(
        jnp.sum(jnp.where(keep, angle**2, 0.0)) / jnp.sum(keep.astype(float))
    )
    peak = jnp.max(jnp.where(keep, jnp.abs(angle), 0.0))
    current = jnp.sum(jnp.where(keep, solution.current, 0.0)) / jnp.sum(
        keep.astype(float)
    )
    return rms, peak, current


def constant(currents):
    return jaxmr.ConstantCurrent(jnp.asarray(currents), jnp.asarray(I_MAX))


def main():
    args = parse_args()
    repeats = 1 if args.quick else args.repeats
    rig = sas_rig()
    rest = rig.equilibrium()[1]
    f_body, f_wheel = (float(f) for f in rig.natural_frequencies())
    cam = jaxmr.Cam(ECCENTRICITY, f_body)
    currents = CURRENTS[::2] if args.quick else CURRENTS
    # Constant currents: one vmapped compilation for all of them.
    batch = jnp.asarray(currents)
    vmapped_decay = eqx.filter_jit(
        eqx.filter_vmap(lambda i: decay_summary(rig, constant(i)))
    )
    vmapped_cam = eqx.filter_jit(
        eqx.filter_vmap(lambda i: cam_summary(rig, constant(i), cam, rest))
    )
    rows, timings = {}, {}
    (settle, mean_i, peak_t), c, r = timed(vmapped_decay, batch, repeats=repeats)
    timings["decay, constant currents (vmapped)"] = (c, r)
    (rms, peak, cam_i), c, r = timed(vmapped_cam, batch, repeats=repeats)
    timings["cam, constant currents (vmapped)"] = (c, r)
    for k, i in enumerate(currents):
        rows[f"{i:g} A"] = dict(
            kind="constant",
            current_A=float(i),
            settling_s=float(settle[k]),
            mean_current_A=float(mean_i[k]),
            peak_torque_Nm=float(peak_t[k]),
            cam_rms_deg=float(np.rad2deg(rms[k])),
            cam_peak_deg=float(np.rad2deg(peak[k])),
            cam_mean_current_A=float(cam_i[k]),
        )
    for name, law in controllers(rig, rest, f_body, args.quick).items():
        (s, m, p), c, r = timed(decay_summary, rig, law, repeats=repeats)
        timings[f"decay, {name}"] = (c, r)
        (cr, cp, ci), c, r = timed(cam_summary, rig, law, cam, rest, repeats=repeats)
        timings[f"cam, {name}"] = (c, r)
        rows[name] = dict(
            kind="controller",
            settling_s=float(s),
            mean_current_A=float(m),
            peak_torque_Nm=float(p),
            cam_rms_deg=float(np.rad2deg(cr)),
            cam_peak_deg=float(np.rad2deg(cp)),
            cam_mean_current_A=float(ci),
        )

    constants = {k: v for k, v in rows.items() if v["kind"] == "constant"}
    laws = {k: v for k, v in rows.items() if v["kind"] == "controller"}
    fastest = min(constants, key=lambda k: constants[k]["settling_s"])
    quickest = min(v["settling_s"] for v in laws.values())
    best = min(
        (k for k, v in laws.items() if v["settling_s"] <= 1.01 * quickest),
        key=lambda k: laws[k]["mean_current_A"],
    )
    settling_ratio = laws[best]["settling_s"] / constants[fastest]["settling_s"]
    current_ratio = laws[best]["mean_current_A"] / constants[fastest]["mean_current_A"]
    settling = {
        f"{i:g}": rows[f"{i:g} A"]["settling_s"]
        for i in (0.0, 0.2, 1.0)
        if f"{i:g} A" in rows
    }
    falls = all(
        a > b for a, b in zip(list(settling.values()), list(settling.values())[1:])
    )

    print(
        f"SAS rig: body mode {f_body:.3f} Hz, wheel mode {f_wheel:.2f} Hz; "
        f"decay from {RELEASE_DEG:g}° over {DECAY_S:g} s; cam {ECCENTRICITY * 1e3:g} mm "
        f"at {f_body:.3f} Hz"
    )
    header = (
        f"{'':>24} {'settle [s]':>10} {'mean i [A]':>10} {'peak T [N·m]':>12} "
        f"{'cam rms [°]':>11} {'cam peak [°]':>12} {'cam i [A]':>9}"
    )
    print(header)
    for name, v in rows.items():
        print(
            f"{name:>24} {v['settling_s']:10.3f} {v['mean_current_A']:10.3f} "
            f"{v['peak_torque_Nm']:12.2f} {v['cam_rms_deg']:11.3f} "
            f"{v['cam_peak_deg']:12.3f} {v['cam_mean_current_A']:9.3f}"
        )
    print(f"fastest constant current: {fastest}; best controller: {best}")
    print(f"controller_settling_ratio = {settling_ratio:.3f} (goal <= 1.1)")
    print(f"controller_current_ratio  = {current_ratio:.3f} (goal <= 0.5)")
    print(f"settling falls with current (0, 0.2, 1 A): {falls}")
    print(f"{'timing':>40} {'compile [s]':>11} {'run [s]':>8}")
    for name, (c, r) in timings.items():
        print(f"{name:>40} {c:11.2f} {r:8.3f}")

    out = dict(
        benchmark="sas_rig",
        date=datetime.datetime.now(datetime.UTC).isoformat(),
        machine=dict(
            platform=platform.platform(),
            python=platform.python_version(),
            jax=jax.__version__,
            device=str(jax.devices()[0]),
        ),
        quick=args.quick,
        settings=dict(
            release_deg=RELEASE_DEG,
            decay_s=DECAY_S,
            dt_s=1e-3,
            substeps=4,
            delay_samples=1,
            i_max_A=I_MAX,
            band_deg=0.5,
            cam_eccentricity_m=ECCENTRICITY,
            cam_frequency_Hz=f_body,
            cam_s=CAM_S,
            cam_rms_window_s=CAM_KEEP_S,
        ),
        rig=dict(
            body_mode_Hz=f_body,
            wheel_mode_Hz=f_wheel,
            rest_angles_deg=[float(a) for a in np.rad2deg(rig.equilibrium())],
        ),
        settling_s=settling,
        settling_falls_with_current=falls,
        fastest_constant_current=fastest,
        best_controller=best,
        controller_settling_ratio=settling_ratio,
        controller_current_ratio=current_ratio,
        cam_rms_deg={k: v["cam_rms_deg"] for k, v in rows.items()},
        table=rows,
        timings_s={k: dict(compile=c, run=r) for k, (c, r) in timings.items()},
    )
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
