"""`jaxmr convert`: a public dataset as canonical CSV files
(`jaxmr.data.convert_dataset`)."""

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import jaxmr

from .errors import CLIError

if TYPE_CHECKING:
    import jaxmr.data  # at run time `jaxmr.data` is imported on first use (it imports JAX)

# The names of `jaxmr.data.DATASETS`, for the help (`jaxmr.data` imports JAX;
# tests/test_cli.py checks that the lists agree).
DATASET_NAMES = ("utfsm", "nees", "boucwen")


def add_parser(subparsers) -> None:
    """Register `jaxmr convert`."""
    command = subparsers.add_parser(
        "convert",
        help="turn a public dataset into jaxmr's canonical CSV files",
        description=(
            "Convert a public dataset that jaxmr's loaders know into canonical CSV "
            "files (one per experiment, with the dataset's own smoothing and discarded "
            "start as comment lines, which `jaxmr fit` reads): "
            + ", ".join(DATASET_NAMES)
            + ". Existing files are never replaced without --force."
        ),
    )
    command.add_argument("dataset", choices=DATASET_NAMES, help="the dataset")
    command.add_argument(
        "source", metavar="SOURCE", help="the dataset's directory or file as published"
    )
    command.add_argument("--out", required=True, metavar="DIR", help="output directory")
    command.add_argument(
        "--force", action="store_true", help="replace files that already exist"
    )
    command.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run `jaxmr convert` (see `add_parser`)."""
    # convert_dataset applies the rule of every command itself (never over the
    # source, an existing file only with force, each file through a rename).
    out = Path(args.out)
    existed = set(out.iterdir()) if args.force and out.is_dir() else set()
    try:
        written = jaxmr.data.convert_dataset(
            args.dataset, args.source, args.out, force=args.force
        )
    except (ValueError, FileExistsError, OSError) as e:
        raise CLIError(str(e)) from e
    for path in written:
        replaced = " (replaced the existing file)" if Path(path) in existed else ""
        print(f"wrote {path}{replaced}")
    print(f"{len(written)} file(s) in {args.out}")
    return 0
