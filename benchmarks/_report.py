"""The figures of a benchmark: printed, and written as JSON where `--json` asks, with
a description of the machine and the checkout that measured them (`machine`)."""

import datetime
import importlib.metadata
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# The versions a figure depends on; a package that is not installed is recorded as None.
PACKAGES = (
    "jax",
    "jaxlib",
    "numpy",
    "scipy",
    "diffrax",
    "equinox",
    "optimistix",
    "jaxmr",
    "numba",
    "evosax",
)
# Taken when a benchmark imports this module, which each does before its work starts:
# the load average "at start" of the machine block (a speed figure is only worth
# something on an idle machine, so the reader needs the load before and after).
_STARTED = time.time()
_LOAD_AT_START = os.getloadavg()


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def _git() -> dict | None:
    """The commit measured and the files of jaxmr/ and benchmarks/ changed since it
    (uncommitted work changes what a figure measures)."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout

    try:
        commit = git("rev-parse", "HEAD").strip()
        changed = git("status", "--porcelain", "--", "jaxmr", "benchmarks")
    except (OSError, subprocess.CalledProcessError):
        return None
    return {
        "commit": commit,
        "changed": [line[3:] for line in changed.splitlines() if line.strip()],
    }


def machine(
    load_average_at_start: tuple[float, ...] | None = None,
    started: float | None = None,
    command: list[str] | None = None,
) -> dict:
    """The machine, software and checkout of a measurement, now.

    `load_average_at_start` (1, 5 and 15 min) and `started` (seconds since the epoch)
    default to when this module was imported; `command` to this process's `sys.argv`.
    """
    start = _STARTED if started is None else started
    cores = os.cpu_count()
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on every platform
        usable = cores
    return {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "cpu": _cpu_model(),
        "cores": cores,
        "cores_usable": usable,
        "load_average_start": list(
            _LOAD_AT_START if load_average_at_start is None else load_average_at_start
        ),
        "load_average_end": list(os.getloadavg()),
        "wall_seconds": time.time() - start,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "versions": {name: _version(name) for name in PACKAGES},
        "xla_flags": os.environ.get("XLA_FLAGS"),
        "git": _git(),
        "command": list(sys.argv if command is None else command),
    }


def with_machine(figures: dict, **kwargs) -> dict:
    """`figures` with a `machine` block (`machine(**kwargs)`). A `machine` entry the
    benchmark wrote itself is kept: a dict's entries override the description's, a
    text becomes its `note`."""
    described = machine(**kwargs)
    own = figures.get("machine")
    if isinstance(own, dict):
        described |= own
    elif own is not None:
        described["note"] = own
    return {**figures, "machine": described}


def write_figures(figures: dict, path: Path | None) -> None:
    """Print `figures` as JSON with the machine described (`machine`), and write them
    to `path` where given (its folder made if needed)."""
    text = json.dumps(with_machine(figures), indent=2, default=float)
    print(text)
    if path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
