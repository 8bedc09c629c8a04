"""The README's tables of headline figures are written from the result files
(`benchmarks/_tables.py`), never typed: the writer's verdicts, its "not measured", its
insertion of blocks, and the README's agreement with `benchmarks/results/*.json`; and
`benchmarks/run_all.py`'s commands against the scripts' own options. No JAX."""

import json
import re
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
# The benchmarks import their helpers by module name, as their scripts do.
sys.path.insert(0, str(BENCHMARKS))

import _report  # noqa: E402
import _tables  # noqa: E402
import run_all  # noqa: E402
from _tables import Row, Table  # noqa: E402

SYNTHETIC = Table(
    "synthetic",
    "synthetic.py",
    (
        Row("speedup", "met", _tables.at_least(10, 28)),
        Row("ratio", "missed", _tables.at_most(1.5, 10)),
        Row("gain", "a strict goal at its bound", _tables.below(1, 28)),
        Row("coverage", "inside a range", _tables.between(0.90, 0.98, 25)),
        Row("coverage_low", "below a range", _tables.between(0.90, 0.98, 25)),
        Row("equal", "must be true", _tables.is_true(12)),
        Row("nested/value", "a nested figure, no goal"),
        Row(
            "spread", "a spread over seeds, judged by its mean", _tables.at_least(3, 28)
        ),
        Row("absent", "a key the file lacks", _tables.at_least(2, 28)),
        Row("absent_no_goal", "lacking, no goal"),
        Row("choice", "a text"),
        Row("per_seed", "a list, None where a seed has no value"),
    ),
)
FIGURES = {
    "speedup": 14.2,
    "ratio": 1.51,
    "gain": 1.0,
    "coverage": 0.95,
    "coverage_low": 0.896,
    "equal": True,
    "nested": {"value": 29108.4},
    "spread": {"mean": 2.5, "std": 0.25, "min": 2.2, "max": 2.8, "values": []},
    "choice": "shear_thinning_spencer",
    "per_seed": [None, 0.0123, 2.5e-7],
}


def cells(block: str) -> dict[str, list[str]]:
    """The table's rows by figure key: [measured, goal, met]."""
    out = {}
    for line in block.splitlines():
        if line.startswith("| `"):
            name, measured, goal, met = (c.strip() for c in line.strip("|").split("|"))
            out[name.split("`")[1]] = [measured, goal, met]
    return out


def test_render_met_missed_and_not_measured():
    rows = cells(_tables.render(SYNTHETIC, FIGURES, "results/synthetic.json"))
    assert rows["speedup"] == ["14.2", "≥ 10 (issue 28)", "met"]
    assert rows["ratio"] == ["1.51", "≤ 1.5 (issue 10)", "**not met**"]
    # "< 1" is strict: exactly 1 misses it.
    assert rows["gain"] == ["1.00", "< 1 (issue 28)", "**not met**"]
    assert rows["coverage"][2] == "met"
    assert rows["coverage_low"] == ["0.896", "0.9–0.98 (issue 25)", "**not met**"]
    assert rows["equal"] == ["yes", "yes (issue 12)", "met"]
    assert rows["nested/value"] == ["29 108", "", ""]
    assert rows["spread"] == [
        "2.50 ± 0.250 (2.20–2.80)",
        "≥ 3 (issue 28)",
        "**not met**",
    ]
    assert rows["absent"] == ["not measured", "≥ 2 (issue 28)", "–"]
    assert rows["absent_no_goal"] == ["not measured", "", ""]
    assert rows["choice"] == ["shear_thinning_spencer", "", ""]
    assert rows["per_seed"] == ["–, 0.0123, 2.5e-7", "", ""]
    # A met figure flips when it misses: the verdict is computed, not stored.
    missed = _tables.render(SYNTHETIC, FIGURES | {"speedup": 9.99}, "x")
    assert cells(missed)["speedup"][2] == "**not met**"


def test_render_without_a_file_and_the_machine_line():
    block = _tables.render(SYNTHETIC, None, "results/synthetic.json")
    assert {r[0] for r in cells(block).values()} == {"not measured"}
    assert "Not measured yet: no `results/synthetic.json`" in block
    machine = {
        "date": "2026-11-26T10:00:00+00:00",
        "cpu": "Some CPU",
        "cores": 2,
        "load_average_start": [0.25, 0.5, 0.5],
        "load_average_end": [0.75, 0.5, 0.5],
        "versions": {"jax": "0.10.2", "jaxlib": "0.10.2", "numpy": "2.3.0"},
        "git": {"commit": "0123456789abcdef", "changed": ["jaxmr/a.py"]},
    }
    block = _tables.render(SYNTHETIC, FIGURES | {"machine": machine}, "x")
    assert (
        "Measured 2026-11-26 on Some CPU (2 cores), load average (1 min) 0.250 → "
        "0.750; jax 0.10.2, jaxlib 0.10.2, numpy 2.3.0; commit 0123456789 with 1 "
        "changed files."
    ) in block
    quick = _tables.render(SYNTHETIC, FIGURES | {"quick": True}, "x")
    assert "not a measurement" in quick


def test_update_inserts_at_the_top_of_the_section_then_replaces():
    text = "# B\n\n## `synthetic.py`: a section\n\nProse.\n\n## `other.py`: next\n"
    second = Table("synthetic_2", "synthetic.py", ())
    tables = (*_tables.TABLES, SYNTHETIC, second)
    original = _tables.TABLES
    _tables.TABLES = tables
    try:
        once = _tables.update(text, {"synthetic": "ONE", "synthetic_2": "TWO"})
        assert once == (
            "# B\n\n## `synthetic.py`: a section\n\n"
            "<!-- figures:synthetic -->\nONE\n<!-- /figures:synthetic -->\n\n"
            "<!-- figures:synthetic_2 -->\nTWO\n<!-- /figures:synthetic_2 -->\n\n"
            "Prose.\n\n## `other.py`: next\n"
        )
        again = _tables.update(once, {"synthetic": "NEW", "synthetic_2": "TWO"})
        assert again == once.replace("\nONE\n", "\nNEW\n")
        assert (
            _tables.update(again, {"synthetic": "NEW", "synthetic_2": "TWO"}) == again
        )
        with pytest.raises(ValueError, match="no section"):
            _tables.update("# nothing here\n", {"synthetic": "ONE"})
    finally:
        _tables.TABLES = original


def test_readme_agrees_with_the_committed_results():
    # What `python benchmarks/_tables.py --check` checks: every block present, and
    # each exactly as its result file gives it. A number typed into a block, or a
    # result file committed without rewriting the tables, fails here.
    readme = _tables.README.read_text()
    for table in _tables.TABLES:
        assert f"<!-- figures:{table.name} -->" in readme, table.name
    assert _tables.update(readme, _tables.blocks()) == readme
    assert _tables.main(["--check"]) == 0


def test_check_fails_on_drift(tmp_path):
    results = tmp_path / "results"
    shutil.copytree(_tables.RESULTS, results, ignore=shutil.ignore_patterns("quick"))
    readme = tmp_path / "README.md"
    readme.write_text(_tables.README.read_text())
    args = ["--check", "--results", str(results), "--readme", str(readme)]
    assert _tables.main(args) == 0
    # A figure changed in its file: the README no longer agrees until rewritten.
    path = results / "calibration.json"
    figures = json.loads(path.read_text())
    figures["min_coverage"] = 0.5
    path.write_text(json.dumps(figures))
    assert _tables.main(args) == 1
    assert _tables.main(args[1:]) == 0  # rewrite
    assert "| 0.500 | 0.9–0.98 (issue 25) | **not met** |" in readme.read_text()
    assert _tables.main(args) == 0
    # A number typed into a block is drift too.
    text = readme.read_text()
    readme.write_text(text.replace("| 0.500 |", "| 0.950 |"))
    assert _tables.main(args) == 1


def test_run_all_commands_use_options_the_scripts_define():
    names = [b.name for b in run_all.BENCHMARKS]
    assert len(set(names)) == len(names)
    # Every benchmark run has its table and every table a benchmark that writes it.
    assert set(names) == {t.name for t in _tables.TABLES}
    for benchmark in run_all.BENCHMARKS:
        source = (BENCHMARKS / benchmark.script).read_text()
        defined = set(re.findall(r"add_argument\(\s*[\"'](--[a-z-]+)", source))
        assert "--json" in defined, benchmark.script
        for quick in (False, True):
            command = benchmark.command(run_all.ROOT / "results", quick)
            assert command[1] == f"benchmarks/{benchmark.script}"
            used = {a for a in command[2:] if a.startswith("--")}
            assert used <= defined, (benchmark.name, used - defined)
        quick = benchmark.command(run_all.ROOT / "results", True)
        assert ("--quick" in quick) == ("--quick" in defined)


def test_quick_results_never_overwrite_the_real_ones(tmp_path, capsys):
    assert run_all.main(["--list", "--quick"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert len(listed) == len(run_all.BENCHMARKS)
    for line in listed:
        assert re.search(r"--json benchmarks/results/quick/\w+\.json$", line), line
    with pytest.raises(SystemExit):
        run_all.main(["--only", "no_such_benchmark", "--list"])


def test_machine_block(tmp_path):
    path = tmp_path / "figures.json"
    _report.write_figures({"figure": 1.5, "machine": "x86_64, 2 cores"}, path)
    written = json.loads(path.read_text())
    assert written["figure"] == 1.5
    machine = written["machine"]
    assert machine["note"] == "x86_64, 2 cores"  # the script's own text is kept
    assert machine["cores"] >= 1 and machine["cpu"]
    assert len(machine["load_average_start"]) == len(machine["load_average_end"]) == 3
    assert set(machine["versions"]) >= {"jax", "jaxlib", "numpy", "scipy"}
    assert machine["versions"]["numpy"]  # installed: a version, not None
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT.*", machine["date"])
    assert re.fullmatch(r"[0-9a-f]{40}", machine["git"]["commit"])
    # A file written without one (a script that writes its own JSON) gets one.
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps({"cases": [1, 2]}))
    run_all._describe(bare, (0.1, 0.2, 0.3), 0.0, ["python", "x.py"])
    described = json.loads(bare.read_text())
    assert described["cases"] == [1, 2]
    assert described["machine"]["load_average_start"] == [0.1, 0.2, 0.3]
    assert described["machine"]["command"] == ["python", "x.py"]
