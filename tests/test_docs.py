"""The API reference (docs/api/*.md) documents every public name of jaxmr, jaxmr.data
and jaxmr.plot, and only real ones.

The check reads the pages' `::: identifier` lines (mkdocstrings' syntax) without
MkDocs; it is the documentation build's own hook (docs/_hooks/api_coverage.py), so
`mkdocs build` and this test cannot disagree. The build also checks that each block
renders and that every link resolves."""

import importlib.util
import inspect
import re
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


# ---------------------------------------------------------------------------------------
# Defaults: each stated once in the guides, as the code has it

DOCS = HOOK.parents[1]
README = DOCS.parent / "README.md"


def _prose(path: Path) -> str:
    """A page's text with its line breaks and indentation folded into single spaces,
    so that a statement matches however it is wrapped."""
    return " ".join(path.read_text(encoding="utf-8").split())


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:g} ms"


def _number(x: float) -> str:
    """As the docs write a number: 1e-8, not Python's 1e-08."""
    return f"{x:g}".replace("e-0", "e-").replace("e+0", "e")


def _defaults() -> dict[str, list[str]]:
    """Guide page -> the statements of defaults it must make, written from the code's
    own values."""
    import jaxmr

    policy = jaxmr.StepPolicy()
    linear_step, linear_travel = policy.limits(rotary=False)
    rotary_step, rotary_travel = policy.limits(rotary=True)
    assert linear_travel is not None and rotary_travel is None  # as worded below
    adaptive = jaxmr.Adaptive()
    sampling = jaxmr.Sampling()
    sensors = inspect.signature(jaxmr.simulate_system).parameters["sensors"].default
    return {
        "control.md": [
            f"`Sampling()` samples every {_ms(sampling.dt)} "
            f"({1e-3 / sampling.dt:g} kHz) with a delay of {sampling.delay} sample",
            f"By default (`sensors={sensors!r}`) perfect readings",
        ],
        "identification.md": [
            f"steps of at most {_ms(linear_step)} and {linear_travel * 1e6:g} µm of "
            f"travel for a linear damper, {_ms(rotary_step)} and no travel limit for "
            "a rotary brake"
        ],
        "simulation.md": [
            f"(default): diffrax's `{type(adaptive.solver).__name__}` at rtol "
            f"{_number(adaptive.rtol)}, atol {_number(adaptive.atol)}",
            f"[`FixedStep(substeps={jaxmr.FixedStep().substeps})`][jaxmr.FixedStep]",
        ],
    }


def test_the_guides_state_each_default_once_as_the_code_has_it():
    pages = {p.name: _prose(p) for p in sorted(DOCS.glob("*.md"))}
    pages["README.md"] = _prose(README)
    for page, statements in _defaults().items():
        for statement in statements:
            assert statement in pages[page], f"docs/{page} should say: {statement}"
            elsewhere = [
                name
                for name, text in pages.items()
                if name != page and statement in text
            ]
            assert not elsewhere, f"{statement!r} stated again in {elsewhere}"


def test_step_policys_docstring_gives_the_code_defaults():
    import jaxmr

    doc = " ".join((jaxmr.StepPolicy.__doc__ or "").split())
    step, travel = jaxmr.StepPolicy().limits(rotary=False)
    assert f"linear dampers: {_ms(step)} and {travel * 1e6:g} µm." in doc
    step, travel = jaxmr.StepPolicy().limits(rotary=True)
    assert travel is None
    assert f"rotary brakes: {_ms(step)} and no travel limit." in doc
    # `fit` and the scores refer to it rather than restating the numbers.
    for function in (jaxmr.fit, jaxmr.predict_all):
        doc = " ".join((function.__doc__ or "").split())
        assert "StepPolicy()" in doc and " ms" not in doc, function.__name__


# ---------------------------------------------------------------------------------------
# The README: a front page whose commands and links are true

CI = DOCS.parent / ".ci" / "run"


def _blocks(text: str, language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", text, re.MULTILINE | re.DOTALL)


def test_the_readme_is_a_front_page_with_true_commands_and_links():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 150
    commands = [b.strip() for b in _blocks(text, "bash")]
    assert "pip install . && jaxmr demo --out demo_out" in commands
    test = 'pip install -e ".[test]" && python -m pytest -q -n 2'
    assert test in commands
    # CI runs the README's test command (as `python3`), after its checks.
    ci = CI.read_text(encoding="utf-8").splitlines()
    assert (
        ci[-1]
        == "python3 -m pytest -q -n 2"
        == test.split(" && ")[1].replace("python ", "python3 ", 1)
    )
    # Its one example is the getting-started page's, whose figure the site draws.
    guide = (DOCS / "getting-started.md").read_text(encoding="utf-8")
    assert _blocks(text, "python") == _blocks(guide, "python")[:1]
    # Every relative link and image names a file or folder of the repository.
    targets = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if "://" not in t]
    assert "docs/_static/quick_example.png" in local
    missing = [t for t in local if not (README.parent / t).exists()]
    assert not missing, missing
