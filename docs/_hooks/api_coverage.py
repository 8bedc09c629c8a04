"""MkDocs hook: the API reference documents every public name, and only real ones.

Every public name of `jaxmr` and of its public submodules (`jaxmr.data`, `jaxmr.plot`,
`jaxmr.templates`, ...: every module of the package whose name does not start with an
underscore) must have a `::: name` block (mkdocstrings) in `docs/api/*.md`: `mkdocs
build` fails otherwise, so a new public name, or a new public module, cannot ship
undocumented. `tests/test_docs.py` runs the same check without MkDocs.
"""

import re
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
API = ROOT / "docs" / "api"
PACKAGE = ROOT / "jaxmr"
# The package and its public submodules, found on disk: a new one is checked too.
MODULES = ("jaxmr",) + tuple(
    sorted(
        f"jaxmr.{path.stem if path.suffix else path.name}"
        for path in PACKAGE.iterdir()
        if not path.name.startswith("_")
        and (path.suffix == ".py" or (path / "__init__.py").is_file())
    )
)
_DIRECTIVE = re.compile(r"^:::\s+(\S+)\s*$", re.MULTILINE)


def documented() -> set[str]:
    """The identifiers of the API pages' `:::` blocks."""
    return {
        name
        for page in sorted(API.glob("*.md"))
        for name in _DIRECTIVE.findall(page.read_text(encoding="utf-8"))
    }


def _modules() -> dict[str, types.ModuleType]:
    # This checkout's jaxmr, installed or not.
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    import importlib

    return {name: importlib.import_module(name) for name in MODULES}


def public() -> set[str]:
    """`module.name` for every public name: a module's `__all__`, else the names of
    its `dir()` that are neither private nor submodules."""
    names = set()
    for prefix, module in _modules().items():
        listed = getattr(module, "__all__", None)
        if listed is None:
            listed = [
                n
                for n in dir(module)
                if not n.startswith("_")
                and n != "TYPE_CHECKING"
                and not isinstance(getattr(module, n), types.ModuleType)
            ]
        names |= {f"{prefix}.{n}" for n in listed}
    return names


def problems() -> list[str]:
    """What is wrong with the API reference, one message per kind (empty: nothing)."""
    found = documented()
    modules = _modules()
    messages = []
    missing = sorted(public() - found)
    if missing:
        messages.append(
            f"public names missing from the API reference (docs/api/*.md): {missing}; "
            "add a `::: name` line to the page where each belongs."
        )

    def exists(identifier: str) -> bool:
        owner, _, name = identifier.rpartition(".")
        return identifier in modules or (
            owner in modules and hasattr(modules[owner], name)
        )

    stale = sorted(i for i in found if not exists(i))
    if stale:
        messages.append(f"the API reference names what jaxmr does not have: {stale}")
    return messages


def on_pre_build(config):
    from mkdocs.exceptions import PluginError

    messages = problems()
    if messages:
        raise PluginError("\n".join(messages))
