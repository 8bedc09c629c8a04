"""`jaxmr demo`: an MR device at five currents, its loops, energy per cycle and a
table (no data needed). The default is a linear passenger-car damper, whose force grows
nearly twentyfold from 0 to 1 A; `--device brake` is the SAS study's rotary brake."""

import argparse
import csv
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import jaxmr
import jaxmr.plot

from .errors import CLIError
from .files import FORCE_HELP, plan_outputs, prepare_directory, save_figure, write_text

DEMO_CURRENTS = (0.0, 0.25, 0.5, 0.75, 1.0)  # A
DEMO_RATE = 1000.0  # Hz, output samples


@dataclass(frozen=True)
class DemoDevice:
    """One device of the demo and the sine test it runs (SI units: m or rad, Hz, s)."""

    # The preset's name in jaxmr, called at run time: `jaxmr demo --help` imports no JAX.
    model: str
    name: str  # in titles and messages
    amplitude: float  # m (linear) or rad (rotary)
    amplitude_text: str  # as printed: "±20 mm", "±3.5°"
    frequency: float  # Hz
    duration: float  # s: the transient from the virgin state, then one cycle kept
    rotary: bool
    note: str  # printed after the table and in --help


# Why the brake's loops barely change with current (printed by the demo and in its
# --help).
BRAKE_NOTE = (
    "The brake's loops grow by only about 9 % from 0 to 1 A: that is its published "
    "law (SAS study, Table 1), not a numerical effect. Its hysteretic torque "
    "alpha(i) z grows with alpha = 1 + 0.07 i N·m, 7 % per ampere, and its viscous "
    "torque (0.0015 + 0.07 i) N·m·s/rad times at most 0.38 rad/s at ±3.5°, 1 Hz adds "
    "about 2 % of the energy at 1 A. The energy axis starts at 0 so that the change "
    "is seen at its true scale."
)
DAMPER_NOTE = (
    "The damper's yield force grows from 30 N at 0 A to 1 000 N at 1 A and its "
    "viscous coefficient from 200 to 2 000 N·s/m (jaxmr.passenger_car_mr_damper): "
    "the field effect that a semi-active law uses."
)
DEVICES = {
    # A damper test rig's sine: ±20 mm at 2 Hz, 0.25 m/s peak velocity.
    "damper": DemoDevice(
        "passenger_car_mr_damper",
        "passenger-car MR damper, Bouc-Wen",
        0.020,
        "±20 mm",
        2.0,
        1.5,
        False,
        DAMPER_NOTE,
    ),
    # The SAS study's test: its brake under a 1 Hz sine of ±3.5°.
    "brake": DemoDevice(
        "sas_brake_bouc_wen",
        "SAS MR brake, Bouc-Wen",
        float(np.deg2rad(3.5)),
        "±3.5°",
        1.0,
        3.0,
        True,
        BRAKE_NOTE,
    ),
}


def add_parser(subparsers) -> None:
    """Register `jaxmr demo`."""
    demo = subparsers.add_parser(
        "demo",
        help="simulate an MR damper (or brake) at five currents; write loops and a table",
        description=(
            "Simulate an MR device under a sine at currents "
            f"{', '.join(f'{c:g}' for c in DEMO_CURRENTS)} A, and write force (torque) "
            "loops of the last cycle, energy per cycle against current, and a table of "
            "peak force and energy per cycle (summary.csv, summary.md). The default "
            "device is a linear passenger-car MR damper under "
            f"{DEVICES['damper'].amplitude_text} at {DEVICES['damper'].frequency:g} Hz; "
            f"--device brake is the SAS study's rotary brake (its published Bouc-Wen "
            f"parameters) under {DEVICES['brake'].amplitude_text} at "
            f"{DEVICES['brake'].frequency:g} Hz. " + BRAKE_NOTE
        ),
    )
    demo.add_argument(
        "--device",
        choices=tuple(DEVICES),
        default="damper",
        help="the device: a translational (linear-motion) damper (default) or the SAS "
        "rotary brake",
    )
    demo.add_argument(
        "--out",
        metavar="DIR",
        default="demo_out",
        help="directory for the figures and tables (created; default: demo_out)",
    )
    demo.add_argument("--force", action="store_true", help=FORCE_HELP)
    demo.set_defaults(run=run)


def demo_files(device: str) -> tuple[tuple[tuple[str, str], ...], tuple[str, ...]]:
    """The demo's figures (file name, abscissa) and all its files, for a device."""
    quantity, position = (
        ("torque", "angle") if DEVICES[device].rotary else ("force", "displacement")
    )
    figures = (
        (f"{quantity}_{position}.png", "displacement"),
        (f"{quantity}_velocity.png", "velocity"),
        (f"{quantity}_time.png", "time"),
    )
    files = (
        *(name for name, _ in figures),
        "energy_vs_current.png",
        "summary.csv",
        "summary.md",
    )
    return figures, files


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr demo` (see `add_parser`)."""
    device = DEVICES[getattr(args, "device", "damper")]
    figures, files = demo_files(getattr(args, "device", "damper"))
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"the output path {str(out)!r} exists and is not a directory")
    replacing = plan_outputs([out / n for n in files], [], force=args.force)
    prepare_directory(out)
    # Before pyplot is imported (by jaxmr.plot, on use): no display is needed.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxmr.metrics import energy_per_cycle  # imports JAX: at run time only

    currents = np.array(DEMO_CURRENTS)
    period = 1 / device.frequency
    ts = np.linspace(0.0, device.duration, round(device.duration * DEMO_RATE) + 1)
    motion = jaxmr.Sine(device.amplitude, device.frequency)
    test = f"{device.frequency:g} Hz, {device.amplitude_text}"
    print(
        f"simulating {len(currents)} currents ({device.name}; {test}, "
        f"{device.duration:g} s at {DEMO_RATE / 1000:g} kHz, RK4 0.5 ms steps)...",
        flush=True,
    )
    start = time.perf_counter()
    # Fixed-step RK4 at 0.5 ms: on these excitations it agrees with the adaptive
    # default (Dopri8, rtol 1e-8) to 5e-5 of the peak force (3e-5 for the damper),
    # and the demo takes a quarter to a half of the CPU time (mostly compilation).
    model = getattr(jaxmr, device.model)()
    solution = jaxmr.sweep(
        model, motion, currents, ts, integrator=jaxmr.FixedStep(substeps=2)
    )
    energy = np.asarray(energy_per_cycle(solution, period))
    print(f"simulated in {time.perf_counter() - start:.1f} s", flush=True)

    # The last full cycle; half a sample of slack so rounding in ts keeps its first one.
    last_cycle_from = ts[-1] - period - 0.5 / DEMO_RATE
    last = ts >= last_cycle_from
    peak = np.max(np.abs(np.asarray(solution.force)[:, last]), axis=-1)

    labels = [f"{c:g} A" for c in currents]
    title = f"{device.name}\n{test}, last cycle"
    units = "rotary" if device.rotary else "linear_mm"
    for name, against in figures:
        ax = jaxmr.plot.loop(
            solution,
            against,
            units=units,
            labels=labels,
            last_cycles_from=last_cycle_from,
        )
        ax.set_title(title, fontsize="medium")
        save_figure(plt, ax.figure, out / name, replacing=out / name in replacing)
    growth = energy[-1] / energy[0]
    ax = jaxmr.plot.energy_vs_current(currents, energy)
    ax.set_title(
        f"{device.name}: energy per cycle\n×{growth:.3g} from "
        f"{currents[0]:g} to {currents[-1]:g} A",
        fontsize="medium",
    )
    path = out / "energy_vs_current.png"
    save_figure(plt, ax.figure, path, replacing=path in replacing)

    quantity, unit = ("torque", "N·m") if device.rotary else ("force", "N")
    header = ("current [A]", f"peak {quantity} [{unit}]", "energy per cycle [J]")
    columns = ("current_A", f"peak_{quantity}_{unit.replace('·', '')}", "energy_J")
    rows = list(zip(currents, peak, energy))
    write_text(
        out / "summary.csv",
        lambda f: _write_csv(f, columns, rows),
        replacing=out / "summary.csv" in replacing,
    )
    table = _markdown_table(header, rows)
    write_text(
        out / "summary.md",
        lambda f: f.write(table),
        replacing=out / "summary.md" in replacing,
    )
    print()
    print(table, end="")
    # The energy of a linear dashpot over a sine cycle is exactly π c ω X²: the rest is
    # the hysteretic part (α z).
    omega = 2 * np.pi * device.frequency
    law = model.hysteresis if isinstance(model, jaxmr.Damper) else model
    at = [law.at(c) for c in currents]
    # Both devices are Bouc-Wen models, whose viscous coefficient is `c0`.
    c0 = np.array([float(m.c0) for m in at if isinstance(m, jaxmr.BoucWen)])
    viscous = np.pi * c0 * omega * device.amplitude**2
    hysteretic = energy - viscous
    print(
        f"\nenergy per cycle {energy[0]:.4g} J at {currents[0]:g} A, "
        f"{energy[-1]:.4g} J at {currents[-1]:g} A: ×{growth:.3g} ({growth - 1:+.1%}); "
        f"its hysteretic part ×{hysteretic[-1] / hysteretic[0]:.3g}, its viscous part "
        f"×{viscous[-1] / viscous[0]:.3g}.\n{device.note}"
    )
    return 0


def _write_csv(f, header: Sequence[str], rows) -> None:
    writer = csv.writer(f, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([[f"{float(x):.10g}" for x in row] for row in rows])


def _markdown_table(header: Sequence[str], rows) -> str:
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join("---:" for _ in header) + "|",
    ]
    for current, peak, energy in rows:
        lines.append(f"| {current:.2f} | {peak:.4f} | {energy:.4f} |")
    return "\n".join(lines) + "\n"
