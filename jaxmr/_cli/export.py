"""`jaxmr export`: a tuned controller saved by `jaxmr.save_model` as C99
(`jaxmr.export_c`) and, on request, as a StableHLO program
(`jaxmr.export_stablehlo`)."""

import argparse
from pathlib import Path

import jaxmr

from .errors import CLIError


def add_parser(subparsers) -> None:
    """Register `jaxmr export`."""
    command = subparsers.add_parser(
        "export",
        help="write a tuned controller as C99 (and StableHLO) for a real-time target",
        description=(
            "Write CONTROLLER (a jaxmr.ObserverBasedController saved by "
            "jaxmr.save_model) as dependency-free C99: DIR/NAME.h and DIR/NAME.c with "
            "NAME_init and NAME_step over a fixed-size state struct, no allocation, "
            "the sample period stated (jaxmr.export_c). --stablehlo also writes "
            "DIR/NAME.stablehlo, a jax.export program for an XLA runtime "
            "(jaxmr.export_stablehlo). An existing file is an error unless --force."
        ),
    )
    command.add_argument(
        "controller", metavar="CONTROLLER", help="the controller's JSON file"
    )
    command.add_argument("--out", required=True, metavar="DIR", help="output directory")
    command.add_argument(
        "--name",
        default="controller",
        help="the files' and C functions' prefix, a C identifier (default controller)",
    )
    command.add_argument(
        "--measurements",
        nargs="+",
        metavar="NAME",
        help="the measurements the controller reads, in the order of the C inputs "
        "(default: with a velocity estimator the quarter car's body_acceleration "
        "wheel_acceleration damper_displacement)",
    )
    command.add_argument(
        "--stablehlo", action="store_true", help="also write NAME.stablehlo"
    )
    command.add_argument(
        "--force", action="store_true", help="replace existing output files"
    )
    command.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr export` (see `add_parser`)."""
    source = Path(args.controller)
    if not source.is_file():
        raise CLIError(f"{source}: no such file")
    try:
        controller = jaxmr.load_model(source)
    except (OSError, ValueError, TypeError, KeyError) as e:
        # `load_model`'s messages name the file already.
        message = str(e)
        raise CLIError(
            message if str(source) in message else f"{source}: {message}"
        ) from e
    if not isinstance(controller, jaxmr.ObserverBasedController):
        raise CLIError(
            f"{source}: holds a {type(controller).__name__}; export takes a "
            "jaxmr.ObserverBasedController (the law with its estimator, observer and "
            "sampling)"
        )
    out = Path(args.out)
    outputs = [out / f"{args.name}.h", out / f"{args.name}.c"]
    if args.stablehlo:
        outputs.append(out / f"{args.name}.stablehlo")
    existing = [str(p) for p in outputs if p.exists()]
    if existing and not args.force:
        raise CLIError(f"{', '.join(existing)} exist(s); use --force to replace")
    try:
        written = list(
            jaxmr.export_c(
                controller,
                out,
                name=args.name,
                measurements=args.measurements,
                force=args.force,
            )
        )
        if args.stablehlo:
            jaxmr.export_stablehlo(
                controller,
                outputs[2],
                measurements=args.measurements,
                force=args.force,
            )
            written.append(outputs[2])
    except (NotImplementedError, ValueError, TypeError, OSError) as e:
        raise CLIError(str(e)) from e
    for path in written:
        print(path)
    return 0
