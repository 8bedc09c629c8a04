"""Conversion of the public datasets that the loaders read into jaxmr's CSV files.

`convert_dataset("utfsm" | "nees" | "boucwen", source, out_dir)` writes one file per
experiment: the damper tests in the canonical CSV format (`read_csv`, with the
processing comments that `read_processing` reads), the Bouc–Wen benchmark, a system
driven by a force, as a plain `t,u,y` CSV (see `convert_dataset`).
"""

import importlib.metadata
import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ._csv import SYSTEM_RECORD, write_csv
from ._files import write_atomically
from ._loaders import (
    _UTFSM_NAME,
    load_boucwen_benchmark_train,
    load_nees,
    load_utfsm,
    utfsm_test_conditions,
)

_UTFSM_CITATION = (
    "M. Quiroz, thesis data, Universidad Técnica Federico Santa María (Chile); GitHub "
    "repository DanielMaurelE/vRTHS_AMBC_MRdamper (commit 08753ff, 2022; MIT licence), "
    "folder Cap7_ModeloMR/BoucWen Ajuste 2/Preprocesamiento-sinusoidales/Preprocesados/"
)
_NEES_CITATION = (
    'S. Dyke, "Prototype MR Damper Characterization Tests Using White Noise", '
    "DesignSafe/NEES project NEES-2012-1158, DOI 10.4231/D3V11VM6X (CSV copy from the "
    "GitHub repository Abhay3757/PSO-Optimized-Dual-Attention-LSTM-for-MR-Damper-Force-"
    "Prediction, commit 92619e4); cite the DOI"
)
_BOUCWEN_CITATION = (
    'J.-P. Noël and M. Schoukens (2016), "Hysteretic benchmark with a dynamic '
    'nonlinearity", Workshop on Nonlinear System Identification Benchmarks; data DOI '
    "10.4121/12967592 (nonlinearbenchmark.org); train.h5 made with the benchmark's "
    "generator, copy from the GitHub repository forgi86/dynonet"
)
_BOUCWEN_FILE = "boucwen_benchmark_train.csv"


class _File(NamedTuple):
    """One file to write: its name in out_dir and a function writing it to a path."""

    name: str
    write: Callable[[Path], None]


def _version() -> str:
    try:
        return importlib.metadata.version("jaxmr")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover
        return "(version unknown)"


def _provenance(dataset: str, source: Path, citation: str, *notes: str) -> str:
    return "\n".join(
        [
            f"dataset: {dataset}, converted by jaxmr {_version()} "
            f"(jaxmr.data.convert_dataset)",
            f"source: {source}",
            f"citation: {citation}",
            *notes,
        ]
    )


# ---------------------------------------------------------------------------------------
# One function per dataset: the names of the files (cheap, from the source alone, so an
# existing file is reported before the data are read) and the files themselves.


def _utfsm_names(source: Path) -> list[str]:
    if not source.is_dir():
        raise ValueError(
            f"convert_dataset('utfsm'): {str(source)!r} is not a folder; pass the folder "
            "that holds the 30 UTFSM sine files <amplitude>mm<frequency>Hz<current>A.txt "
            f"(e.g. 10mm1Hz0x5A.txt). Download: {_UTFSM_CITATION}."
        )
    stems = [p.stem for p in source.glob("*.txt") if _UTFSM_NAME.match(p.stem)]
    stems.sort(key=utfsm_test_conditions)  # the loader's order
    if not stems:
        raise ValueError(
            f"convert_dataset('utfsm'): no file named <amplitude>mm<frequency>Hz"
            f"<current>A.txt in {str(source)!r}; pass the folder of the UTFSM sine "
            f"files. Download: {_UTFSM_CITATION}."
        )
    return [f"{stem}.csv" for stem in stems]


def _utfsm_files(source: Path) -> list[_File]:
    files = []
    # `load_utfsm` sets each test's smoothing and discard, which `write_csv` writes.
    for e in load_utfsm(source):
        comment = _provenance(
            "utfsm",
            source / f"{e.name}.txt",
            _UTFSM_CITATION,
            "processing: the authors smoothed displacement and force with a moving "
            "average of a tenth of the nominal period (`smoothing`) and removed the "
            "means; `discard` is one nominal period (the hysteretic state is unknown "
            "there and the moving average starts); x and v converted from mm and "
            "mm/s, v recomputed from x (the file's column lags by half a sample)",
        )

        def write(path, e=e, comment=comment):
            write_csv(e, path, comment=comment)

        files.append(_File(f"{e.name}.csv", write))
    return files


def _file_source(dataset: str, source: Path, expected: str, citation: str) -> None:
    """Refuse a folder where the dataset is one file (`expected`), naming it."""
    if source.is_dir():
        inside = source / expected
        hint = f" (did you mean {str(inside)!r}?)" if inside.is_file() else ""
        raise ValueError(
            f"convert_dataset({dataset!r}): {str(source)!r} is a folder; pass the file "
            f"{expected} itself{hint}. Download: {citation}."
        )


def _nees_check(source: Path) -> None:
    _file_source("nees", source, "ranran_50.csv", _NEES_CITATION)


def _nees_names(source: Path) -> list[str]:
    _nees_check(source)
    return [f"{source.stem}.csv"]


def _nees_files(source: Path) -> list[_File]:
    e = load_nees(source, trim=True)
    comment = _provenance(
        "nees",
        source,
        _NEES_CITATION,
        f"processing: trimmed to the moving part (load_nees(trim=True)): the first "
        f"{len(e)} samples ({e.duration:.4g} s) of the record; "
        "time rebuilt as k / fs from the sampling rate; x and v converted from cm and "
        "cm/s; the input column u is the command voltage [V]; `discard`: the record "
        "starts during the motion (hysteretic state unknown)",
    )

    def write(path):  # with `load_nees`'s discard (`NEES_DISCARD`)
        write_csv(e, path, comment=comment)

    return [_File(f"{e.name}.csv", write)]


def _boucwen_check(source: Path) -> None:
    _file_source("boucwen", source, "train.h5", _BOUCWEN_CITATION)


def _boucwen_names(source: Path) -> list[str]:
    _boucwen_check(source)
    return [_BOUCWEN_FILE]


def _boucwen_files(source: Path) -> list[_File]:
    record = load_boucwen_benchmark_train(source)
    notes = [
        "not a damper experiment: the benchmark is a single-degree-of-freedom "
        "oscillator with a Bouc–Wen hysteretic restoring force, driven by the force u "
        "and observed through its displacement y (force in, displacement out; a damper "
        "test is motion in, force out), so this file has not the damper columns and "
        "read_csv refuses it",
        "units: t [s], u [N] (input force; not the voltage [V] that a column u means "
        "in a damper CSV), y [m] (output displacement, measurement noise about 8e-6 m "
        "RMS)",
        f"sample rate: {record.fs!r} Hz; the multisine record (five periods of 8192 "
        "samples, 5-150 Hz, 50 N RMS) starts from rest",
    ]
    comment = _provenance("boucwen", source, _BOUCWEN_CITATION, *notes)
    lines = [SYSTEM_RECORD + " (plain CSV: comment lines start with '#')"]
    lines += [f"# {line}" for line in comment.splitlines()]
    # The line below counts itself and the column header: everything loadtxt skips.
    skip = len(lines) + 2
    lines.append(
        f'# read with numpy.loadtxt(path, delimiter=",", skiprows={skip}) (columns t, '
        'u, y) or pandas.read_csv(path, comment="#")'
    )
    lines.append("t,u,y")
    data = np.stack([record.t, record.u, record.y], axis=1)
    body = "\n".join(",".join(map(repr, row)) for row in data.tolist())
    text = "\n".join(lines) + "\n" + body + "\n"

    def write(path):
        Path(path).write_text(text, encoding="utf-8")

    return [_File(_BOUCWEN_FILE, write)]


class _Dataset(NamedTuple):
    source: str  # what to pass, for the messages
    names: Callable[[Path], list[str]]
    files: Callable[[Path], list[_File]]


_DATASETS = {
    "utfsm": _Dataset(
        "the folder of the 30 UTFSM sine files <amplitude>mm<frequency>Hz<current>A.txt",
        _utfsm_names,
        _utfsm_files,
    ),
    "nees": _Dataset("the file ranran_50.csv", _nees_names, _nees_files),
    "boucwen": _Dataset(
        "the file train.h5 of the Bouc–Wen benchmark", _boucwen_names, _boucwen_files
    ),
}
DATASETS = tuple(_DATASETS)


def convert_dataset(
    dataset: str,
    source: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    force: bool = False,
) -> list[Path]:
    """Convert a public dataset that the loaders read into jaxmr's CSV files.

    One file per experiment, written into `out_dir` (created if missing), each with
    comment lines giving the dataset, the source path and the citation:

    - `"utfsm"`: `source` is the folder of the 30 UTFSM sine files (`load_utfsm`); gives
      `<stem>.csv` per file, in the canonical format, with `# smoothing:` (a tenth of
      the nominal period, `utfsm_smoothing`) and `# discard:` (one period,
      `utfsm_first_cycle`).
    - `"nees"`: `source` is `ranran_50.csv` (`load_nees(path, trim=True)`: the moving
      part, voltage-driven); gives `ranran_50.csv` in the canonical format with
      `# discard: 0.2 s` (the record starts during the motion) and no smoothing.
    - `"boucwen"`: `source` is the benchmark's `train.h5`
      (`load_boucwen_benchmark_train`). The benchmark is an oscillator driven by a
      force `u` [N] whose displacement `y` [m] is measured, not a damper test (motion
      in, force out), so it is written as a plain CSV `boucwen_benchmark_train.csv`
      with the columns `t,u,y` and a first line `# jaxmr system record` saying so;
      `read_csv` refuses it, and its comments say how to read it with numpy.

    Numbers are written in Python's shortest exact form: reading a file back gives the
    loader's values exactly.

    **Arguments:**

    - `dataset`: one of `DATASETS` (`"utfsm"`, `"nees"`, `"boucwen"`).
    - `source`: the downloaded data, as above.
    - `out_dir`: the folder to write into.
    - `force`: overwrite existing files. Without it an existing file is an error, and
      all the target paths are checked before anything is written.

    **Returns:** the paths written, in the loader's order.

    **Raises:** `ValueError` for an unknown `dataset`, a missing or wrong `source`, a
    target that is the source itself, or an `out_dir` that is a file;
    `FileExistsError` naming the existing files unless `force`. Each file is written
    by `write_atomically` (a temporary file in `out_dir`, then renamed), so a file is
    either complete or not there (an error part-way leaves the files written before
    it).
    """
    if dataset not in _DATASETS:
        raise ValueError(
            f"convert_dataset: unknown dataset {dataset!r}; choose one of "
            f"{', '.join(repr(d) for d in DATASETS)}."
        )
    spec = _DATASETS[dataset]
    source = Path(source).resolve()
    if not source.exists():
        raise ValueError(
            f"convert_dataset({dataset!r}): the source {str(source)!r} does not exist; "
            f"pass {spec.source} (the dataset's loader in jaxmr.data says where to "
            "download it)."
        )
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(
            f"convert_dataset({dataset!r}): the output folder {str(out_dir)!r} is a "
            "file; pass a folder (it is created if missing)."
        )
    targets = [out_dir / name for name in spec.names(source)]
    for target in targets:
        if target.exists() and target.resolve() == source.resolve():
            raise ValueError(
                f"convert_dataset({dataset!r}): the output {str(target)!r} would "
                "replace the source file; choose another output folder."
            )
    existing = [str(t) for t in targets if t.exists()]
    if existing and not force:
        listed = ", ".join(repr(p) for p in existing[:3])
        more = f" and {len(existing) - 3} more" if len(existing) > 3 else ""
        raise FileExistsError(
            f"convert_dataset({dataset!r}): {len(existing)} of the {len(targets)} "
            f"output file(s) already exist: {listed}{more}. Nothing was written; pass "
            "force=True (CLI: --force) to overwrite them, or choose another output "
            "folder."
        )
    files = spec.files(source)
    written = [out_dir / f.name for f in files]
    if sorted(written) != sorted(targets):  # the loader's files are the ones checked
        raise RuntimeError(  # pragma: no cover
            f"convert_dataset({dataset!r}): the loader gave the files "
            f"{[f.name for f in files]}, not the expected {[t.name for t in targets]}."
        )
    out_dir.mkdir(parents=True, exist_ok=True)
    for file, target in zip(files, written):
        write_atomically(target, file.write)
    return written
