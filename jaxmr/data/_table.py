"""A user's own measurement table (any delimiter, decimal point or comma, any units)
read into an `Experiment` in SI units: `read_table`."""

import csv
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._csv import _lines, _suggest, experiment_name
from ._experiment import Experiment, check_columns, named_by_file

# Per column, its units as written after the colon and the factor to the SI unit that
# an `Experiment` holds (exact definitions; 1 lbf = 4.4482216152605 N, 1 in = 25.4 mm).
_DEG = math.pi / 180.0
UNITS: dict[str, dict[str, float]] = {
    "t": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0},
    "x": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "in": 0.0254},
    "v": {"m/s": 1.0, "cm/s": 1e-2, "mm/s": 1e-3, "in/s": 0.0254},
    "F": {"N": 1.0, "kN": 1e3, "daN": 10.0, "lbf": 4.4482216152605},
    "i": {"A": 1.0, "mA": 1e-3},
    "u": {"V": 1.0, "mV": 1e-3},
    "theta": {"rad": 1.0, "mrad": 1e-3, "deg": _DEG},
    "omega": {"rad/s": 1.0, "deg/s": _DEG, "rpm": 2.0 * math.pi / 60.0},
    "T": {
        "N·m": 1.0,
        "Nm": 1.0,
        "N*m": 1.0,
        "N.m": 1.0,
        "N·mm": 1e-3,
        "Nmm": 1e-3,
        "kN·m": 1e3,
        "kNm": 1e3,
    },
}
_GREEK = {"θ": "theta", "ω": "omega"}
# The columns whose sign depends on how the rig reads them: a unit written with a minus
# sign (`F:-kN`) negates the column (a load cell read the other way round; see
# `Experiment`'s sign convention).
_SIGNED = ("x", "v", "F", "theta", "omega", "T")
_SKIP = "_"  # a column of the file to leave out
# The layouts tried, in this order: (delimiter name, split, decimal mark).
_DELIMITERS = {
    "tabs": lambda s: s.split("\t"),
    "semicolons": lambda s: s.split(";"),
    "commas": lambda s: s.split(","),
    "whitespace": str.split,
}
# A row of numbers holds digits, signs, exponents, decimal marks, delimiters and quotes
# only;
# the lines before the first such row are a header and skipped.
_NUMERIC_ROW = re.compile(r'^[\d\s.,;+\-eE"]+$')


def _parse_columns(columns: str | Sequence[str], where: str) -> list[tuple[str, float]]:
    """`"t,x:mm,v:mm/s,F:kN"` -> [(name, factor to SI)], one per column of the file."""
    specs = columns.split(",") if isinstance(columns, str) else list(columns)
    parsed = []
    for spec in specs:
        name, _, unit = (part.strip() for part in spec.strip().partition(":"))
        name = _GREEK.get(name, name)
        if name == _SKIP:
            parsed.append((name, 1.0))
            continue
        if name not in UNITS:
            guess = _suggest(name)
            hint = f" (did you mean {guess!r}?)" if guess in UNITS else ""
            raise ValueError(
                f"{where}: unknown column name {name!r}{hint} in the columns "
                f"{columns!r}; use {', '.join(UNITS)} (θ and ω are accepted), and _ "
                "for a column to leave out."
            )
        units = UNITS[name]
        sign = 1.0
        if unit.startswith("-"):
            if name not in _SIGNED:
                raise ValueError(
                    f"{where}: the column {name!r} cannot be negated ({spec.strip()!r});"
                    f" a minus sign before the unit is for {', '.join(_SIGNED)}."
                )
            sign, unit = -1.0, unit[1:].strip()
        if unit and unit not in units:
            raise ValueError(
                f"{where}: unknown unit {unit!r} for column {name!r}; use one of "
                f"{', '.join(units)} (e.g. {name}:{next(iter(units))})."
            )
        parsed.append((name, sign * (units[unit] if unit else 1.0)))
    names = [n for n, _ in parsed if n != _SKIP]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ValueError(f"{where}: the columns {repeated} are named twice.")
    rotary = [n for n in names if n in ("theta", "omega", "T")]
    linear = [n for n in names if n in ("x", "v", "F")]
    if rotary and linear:
        raise ValueError(
            f"{where}: linear columns {linear} and rotary columns {rotary} are mixed; "
            "use x, v, F for a damper or theta, omega, T for a brake."
        )
    position = "theta" if rotary else "x"
    missing = [n for n in ("t", position) if n not in names]
    if missing:
        raise ValueError(
            f"{where}: the columns {columns!r} lack {missing}: a table needs the time "
            f"`t` and the {'angle `theta`' if rotary else 'displacement `x`'}."
        )
    return parsed


def _to_si(values: np.ndarray, factor: float) -> np.ndarray:
    """`values * factor`, dividing by a whole number instead where the factor is its
    inverse (mm: / 1000), so that `62.845 mm` becomes the double nearest 0.062845 m,
    which `write_csv` writes as such (multiplying by the inexact 1e-3 may not)."""
    inverse = 1.0 / factor
    if abs(factor) < 1 and inverse == round(inverse):
        return values / inverse
    return values * factor


def _split(text: str, delimiter: str) -> list[str]:
    """The cells of one line at `delimiter`, each without the quotes a spreadsheet
    puts around it (`"1,5";"2"`; a quoted cell may hold the delimiter)."""
    if '"' in text and delimiter != "whitespace":
        char = {"tabs": "\t", "semicolons": ";", "commas": ","}[delimiter]
        parts = next(csv.reader([text], delimiter=char))
    else:
        parts = _DELIMITERS[delimiter](text)
    return [p.strip().strip('"').strip() for p in parts]


def _cells(text: str, delimiter: str, decimal: str, count: int) -> list[float] | None:
    """The `count` numbers of one line in one layout, or None if it is not that
    layout. An empty cell is a missing value (NaN, which the column checks then name
    with its line); one empty cell past `count` is the delimiter a spreadsheet
    leaves at the end of each row."""
    parts = _split(text, delimiter)
    if len(parts) == count + 1 and parts[-1] == "":
        parts = parts[:-1]
    if len(parts) != count or all(p == "" for p in parts):
        return None
    try:
        if decimal == ",":
            if any("." in p for p in parts):
                return None  # a decimal comma beside a point: not this layout
            parts = [p.replace(",", ".") for p in parts]
        return [float(p) if p else math.nan for p in parts]
    except ValueError:
        return None


def _layouts(first: str, count: int) -> list[tuple[str, str]]:
    """The (delimiter, decimal mark) layouts that read `first` as `count` numbers."""
    found = []
    for delimiter in _DELIMITERS:
        for decimal in (".", ","):
            if decimal == "," and delimiter == "commas" and '"' not in first:
                continue  # a decimal comma between commas only in quoted cells
            if _cells(first, delimiter, decimal, count) is not None:
                found.append((delimiter, decimal))
    return found


def _describe(text: str) -> str:
    """What a line looks like, for the messages: its cells under each delimiter."""
    counts = [f"{len(_split(text.strip(), d))} at {d}" for d in _DELIMITERS]
    return "cells when split " + ", ".join(counts)


def read_table(
    path: str | os.PathLike,
    columns: str | Sequence[str],
    *,
    current: float | int | None = None,
    voltage: float | int | None = None,
    name: str | None = None,
    smoothing: float | int = 0.0,
    discard: float | int = 0.0,
) -> Experiment:
    """Read a measurement table of any common layout into an `Experiment` in SI units.

    The table is one sample a line, one number a column, as a test rig's software
    writes it. The layout is detected and then required of every row: the delimiter
    (tabs, semicolons, commas or whitespace) and the decimal mark (`.` or `,`; a
    decimal comma needs another delimiter than the comma) that read each row as one
    number per named column (where several do, as `0;1` for both marks, they read it
    alike; a row that none of the layouts of the rows before it reads is an error).
    A spreadsheet's export reads too: cells in double quotes (a quoted cell may hold
    the delimiter, as a decimal comma between commas) and a delimiter closing every
    row. An empty cell is a missing value, refused with its column and line.
    Lines starting with `#` and blank lines are skipped, and so are the lines before
    the first row of numbers (a header: a line with a letter other than an
    exponent's `e`). The file may be gzip-compressed.

    **Arguments:**

    - `path`: the file.
    - `columns`: the file's columns in order, e.g. `"t,x:mm,v:mm/s,F:kN"` (or a list
      of such items): a name, then optionally `:` and the unit the file uses (default:
      the SI unit). Names: `t` [s: s, ms, us, min]; for a damper `x` [m: m, cm, mm, um,
      in], `v` [m/s: m/s, cm/s, mm/s, in/s] (optional: computed from `x` when absent,
      `Experiment.from_arrays`), `F` [N: N, kN, daN, lbf] (optional: needed to fit);
      for a brake `theta` or `θ` [rad: rad, mrad, deg], `omega` or `ω` [rad/s: rad/s,
      deg/s, rpm], `T` [N·m: N·m, Nm, N·mm, kN·m]; the input `i` [A: A, mA] or `u`
      [V: V, mV]; `_` for a column to leave out. A minus sign before the unit
      negates a motion or force column (`F:-kN`, `F:-` in SI): for a load cell
      that reads the force against `Experiment`'s sign convention.
    - `current`: the constant coil current [A] when the table has no input column.
    - `voltage`: the constant command voltage [V] instead (a voltage-driven damper).
    - `name`: the experiment's name (default: the file stem).
    - `smoothing`, `discard`: the experiment's (see `Experiment`), in seconds.

    **Returns:** an `Experiment` in SI units (`write_csv` then writes the canonical CSV).

    **Raises:** `ValueError` naming the file and what was found: an unknown column
    name or unit; no input or two (an `i`/`u` column, `current`, `voltage`: exactly
    one); no row of numbers; a first row that no layout reads as one number per column
    (with its cell counts at each delimiter); a later row in another layout (with its
    line number); and the checks of `Experiment` (finite
    values, increasing time). Implausible values after the conversion (a displacement
    in millimetres declared as metres) give the `Experiment`'s `DataWarning`s.
    """
    path = Path(path)
    where = str(path)
    spec = _parse_columns(columns, where)
    names = [n for n, _ in spec]
    inputs = [n for n in names if n in ("i", "u")]
    given = [
        k
        for k, value in (("current", current), ("voltage", voltage))
        if value is not None
    ]
    if len(inputs) + len(given) != 1:
        found = [f"column `{n}`" for n in inputs] + [
            f"`{k}` = {current if k == 'current' else voltage!r}" for k in given
        ]
        raise ValueError(
            f"{where}: give exactly one input: a column `i` [A] or `u` [V], or a "
            f"constant `current` [A] or `voltage` [V]; got "
            f"{', '.join(found) if found else 'none'}."
        )
    # The layouts that read every row so far (the first row's, narrowed by the
    # others: `0;1` leaves the decimal mark open, a later `0,5;2` settles it). Where
    # several remain they read the rows alike (a point and a comma never both parse).
    layouts: list[tuple[str, str]] | None = None
    rows: list[list[float]] = []
    lines: list[int] = []
    header = 0
    for number, text in _lines(path):
        text = text.strip()
        if not text or text.startswith("#"):
            continue
        if layouts is None:
            if not _NUMERIC_ROW.match(text):
                header += 1  # a header line before the numbers
                continue
            layouts = _layouts(text, len(spec))
            if not layouts:
                raise ValueError(
                    f"{where}: line {number} {text!r} is not {len(spec)} numbers (the "
                    f"columns {columns!r} name {len(spec)}) in any layout jaxmr reads: "
                    f"{_describe(text)}; the decimal mark is '.' or ',' (a decimal "
                    "comma with another delimiter than the comma). Check the columns "
                    "(`_` for a column to leave out) or the file."
                )
        read = {}
        for layout in layouts:
            cells = _cells(text, *layout, len(spec))
            if cells is not None:
                read[layout] = cells
        if not read:
            described = " or ".join(
                f"{delimiter} between columns and {decimal!r} as the decimal mark"
                for delimiter, decimal in layouts
            )
            raise ValueError(
                f"{where}: line {number} {text!r} is not {len(spec)} numbers in the "
                f"layout of the rows before it (line {lines[0]} on: {described}): "
                f"{_describe(text)}."
            )
        layouts = list(read)
        cells = read[layouts[0]]
        rows.append(cells)
        lines.append(number)
    if not rows:
        raise ValueError(
            f"{where}: no row of numbers ({header} header line(s), comments and "
            "blank lines only)."
        )
    data = np.array(rows, dtype=np.float64)
    table = {n: _to_si(data[:, k], f) for k, (n, f) in enumerate(spec) if n != _SKIP}
    ordered = {"t": table["t"]} | {k: c for k, c in table.items() if k != "t"}
    check_columns(ordered, where, row=lambda k: f"line {lines[k]}")
    rotary = "theta" in table
    position, velocity, load = ("theta", "omega", "T") if rotary else ("x", "v", "F")
    if inputs:
        drive = "current" if inputs[0] == "i" else "voltage"
        level = table[inputs[0]]
    else:
        drive = given[0]
        value = current if drive == "current" else voltage
        try:
            level = float(value)  # pyright: ignore[reportArgumentType]
        except (TypeError, ValueError):
            raise TypeError(
                f"{where}: `{drive}` must be one number (the table's constant input), "
                f"got {value!r}; for several tables call read_table once per table."
            ) from None
        if not math.isfinite(level):
            raise ValueError(
                f"{where}: the constant `{drive}` must be a finite number, got {level!r}."
            )
    with named_by_file(path):  # the warnings name the file
        return Experiment.from_arrays(
            table["t"],
            table[position],
            v=table.get(velocity),
            current=level,
            force=table.get(load),
            name=experiment_name(path) if name is None else name,
            rotary=rotary,
            drive=drive,
            smoothing=smoothing,
            discard=discard,
        )
