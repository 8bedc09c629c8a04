"""The processing comments of the canonical CSV and `jaxmr.data.convert_dataset`.

The conversions run on the real files in `../shared/data` (beside the repository);
missing data is a failure, not a skip. `write_csv` prints every number with `repr`
(Python's shortest form that reads back to the same float), so a converted file read
back must equal the loader's arrays exactly: the comparisons below have no tolerance.
"""

import os
from pathlib import Path

import numpy as np
import pytest

import jaxmr.data as jd
import jaxmr.data._convert as convert

from .helpers import shared_data


def _assert_same(a: jd.Experiment, b: jd.Experiment):
    for field in ("t", "x", "v", "current", "force"):
        fa, fb = getattr(a, field), getattr(b, field)
        assert (fa is None) == (fb is None), field
        if fa is not None:
            np.testing.assert_array_equal(np.asarray(fa), np.asarray(fb), err_msg=field)
    for field in ("name", "rotary", "drive", "velocity_source"):
        assert getattr(a, field) == getattr(b, field), field


def _experiment() -> jd.Experiment:
    t = np.arange(200) / 1000.0 + 0.1 / 3
    x = 0.01 * np.sin(2 * np.pi * 2.0 * t)
    return jd.Experiment.from_arrays(t, x, current=0.5, force=1e4 * x, name="e")


def _no_leftovers(folder: Path):
    hidden = [p.name for p in folder.iterdir() if p.name.startswith(".")]
    assert hidden == [], f"temporary files left in {folder}: {hidden}"


# ---------------------------------------------------------------------------------------
# Processing comments


def test_processing_round_trip(tmp_path):
    e = _experiment()
    path = tmp_path / "e.csv"
    jd.write_csv(
        e, path, comment="lab: test", smoothing=0.1 / 3, discard=np.float64(0.1)
    )
    text = path.read_text()
    assert f"# smoothing: {0.1 / 3!r} s\n# discard: 0.1 s\n# lab: test\n" in text
    assert jd.read_processing(path) == {"smoothing": 0.1 / 3, "discard": 0.1}
    _assert_same(e, jd.read_csv(path))  # read_csv ignores the new lines

    jd.write_csv(e, path, discard=0.0)
    assert "smoothing" not in path.read_text()
    assert jd.read_processing(path) == {"smoothing": None, "discard": 0.0}
    jd.write_csv(e, path)
    assert jd.read_processing(path) == {"smoothing": None, "discard": None}

    # Hand-written forms: any case of the key, no space before the unit, comment lines
    # anywhere (here after the data), a repeated line that agrees.
    lines = path.read_text().splitlines()
    lines.insert(3, "#Smoothing:0.05s")
    lines += ["# discard: 1e-1 s", "  # discard: 0.1 s"]
    path.write_text("\n".join(lines) + "\n")
    assert jd.read_processing(path) == {"smoothing": 0.05, "discard": 0.1}
    _assert_same(e, jd.read_csv(path))


@pytest.mark.parametrize(
    "line, match",
    [
        ("# smoothing: 0.1", r"cannot read '0.1' as the smoothing width"),
        ("# smoothing: 20 ms", r"cannot read '20 ms' as the smoothing width"),
        ("# smoothing: 20ms", r"cannot read '20ms'"),
        ("# discard: one s", r"cannot read 'one s' as the discard duration"),
        ("# discard: -1 s", r"cannot read '-1 s'"),
        ("# discard: nan s", r"cannot read 'nan s'"),
        ("# DISCARD: inf s", r"cannot read 'inf s'"),
        ("# discard:", r"cannot read '' as the discard duration"),
    ],
)
def test_read_processing_rejects_malformed_values(tmp_path, line, match):
    path = tmp_path / "bad.csv"
    jd.write_csv(_experiment(), path)
    lines = path.read_text().splitlines()
    lines.insert(2, line)
    path.write_text("\n".join(lines) + "\n")
    key = "smoothing" if "smoothing" in line else "discard"
    form = "<width> s" if key == "smoothing" else "<duration> s"
    with pytest.raises(ValueError, match=match) as info:
        jd.read_processing(path)
    message = str(info.value)
    assert message.startswith(f"{path}: line 3: ")
    assert f"expected `# {key}: {form}`" in message
    with pytest.raises(ValueError, match=match):  # it reads them into the experiment
        jd.read_csv(path)


def test_read_processing_rejects_contradicting_lines(tmp_path):
    path = tmp_path / "twice.csv"
    jd.write_csv(_experiment(), path, smoothing=0.1)
    path.write_text(path.read_text() + "# smoothing: 0.2 s\n")
    # Comment lines 1-5 (smoothing on 5), the column header 6, 200 rows, then line 207.
    with pytest.raises(ValueError, match=r"line 207: a second `# smoothing:` line "):
        jd.read_processing(path)
    with pytest.raises(ValueError, match=r"contradicts line 5 \(0.1 s\)"):
        jd.read_processing(path)


@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf")])
def test_write_csv_rejects_bad_processing(tmp_path, value):
    with pytest.raises(ValueError, match=r"`discard` must be a finite duration >= 0"):
        jd.write_csv(_experiment(), tmp_path / "e.csv", discard=value)
    with pytest.raises(ValueError, match=r"`smoothing` must be a finite width >= 0"):
        jd.write_csv(_experiment(), tmp_path / "e.csv", smoothing=value)
    assert not (tmp_path / "e.csv").exists()


# ---------------------------------------------------------------------------------------
# convert_dataset


@pytest.fixture(scope="module")
def utfsm(tmp_path_factory):
    """The UTFSM folder converted once (loading the 30 files takes about 2 s)."""
    out = tmp_path_factory.mktemp("utfsm") / "new" / "folder"  # created by the call
    source = shared_data("utfsm_mr_damper", "sine")
    paths = jd.convert_dataset("utfsm", source, out)
    return source, out, paths


def test_datasets():
    assert jd.DATASETS == ("utfsm", "nees", "boucwen")


def test_convert_utfsm(utfsm):
    source, out, paths = utfsm
    experiments = jd.load_utfsm(source)
    assert len(paths) == 30
    assert paths == [out / f"{e.name}.csv" for e in experiments]  # the loader's order
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in paths)
    _no_leftovers(out)
    smoothing, discard = (
        jd.utfsm_smoothing(experiments),
        jd.utfsm_first_cycle(experiments),
    )
    for k, path in enumerate(paths):
        processing = jd.read_processing(path)
        assert processing == {"smoothing": smoothing[k], "discard": discard[k]}, path
    by_name = dict(zip((e.name for e in experiments), paths))
    assert jd.read_processing(by_name["10mm1Hz0x5A"]) == {
        "smoothing": 0.1,
        "discard": 1.0,
    }
    assert jd.read_processing(by_name["25mm0x1Hz1A"]) == {
        "smoothing": 1.0,
        "discard": 10.0,
    }
    # Exactly the loader's data: a 1 ms file and a 5 ms one.
    for e in experiments:
        if e.name in ("10mm1Hz0x5A", "2mm5Hz0x25A"):
            _assert_same(e, jd.read_csv(by_name[e.name]))
    text = by_name["10mm1Hz0x5A"].read_text(encoding="utf-8")
    assert "# dataset: utfsm," in text
    # The converter records the resolved path (the data folder may be a symlink).
    assert f"# source: {(source / '10mm1Hz0x5A.txt').resolve()}\n" in text
    assert "DanielMaurelE/vRTHS_AMBC_MRdamper" in text


def test_convert_refuses_to_overwrite(utfsm, tmp_path):
    source, out, paths = utfsm
    before = {p: p.stat().st_mtime_ns for p in paths}
    with pytest.raises(FileExistsError, match=r"30 of the 30 output file\(s\)") as info:
        jd.convert_dataset("utfsm", source, out)
    assert repr(str(paths[0])) in str(info.value)
    assert "force=True (CLI: --force)" in str(info.value)
    assert {p: p.stat().st_mtime_ns for p in paths} == before

    # One existing target is enough, and it is found before anything is written.
    (tmp_path / "2mm5Hz0A.csv").write_text("mine\n")
    with pytest.raises(FileExistsError, match=r"1 of the 30 .*2mm5Hz0A.csv'\. Nothing"):
        jd.convert_dataset("utfsm", source, tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["2mm5Hz0A.csv"]
    assert (tmp_path / "2mm5Hz0A.csv").read_text() == "mine\n"


def test_convert_nees(tmp_path):
    source = shared_data("nees_dyke_mr_damper", "ranran_50.csv")
    (path,) = jd.convert_dataset("nees", source, tmp_path)
    assert path == tmp_path / "ranran_50.csv"
    e = jd.load_nees(source, trim=True)
    back = jd.read_csv(path)
    assert len(back) == len(e) == 64200
    _assert_same(e, back)
    assert back.drive == "voltage"
    assert jd.read_processing(path) == {"smoothing": None, "discard": 0.2}
    text = path.read_text(encoding="utf-8")
    assert "# dataset: nees," in text and "DOI 10.4231/D3V11VM6X" in text
    assert f"# source: {source.resolve()}\n" in text

    # Overwriting only with force; the new file replaces the old one whole.
    path.write_text("old\n")
    with pytest.raises(FileExistsError, match="ranran_50.csv"):
        jd.convert_dataset("nees", source, tmp_path)
    assert path.read_text() == "old\n"
    assert jd.convert_dataset("nees", source, tmp_path, force=True) == [path]
    assert len(jd.read_csv(path)) == len(e)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ranran_50.csv"]


def test_convert_writes_atomically(tmp_path, monkeypatch):
    # A failure while writing leaves neither a partial target nor the temporary file.
    def failing(experiment, path, **kwargs):
        Path(path).write_text("t,x,v,u,F\n0.0,")
        raise OSError("disk full")

    monkeypatch.setattr(convert, "write_csv", failing)
    source = shared_data("nees_dyke_mr_damper", "ranran_50.csv")
    with pytest.raises(OSError, match="disk full"):
        jd.convert_dataset("nees", source, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_convert_boucwen_writes_a_system_record(tmp_path):
    source = shared_data("boucwen_benchmark", "train.h5")
    (path,) = jd.convert_dataset("boucwen", source, tmp_path)
    assert path.name == "boucwen_benchmark_train.csv"
    text = path.read_text(encoding="utf-8")
    assert text.startswith("# jaxmr system record")
    assert "not a damper experiment" in text and "DOI 10.4121/12967592" in text
    # The header's own recipe reads it back exactly.
    skip = int(text.split("skiprows=")[1].split(")")[0])
    assert text.splitlines()[skip - 1] == "t,u,y"
    t, u, y = np.loadtxt(path, delimiter=",", skiprows=skip, unpack=True)
    record = jd.load_boucwen_benchmark_train(source)
    for name, a, b in (("t", t, record.t), ("u", u, record.u), ("y", y, record.y)):
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert jd.read_processing(path) == {"smoothing": None, "discard": None}
    with pytest.raises(ValueError, match=r"a system record \(columns t, u, y"):
        jd.read_csv(path)


def test_convert_rejects_bad_arguments(tmp_path):
    utfsm = shared_data("utfsm_mr_damper", "sine")
    with pytest.raises(ValueError, match=r"unknown dataset 'UTFSM'; .*'utfsm', 'nees'"):
        jd.convert_dataset("UTFSM", utfsm, tmp_path)
    with pytest.raises(
        ValueError, match=r"does not exist; pass the file ranran_50.csv"
    ):
        jd.convert_dataset("nees", tmp_path / "missing.csv", tmp_path / "out")
    with pytest.raises(ValueError, match=r"is not a folder; pass the folder"):
        jd.convert_dataset("utfsm", utfsm / "10mm1Hz0A.txt", tmp_path / "out")
    with pytest.raises(ValueError, match=r"no file named <amplitude>mm"):
        jd.convert_dataset("utfsm", tmp_path, tmp_path / "out")
    nees = shared_data("nees_dyke_mr_damper")
    with pytest.raises(ValueError, match=r"is a folder; .*did you mean .*ranran_50"):
        jd.convert_dataset("nees", nees, tmp_path / "out")
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match=r"output folder .* is a file"):
        jd.convert_dataset("nees", nees / "ranran_50.csv", tmp_path / "file")
    # Never over its own source, even with force (a stand-in file: refused unread).
    own = tmp_path / "ranran_50.csv"
    own.write_text("source\n")
    with pytest.raises(ValueError, match=r"would replace the source file"):
        jd.convert_dataset("nees", own, tmp_path, force=True)
    assert own.read_text() == "source\n"
    assert not (tmp_path / "out").exists()
    _no_leftovers(tmp_path)
    assert sorted(os.listdir(tmp_path)) == ["file", "ranran_50.csv"]  # nothing new


def test_convert_command(tmp_path, capsys):
    """`jaxmr convert`: the files of `convert_dataset`, said as written; an existing
    file is refused (exit 1, unchanged) and replaced only with --force, which says so."""
    from jaxmr._cli import main

    source = shared_data("nees_dyke_mr_damper", "ranran_50.csv")
    out = tmp_path / "out"
    assert main(["convert", "nees", source, "--out", out]) == 0
    path = out / "ranran_50.csv"
    assert f"wrote {path}\n1 file(s) in {out}" in capsys.readouterr().out
    path.write_text("old\n")
    assert main(["convert", "nees", source, "--out", out]) == 1
    assert "already exist" in capsys.readouterr().err
    assert path.read_text() == "old\n"
    assert main(["convert", "nees", source, "--out", out, "--force"]) == 0
    assert f"wrote {path} (replaced the existing file)" in capsys.readouterr().out
    assert len(jd.read_csv(path)) == len(jd.load_nees(source, trim=True))
    _no_leftovers(out)
