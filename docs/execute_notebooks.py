"""Execute the example notebooks in place, so that they are committed with their outputs.

    python docs/execute_notebooks.py                  # every notebook in notebooks/
    python docs/execute_notebooks.py notebooks/05_magnetic_hysteresis.ipynb

Each notebook runs top to bottom in a fresh `python3` kernel against this checkout of
jaxmr (as `tests/test_notebooks.py` runs them; each enables float64 in its first cell)
and is written back with its outputs, through a temporary file and a rename. The
documentation site renders those outputs and never executes a notebook itself. A
notebook whose cell fails is left as it was, and the command exits with status 1.
All of them take several CPU-minutes (about 7 for the first six).
"""

import argparse
import os
import sys
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

ROOT = Path(__file__).resolve().parents[1]


def execute(path: Path, timeout: int) -> None:
    """Run `path` in a fresh kernel and write it back with its outputs."""
    notebook = nbformat.read(path, as_version=4)
    client = NotebookClient(
        notebook,
        kernel_name="python3",
        timeout=timeout,
        resources={"metadata": {"path": str(path.parent)}},
        # No per-cell timestamps: a re-run changes only what the cells print.
        record_timing=False,
    )
    client.execute()
    part = path.with_name(path.name + ".part")
    nbformat.write(notebook, part)
    part.replace(path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "notebooks",
        nargs="*",
        type=Path,
        help="notebooks to execute (default: every notebooks/*.ipynb)",
    )
    parser.add_argument(
        "--timeout", type=int, default=600, help="seconds per cell (default 600)"
    )
    args = parser.parse_args(argv)
    paths = args.notebooks or sorted((ROOT / "notebooks").glob("*.ipynb"))
    # The kernel imports this checkout's jaxmr whether or not it is installed.
    os.environ["PYTHONPATH"] = os.pathsep.join(
        filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])
    )
    failed = []
    for path in paths:
        start = time.perf_counter()
        print(f"{path.name}: executing...", flush=True)
        try:
            execute(path.resolve(), args.timeout)
        except CellExecutionError as error:
            failed.append(path.name)
            print(f"{path.name}: a cell failed, left unchanged:\n{error}", flush=True)
            continue
        print(f"{path.name}: done in {time.perf_counter() - start:.0f} s", flush=True)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
