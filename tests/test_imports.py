"""jaxmr's imports: the import graph has no cycle, and the names that left the top level
still resolve there, with a warning, to their new place.

The layers themselves (command line > public API > identification and tuning > closed
loop > simulation > models and data > helpers) are import-linter contracts in
pyproject.toml, checked by `lint-imports` in CI; import-linter cannot say "acyclic", so
this test does. The graph is read from the sources with `ast` (nothing is imported):
every import counts, at module level, in a function or under `TYPE_CHECKING`, and
importing `a.b.c` also runs the packages `a.b`'s `__init__` (Python's semantics), so a
cycle through a package's `__init__` is a cycle too. The package root is the exception:
it imports its public names lazily and every submodule's import runs it, so only an
explicit import of the root (`import jaxmr`, `from jaxmr import x`) is an edge to it.
"""

import ast
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "jaxmr"


def modules(package: Path) -> dict[str, Path]:
    """Dotted name -> file, for every module of the package at `package`."""
    found = {}
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def _imported(node, module: str, is_package: bool, known) -> set[str]:
    """The modules of `known` that one import statement of `module` names."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        if node.level:
            base = module.split(".")
            # A package's `from . import x` is relative to itself, a module's to its
            # package.
            base = base[: len(base) - node.level + (1 if is_package else 0)]
            stem = ".".join(base + ([node.module] if node.module else []))
        else:
            stem = node.module or ""
        # `from a import b`: the submodule `a.b` where there is one, else `a`.
        names = [
            f"{stem}.{a.name}" if f"{stem}.{a.name}" in known else stem
            for a in node.names
        ]
    out = set()
    for name in names:
        while name and name not in known:  # `import a.b.func`-like: the module
            name = name.rpartition(".")[0]
        if name:
            out.add(name)
    return out


def graph(package: Path) -> dict[str, set[str]]:
    """module -> the modules its import statements run (see the module docstring)."""
    known = modules(package)
    root = package.name  # imported lazily by the root: see the module docstring
    edges: dict[str, set[str]] = {name: set() for name in known}
    for name, path in known.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        is_package = path.name == "__init__.py"
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            for target in _imported(node, name, is_package, known):
                # The target and the packages above it, down from the root's child.
                parts = target.split(".")
                for k in range(1, len(parts) + 1):
                    runs = ".".join(parts[:k])
                    # A module's own packages are already running when it runs; an
                    # explicit import of a package is an edge all the same.
                    implied = runs == root or name.startswith(runs + ".")
                    if runs != name and (runs == target or not implied):
                        edges[name].add(runs)
    return edges


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph as a list of modules (first = last), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(edges):
        if start not in state:
            found = visit(start)
            if found:
                return found
    return None


def test_jaxmr_has_no_import_cycle():
    edges = graph(ROOT)
    # The reader sees the package: a module's import, and the package `__init__` that
    # an import of one of its modules runs.
    assert "jaxmr._misc" in edges["jaxmr._simulate"]
    assert {"jaxmr._systems", "jaxmr._systems.base"} <= edges["jaxmr._closed_loop"]
    cycle = find_cycle(edges)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def _write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    return root / "pkg"


def test_the_reader_finds_cycles_through_functions_and_package_inits(tmp_path):
    # A function-level import that closes a loop through a package's __init__: the
    # shape of the loop that `free_decay` made (systems -> closed loop -> systems).
    package = _write(
        tmp_path,
        {
            "pkg/__init__.py": "from typing import TYPE_CHECKING\n"
            "if TYPE_CHECKING:\n    from ._loop import run as run\n",
            "pkg/_loop.py": "from ._systems.base import System\n",
            "pkg/_systems/__init__.py": "from .rig import Rig\n",
            "pkg/_systems/base.py": "class System: ...\n",
            "pkg/_systems/rig.py": "def decay():\n    from .._loop import run\n",
        },
    )
    cycle = find_cycle(graph(package))
    assert cycle is not None and {"pkg._loop", "pkg._systems"} <= set(cycle), cycle
    # The same package without the function's import has none.
    (package / "_systems" / "rig.py").write_text("def decay(): ...\n")
    assert find_cycle(graph(package)) is None


def test_the_reader_counts_explicit_imports_of_the_root(tmp_path):
    # `import pkg` from a module the root imports (lazily) is a cycle; an import of a
    # sibling, which also runs the root's __init__, is not.
    package = _write(
        tmp_path,
        {
            "pkg/__init__.py": "from typing import TYPE_CHECKING\n"
            "if TYPE_CHECKING:\n    from ._save import save as save\n",
            "pkg/_save.py": "from . import _misc\n\ndef save():\n    import pkg\n",
            "pkg/_misc.py": "X = 1\n",
        },
    )
    assert find_cycle(graph(package)) == ["pkg", "pkg._save", "pkg"]
    (package / "_save.py").write_text("from . import _misc\n")
    assert find_cycle(graph(package)) is None


# ---------------------------------------------------------------------------------------
# The namespace: moved names are deprecated aliases for one release


def test_moved_names_warn_name_their_new_place_and_are_in_the_changelog():
    import jaxmr

    moved = jaxmr._MOVED
    assert moved, "no moved names: drop the aliases' machinery with the last of them"
    changelog = (ROOT.parent / "CHANGELOG.md").read_text(encoding="utf-8")
    for name, module in moved.items():
        new_place = f"jaxmr.{module}.{name}"
        with pytest.warns(DeprecationWarning, match=re.escape(f"use `{new_place}`")):
            old = getattr(jaxmr, name)
        home = importlib.import_module(f"jaxmr.{module}")
        assert old is getattr(home, name) and name in home.__all__
        # Not a public top-level name any more, and never cached: every use warns.
        assert name not in jaxmr.__all__ and name not in vars(jaxmr)
        assert f"| `jaxmr.{name}` | `{new_place}` |" in changelog, name
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        _ = jaxmr.not_a_name


# The figures a run is judged by, and the linear-control solvers, left the top level in
# this release: each must still resolve there, warn, and be the new module's object.
MOVED_TO = {
    "metrics": (
        "comfort",
        "crest_factor",
        "decay_settling_time",
        "dissipated_energy",
        "dissipated_work",
        "energy_per_cycle",
        "mean_current",
        "peak",
        "rms",
        "rms_current",
        "settling_time",
        "vdv",
        "wk_response",
        "wk_rms",
        "wk_state_space",
        "wk_weighted",
    ),
    "linear": ("lqr", "quarter_car_state_space", "solve_lyapunov", "solve_riccati"),
}


@pytest.mark.parametrize("module", sorted(MOVED_TO))
def test_metrics_and_linear_control_moved_with_deprecated_aliases(module):
    import jaxmr

    home = importlib.import_module(f"jaxmr.{module}")
    assert sorted(home.__all__) == sorted(MOVED_TO[module])
    for name in MOVED_TO[module]:
        new_place = f"jaxmr.{module}.{name}"
        with pytest.warns(DeprecationWarning, match=re.escape(f"use `{new_place}`")):
            old = getattr(jaxmr, name)
        assert old is getattr(home, name), name
        assert name not in jaxmr.__all__


def test_dir_lists_the_public_api_and_not_the_init_s_helpers():
    # `dir(jaxmr)` (tab completion) listed `ast`, `importlib`, `warnings` and
    # `TYPE_CHECKING`, which `__init__` imports for itself.
    import jaxmr

    listed = set(dir(jaxmr))
    assert not listed & {"ast", "importlib", "warnings", "TYPE_CHECKING"}
    assert set(jaxmr.__all__) <= listed
    assert {"plot", "data", "__version__"} <= listed
