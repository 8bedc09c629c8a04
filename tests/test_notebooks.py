"""Every example notebook executes without error.

The notebooks run in a separate kernel process (so this file's float64 and strict
promotion settings do not reach them: each notebook enables float64 itself), against
this checkout of jaxmr."""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from tests.xla_flags import FAST_COMPILE_VARIABLE, without_fast_compile_flags

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
RUN_LONGER_THAN_THEY_COMPILE = ("02_",)


def test_notebooks_found():
    assert NOTEBOOKS, f"no notebooks found in {ROOT / 'notebooks'}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes(path, monkeypatch):
    # The kernel imports this checkout's jaxmr whether or not it is installed.
    monkeypatch.setenv(
        "PYTHONPATH",
        os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
    )
    if path.name.startswith(RUN_LONGER_THAN_THEY_COMPILE):
        # Its fits take longer under the suite's fast compilation (tests/xla_flags.py):
        # its cells 143 s instead of 85 s (2026-11-28, a 2.5 GHz Xeon, alone). Notebook
        # 06 compiles more than it runs there: 66 s instead of 86 s with it; the
        # other notebooks gained 0-5 s each (measured earlier).
        flags = without_fast_compile_flags(os.environ.get("XLA_FLAGS", ""))
        monkeypatch.setenv("XLA_FLAGS", flags)
        monkeypatch.delenv(FAST_COMPILE_VARIABLE, raising=False)
    notebook = nbformat.read(path, as_version=4)
    # "python3" is ipykernel's built-in kernel: jupyter_client resolves it to the
    # interpreter running this test (`sys.executable`) even where no kernelspec was
    # installed, e.g. in a virtual environment that is not activated.
    client = NotebookClient(
        notebook,
        kernel_name="python3",
        timeout=600,
        resources={"metadata": {"path": str(path.parent)}},
    )
    client.execute()  # raises CellExecutionError on the first failing cell
