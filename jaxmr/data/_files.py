"""Writing a file whole or not at all: `write_atomically`, shared by `convert_dataset`
and the `jaxmr` command line (which reaches it through the public `jaxmr.data`)."""

import os
import secrets
from collections.abc import Callable
from pathlib import Path


def write_atomically(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Write the file `path` whole or not at all.

    `write(temporary)` writes the content to a new file beside `path` (a hidden name,
    `.<name>.<random hex>.tmp`, in the same directory, created by `write` itself so
    that it gets the usual permissions), which is then renamed to `path` with
    `os.replace`: on one file system the rename is atomic, so `path` is afterwards the
    whole new file, or, if `write` or the rename fails or is interrupted (an
    exception, `KeyboardInterrupt` included), what it was before (an existing file
    untouched, a missing one still missing). The temporary file is removed on failure.

    An existing `path` is replaced: checking that it may be is the caller's business
    (`convert_dataset`'s `force`, the command line's `--force`).

    **Arguments:**

    - `path`: the file to write; its directory must exist.
    - `write`: writes the content to the path it is given, e.g.
      `lambda p: jaxmr.data.write_csv(experiment, p)` or `lambda p: figure.savefig(p,
      format="png")` (give the format: the temporary name ends in `.tmp`).

    **Returns:** `path`, as a `Path`.

    **Raises:** whatever `write` raises, and `OSError` from the rename (a directory
    that does not exist or cannot be written, a full disk), after removing the
    temporary file.
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    try:
        write(temporary)
        os.replace(temporary, path)
    except BaseException:
        try:
            temporary.unlink(missing_ok=True)
        except OSError:  # the error being raised says more than this one
            pass
        raise
    return path
