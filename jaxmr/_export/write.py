"""Writing an export's files: never over a user's file unless asked, each whole or
not at all."""

from collections.abc import Callable, Mapping
from pathlib import Path

from ..data import write_atomically


def write_outputs(
    folder: Path, files: Mapping[str, str | Callable[[Path], object]], *, force: bool
) -> tuple[Path, ...]:
    """Write `files` (name -> text, or a function writing the file at the path it is
    given) into `folder` (made if missing). Without `force` an existing file is a
    `FileExistsError` before anything is written."""
    paths = [folder / name for name in files]
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(
            f"export: {folder} is a file, not a folder: give the folder to write "
            f"{', '.join(files)} into."
        )
    # Checked for every file before any is written, so that a pair is written whole
    # or not at all.
    taken = [str(p) for p in paths if p.is_dir()]
    if taken:
        raise IsADirectoryError(
            f"export: {', '.join(taken)} is a folder; the export writes a file there."
        )
    if not force:
        existing = [str(p) for p in paths if p.exists()]
        if existing:
            raise FileExistsError(
                f"export: {', '.join(existing)} exist(s); pass force=True (the "
                "command line's --force) to replace them."
            )
    folder.mkdir(parents=True, exist_ok=True)
    for path, content in zip(paths, files.values()):
        if isinstance(content, str):
            text = content
            write_atomically(path, lambda p, text=text: Path(p).write_text(text))
        else:
            write_atomically(path, content)
    return tuple(paths)
