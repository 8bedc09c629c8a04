"""The command line's persistent compilation cache: JAX's, in a folder of the user's
cache directory, so that a second `jaxmr fit` (`predict`, `report`, ...) of the same
shapes reads its compiled programs back instead of compiling them again.

Where it lives, first that applies: the command's `--compilation-cache DIR` option;
the `JAXMR_COMPILATION_CACHE` environment variable; JAX's own
`JAX_COMPILATION_CACHE_DIR` (JAX reads it itself, and it is left as it is); else
`$XDG_CACHE_HOME/jaxmr/xla` (by default `~/.cache/jaxmr/xla`; on macOS
`~/Library/Caches/jaxmr/xla`, on Windows `%LOCALAPPDATA%\\jaxmr\\cache\\xla`). `off`
in the option or the variable turns it off. The folder may be deleted at any time; it
grows by one file per distinct program (JAX evicts nothing without the optional
`filelock` package). Its `programs` folder holds the fit's traced programs
(`jaxmr.devices.traced_programs_in`), which a later run reads back without tracing
the model again.

Set up when a command starts (`configure`), never on import: jaxmr the library leaves
JAX's configuration alone. Called from Python (`jaxmr._cli.main` with JAX already
imported, as the tests do), only an explicit option or `JAXMR_COMPILATION_CACHE`
turns it on: the caller's process is not given a cache it did not ask for.
"""

import argparse
import os
import sys
from pathlib import Path

ENV = "JAXMR_COMPILATION_CACHE"
OFF = "off"
# Every compilation is stored, not only those over JAX's default of 1 s: a command
# compiles its fit's few large programs and scores of small ones (array operations
# run outside jit, each compiled on first use), which together took seconds.
MIN_COMPILE_SECONDS = 0.0
# The subfolder of the fit's traced programs (`jaxmr.devices.traced_programs_in`),
# which a later run reads back without tracing the model again (`programs`).
PROGRAMS = "programs"


def programs(folder: Path | None) -> Path | None:
    """Where a command keeps its traced programs: in the compilation cache's folder
    (`folder`, None when it is off), deleted with it."""
    return None if folder is None else folder / PROGRAMS


HELP = (
    "the folder of the persistent compilation cache, which a later run of the same "
    f"shapes reads its compiled programs from, or {OFF}; default: ${ENV}, else "
    "JAX's JAX_COMPILATION_CACHE_DIR, else jaxmr/xla in the user's cache folder "
    "(~/.cache/jaxmr/xla)"
)


def add_argument(parser: argparse.ArgumentParser) -> None:
    """Give a command's parser `--compilation-cache`."""
    parser.add_argument("--compilation-cache", metavar="DIR", default=None, help=HELP)


def default_folder() -> Path:
    """jaxmr's folder of compiled programs in the user's cache directory."""
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local"
        return Path(base) / "jaxmr" / "cache" / "xla"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "jaxmr" / "xla"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxmr" / "xla"


def configure(option: str | None, program: bool) -> Path | None:
    """Turn JAX's persistent compilation cache on for this process (see the module's
    docstring) and return its folder, or None where it stays off.

    `option`: the command's `--compilation-cache` (None: not given); `program`:
    whether this is the `jaxmr` program (JAX not imported before the command), which
    gets the default folder.
    """
    import jax

    choice = option if option is not None else os.environ.get(ENV)
    if choice is None:
        # JAX_COMPILATION_CACHE_DIR, read by JAX itself (a flag JAX's stubs omit).
        own = jax.config.jax_compilation_cache_dir  # pyright: ignore[reportAttributeAccessIssue]
        if own:
            return Path(own)
        if not program:
            return None
        folder = default_folder()
    elif choice.strip().lower() == OFF or not choice.strip():
        return None
    else:
        folder = Path(choice).expanduser()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(
            f"jaxmr: compilation cache off: cannot make {folder} ({e.strerror})",
            file=sys.stderr,
        )
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return folder
