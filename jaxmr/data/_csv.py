"""jaxmr's canonical CSV format for one experiment (read and written with numpy only).

```
# jaxmr experiment
# name: 10mm1Hz0x5A
# units: t [s], x [m], v [m/s], i [A], F [N]
# velocity: measured
# smoothing: 0.1 s
# discard: 1.0 s
t,x,v,i,F
0.0,-9.3e-06,-0.001,0.5,-40.49
...
```

Lines starting with `#` are comments (anywhere); blank lines are skipped. The first
other line is the header naming the columns, comma-separated; every following line is
one sample with one number per column. As spreadsheets write them, a cell may be in
double quotes (`"t","x"`), and a comma may end every line (an empty last column).
Columns (names are case-sensitive):

- `t` [s], required, strictly increasing;
- linear damper: `x` [m] (required), `v` [m/s] (optional: computed from `x` by central
  differences when absent), `F` [N] (optional: needed to fit, not to predict);
- rotary brake: `theta` [rad], `omega` [rad/s], `T` [N·m], in the same roles;
- the input, exactly one of `i` [A] (coil current) or `u` [V] (command voltage),
  constant or time-varying;
- optional, beside a predicted force (`jaxmr predict`, `write_csv`'s `measured` and
  `band`): the measured force `F_measured` [N], and the prediction band, `F_std` (the
  prediction's standard error), `F_lower` and `F_upper` (the band's edges) [N]
  (`T_measured`, `T_std`, `T_lower`, `T_upper` [N·m] for a brake); `read_csv` reads
  past them (an `Experiment` holds one force, here the predicted one).

Comments of the form `# name: ...` and `# velocity: ...` set the experiment's name
(default: the file stem) and the origin of the `v` column (default: measured).

Two optional comments record how the data were processed and how to score them, both in
seconds with the unit written out (`read_csv` reads them into the experiment's
`smoothing` and `discard`; `read_processing` reads them alone):

- `# smoothing: <width> s`: the force (and, for UTFSM, the displacement) went through a
  centred moving average of this width, so a model's force should be smoothed the same
  way before it is compared (the `smoothing` of `jaxmr.fit` and `jaxmr.record_nrmse`);
- `# discard: <duration> s`: leave the first `<duration>` seconds of the record out of
  the score (the hysteretic state is unknown there; the `discard` of the same
  functions).

Absent lines mean none (no smoothing, nothing discarded). Other comments (provenance,
units) are free text.
"""

import difflib
import gzip
import math
import os
import re
from pathlib import Path

import numpy as np

from ._experiment import (
    VELOCITY_MEASURED,
    Experiment,
    check_columns,
    named_by_file,
)

_LINEAR = {"position": "x", "velocity": "v", "force": "F"}
_ROTARY = {"position": "theta", "velocity": "omega", "force": "T"}
_INPUTS = {"i": "current", "u": "voltage"}
_UNITS = {
    "t": "s",
    "x": "m",
    "v": "m/s",
    "F": "N",
    "theta": "rad",
    "omega": "rad/s",
    "T": "N·m",
    "i": "A",
    "u": "V",
}
# The prediction band's columns (`write_csv`'s `band`): `F_std`, `F_lower`, `F_upper`
# (`T_*` for a brake), each in the force's unit.
_BAND = ("std", "lower", "upper")
# The measured force beside a predicted one (`write_csv`'s `measured`): `F_measured`
# (`T_measured`), so that the two are compared in one file.
_MEASURED = "measured"
_UNITS |= {
    f"{load}_{part}": _UNITS[load]
    for load in ("F", "T")
    for part in (_MEASURED, *_BAND)
}
_KNOWN = tuple(_UNITS)
# Names people write for the canonical columns, for the "did you mean" hint.
_ALIASES = {
    "time": "t",
    "displacement": "x",
    "disp": "x",
    "position": "x",
    "pos": "x",
    "d": "x",
    "velocity": "v",
    "vel": "v",
    "speed": "v",
    "force": "F",
    "angle": "theta",
    "phi": "theta",
    "w": "omega",
    "angular_velocity": "omega",
    "torque": "T",
    "current": "i",
    "voltage": "u",
}
# The processing comments: key -> what the number is (for the messages).
_PROCESSING = {"smoothing": "width", "discard": "duration"}
_SECONDS = re.compile(r"^(?P<number>\S+?)\s*s$")
# The first comment line of the `t,u,y` system records that `convert_dataset` writes
# for the Bouc–Wen benchmark (force in, displacement out): not a damper experiment.
SYSTEM_RECORD = "# jaxmr system record"


def _expected() -> str:
    return (
        "t [s]; x [m], v [m/s] (optional), F [N] (optional) for a damper, or theta "
        "[rad], omega [rad/s] (optional), T [N·m] (optional) for a brake; and exactly "
        "one of i [A] or u [V]"
    )


def _suggest(name: str) -> str | None:
    key = name.split("[")[0].strip().strip("\"'")
    if key in _KNOWN:
        return key
    if key.lower() in _ALIASES:
        return _ALIASES[key.lower()]
    lowered = {k.lower(): k for k in _KNOWN}
    if key.lower() in lowered:
        return lowered[key.lower()]
    close = difflib.get_close_matches(key.lower(), list(lowered), n=1, cutoff=0.5)
    return lowered[close[0]] if close else None


def _check_header(names: list[str], where: str) -> None:
    found = ", ".join(repr(n) for n in names)
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(
            f"{where}: repeated column names {duplicates} in the header ({found}); name "
            "each column once."
        )
    if "" in names:
        raise ValueError(
            f"{where}: the header ({found}) has an empty column name at position "
            f"{names.index('') + 1}: two commas in a row, or one at the start of the "
            "line; name every column."
        )
    unknown = [n for n in names if n not in _KNOWN]
    if unknown:
        hints = []
        for n in unknown:
            guess = _suggest(n)
            hints.append(
                f"{n!r} (did you mean {guess!r}?)" if guess else f"{n!r} (no match)"
            )
        raise ValueError(
            f"{where}: unknown column names {', '.join(hints)}. Found {found}; expected "
            f"{_expected()}. Names are case-sensitive and carry no units (SI assumed)."
        )
    # A column beside the force (`F_std`, `F_measured`) belongs to its device.
    linear = [n for n in names if n.partition("_")[0] in _LINEAR.values()]
    rotary = [n for n in names if n.partition("_")[0] in _ROTARY.values()]
    if linear and rotary:
        raise ValueError(
            f"{where}: linear columns {linear} and rotary columns {rotary} are mixed; "
            "use x, v, F for a damper or theta, omega, T for a brake."
        )
    roles = _ROTARY if rotary else _LINEAR
    missing = [n for n in ("t", roles["position"]) if n not in names]
    if missing:
        raise ValueError(
            f"{where}: missing column(s) {missing}; found {found}; expected {_expected()}."
        )
    inputs = [n for n in names if n in _INPUTS]
    if len(inputs) == 2:
        raise ValueError(
            f"{where}: both `i` (current [A]) and `u` (voltage [V]) are given; keep "
            "exactly one input column."
        )
    if not inputs:
        raise ValueError(
            f"{where}: missing the input column: `i` (coil current [A]) or `u` (command "
            f"voltage [V]); found {found}. For a test without current write a column of "
            "zeros."
        )


_GZIP_MAGIC = b"\x1f\x8b"


def experiment_name(path: str | os.PathLike) -> str:
    """The name an experiment read from `path` gets without a `# name:` line: the
    file's name without its extension, and without `.gz` first for a compressed file
    (`run.csv.gz` → `run`)."""
    path = Path(path)
    if path.suffix.lower() == ".gz":
        path = path.with_suffix("")
    return path.stem


def _unquoted(cell: str) -> str:
    """A cell without the double quotes that CSV writers may put around it."""
    if len(cell) >= 2 and cell[0] == cell[-1] == '"':
        return cell[1:-1].strip()
    return cell


def _lines(path: Path):
    """The file's lines as text: UTF-8, a byte-order mark dropped (spreadsheets write
    one), gzip-compressed files (`.csv.gz`) read through; errors name the file."""
    with open(path, "rb") as raw:
        compressed = raw.read(2) == _GZIP_MAGIC
    opener = gzip.open if compressed else open
    try:
        with opener(path, "rt", encoding="utf-8-sig") as file:
            yield from enumerate(file, start=1)
    except UnicodeDecodeError as e:
        raise ValueError(
            f"{path}: not UTF-8 text ({e.reason} at byte {e.start}); save the file as "
            "UTF-8 CSV (comma-separated, '.' as the decimal point)."
        ) from None
    except (OSError, EOFError) as e:  # a damaged gzip stream
        if not compressed:
            raise
        raise ValueError(f"{path}: cannot decompress this gzip file: {e}") from None


def _separator_hint(text: str, where: str) -> None:
    """A header with one cell that other separators would split: say which."""
    if "," in text:
        return
    for separator, name in (
        (";", "semicolons"),
        ("\t", "tabs"),
        ("|", "bars"),
        (" ", "spaces"),
    ):
        if separator in text.strip():
            sep = r"\s+" if separator == " " else separator
            raise ValueError(
                f"{where}: the header {text!r} is separated by {name}; jaxmr CSV is "
                "comma-separated with '.' as the decimal point (e.g. "
                f"pandas.read_csv(path, sep={sep!r}, decimal=',').to_csv(new, "
                "index=False) converts it)."
            )


def read_csv(path: str | os.PathLike) -> Experiment:
    """Read one experiment from jaxmr's canonical CSV format (see the module docstring).

    **Arguments:**

    - `path`: the file.

    **Returns:** an `Experiment`; the velocity is computed from the position by central
    differences (`Experiment.from_arrays`) when the file has no velocity column.

    **Raises:** `ValueError` naming the problem: unknown or missing columns (with the
    expected names and the nearest one), both `i` and `u`, linear and rotary columns
    mixed, a row with the wrong number of cells, an unparsable or non-finite cell
    (with its line number), time not strictly increasing, fewer than 3 rows, a
    `# jaxmr system record` file (`convert_dataset('boucwen')`: not a damper test).
    """
    path = Path(path)
    where = str(path)
    metadata: dict[str, str] = {}
    header: list[str] | None = None
    header_line = 0
    trailing = False
    rows: list[list[float]] = []
    lines: list[int] = []
    processing: dict[str, float | None] = dict.fromkeys(_PROCESSING)
    at: dict[str, int] = {}
    for number, text in _lines(path):
        text = text.strip()
        if not text:
            continue
        if text.startswith("#"):
            if header is None and text.startswith(SYSTEM_RECORD):
                raise ValueError(
                    f"{where}: a system record (columns t, u, y: input force [N], "
                    "output displacement [m]), as `convert_dataset('boucwen')` "
                    "writes, not a damper experiment; read its columns with "
                    "numpy.loadtxt as its header comments say."
                )
            key, sep, value = text[1:].partition(":")
            if sep and key.strip().lower() in ("name", "velocity"):
                metadata.setdefault(key.strip().lower(), value.strip())
            _processing_line(processing, at, path, number, text)
            continue
        cells = [_unquoted(c.strip()) for c in text.split(",")]
        if header is None:
            _separator_hint(text, where)
            header, header_line = cells, number
            # A spreadsheet's trailing comma: an empty last column, on every line.
            trailing = len(header) > 1 and header[-1] == ""
            if trailing:
                header = header[:-1]
            _check_header(header, where)
            continue
        if trailing and len(cells) == len(header) + 1 and cells[-1] == "":
            cells = cells[:-1]
        if len(cells) != len(header):
            raise ValueError(
                f"{where}: line {number} has {len(cells)} cells but the header "
                f"(line {header_line}) names {len(header)} columns "
                f"({', '.join(header)}); every row needs one value per column."
            )
        row = []
        for name, cell in zip(header, cells):
            try:
                row.append(float(cell))
            except ValueError:
                raise ValueError(
                    f"{where}: line {number}, column `{name}`: cannot read "
                    f"{cell!r} as a number."
                ) from None
        rows.append(row)
        lines.append(number)
    if header is None:
        raise ValueError(f"{where}: no header line (only comments or blank lines).")
    data = np.array(rows, dtype=np.float64).reshape(len(rows), len(header))
    columns = {name: data[:, k] for k, name in enumerate(header)}
    # Time first: check_columns reads its first column as the time.
    ordered = {"t": columns["t"]} | {k: c for k, c in columns.items() if k != "t"}
    check_columns(ordered, where, row=lambda k: f"line {lines[k]}")

    rotary = any(n in columns for n in _ROTARY.values())
    roles = _ROTARY if rotary else _LINEAR
    input_name = "i" if "i" in columns else "u"
    t, position = columns["t"], columns[roles["position"]]
    current, force = columns[input_name], columns.get(roles["force"])
    name = metadata.get("name") or experiment_name(path)
    drive = _INPUTS[input_name]
    seconds = {k: 0.0 if v is None else v for k, v in processing.items()}
    # Warnings of implausible units name the file (and point at the user's line that
    # read it).
    with named_by_file(path):
        if roles["velocity"] not in columns:
            return Experiment.from_arrays(
                t,
                position,
                current=current,
                force=force,
                name=name,
                rotary=rotary,
                drive=drive,
                **seconds,
            )
        return Experiment(
            t,
            position,
            columns[roles["velocity"]],
            current,
            force,
            name=name,
            rotary=rotary,
            drive=drive,
            velocity_source=metadata.get("velocity", VELOCITY_MEASURED),
            **seconds,
        )


def _seconds_text(key: str, value: float | None) -> str | None:
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number) or number < 0:
        raise ValueError(
            f"write_csv: `{key}` must be a finite {_PROCESSING[key]} >= 0 in seconds "
            f"(or None to leave the line out), got {value!r}."
        )
    return f"# {key}: {number!r} s"


def read_comments(path: str | os.PathLike) -> dict[str, str]:
    """The `# key: value` comment lines above a canonical CSV file's header, e.g.
    `{"name": "run", "F": "predicted by jaxmr 0.1.0 with ..."}` (`jaxmr predict`
    marks the force it wrote so); the first line of each key counts, keys as
    written.

    **Arguments:** `path`: the file (gzip-compressed too).

    **Returns:** a dict from key to value, both stripped.
    """
    comments: dict[str, str] = {}
    for _, text in _lines(Path(path)):
        text = text.strip()
        if not text:
            continue
        if not text.startswith("#"):
            break  # the header
        key, sep, value = text[1:].partition(":")
        if sep:
            comments.setdefault(key.strip(), value.strip())
    return comments


def read_processing(path: str | os.PathLike) -> dict[str, float | None]:
    """Read the processing comments of a canonical CSV file (see the module docstring).

    **Arguments:**

    - `path`: the file.

    **Returns:** `{"smoothing": width, "discard": duration}`, each a float in seconds
    read from the `# smoothing: <width> s` and `# discard: <duration> s` comment
    lines, or None where the file has no such line.

    **Raises:** `ValueError` naming the file, the line number and the expected form
    when a value is not a finite number >= 0 followed by the unit `s`, or when the same
    key is given twice with different values.
    """
    path = Path(path)
    found: dict[str, float | None] = dict.fromkeys(_PROCESSING)
    at: dict[str, int] = {}
    for number, text in _lines(path):
        _processing_line(found, at, path, number, text.strip())
    return found


def _processing_line(found: dict, at: dict, path, number: int, text: str) -> None:
    """Read a `# smoothing:` or `# discard:` comment line into `found` (`at`: the line
    each key was first read from); other lines are left alone."""
    if not text.startswith("#"):
        return
    key, sep, value = text[1:].partition(":")
    key = key.strip().lower()
    if not sep or key not in _PROCESSING:
        return
    value = value.strip()
    match = _SECONDS.match(value)
    seconds = math.nan
    if match is not None:
        try:
            seconds = float(match["number"])
        except ValueError:
            pass
    if not math.isfinite(seconds) or seconds < 0:
        what = _PROCESSING[key]
        raise ValueError(
            f"{path}: line {number}: cannot read {value!r} as the {key} "
            f"{what}; expected `# {key}: <{what}> s`, a finite number >= 0 in "
            f"seconds followed by the unit s (e.g. `# {key}: 0.1 s`)."
        )
    if key in at and found[key] != seconds:
        raise ValueError(
            f"{path}: line {number}: a second `# {key}:` line ({seconds!r} s) "
            f"contradicts line {at[key]} ({found[key]!r} s); keep one."
        )
    found[key] = seconds
    at.setdefault(key, number)


def write_csv(
    experiment: Experiment,
    path: str | os.PathLike,
    *,
    comment: str | None = None,
    smoothing: float | None = None,
    discard: float | None = None,
    measured=None,
    band=None,
) -> None:
    """Write an experiment in jaxmr's canonical CSV format (see the module docstring).

    Numbers are written in Python's shortest exact form, so `read_csv` gives back the
    same values. The header comments state the units, the name and the velocity's
    origin, then the processing (`smoothing`, `discard`) when given; `comment` (e.g.
    provenance: laboratory, date, source) is added as further comment lines.

    **Arguments:**

    - `experiment`: the `Experiment`.
    - `path`: the file to write (overwritten).
    - `comment`: optional free text, one comment line per text line.
    - `smoothing`: the width [s] of the centred moving average the force went through,
      written as `# smoothing: <width> s`; None (default): the experiment's own
      `smoothing`, written when it is not 0.
    - `discard`: the start [s] to leave out of the score, written as
      `# discard: <duration> s`; None (default): the experiment's own `discard`,
      written when it is not 0.
    - `measured`: the measured force [N] (torque [N·m] for a brake) of a record whose
      `force` is a prediction, one value per sample: written after the force as the
      column `F_measured` (`T_measured`); None (default): no such column.
    - `band`: a `jaxmr.PredictionBand` of the experiment, whose `force` is then the
      prediction: its `std`, `lower` and `upper` are written after the force as the
      columns `F_std`, `F_lower`, `F_upper` [N] (`T_*` [N·m] for a brake); None
      (default): no band.

    `read_csv` reads both back into the experiment (`read_processing` alone), and
    reads past the measured force's and the band's columns.
    """
    own = lambda value: value or None  # an experiment's 0 (none) writes no line
    if smoothing is None:
        smoothing = own(experiment.smoothing)
    if discard is None:
        discard = own(experiment.discard)
    processing = [_seconds_text("smoothing", smoothing)]
    processing.append(_seconds_text("discard", discard))
    roles = _ROTARY if experiment.rotary else _LINEAR
    input_name = "i" if experiment.drive == "current" else "u"
    names = ["t", roles["position"], roles["velocity"], input_name]
    arrays = [experiment.t, experiment.x, experiment.v, experiment.current]
    if experiment.force is not None:
        names.append(roles["force"])
        arrays.append(experiment.force)
    beside = {} if measured is None else {_MEASURED: ("`measured`", measured)}
    if band is not None:
        beside |= {
            part: (f"the band's `{part}`", getattr(band, part)) for part in _BAND
        }
    if beside and experiment.force is None:
        given = "`measured`" if measured is not None else "a `band`"
        raise ValueError(
            f"write_csv: {given} goes with a predicted force: give the experiment "
            "the prediction as its `force`."
        )
    for part, (what, values) in beside.items():
        column = np.asarray(values, dtype=np.float64)
        if column.shape != np.shape(experiment.t):
            raise ValueError(
                f"write_csv: {what} has shape {column.shape}, but the experiment has "
                f"{len(experiment)} samples: give the values of this experiment."
            )
        names.append(f"{roles['force']}_{part}")
        arrays.append(column)
    data = np.stack([np.asarray(a, dtype=np.float64) for a in arrays], axis=1)

    def one_line(text: str) -> str:
        return " ".join(text.splitlines())

    header = [
        "# jaxmr experiment (canonical CSV: comment lines start with '#')",
        f"# name: {one_line(experiment.name)}",
        "# units: " + ", ".join(f"{n} [{_UNITS[n]}]" for n in names),
        f"# velocity: {one_line(experiment.velocity_source)}",
    ]
    header += [line for line in processing if line is not None]
    if comment:
        header += [f"# {line}" for line in comment.splitlines()]
    header.append(",".join(names))
    body = "\n".join(",".join(map(repr, row)) for row in data.tolist())
    Path(path).write_text("\n".join(header) + "\n" + body + "\n", encoding="utf-8")
