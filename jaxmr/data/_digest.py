"""Fingerprints of measured data: by which a parameter file's report knows the files
and experiments it was fitted on (`jaxmr.fit_report`, `jaxmr report`)."""

import hashlib
import os
from pathlib import Path

import numpy as np


def file_digest(path: str | os.PathLike) -> str | None:
    """The SHA-256 of a file's bytes (hex): the same file under any name or
    directory; None when it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def experiment_digest(experiment) -> str:
    """The SHA-256 (hex) of an experiment's numbers: time, motion, input and force
    as float64, and its kind of device (rotary or linear, current or voltage). The
    same experiment whatever file it was read from or written to (`write_csv`
    writes every number so that it reads back exactly); smoothing and the
    discarded start are settings, not data, and do not count."""
    digest = hashlib.sha256()
    t = np.asarray(experiment.t, np.float64)
    force = getattr(experiment, "force", None)
    for column in (t, experiment.x, experiment.v, experiment.current, force):
        if column is None:
            digest.update(b"none")
            continue
        values = np.broadcast_to(np.asarray(column, np.float64), t.shape)
        digest.update(np.ascontiguousarray(values).tobytes())
    rotary = bool(getattr(experiment, "rotary", False))
    drive = str(getattr(experiment, "drive", "current"))
    digest.update(f"{rotary},{drive}".encode())
    return digest.hexdigest()
