"""jaxmr.data: experiments, the canonical CSV format and the public-dataset loaders.

The loaders are tested on the real files in `../shared/data` (beside the repository);
missing data is a failure, not a skip.
"""

import inspect
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmr
import jaxmr.data as jd

from .helpers import shared_data


def _sine(n=2001, rate=1000.0, amplitude=0.01, frequency=2.0):
    t = np.arange(n) / rate
    w = 2 * np.pi * frequency
    return t, amplitude * np.sin(w * t), amplitude * w * np.cos(w * t)


# ---------------------------------------------------------------------------------------
# Experiment


def test_experiment_signals():
    t, x, v = _sine()
    force = 100.0 * v
    e = jd.Experiment(t, x, v, 0.5, force, name="sine")
    assert len(e) == t.size
    assert e.is_constant_current
    assert e.current.shape == t.shape  # a constant input is stored broadcast
    assert e.duration == pytest.approx(2.0)
    assert e.sample_rate == pytest.approx(1000.0)
    assert e.velocity_source == "measured"
    current = e.current_signal()
    assert isinstance(current, jaxmr.Constant)
    assert float(current.value) == 0.5
    motion = e.motion()
    assert isinstance(motion, jaxmr.Sampled)
    # Hermite interpolation: values and derivatives at the samples are the data's.
    ts = jnp.asarray(t[100:110])
    np.testing.assert_allclose(jax.vmap(motion)(ts), x[100:110], rtol=1e-12)
    np.testing.assert_allclose(jax.vmap(motion.derivative)(ts), v[100:110], rtol=1e-12)

    varying = jd.Experiment.from_arrays(t, x, v=v, current=np.sin(t), force=force)
    assert not varying.is_constant_current
    assert isinstance(varying.current_signal(), jaxmr.Sampled)

    part = e.window(0.5, 1.0)
    assert float(part.t[0]) == 0.5 and float(part.t[-1]) == 1.0 and len(part) == 501
    assert part.name == "sine" and part.velocity_source == e.velocity_source


def test_experiment_goes_through_simulate():
    t, x, v = _sine(n=201, rate=100.0, amplitude=0.01, frequency=1.0)
    e = jd.Experiment(t, x, v, 0.5)
    sol = jaxmr.simulate(
        jaxmr.Bingham(f_c=10.0, c0=100.0, velocity_scale=0.01),
        e.motion(),
        e.current_signal(),
        e.t,
        integrator=jaxmr.FixedStep(2),
    )
    assert sol.force.shape == t.shape


@pytest.mark.parametrize("uneven", [False, True])
def test_velocity_from_x_matches_the_sine_derivative(uneven):
    # Second-order differences: relative truncation error about (w h)^2 / 6 inside and
    # (w h)^2 / 3 at the ends; w h = 2 pi 2 Hz 1 ms = 0.0126, so <= 5.3e-5 (5 % more
    # for steps up to 1.05 ms). Tolerance 1e-4 of the velocity amplitude.
    t, x, v = _sine()
    if uneven:
        rng = np.random.default_rng(0)
        t = t + rng.uniform(-0.05e-3, 0.05e-3, t.size)  # ±5 % jitter of the 1 ms step
        w = 2 * np.pi * 2.0
        x, v = 0.01 * np.sin(w * t), 0.01 * w * np.cos(w * t)
    e = jd.Experiment.from_arrays(t, x, current=0.0)
    assert e.velocity_source.startswith("computed: central differences")
    error = np.max(np.abs(np.asarray(e.v) - v)) / np.max(np.abs(v))
    assert error < 1e-4


def _bad(**change):
    t, x, v = _sine(n=10)
    columns = dict(t=t, x=x, v=v, current=0.5, force=100 * v)
    columns.update(change)
    return columns


def _nan_at(a, k, value=np.nan):
    a = np.array(a, dtype=float)
    a[k] = value
    return a


@pytest.mark.parametrize(
    "columns, match",
    [
        (
            _bad(x=_nan_at(_sine(n=10)[1], 4)),
            r"column `x` has a non-finite value \(nan\) at index 4 \(1 non-finite",
        ),
        (
            _bad(force=_nan_at(_nan_at(np.zeros(10), 7, np.inf), 9)),
            r"column `force` has a non-finite value \(inf\) at index 7 \(2 non-finite",
        ),
        (
            _bad(current=_nan_at(np.zeros(10), 0)),
            r"column `current` has a non-finite value \(nan\) at index 0",
        ),
        (
            _bad(v=np.zeros(9)),
            r"equal lengths .* got `t`: 10, `x`: 10, `v`: 9, `current`: 10, `force`: 10",
        ),
        (
            _bad(t=_nan_at(_sine(n=10)[0], 6, 0.001)),
            r"time `t` must be strictly increasing, but t=0.001 at index 6 does not "
            r"exceed 0.005 at index 5 \(1 such steps\)",
        ),
        (
            dict(t=[0.0, 1.0], x=[0.0, 0.1], v=[0.1, 0.1]),
            r"at least 3 samples are needed .* got 2",
        ),
        (_bad(x=np.zeros((10, 1))), r"column `x` must be 1-D .* shape \(10, 1\)"),
    ],
)
def test_experiment_rejects_bad_columns(columns, match):
    with pytest.raises(ValueError, match=match):
        jd.Experiment(**columns, name="bad")


def test_experiment_rejects_bad_settings():
    t, x, v = _sine(n=10)
    with pytest.raises(ValueError, match=r"`drive` must be 'current' .* got 'amps'"):
        jd.Experiment(t, x, v, drive="amps")
    # Checked before the differencing that would divide by zero or spread the NaN.
    with pytest.raises(ValueError, match=r"time `t` must be strictly increasing"):
        jd.Experiment.from_arrays(np.zeros(10), x)
    with pytest.raises(ValueError, match=r"column `x` has a non-finite .* index 3"):
        jd.Experiment.from_arrays(t, _nan_at(x, 3))
    lists = jd.Experiment.from_arrays(t.tolist(), x.tolist(), current=[0.5] * 10)
    assert lists.is_constant_current


@pytest.mark.parametrize(
    "change, match",
    [
        (
            dict(x=_sine(n=10)[1] * 1e3, v=_sine(n=10)[2] * 1e3),
            r"displacement amplitude \(half peak-to-peak\) is \d+(\.\d+)? m .* "
            r"millimetres",
        ),
        (
            dict(t=_sine(n=10)[0] * 1e4, v=_sine(n=10)[2] * 1e-4),
            r"median time step is 10 s .* milliseconds",
        ),
        (  # a 1 kHz rig's time in milliseconds: exactly 1 (the bound was > 1 s)
            dict(t=_sine(n=10)[0] * 1e3, v=_sine(n=10)[2] * 1e-3),
            r"median time step is 1 s \(sampled at 1 Hz, below 20 Hz\).* milliseconds",
        ),
        (dict(force=np.full(10, 2e6)), r"largest \|F\| is 2e\+06 N"),
        (dict(current=500.0), r"largest \|current\| is 500 A .* milliamperes"),
        (
            dict(v=_sine(n=10)[2] * 1e3),
            r"RMS of `v` is 99\d\.\d+ times that of the derivative of `x`",
        ),
    ],
)
def test_experiment_warns_about_implausible_units(change, match):
    columns = _bad(**change)
    with pytest.warns(UserWarning, match=match):
        jd.Experiment(**columns)


@pytest.mark.parametrize("rotary", [False, True])
def test_a_force_that_feeds_energy_into_the_motion_is_warned_about(rotary):
    t, x, v = _sine(n=200)
    rng = np.random.default_rng(0)
    hysteretic = 50.0 * np.tanh(v / 0.01) + 20.0 * v
    with pytest.warns(jd.DataWarning, match=r"works against .* is -0\.9") as w:
        jd.Experiment(t, x, v, 0.0, -hysteretic, rotary=rotary)
    load = "T" if rotary else "F"
    assert [(c.message.kind, c.message.column) for c in w] == [("sign", load)]  # pyright: ignore[reportAttributeAccessIssue]
    # The convention's sign, and a force that does not depend on the motion (noise
    # about an offset, a record at rest), raise nothing.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        jd.Experiment(t, x, v, 0.0, hysteretic, rotary=rotary)
        jd.Experiment(t, x, v, 0.0, 5.0 + rng.standard_normal(t.size), rotary=rotary)
        jd.Experiment(t, 0 * x, 0 * v, 0.0, -hysteretic, rotary=rotary)


def test_a_velocity_against_the_displacement_is_named_instead_of_the_force():
    """A velocity sensor wired the other way round: the warning names `v`, and the
    force (right, but against the reversed `v`) is not blamed."""
    t, x, v = _sine(n=200)
    force = 50.0 * np.tanh(v / 0.01) + 20.0 * v
    with pytest.warns(jd.DataWarning, match=r"`v` runs against the derivative") as w:
        jd.Experiment(t, x, -v, 0.0, force)
    assert [(c.message.kind, c.message.column) for c in w] == [("sign", "v")]  # pyright: ignore[reportAttributeAccessIssue]


def test_voltage_drive_and_rotary_are_not_checked_as_current_or_stroke():
    t, x, v = _sine(n=10)
    jd.Experiment(t, 100 * x, 100 * v, 500.0, drive="voltage", rotary=True)


# ---------------------------------------------------------------------------------------
# CSV


def _assert_same(a: jd.Experiment, b: jd.Experiment):
    for field in ("t", "x", "v", "current", "force"):
        fa, fb = getattr(a, field), getattr(b, field)
        assert (fa is None) == (fb is None), field
        if fa is not None:
            np.testing.assert_array_equal(np.asarray(fa), np.asarray(fb), err_msg=field)
    for field in ("name", "rotary", "drive", "velocity_source", "smoothing", "discard"):
        assert getattr(a, field) == getattr(b, field), field


@pytest.mark.parametrize(
    "rotary, drive, constant, with_force",
    [
        (False, "current", True, True),
        (False, "voltage", False, True),
        (True, "current", False, True),
        (True, "voltage", True, False),
    ],
)
def test_csv_round_trip(tmp_path, rotary, drive, constant, with_force):
    t, x, v = _sine(n=300)
    t = t + 0.1 / 3  # not round numbers
    current = 0.75 if constant else 0.5 + 0.25 * np.sin(3 * t)
    e = jd.Experiment.from_arrays(
        t,
        x,
        v=None if constant else v,  # both a computed and a measured velocity
        current=current,
        force=300.0 * v + 1e-3 if with_force else None,
        name="round trip",
        rotary=rotary,
        drive=drive,
    )
    path = tmp_path / "e.csv"
    jd.write_csv(e, path, comment="rig: test\nsecond line")
    text = path.read_text()
    assert "# rig: test\n# second line\n" in text
    names = ("theta", "omega", "T") if rotary else ("x", "v", "F")
    header = ["t", names[0], names[1], "i" if drive == "current" else "u"]
    header += [names[2]] if with_force else []
    assert ",".join(header) + "\n" in text
    assert "[N·m]" in text if rotary and with_force else True
    back = jd.read_csv(path)
    _assert_same(e, back)
    assert back.is_constant_current == constant


def test_a_measured_force_beside_a_prediction(tmp_path):
    """`write_csv(measured=)` writes the measured torque of a brake's record beside its
    predicted one (`T_measured`, after `T`, in N·m); `read_csv` reads the predicted one
    back and past the column. Without a predicted force, or of another length, it is
    refused before anything is written."""
    t, x, v = _sine(n=200)
    predicted = jd.Experiment(t, x, v, 0.5, 3.0 * v, name="brake", rotary=True)
    measured = 3.0 * v + 0.01 * np.sin(7 * t)
    path = tmp_path / "p.csv"
    jd.write_csv(predicted, path, measured=measured)
    text = path.read_text()
    assert "t,theta,omega,i,T,T_measured\n" in text and "T_measured [N·m]" in text
    _assert_same(predicted, jd.read_csv(path))
    lines = [line for line in text.splitlines() if not line.startswith("#")][1:]
    column = np.array([float(line.split(",")[5]) for line in lines])
    np.testing.assert_array_equal(column, measured)  # shortest exact form
    with pytest.raises(ValueError, match="`measured` goes with a predicted force"):
        jd.write_csv(jd.Experiment(t, x, v, 0.5), tmp_path / "a.csv", measured=measured)
    with pytest.raises(ValueError, match=r"`measured` has shape \(199,\)"):
        jd.write_csv(predicted, tmp_path / "b.csv", measured=measured[1:])
    assert not (tmp_path / "a.csv").exists() and not (tmp_path / "b.csv").exists()


def test_processing_travels_with_the_experiment(tmp_path):
    """`smoothing` and `discard` [s] go to a file's comment lines and come back."""
    t, x, v = _sine(n=300)
    e = jd.Experiment(
        t, x, v, 0.5, 300.0 * v, name="processed", smoothing=0.1 / 3, discard=0.25
    )
    path = tmp_path / "e.csv"
    jd.write_csv(e, path)
    text = path.read_text()
    assert f"# smoothing: {0.1 / 3!r} s\n# discard: 0.25 s\n" in text
    back = jd.read_csv(path)
    _assert_same(e, back)
    assert (back.smoothing, back.discard) == (0.1 / 3, 0.25)
    # An explicit argument overrides the experiment's own; 0 (none) writes no line.
    jd.write_csv(e, path, smoothing=0.0, discard=0.2)
    assert (jd.read_csv(path).smoothing, jd.read_csv(path).discard) == (0.0, 0.2)
    plain = jd.Experiment(t, x, v, 0.5, 300.0 * v)
    jd.write_csv(plain, path)
    assert "smoothing" not in path.read_text() and "discard" not in path.read_text()
    assert (jd.read_csv(path).smoothing, jd.read_csv(path).discard) == (0.0, 0.0)
    # A window keeps the smoothing; its discard still ends where the record's did.
    later = e.window(float(t[50]), None)
    assert later.smoothing == e.smoothing
    np.testing.assert_allclose(later.discard, 0.25 - (t[50] - t[0]), rtol=1e-12)
    assert e.window(float(t[0]) + 0.28, None).discard == 0.0
    assert e.window(None, 0.5).discard == 0.25
    for bad in (-0.1, np.nan, np.inf):
        with pytest.raises(ValueError, match="`discard` must be a finite number"):
            jd.Experiment(t, x, v, 0.5, discard=bad)


def test_csv_without_velocity_computes_it(tmp_path):
    t, x, v = _sine(n=400)
    rows = "\n".join(f"{a!r},{b!r},0.0" for a, b in zip(t.tolist(), x.tolist()))
    path = tmp_path / "no_v.csv"
    path.write_text("# a comment\n\nt,x,i\n" + rows + "\n")
    e = jd.read_csv(path)
    assert e.name == "no_v"
    assert e.force is None
    assert e.velocity_source.startswith("computed")
    assert np.max(np.abs(np.asarray(e.v) - v)) < 1e-4 * np.max(np.abs(v))


_GOOD_ROWS = ["0.0,0.0,0.0,1.0", "0.001,0.001,0.0,2.0", "0.002,0.002,0.0,3.0"]


@pytest.mark.parametrize(
    "header, rows, match",
    [
        (
            "time,x,i,F",
            _GOOD_ROWS,
            r"unknown column names 'time' \(did you mean 't'\?\). Found 'time', 'x', "
            r"'i', 'F'; expected t \[s\]; x \[m\]",
        ),
        ("t,X,i,F", _GOOD_ROWS, r"'X' \(did you mean 'x'\?\)"),
        ("t,x [m],i,F", _GOOD_ROWS, r"'x \[m\]' \(did you mean 'x'\?\)"),
        ("t,v,i,F", _GOOD_ROWS, r"missing column\(s\) \['x'\]; found 't', 'v'"),
        ("t,x,i,u", _GOOD_ROWS, r"both `i` \(current \[A\]\) and `u`"),
        ("t,x,v,F", _GOOD_ROWS, r"missing the input column: `i` .* or `u`"),
        ("t,x,i,T", _GOOD_ROWS, r"linear columns \['x'\] and rotary columns \['T'\]"),
        ("t,x,i,x", _GOOD_ROWS, r"repeated column names \['x'\]"),
        (
            "t,x,i,F",
            ["0.0,0.0,0.0,1.0", "0.001,0.001,0.0", "0.002,0.002,0.0,3.0"],
            r"line 3 has 3 cells but the header \(line 1\) names 4 columns",
        ),
        (
            "t,x,i,F",
            ["0.0,0.0,0.0,1.0", "# comment", "0.001,0.001,0.0,abc", "0.002,0,0,3"],
            r"line 4, column `F`: cannot read 'abc' as a number",
        ),
        (
            "t,x,i,F",
            ["0.0,0.0,0.0,1.0", "0.001,,0.0,2.0", "0.002,0.002,0.0,3.0"],
            r"line 3, column `x`: cannot read '' as a number",
        ),
        (
            "t,x,i,F",
            ["0.0,0.0,0.0,1.0", "0.001,0.001,0.0,2.0", "0.002,nan,0.0,3.0"],
            r"column `x` has a non-finite value \(nan\) at line 4",
        ),
        (
            "t,x,i,F",
            ["0.0,0.0,0.0,1.0", "0.001,0.001,0.0,-inf", "0.002,0.002,0.0,3.0"],
            r"column `F` has a non-finite value \(-inf\) at line 3",
        ),
        (
            "t,x,i,F",
            ["0.0,0.0,0.0,1.0", "0.002,0.001,0.0,2.0", "0.001,0.002,0.0,3.0"],
            r"time `t` must be strictly increasing, but t=0.001 at line 4 does not "
            r"exceed 0.002 at line 3",
        ),
        ("t,x,i,F", _GOOD_ROWS[:2], r"at least 3 samples are needed .* got 2"),
    ],
)
def test_csv_rejects_bad_files(tmp_path, header, rows, match):
    path = tmp_path / "bad.csv"
    path.write_text("\n".join([header, *rows]) + "\n")
    with pytest.raises(ValueError, match=match) as info:
        jd.read_csv(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    "separator, name",
    [(";", "semicolons"), ("\t", "tabs"), ("|", "bars"), (" ", "spaces")],
)
def test_csv_names_another_separator(tmp_path, separator, name):
    path = tmp_path / "sep.csv"
    rows = [r.replace(",", separator) for r in ["t,x,i,F", *_GOOD_ROWS]]
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(ValueError, match=f"separated by {name}; jaxmr CSV is comma"):
        jd.read_csv(path)


def test_csv_reads_a_byte_order_mark_and_gzip(tmp_path):
    """What spreadsheets and archives hand over: a UTF-8 BOM before the header (it
    made the header's first name '\\ufefft'), and a gzip-compressed file."""
    import gzip

    text = "\n".join(["# name: run", "t,x,i,F", *_GOOD_ROWS]) + "\n"
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + text.encode())
    packed = tmp_path / "run.csv.gz"
    packed.write_bytes(gzip.compress(text.encode()))
    for path in (bom, packed):
        e = jd.read_csv(path)
        assert e.name == "run"
        np.testing.assert_array_equal(e.force, [1.0, 2.0, 3.0])
    assert jd.read_processing(packed) == {"smoothing": None, "discard": None}


def test_csv_reads_what_spreadsheets_write(tmp_path):
    """Quoted cells (`"t","x"`) and a comma ending every line (an empty last column)
    read as the plain file; an empty name inside the header is named as such; a
    compressed file without a `# name:` line is named after the file without
    `.csv.gz`."""
    import gzip

    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join(["t,x,i,F", *_GOOD_ROWS]) + "\n")
    quoted = tmp_path / "quoted.csv"
    quoted.write_text(
        "\n".join(
            [
                '"t","x","i","F"',
                *(",".join(f'"{c}"' for c in r.split(",")) for r in _GOOD_ROWS),
            ]
        )
        + "\n"
    )
    trailing = tmp_path / "trailing.csv"
    trailing.write_text("\n".join(f"{r}," for r in ["t,x,i,F", *_GOOD_ROWS]) + "\n")
    expected = jd.read_csv(plain)
    for path in (quoted, trailing):
        e = jd.read_csv(path)
        for key in ("t", "x", "v", "current", "force"):
            np.testing.assert_array_equal(getattr(e, key), getattr(expected, key))
    empty = tmp_path / "empty.csv"
    empty.write_text("\n".join(["t,,x,i,F", *(f"{r},0" for r in _GOOD_ROWS)]) + "\n")
    with pytest.raises(ValueError, match="empty column name at position 2"):
        jd.read_csv(empty)
    packed = tmp_path / "run 7.csv.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    assert jd.read_csv(packed).name == "run 7"
    assert (
        jd.experiment_name("a/b.CSV.GZ") == "b" and jd.experiment_name("c.txt") == "c"
    )


def test_read_comments_reads_the_lines_above_the_header(tmp_path):
    """`# key: value` lines above the header, the first of each key, gzip too; a
    comment after the header is not one of them."""
    import gzip

    text = "\n".join(
        ["# name: run", "# F: predicted by jaxmr", "# name: other", "#no colon"]
        + ["t,x,i,F", *_GOOD_ROWS, "# after: the header"]
    )
    path = tmp_path / "run.csv"
    path.write_text(text + "\n")
    expected = {"name": "run", "F": "predicted by jaxmr"}
    assert jd.read_comments(path) == expected
    packed = tmp_path / "run.csv.gz"
    packed.write_bytes(gzip.compress(path.read_bytes()))
    assert jd.read_comments(packed) == expected


def test_processing_longer_than_the_record_is_refused():
    """A discarded start past the record's end, or a moving average wider than the
    record, is refused where the experiment is made, naming both durations."""
    t = np.linspace(0.0, 2.0, 201)
    arrays = (t, np.sin(t), np.cos(t), 0.0, np.cos(t))
    jd.Experiment(*arrays, discard=2.0, smoothing=2.0)  # the whole record: allowed
    with pytest.raises(ValueError, match=r"`discard` = 2.5 s leaves no sample of a "):
        jd.Experiment(*arrays, discard=2.5, name="run")
    with pytest.raises(ValueError, match=r"`smoothing` = 3 s is wider than the record"):
        jd.Experiment(*arrays, smoothing=3.0)


def test_experiment_names_a_missing_velocity_and_an_empty_window():
    """`v=None` points to `from_arrays`; a window past the record names the times it
    was given and the record's span (it had said only "got 0")."""
    t = np.linspace(0.0, 1.0, 50)
    e = jd.Experiment.from_arrays(t, 0.01 * np.sin(6 * t), name="run")
    with pytest.raises(ValueError, match=r"window\(5.0, 6.0\) keeps 0 sample\(s\) of "):
        e.window(5.0, 6.0)
    # The suite's type checker may refuse None first, naming the parameter.
    with pytest.raises(TypeError, match=r"Experiment.from_arrays|parameter 'v'"):
        jd.Experiment(t, np.asarray(e.x), None)  # pyright: ignore[reportArgumentType]


def test_csv_names_the_file_that_is_not_text(tmp_path):
    latin = tmp_path / "latin.csv"
    latin.write_bytes("# Kraft in N, Weg \xb5m\nt,x,i,F\n".encode("latin-1"))
    with pytest.raises(ValueError, match=f"{latin}: not UTF-8 text"):
        jd.read_csv(latin)
    broken = tmp_path / "broken.csv.gz"
    broken.write_bytes(b"\x1f\x8b" + b"not a gzip stream")
    with pytest.raises(ValueError, match=f"{broken}: cannot decompress"):
        jd.read_csv(broken)


def test_csv_without_header(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_text("# only a comment\n")
    with pytest.raises(ValueError, match="no header line"):
        jd.read_csv(path)


def test_csv_warns_about_millimetres(tmp_path):
    path = tmp_path / "mm.csv"
    t, x, _ = _sine(n=50)
    path.write_text("t,x,i\n" + "\n".join(f"{a},{1e3 * b},0" for a, b in zip(t, x)))
    with pytest.warns(UserWarning, match=r"amplitude .* is \d+(\.\d+)? m") as caught:
        line = inspect.currentframe().f_lineno + 1
        jd.read_csv(path)
    # The warning names the file, and points at the line above (the user's call),
    # not at equinox's code that runs the experiment's checks.
    (warning,) = caught
    assert str(warning.message).startswith(f"{path}: ")
    assert (warning.filename, warning.lineno) == (__file__, line)


def test_unit_warnings_point_at_the_callers_line():
    t, x, v = _sine(n=10)
    with pytest.warns(UserWarning, match="millimetres") as caught:
        line = inspect.currentframe().f_lineno + 1
        experiment = jd.Experiment(t, 1e3 * x, 1e3 * v, 0.5)
    assert (caught[0].filename, caught[0].lineno) == (__file__, line)
    # A window of a checked experiment is not warned about again.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        experiment.window(0.0, float(t[5]))


# Read, converted and written back by a process whose JAX runs in float32 (its
# default): every column must still be float64, so the file's numbers come back exactly.
_FLOAT32_PROCESS = """
import sys
import jax
import numpy as np
import jaxmr.data as jd

assert not jax.config.jax_enable_x64
e = jd.read_csv(sys.argv[1])
assert all(np.asarray(getattr(e, k)).dtype == np.float64 for k in ("t", "x", "v", "current", "force")), e
jd.write_csv(e, sys.argv[2])
"""


def test_csv_is_read_and_written_in_float64_when_jax_is_float32(tmp_path):
    t = np.arange(50) * 1e-3  # 0.001 is not a float32 (0.0010000000474974513)
    x = 0.0123456789 * np.sin(2 * np.pi * t)
    source, copy = tmp_path / "in.csv", tmp_path / "out.csv"
    jd.write_csv(jd.Experiment.from_arrays(t, x, current=0.5, force=1e3 * x), source)
    environment = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    done = subprocess.run(
        [sys.executable, "-c", _FLOAT32_PROCESS, str(source), str(copy)],
        capture_output=True,
        text=True,
        env=environment | {"JAX_ENABLE_X64": "0"},
        cwd=Path(__file__).parents[1],
    )
    assert done.returncode == 0, done.stderr
    data = lambda path: [
        line for line in path.read_text().splitlines() if not line.startswith("#")
    ]
    assert data(copy) == data(source)  # the same text: no number went through float32
    assert data(copy)[2].startswith("0.001,")


# ---------------------------------------------------------------------------------------
# Public datasets


def test_load_utfsm():
    experiments = jd.load_utfsm(shared_data("utfsm_mr_damper", "sine"))
    assert len(experiments) == 30
    measured = {0.002: 1.6e-3, 0.005: 4.55e-3, 0.010: 9.7e-3, 0.025: 24.5e-3}  # m
    pairs = {(0.002, 5.0), (0.005, 3.0), (0.010, 1.0)}
    pairs |= {(0.025, f) for f in (0.1, 0.25, 0.5)}
    seen = set()
    for e in experiments:
        amplitude, frequency, current = jd.utfsm_test_conditions(e)
        assert re.fullmatch(r"\d+mm[\dx]+Hz[\dx]+A", e.name)
        seen.add((amplitude, frequency, current))
        assert e.is_constant_current and np.asarray(e.current)[0] == current
        assert e.drive == "current" and not e.rotary and e.force is not None
        x = np.asarray(e.x)
        # Measured amplitude within 5 % of the README's (the 25 mm / 0.1 Hz records
        # are offset by up to 1.1 mm: -23.3 to +25.6 mm).
        half_range = 0.5 * (x.max() - x.min())
        assert half_range == pytest.approx(measured[amplitude], rel=0.05), e.name
        assert np.max(np.abs(x)) < 1.06 * measured[amplitude], e.name
        dt = (
            0.005
            if (amplitude, frequency) in {(0.002, 5.0)} or amplitude == 0.025
            else 0.001
        )
        assert e.sample_rate == pytest.approx(1 / dt)
        assert np.max(np.abs(np.asarray(e.force))) < 1.6e3  # N
    assert seen == {(a, f, i) for a, f in pairs for i in (0.0, 0.25, 0.5, 0.75, 1.0)}
    assert jd.utfsm_test_conditions("25mm0x25Hz0x5A") == (0.025, 0.25, 0.5)
    with pytest.raises(ValueError, match="not a UTFSM test name"):
        jd.utfsm_test_conditions("ranran_50")


def test_load_utfsm_file_velocity_is_a_backward_difference():
    e_file, e_central = (
        next(
            e
            for e in jd.load_utfsm(
                shared_data("utfsm_mr_damper", "sine"), velocity=kind
            )
            if e.name == "10mm1Hz0x5A"
        )
        for kind in ("file", "central")
    )
    assert e_file.velocity_source.startswith("file: backward differences")
    x, v = np.asarray(e_file.x), np.asarray(e_file.v)
    # The file prints 8 significant digits: x to 1e-11 m, so differences to 2e-8 m/s.
    np.testing.assert_allclose(v[1:], np.diff(x) / 1e-3, rtol=0, atol=2e-8)
    np.testing.assert_array_equal(np.asarray(e_central.x), x)


def test_load_nees():
    path = shared_data("nees_dyke_mr_damper", "ranran_50.csv")
    e = jd.load_nees(path)
    assert len(e) == 74068
    assert e.sample_rate == pytest.approx(3004.8, rel=1e-9)
    assert float(e.t[1]) == pytest.approx(1 / 3004.8, rel=1e-12)
    assert e.duration == pytest.approx(74067 / 3004.8)
    assert e.drive == "voltage" and e.name == "ranran_50"
    force = np.asarray(e.force)
    assert np.max(np.abs(force)) < 2.5e3 and np.max(np.abs(force)) > 1.5e3  # N
    assert np.max(np.abs(np.asarray(e.x))) < 0.0075  # m: ±0.6 cm
    assert -0.5 < float(jnp.min(e.current)) and float(jnp.max(e.current)) < 3.0  # V
    trimmed = jd.load_nees(path, trim=True, velocity="central")
    assert 21.0 < trimmed.duration < 22.0
    assert trimmed.velocity_source.startswith("computed")


def test_load_boucwen_benchmark():
    t, u, y, fs = jd.load_boucwen_benchmark_train(
        shared_data("boucwen_benchmark", "train.h5")
    )
    assert t.shape == u.shape == y.shape == (40960,)
    assert fs == 750.0 and t[1] == pytest.approx(1 / 750)
    assert np.std(u) == pytest.approx(50.0, rel=0.01)  # N RMS
    assert np.max(np.abs(y)) < 5e-3  # m
    for kind, n in (("multisine", 8192), ("sinesweep", 153000)):
        record = jd.load_boucwen_benchmark_input(
            shared_data("boucwen_benchmark", f"uval_{kind}.mat")
        )
        assert record.kind == kind
        assert record.t.shape == record.u.shape == (n,)


def test_loaders_say_where_to_download(tmp_path):
    with pytest.raises(FileNotFoundError, match="DanielMaurelE/vRTHS_AMBC_MRdamper"):
        jd.load_utfsm(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match="no file named"):
        jd.load_utfsm(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"10\.4231/D3V11VM6X"):
        jd.load_nees(tmp_path / "ranran_50.csv")
    with pytest.raises(FileNotFoundError, match=r"10\.4121/12967592"):
        jd.load_boucwen_benchmark_train(tmp_path / "train.h5")


def test_a_velocity_differenced_from_a_noisy_displacement_is_warned():
    # 20 µm of noise on a ±10 mm, 2 Hz displacement at 1 kHz: central differences
    # give a velocity whose noise is about 15 % of its RMS (the estimate: third
    # differences of the displacement; see `differenced_noise`). A clean sine, or
    # 2 µm of noise (1.6 %), says nothing; a measured velocity is never judged so.
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 2.0, 1e-3)
    clean = 0.01 * np.sin(2 * np.pi * 2.0 * t)
    with pytest.warns(jd.DataWarning, match=r"differencing `x`.*about 15%") as caught:
        jd.Experiment.from_arrays(t, clean + 20e-6 * rng.standard_normal(t.size))
    assert [w.message.kind for w in caught] == ["noise"]
    assert caught[0].message.column == "v"
    with warnings.catch_warnings():
        warnings.simplefilter("error", jd.DataWarning)
        jd.Experiment.from_arrays(t, clean)
        jd.Experiment.from_arrays(t, 0.05 * t)  # a ramp: constant velocity, no noise
        jd.Experiment.from_arrays(t, clean + 2e-6 * rng.standard_normal(t.size))
        noisy = clean + 20e-6 * rng.standard_normal(t.size)
        jd.Experiment.from_arrays(t, noisy, v=np.gradient(clean, t))
