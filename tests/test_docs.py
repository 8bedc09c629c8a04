"""The API reference (docs/api/*.md) documents every public name of jaxmr, jaxmr.data
and jaxmr.plot, and only real ones.

The check reads the pages' `::: identifier` lines (mkdocstrings' syntax) without
MkDocs; it is the documentation build's own hook (docs/_hooks/api_coverage.py), so
`mkdocs build` and this test cannot disagree. The build also checks that each block
renders and that every link resolves."""

import importlib.util
from pathlib import Path

HOOK = Path(__file__).resolve().parents[1] / "docs" / "_hooks" / "api_coverage.py"


def _hook():
    spec = importlib.util.spec_from_file_location("jaxmr_docs_api_coverage", HOOK)
    assert spec is not None and spec.loader is not None, f"cannot load {HOOK}"
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_api_reference_has_pages():
    assert _hook().documented(), "no `:::` blocks in docs/api/*.md"


def test_every_public_name_is_documented_and_every_documented_name_exists():
    messages = _hook().problems()
    assert not messages, "\n".join(messages)
