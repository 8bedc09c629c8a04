"""A user's own tables (`jaxmr.data.read_table`, `jaxmr convert table`), one answer from
the Python API and the command line on the same files, implausible units refused by
`jaxmr fit`, a force read the other way round refused and negated by its column's
unit, and a step in the displacement named when a record is read.

The fits are tiny (Bingham, two files of 1.5 cycles at 100 Hz, 4 steps) and share one
data shape, so they compile once.
"""

import contextlib
import io
import json
import warnings

import numpy as np
import pytest

import jaxmr
import jaxmr.data
from jaxmr._cli import main
from jaxmr._cli.files import with_processing
from jaxmr.templates import MODEL_TEMPLATES

CURRENTS = (0.0, 1.0)  # A
AMPLITUDE, FREQUENCY, RATE, CYCLES = 0.01, 1.0, 100.0, 1.5  # m, Hz, Hz, -
SMOOTHING, DISCARD = 0.05, 0.25  # s, as the files' comment lines say
MAX_STEPS = 4


def _experiment(current: float, rng) -> jaxmr.data.Experiment:
    """A Bingham-like damper (viscous plus a smoothed friction growing with current)
    under x = X sin(2πft), 1 % noise on the force."""
    t = np.arange(round(CYCLES * RATE / FREQUENCY) + 1) / RATE
    w = 2 * np.pi * FREQUENCY
    x, v = AMPLITUDE * np.sin(w * t), AMPLITUDE * w * np.cos(w * t)
    f = (900 + 1200 * current) * v + (120 + 600 * current) * np.tanh(v / 0.005)
    f = f + 0.01 * np.std(f) * rng.standard_normal(f.shape)
    return jaxmr.data.Experiment(t, x, v, current, f, name=f"rig_{current:g}A")


def _run(argv) -> tuple[int, str]:
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        status = main([str(a) for a in argv])
    return status, stdout.getvalue()


def _raw_text(e: jaxmr.data.Experiment) -> str:
    """The experiment as a rig's export: two header lines, whitespace between the
    columns, a decimal comma, displacement in mm, velocity in mm/s, force in kN."""
    lines = ["Zeit Weg Geschwindigkeit Kraft", "s mm mm/s kN"]
    for row in zip(e.t, 1e3 * e.x, 1e3 * e.v, 1e-3 * e.force):  # pyright: ignore[reportArgumentType]
        lines.append("   ".join(f"{c:.12g}".replace(".", ",") for c in row))
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The SI CSV files (with `# smoothing:` and `# discard:` lines) and the raw tables
    of the same data."""
    directory = tmp_path_factory.mktemp("table")
    rng = np.random.default_rng(3)
    si, raw = [], []
    for current in CURRENTS:
        e = _experiment(current, rng)
        path = directory / f"{e.name}.csv"
        jaxmr.data.write_csv(e, path, smoothing=SMOOTHING, discard=DISCARD)
        si.append(path)
        table = directory / f"{e.name}.txt"
        table.write_text(_raw_text(e), encoding="utf-8")
        raw.append(table)
    return si, raw


@pytest.fixture(scope="module")
def cli_fit(files, tmp_path_factory):
    """`jaxmr fit --model bingham` on the SI files, defaults otherwise."""
    out = tmp_path_factory.mktemp("fit") / "si.json"
    status, _ = _run(
        ["fit", "--model", "bingham", "--max-steps", MAX_STEPS, "--out", out, *files[0]]
    )
    assert status == 0
    return json.loads(out.read_text())["report"]


def _parameters(report) -> dict:
    return {p["name"]: p["value"] for p in report["parameters"]}


def test_python_and_command_line_give_one_answer(files, cli_fit):
    """`jaxmr.fit` (defaults: each experiment's smoothing and discard, read from the
    files' comment lines) and `jaxmr fit` (defaults: `--smoothing file --discard
    file`) on the same files give the same parameters and NRMSEs. Tolerance 1e-9
    relative: the same float64 computation in one process (the command's progress
    and stop hooks change no arithmetic), written to JSON exactly."""
    experiments = [jaxmr.data.read_csv(p) for p in files[0]]
    assert [(e.smoothing, e.discard) for e in experiments] == [(SMOOTHING, DISCARD)] * 2
    assert cli_fit["smoothing_s"] == [SMOOTHING] * 2
    assert cli_fit["discard_s"] == [DISCARD] * 2
    model = MODEL_TEMPLATES["bingham"](experiments)
    result = jaxmr.fit(model, experiments, max_steps=MAX_STEPS, progress=False)
    cli = _parameters(cli_fit)
    assert set(cli) == set(result.names)
    for name, value in zip(result.names, result.values):
        np.testing.assert_allclose(cli[name], value, rtol=1e-9, err_msg=name)
    np.testing.assert_allclose(
        [row["nrmse"] for row in cli_fit["per_file"]], result.nrmse, rtol=1e-9
    )
    # The processing matters here: without it the same fit lands elsewhere, so the
    # comparison above would catch a door that ignored the files' lines.
    plain = jaxmr.fit(
        model,
        experiments,
        max_steps=MAX_STEPS,
        progress=False,
        smoothing=0.0,
        discard=0.0,
    )
    assert not np.allclose(plain.nrmse, result.nrmse, rtol=1e-3)


def test_convert_table_fits_like_the_si_csv(files, cli_fit, tmp_path, capsys):
    """Whitespace tables in mm, mm/s and kN with a decimal comma and two header
    lines, through `jaxmr convert table`, fit as the SI CSV files of the same data.
    Tolerance 1e-7 relative: the tables hold 12 significant digits, so the data agree
    to about 5e-13, and 4 Levenberg–Marquardt steps amplify that by far less than
    1e5."""
    si, raw = files
    out = tmp_path / "converted"
    status, stdout = _run(
        [
            "convert",
            "table",
            *raw,
            "--columns",
            "t,x:mm,v:mm/s,F:kN",
            "--current",
            ",".join(f"{c:g}" for c in CURRENTS),
            "--smoothing",
            SMOOTHING,
            "--discard",
            DISCARD,
            "--out",
            out,
        ]
    )
    assert status == 0, capsys.readouterr().err
    converted = [out / f"{p.stem}.csv" for p in raw]
    assert stdout.count("wrote ") == 2 and all(p.is_file() for p in converted)
    for a, b in zip(converted, si):
        ea, eb = jaxmr.data.read_csv(a), jaxmr.data.read_csv(b)
        for column in ("t", "x", "v", "current", "force"):
            np.testing.assert_allclose(
                getattr(ea, column), getattr(eb, column), rtol=1e-11, atol=1e-14
            )
        assert (ea.smoothing, ea.discard) == (SMOOTHING, DISCARD)
    params = tmp_path / "converted.json"
    status, _ = _run(
        ["fit", "--model", "bingham", "--max-steps", MAX_STEPS, "--out", params]
        + converted
    )
    assert status == 0
    report = json.loads(params.read_text())["report"]
    expected = _parameters(cli_fit)
    for name, value in _parameters(report).items():
        np.testing.assert_allclose(value, expected[name], rtol=1e-7, err_msg=name)
    np.testing.assert_allclose(
        [r["nrmse"] for r in report["per_file"]],
        [r["nrmse"] for r in cli_fit["per_file"]],
        rtol=1e-7,
    )
    # Never over an existing file without --force; nothing is written then.
    before = converted[0].read_bytes()
    status, _ = _run(
        ["convert", "table", raw[0], "--columns", "t,x:mm,v:mm/s,F:kN"]
        + ["--current", "0", "--out", out]
    )
    assert status == 1 and "already exists" in capsys.readouterr().err
    assert converted[0].read_bytes() == before


def test_fit_refuses_an_implausible_unit(files, tmp_path, capsys):
    """A file in mm written as metres stops `jaxmr fit` before any fit, naming the
    column and the unit its values look like, and how to go on."""
    e = jaxmr.data.read_csv(files[0][0])
    with pytest.warns(jaxmr.data.DataWarning) as caught:
        mm = jaxmr.data.Experiment(e.t, 1e3 * e.x, 1e3 * e.v, e.current, e.force)
    assert [
        (w.message.kind, w.message.column, w.message.suggested) for w in caught
    ] == [  # pyright: ignore[reportAttributeAccessIssue]
        ("unit", "x", "mm")
    ]
    path = tmp_path / "in_mm.csv"
    jaxmr.data.write_csv(mm, path)
    out = tmp_path / "p.json"
    status, stdout = _run(["fit", "--model", "bingham", "--out", out, path])
    err = capsys.readouterr().err
    assert status == 1 and not out.exists() and "fitting" not in stdout
    assert "implausible unit" in err and "column `x`, which look like mm" in err
    assert "--accept-units" in err and "x:mm" in err
    # An option that rebuilds the read experiments (--smoothing) checks them again:
    # that must not warn a second time, naming the experiment instead of the file
    # (the "millimetres?" warning used to be printed twice).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (again,) = with_processing([mm], "0.1", "smoothing", "--smoothing")
    assert again.smoothing == 0.1


def test_convert_table_without_an_input_names_its_options(tmp_path, capsys):
    path = tmp_path / "run.txt"
    path.write_text("0 1\n0.01 2\n0.02 3\n")
    status, _ = _run(
        ["convert", "table", path, "--columns", "t,x", "--out", tmp_path / "out"]
    )
    err = capsys.readouterr().err
    assert status == 1 and "--current LEVELS [A] or --voltage LEVELS [V]" in err
    assert not (tmp_path / "out").exists()


def test_convert_table_names_its_unit_mistakes(tmp_path, capsys):
    """`jaxmr convert table` refuses a declared unit that gives implausible values,
    naming the column and the unit to declare."""
    t = np.arange(201) / 200
    text = "\n".join(f"{a} {1e3 * 0.01 * np.sin(6.28 * a)} 5" for a in t)
    path = tmp_path / "mm.txt"
    path.write_text(text + "\n")
    other = tmp_path / "mm2.txt"
    other.write_text(text + "\n")
    status, _ = _run(
        ["convert", "table", path, other, "--columns", "t,x,F", "--current", "1,0"]
        + ["--out", tmp_path / "out"]
    )
    err = capsys.readouterr().err
    assert status == 1 and "[column `x`, which look like mm]" in err
    # Every table in other units is named, not only the first.
    assert "mm.txt" in err and "mm2.txt" in err
    assert "declare the unit in --columns" in err and not (tmp_path / "out").exists()
    status, stdout = _run(
        ["convert", "table", path, other, "--columns", "t,x:mm,F", "--current", "1,0"]
        + ["--out", tmp_path / "out"]
    )
    assert status == 0
    # The input each table was given, in the order given.
    assert "mm.txt -> " in stdout and "(current 1 A)" in stdout
    assert stdout.index("(current 1 A)") < stdout.index("(current 0 A)")
    e = jaxmr.data.read_csv(tmp_path / "out" / "mm.csv")
    np.testing.assert_allclose(e.x, 0.01 * np.sin(6.28 * t), rtol=1e-12, atol=1e-15)
    assert e.velocity_source != "measured"  # computed from x


# The force rises with the displacement (along the velocity: a passive device's sign).
LAYOUTS = {
    "tabs, decimal point": "0.0\t1.0\t2\n0.1\t1.25\t3\n0.2\t1.5\t4\n",
    "semicolons, decimal comma": "0,0;1,0;2\n0,1;1,25;3\n0,2;1,5;4\n",
    "commas, header": "t,x,F\n0.0,1.0,2\n0.1,1.25,3\n0.2,1.5,4\n",
    "whitespace, decimal comma": "0,0  1,0 2\n 0,1 1,25   3\n0,2 1,5 4\n",
    "whitespace, comment and blank lines": "# rig 3\n\n0 1 2\n0.1 1.25 3\n\n0.2 1.5 4\n",
    # A spreadsheet's export: quoted cells (a quoted decimal comma may sit between
    # commas), a delimiter closing every row.
    "quoted, semicolons, decimal comma": (
        '"t";"x";"F"\n"0,0";"1,0";"2"\n"0,1";"1,25";"3"\n"0,2";"1,5";"4"\n'
    ),
    "quoted, commas, decimal comma": '"0,0","1,0",2\n"0,1","1,25",3\n"0,2","1,5",4\n',
    "semicolons, one closing every row": "0,0;1,0;2;\n0,1;1,25;3;\n0,2;1,5;4;\n",
}


@pytest.mark.parametrize("layout", LAYOUTS)
def test_read_table_detects_the_layout(layout, tmp_path):
    path = tmp_path / "table.txt"
    path.write_text(LAYOUTS[layout], encoding="utf-8")
    e = jaxmr.data.read_table(path, "t:ms,x:cm,F:kN", current=0.5)
    np.testing.assert_array_equal(e.t, [0.0, 1e-4, 2e-4])
    np.testing.assert_allclose(e.x, [0.01, 0.0125, 0.015], rtol=1e-15)
    np.testing.assert_array_equal(e.force, [2e3, 3e3, 4e3])  # pyright: ignore[reportArgumentType]
    np.testing.assert_array_equal(e.current, [0.5] * 3)
    assert e.drive == "current" and e.name == "table"


def test_read_table_rotary_with_skipped_column(tmp_path):
    path = tmp_path / "brake.csv"
    path.write_text("0;9;0;1,5\n0,01;9;1;1,25\n0,02;9;2;1\n")
    e = jaxmr.data.read_table(path, ["t", "_", "θ:deg", "u:V"])
    assert e.rotary and e.drive == "voltage" and e.force is None
    np.testing.assert_allclose(e.x, np.deg2rad([0, 1, 2]), rtol=1e-15)
    np.testing.assert_array_equal(e.current, [1.5, 1.25, 1.0])


@pytest.mark.parametrize(
    "text, columns, options, match",
    [
        # a decimal comma with commas between the columns: no layout reads it
        ("0,0,1,5\n0,1,1,25\n0,2,1,0\n", "t,x", {"current": 1}, r"is not 2 numbers"),
        # the cell counts at each delimiter are named
        ("0 1 2 3\n", "t,x", {"current": 1}, r"4 at whitespace"),
        # a row that changes layout, with its line number
        ("0;1\n0,1;2\n0.2;3\n", "t,x", {"current": 1}, r"line 3 '0\.2;3'.*semicolons"),
        ("t x\n", "t,x", {"current": 1}, r"no row of numbers \(1 header line"),
        ("0 1\n", "t,x:furlong", {"current": 1}, r"unknown unit 'furlong'.*mm"),
        ("0 1\n", "time,x", {"current": 1}, r"unknown column name 'time' .*'t'"),
        (
            "0 1 2\n",
            "t,x,i",
            {"current": 1},
            r"exactly one input.*got column `i`, `current` = 1",
        ),
        (
            "0 1\n0.1 2\n0.2 3\n",
            "t,x",
            {"current": float("nan")},
            r"constant `current` must be a finite number, got nan",
        ),
        ("0 1\n", "t,x", {}, r"exactly one input.*got none"),
        ("0 1\n", "t,F", {"current": 1}, r"lack \['x'\]"),
        ("0 1 2\n", "t,x,T", {"current": 1}, r"mixed"),
        ("0 1\n0 2\n0.1 3\n", "t,x", {"current": 1}, r"strictly increasing.*line 2"),
        # an empty cell is a missing value, named by its column and line
        (
            "0;1;2\n0,1;;3\n0,2;1;4\n",
            "t,x,F",
            {"current": 1},
            r"column `x` has a non-finite value \(nan\) at line 2",
        ),
    ],
)
def test_read_table_refusals(text, columns, options, match, tmp_path):
    path = tmp_path / "bad.txt"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ValueError, match=match):
        jaxmr.data.read_table(path, columns, **options)


def _joined_runs():
    """Two runs of a 2 Hz, 10 mm sine joined a quarter cycle apart in x, with a
    continuous velocity column: a 10 mm step in x at t = 0.5 s."""
    t = np.arange(401) / 400
    w = 2 * np.pi * 2.0
    x, v = 0.01 * np.sin(w * t), 0.01 * w * np.cos(w * t)
    x[t > 0.5] += 0.01
    return t, x, v


def test_a_step_in_x_is_named_when_read(tmp_path):
    t, x, v = _joined_runs()
    path = tmp_path / "joined.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", jaxmr.data.DataWarning)
        jaxmr.data.write_csv(jaxmr.data.Experiment(t, x, v, 1.0), path)
    with pytest.warns(jaxmr.data.DataWarning) as caught:
        jaxmr.data.read_csv(path)
    (w,) = caught
    message = w.message
    assert isinstance(message, jaxmr.data.DataWarning)
    assert (message.kind, message.column, message.time) == ("motion", "x", 0.5)
    assert str(path) in str(message) and "t = 0.5 s and 0.5025 s" in str(message)
    # The reverse: a spike in v that x does not show names `v`.
    v_spike = _joined_runs()[2]
    v_spike[200] += 5.0
    with pytest.warns(jaxmr.data.DataWarning) as caught:
        jaxmr.data.Experiment(t, 0.01 * np.sin(4 * np.pi * t), v_spike, 1.0)
    assert [(w.message.column, w.message.time) for w in caught] == [("v", 0.4975)]  # pyright: ignore[reportAttributeAccessIssue]


def test_consistent_records_give_no_motion_warning():
    """Neither a clean sine nor one whose velocity lags by half a sample and is 10 %
    off in scale (a filtered velocity transducer) is taken for a step."""
    t = np.arange(401) / 400
    w = 2 * np.pi * 2.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", jaxmr.data.DataWarning)
        jaxmr.data.Experiment(t, 0.01 * np.sin(w * t), 0.01 * w * np.cos(w * t))
        lagged = 1.1 * 0.01 * w * np.cos(w * (t - 0.5 / 400))
        jaxmr.data.Experiment(t, 0.01 * np.sin(w * t), lagged)


def test_a_reversed_force_is_refused_and_a_minus_unit_negates_it(
    files, tmp_path, capsys
):
    """A load cell read the other way round: `jaxmr convert table` and `jaxmr fit`
    stop before any work, naming the column and the fix; `F:-kN` in --columns reads
    the same table as the original force."""
    e = jaxmr.data.read_csv(files[0][0])
    assert e.force is not None
    with pytest.warns(jaxmr.data.DataWarning, match="works against"):
        reversed_force = jaxmr.data.Experiment(e.t, e.x, e.v, e.current, -e.force)
    raw = tmp_path / "reversed.txt"
    raw.write_text(_raw_text(reversed_force), encoding="utf-8")
    columns = ["--columns", "t,x:mm,v:mm/s,F:kN", "--current", "0"]
    out = tmp_path / "converted"
    status, _ = _run(["convert", "table", raw, *columns, "--out", out])
    err = capsys.readouterr().err
    assert status == 1 and not out.exists()
    assert "a reversed sign, nothing done" in err and "column `F`" in err
    assert "F:-kN" in err and "--accept-units" in err
    # A velocity declared the other way round is named, not the force.
    spec = ["--columns", "t,x:mm,v:-mm/s,F:kN", "--current", "0"]
    status, _ = _run(["convert", "table", files[1][0], *spec, "--out", out])
    err = capsys.readouterr().err
    assert status == 1 and not out.exists()
    assert "column `v`" in err and "column `F`" not in err
    columns[1] = "t,x:mm,v:mm/s,F:-kN"
    status, _ = _run(["convert", "table", raw, *columns, "--out", out])
    assert status == 0, capsys.readouterr().err
    (converted,) = out.glob("*.csv")
    back = jaxmr.data.read_csv(converted)
    # The table holds 12 significant digits of the force in kN.
    np.testing.assert_allclose(back.force, e.force, rtol=1e-10, atol=1e-9)
    # A canonical CSV with the reversed force stops `jaxmr fit` the same way.
    path = tmp_path / "reversed.csv"
    jaxmr.data.write_csv(reversed_force, path)
    fitted = tmp_path / "p.json"
    status, _ = _run(["fit", "--model", "bingham", "--out", fitted, path])
    err = capsys.readouterr().err
    assert status == 1 and not fitted.exists()
    assert "a reversed sign" in err and "F:-kN" in err


def test_only_motion_and_force_columns_take_a_minus_sign(files):
    with pytest.raises(ValueError, match=r"column 't' cannot be negated"):
        jaxmr.data.read_table(files[1][0], "t:-s,x:mm,v:mm/s,F:kN", current=0.0)


def test_read_table_names_a_list_given_for_its_constant_input(tmp_path):
    """One table, one constant input: a list (as the command line's `--current 0,1`
    for several tables) is named, not a failed float() conversion."""
    path = tmp_path / "run.txt"
    path.write_text("0 1\n0.1 2\n0.2 3\n", encoding="utf-8")
    with pytest.raises(TypeError, match=r"must be one number|parameter 'current'"):
        jaxmr.data.read_table(path, "t,x", current=[0.5])  # pyright: ignore[reportArgumentType]
