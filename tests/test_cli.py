"""The `jaxmr` command line, run in-process: `jaxmr demo` writes its figures and table,
and the numbers in the table behave physically."""

import contextlib
import csv
import io

import numpy as np
import pytest

import jaxmr
from jaxmr._cli import DEMO_AMPLITUDE_DEG, DEMO_CURRENTS, main

FIGURES = (
    "torque_angle.png",
    "torque_velocity.png",
    "torque_time.png",
    "energy_vs_current.png",
)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """One run of `jaxmr demo` shared by the tests below (it is the slow part)."""
    out = tmp_path_factory.mktemp("demo") / "out"  # a directory the demo must create
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        status = main(["demo", "--out", out])  # a Path is accepted in argv
    return status, out, stdout.getvalue()


def _summary(out):
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return {key: np.array([float(r[key]) for r in rows]) for key in rows[0]}


def test_demo_writes_files(demo):
    status, out, stdout = demo
    assert status == 0
    for name in FIGURES + ("summary.csv", "summary.md"):
        assert (out / name).is_file(), name
        assert f"wrote {out / name}" in stdout
    assert stdout.startswith(f"simulating {len(DEMO_CURRENTS)} currents")


def test_demo_figures_are_png(demo):
    import matplotlib.image

    _, out, _ = demo
    for name in FIGURES:
        data = (out / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE), name
        image = matplotlib.image.imread(out / name)
        assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
        assert np.ptp(image) > 0, f"{name} is blank"


def test_demo_table(demo):
    _, out, stdout = demo
    table = _summary(out)
    assert list(table) == ["current_A", "peak_torque_Nm", "energy_J"]
    np.testing.assert_allclose(table["current_A"], DEMO_CURRENTS)
    peak, energy = table["peak_torque_Nm"], table["energy_J"]
    assert peak.shape == (5,) and np.all(np.diff(peak) > 0)
    assert np.all(energy >= 0) and np.all(np.diff(energy) > 0)
    # The loop fits in the box of ±peak torque × ±amplitude: its area is at most that.
    box = 4 * peak * np.deg2rad(DEMO_AMPLITUDE_DEG)
    assert np.all(energy <= box)
    # At 0 A the torque saturates at α_a z0 = 1 N·m × (843/738)^(1/0.9), plus a
    # viscous C0a·θ̇ of under 1e-3 N·m.
    z0 = (843.0 / 738.0) ** (1 / 0.9)
    np.testing.assert_allclose(peak[0], z0, atol=1e-3)

    markdown = (out / "summary.md").read_text(encoding="utf-8").splitlines()
    assert len(markdown) == 2 + 5 and markdown[0].startswith("| current [A]")
    for line in markdown:
        assert line in stdout  # the table is printed too


def test_demo_does_not_replace_its_files_without_force(demo, capsys):
    """A second `jaxmr demo` into the same directory stops before simulating: its
    files are there already, and only --force replaces them."""
    _, out, _ = demo
    names = FIGURES + ("summary.csv", "summary.md")
    before = {name: (out / name).read_bytes() for name in names}
    assert main(["demo", "--out", out]) == 1
    captured = capsys.readouterr()
    assert "already exist: pass --force to replace" in captured.err
    assert "simulating" not in captured.out
    assert {name: (out / name).read_bytes() for name in names} == before
    assert sorted(p.name for p in out.iterdir()) == sorted(names)


def test_demo_unwritable_directory(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    assert main(["demo", "--out", str(blocker / "out")]) == 1
    err = capsys.readouterr().err
    assert "jaxmr demo: error: cannot write to the output directory" in err
    assert main(["demo", "--out", str(blocker)]) == 1
    assert "exists and is not a directory" in capsys.readouterr().err


def test_version_and_usage(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"jaxmr {jaxmr.__version__}"
    with pytest.raises(SystemExit) as exit_info:
        main([])  # a command is required
    assert exit_info.value.code == 2
