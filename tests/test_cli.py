"""The `jaxmr` command line, run in-process: `jaxmr demo` writes its figures and table,
and the numbers in the table behave physically."""

import ast
import contextlib
import csv
import importlib.util
import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxmr
import jaxmr.data
import jaxmr.plot
import jaxmr.templates
from jaxmr._cli import main
from jaxmr._cli.demo import DEMO_CURRENTS, DEVICES, demo_files

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _run_demo(out, *options):
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        status = main(["demo", "--out", out, *options])  # a Path is accepted in argv
    return status, out, stdout.getvalue()


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """One run of `jaxmr demo` (the linear damper) shared by the tests below (it is
    the slow part)."""
    # A directory the demo must create.
    return _run_demo(tmp_path_factory.mktemp("demo") / "out")


@pytest.fixture(scope="module")
def brake_demo(tmp_path_factory):
    """One run of `jaxmr demo --device brake`."""
    return _run_demo(tmp_path_factory.mktemp("demo") / "out", "--device", "brake")


def _summary(out):
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return {key: np.array([float(r[key]) for r in rows]) for key in rows[0]}


@pytest.mark.parametrize("device", ["damper", "brake"])
def test_demo_writes_files(device, demo, brake_demo):
    status, out, stdout = demo if device == "damper" else brake_demo
    assert status == 0
    figures, files = demo_files(device)
    assert len(figures) == 3
    for name in files:
        assert (out / name).is_file(), name
        assert f"wrote {out / name}" in stdout
    assert sorted(p.name for p in out.iterdir()) == sorted(files)
    assert stdout.startswith(f"simulating {len(DEMO_CURRENTS)} currents")


def test_demo_figures_are_png(demo):
    import matplotlib.image

    _, out, _ = demo
    figures, _ = demo_files("damper")
    for name in [name for name, _ in figures] + ["energy_vs_current.png"]:
        data = (out / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE), name
        image = matplotlib.image.imread(out / name)
        assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
        assert np.ptp(image) > 0, f"{name} is blank"


def test_demo_table_shows_the_field_effect(demo):
    """The default demo is the linear damper: its force and energy per cycle grow
    several-fold from 0 to 1 A."""
    _, out, stdout = demo
    table = _summary(out)
    assert list(table) == ["current_A", "peak_force_N", "energy_J"]
    np.testing.assert_allclose(table["current_A"], DEMO_CURRENTS)
    peak, energy = table["peak_force_N"], table["energy_J"]
    assert peak.shape == (5,) and np.all(np.diff(peak) > 0)
    assert np.all(energy >= 0) and np.all(np.diff(energy) > 0)
    assert peak[-1] > 5 * peak[0] and energy[-1] > 5 * energy[0]
    device = DEVICES["damper"]
    # The loop fits in the box of ±peak force × ±amplitude: its area is at most that.
    assert np.all(energy <= 4 * peak * device.amplitude)
    # At the middle of the stroke the velocity peaks at X ω and z has saturated at
    # z0 = A/(β + γ): the force is α z0 + c0 X ω (the preset's laws), within 1 % (the
    # peak of the last cycle is a little past mid-stroke, where z still grows).
    law = jaxmr.passenger_car_mr_damper().hysteresis
    assert isinstance(law, jaxmr.BoucWen)
    velocity = device.amplitude * 2 * np.pi * device.frequency
    for current, measured in zip(DEMO_CURRENTS, peak):
        at = law.at(current)
        assert isinstance(at, jaxmr.BoucWen)
        z0 = float(at.A) / (float(at.beta) + float(at.gamma))
        expected = float(at.alpha) * z0 + float(at.c0) * velocity
        np.testing.assert_allclose(measured, expected, rtol=0.01)

    markdown = (out / "summary.md").read_text(encoding="utf-8").splitlines()
    assert len(markdown) == 2 + 5 and markdown[0].startswith("| current [A]")
    for line in markdown:
        assert line in stdout  # the table is printed too
    assert f"×{energy[-1] / energy[0]:.3g}" in stdout


def test_the_brake_demo_table(brake_demo):
    _, out, stdout = brake_demo
    table = _summary(out)
    assert list(table) == ["current_A", "peak_torque_Nm", "energy_J"]
    peak, energy = table["peak_torque_Nm"], table["energy_J"]
    assert np.all(np.diff(peak) > 0) and np.all(np.diff(energy) > 0)
    # The loop fits in the box of ±peak torque × ±amplitude: its area is at most that.
    assert np.all(energy <= 4 * peak * DEVICES["brake"].amplitude)
    # At 0 A the torque saturates at α_a z0 = 1 N·m × (843/738)^(1/0.9), plus a
    # viscous C0a·θ̇ of under 1e-3 N·m.
    z0 = (843.0 / 738.0) ** (1 / 0.9)
    np.testing.assert_allclose(peak[0], z0, atol=1e-3)


def test_demo_does_not_replace_its_files_without_force(demo, capsys):
    """A second `jaxmr demo` into the same directory stops before simulating: its
    files are there already, and only --force replaces them."""
    _, out, _ = demo
    _, names = demo_files("damper")
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


def test_the_brake_demo_says_why_its_loops_grow_so_little(brake_demo, capsys):
    """The printed growth of the brake's energy per cycle from 0 to 1 A is the
    table's, and the help gives the same round figure and its cause (the published
    law)."""
    _, out, stdout = brake_demo
    energy = _summary(out)["energy_J"]
    growth = energy[-1] / energy[0] - 1
    assert f"{growth:+.1%}" in stdout
    assert "published law" in stdout and "energy axis starts at 0" in stdout
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert f"about {100 * growth:.0f} % from 0 to 1 A" in help_text
    assert "published law" in help_text and "alpha = 1 + 0.07 i" in help_text
    assert "--device brake" in help_text


# ---------------------------------------------------------------------------------------
# Figures


def test_energy_axis_starts_at_zero():
    # The SAS brake's energies: 9 % apart. An axis from the smallest value made the
    # change fill the figure.
    ax = jaxmr.plot.energy_vs_current([0.0, 0.5, 1.0], [0.2425, 0.2536, 0.2646])
    bottom, top = ax.get_ylim()
    assert bottom == 0.0 and top >= 0.2646
    ax.figure.clf()


def test_energy_of_a_sweep_over_devices_is_one_line_per_device():
    """Rows are devices, columns currents: one line per device against the currents
    (matplotlib alone draws the columns of a 2-D y, the wrong axis); a count that
    does not match the currents is named."""
    energies = np.array([[0.1, 0.2, 0.25], [0.3, 0.5, 0.6]])
    ax = jaxmr.plot.energy_vs_current([0.0, 0.5, 1.0], energies)
    lines = [line.get_ydata().tolist() for line in ax.get_lines()]
    assert lines == energies.tolist()
    ax.figure.clf()
    with pytest.raises(ValueError, match="one value per current"):
        jaxmr.plot.energy_vs_current([0.0, 1.0], energies)


def test_loop_legend_outside_the_axes():
    solution = jaxmr.sweep(
        jaxmr.sas_brake_dahl(),
        jaxmr.Sine(0.06, 1.0),
        np.array([0.0, 6.0]),
        np.linspace(0.0, 1.0, 101),
        integrator=jaxmr.FixedStep(),
    )
    ax = jaxmr.plot.loop(solution, "velocity", labels=["0 A", "6 A"], legend="outside")
    ax.figure.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    assert legend.x0 >= ax.get_window_extent().x1  # right of the axes, over no curve
    ax = jaxmr.plot.loop(solution, labels=["0 A", "6 A"], legend=False)
    assert ax.get_legend() is None
    ax.figure.clf()


# ---------------------------------------------------------------------------------------
# Start-up: `jaxmr --help` and `import jaxmr` do not import JAX

# Run in a fresh interpreter: this test process imported JAX long ago.
_HELP_PROCESS = """
import sys
from jaxmr._cli import main

for command in ([], ["demo"], ["fit"], ["predict"], ["report"], ["convert"], ["design"]):
    try:
        main([*command, "--help"])
    except SystemExit as e:
        assert e.code == 0, (command, e.code)
heavy = sorted(m for m in ("jax", "jaxlib", "equinox", "diffrax", "matplotlib") if m in sys.modules)
print("imported:", heavy)
"""


def test_help_does_not_import_jax():
    done = subprocess.run(
        [sys.executable, "-c", _HELP_PROCESS],
        capture_output=True,
        text=True,
        cwd=Path(__file__).parents[1],
    )
    assert done.returncode == 0, done.stderr
    # Every command's help was printed, and none of the heavy packages imported.
    assert done.stdout.count("usage: jaxmr") == 7
    assert done.stdout.strip().endswith("imported: []"), done.stdout[-300:]


def test_help_names_agree_with_the_package():
    """The command line's own lists of the model templates and datasets (it cannot
    import them for --help without JAX) are the package's."""
    from jaxmr._cli.convert import DATASET_NAMES
    from jaxmr._cli.fit import AUTO_STARTS, TEMPLATE_NAMES
    from jaxmr._identify import select

    assert TEMPLATE_NAMES == tuple(jaxmr.templates.MODEL_TEMPLATES)
    assert DATASET_NAMES == jaxmr.data.DATASETS
    assert AUTO_STARTS == select.AUTO_STARTS


def test_public_names_are_imported_on_first_use():
    """`jaxmr/__init__.py` imports its public names lazily: every name of `__all__`
    resolves, `dir` lists them, and after the first use `vars(jaxmr)` holds them all
    (but the deprecated aliases, which warn at every use: tests/test_imports.py)."""
    names = jaxmr.__all__
    assert len(names) > 100 and "simulate" in names and "BoucWen" in names
    assert set(names) <= set(dir(jaxmr))
    for name in names:
        assert getattr(jaxmr, name) is not None, name
    assert set(names) <= set(vars(jaxmr))
    assert jaxmr.data.read_csv is not None and jaxmr.plot.loop is not None
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        _ = jaxmr.not_a_name


# ---------------------------------------------------------------------------------------
# The command line is a user of the public API

# (module of jaxmr/_cli, name) of a private import the command line still needs, each
# with why, to be removed; an entry no longer needed fails the test too, so that the
# list only shrinks. Empty: the command line uses the public API only.
KNOWN_PRIVATE_IMPORTS: set[tuple[str, str]] = set()


def _cli_sources() -> list[Path]:
    spec = importlib.util.find_spec("jaxmr._cli")
    assert spec is not None and spec.origin is not None
    if spec.submodule_search_locations:  # the package: every module in it
        return sorted(Path(spec.submodule_search_locations[0]).glob("*.py"))
    return [Path(spec.origin)]


def _private_imports(path: Path, package: str) -> set[str]:
    """The names from jaxmr's private modules (a component after `jaxmr` starting
    with `_`, outside the command line's own `jaxmr._cli`) that the module at `path`,
    in `package`, imports."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, one level up per extra dot
                parts = package.split(".")
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            names = [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            if name.split(".")[0] != "jaxmr" or name.startswith("jaxmr._cli."):
                continue
            if any(part.startswith("_") for part in name.split(".")[1:]):
                found.add(name)
    return found


def test_cli_imports_no_private_jaxmr_module():
    """Every module of `jaxmr._cli` imports jaxmr's public API only (`jaxmr`,
    `jaxmr.data`, `jaxmr.templates`, `jaxmr.plot`), except the listed exceptions."""
    sources = _cli_sources()
    package = "jaxmr._cli" if sources[0].parent.name == "_cli" else "jaxmr"
    found = {
        (path.name, name)
        for path in sources
        for name in _private_imports(path, package)
    }
    assert found - KNOWN_PRIVATE_IMPORTS == set()
    assert KNOWN_PRIVATE_IMPORTS - found == set(), "no longer imported: drop it"
    assert {p.name for p in sources} >= {"files.py", "fit.py", "design.py"}


def test_plots_name_the_wrong_object():
    """The plots take different objects (a Solution, an Experiment and a force, a
    PredictionBand): given another, the error names the argument and what to give
    (it had been an AttributeError from inside the drawing), and one label given as
    a string is not read as one label per character."""
    import jaxmr.data

    t = np.linspace(0.0, 1.0, 50)
    run = jaxmr.data.Experiment.from_arrays(
        t, 0.01 * np.sin(6 * t), force=np.cos(6 * t)
    )
    with pytest.raises(
        TypeError, match="`solution` must be a Solution .* got Experiment"
    ):
        jaxmr.plot.loop(run)
    with pytest.raises(TypeError, match="`experiment` must be a jaxmr.data.Experiment"):
        jaxmr.plot.measured_vs_predicted(np.cos(6 * t), run)
    with pytest.raises(TypeError, match="`band` must be a jaxmr.PredictionBand"):
        jaxmr.plot.prediction_band(run)
    solution = jaxmr.simulate(
        jaxmr.Dahl(k_x=1.0, k_w=10.0, rho=100.0), jaxmr.Sine(0.01, 1.0), 0.0, t
    )
    with pytest.raises(TypeError, match="one label per run"):
        jaxmr.plot.loop(solution, labels="abc")
    ax = jaxmr.plot.loop(solution, labels=["abc"])
    assert [text.get_text() for text in ax.get_legend().get_texts()] == ["abc"]
    ax.figure.clf()
