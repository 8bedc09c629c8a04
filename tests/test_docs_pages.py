"""The documentation's pages as a reader meets them: their formulas need no network,
and the code on the control and "Your rig's data" pages runs as written."""

import importlib.util
import re
import shlex
import shutil
from pathlib import Path

import pytest

from jaxmr._cli import main

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None, f"cannot load {path}"
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ---------------------------------------------------------------------------------------
# Formulas: MathML written at build time, no script from the network

REMOTE = re.compile(
    r"<(?:script|link|img|iframe)\b[^>]*\b(?:src|href)\s*=\s*[\"']?(?:https?:)?//",
    re.IGNORECASE,
)


def _site_config(**overrides):
    """mkdocs.yml, less the plugins and hooks that need the `docs` extra's API and
    notebook renderers (the `test` extra has MkDocs, its theme and latex2mathml) or
    draw figures: the theme, Markdown extensions and math hook are the site's."""
    from mkdocs.config import load_config

    return load_config(
        str(DOCS.parent / "mkdocs.yml"),
        plugins=["search"],
        hooks=[str(DOCS / "_hooks" / "math.py")],
        **overrides,
    )


def _page(markdown: str) -> str:
    """A page's Markdown as the site renders its content: the site's Markdown
    extensions (mkdocs.yml), then the math hook."""
    import markdown as md

    site = _site_config()
    html = md.Markdown(
        extensions=site["markdown_extensions"],
        extension_configs=site["mdx_configs"],
    ).convert(markdown)
    math = _load(DOCS / "_hooks" / "math.py", "jaxmr_docs_math")
    return math.render(html, "test.md")


def test_formulas_become_mathml_at_build_time():
    html = _page(
        r"Inline \(F = c_0(i)\,v + \alpha z\), and displayed:"
        "\n\n"
        r"\[\dot z = A\dot x - \beta |\dot x| |z|^{n-1} z - \gamma \dot x |z|^n\]"
        "\n\nand \\(\\text{simulate\\_system}(a < b)\\)."
    )
    assert html.count('display="inline"') == 2, html
    assert html.count('display="block"') == 1, html
    assert "arithmatex" not in html and "\\(" not in html and "\\[" not in html
    assert "<mi>&#x003B1;</mi>" in html  # α
    assert "<mtext>simulate_system</mtext>" in html  # no stray backslash
    assert "<mo>&#x0003C;</mo>" in html  # the page's escaped `<`, read as TeX's


def test_a_notebooks_dollar_formulas_become_mathml():
    math = _load(DOCS / "_hooks" / "math.py", "jaxmr_docs_math")
    cell = (
        '<div class="jp-RenderedHTMLCommon jp-RenderedMarkdown jp-MarkdownOutput" '
        'data-mime-type="text/markdown"><p>The angle $\\theta$ and $$T = \\alpha z$$'
        "</p></div><pre>costs $5 and $6</pre>"
    )
    html = math.render(cell, "nb.ipynb", notebook=True)
    assert html.count("<math") == 2 and "$" not in html.split("<pre>")[0]
    assert "<pre>costs $5 and $6</pre>" in html  # outside Markdown cells: as written


def test_an_unconvertible_formula_fails_the_build_naming_it():
    math = _load(DOCS / "_hooks" / "math.py", "jaxmr_docs_math")
    for tex, why in [(r"\left( x", "cannot convert"), (r"\sgn(v)", r"uses \\sgn")]:
        with pytest.raises(ValueError, match=rf"models/x.md: .*{why}"):
            math.render(f'<span class="arithmatex">\\({tex}\\)</span>', "models/x.md")


def test_a_built_model_page_loads_nothing_from_another_host(tmp_path):
    """A model page built by MkDocs with the site's configuration (mkdocs.yml: its
    theme, Markdown extensions, `extra_javascript` and math hook; `_site_config`
    leaves out what this page does not use, to keep the build short): its formulas
    are MathML and no script, stylesheet or font comes from the network."""
    from mkdocs.commands.build import build

    docs = tmp_path / "docs"
    docs.mkdir()
    shutil.copy(DOCS / "models" / "spencer.md", docs / "index.md")
    site = _site_config(
        docs_dir=str(docs),
        site_dir=str(tmp_path / "site"),
        nav=["index.md"],
        strict=False,  # the page's links to the rest of the site lead nowhere here
    )
    build(site)
    html = (tmp_path / "site" / "index.html").read_text(encoding="utf-8")
    assert html.count("<math") >= 10 and "arithmatex" not in html
    assert "<script" in html  # the theme's own, served with the site
    found = REMOTE.findall(html)
    assert not found, found


# ---------------------------------------------------------------------------------------
# The pages' code runs as written

PAGES = ["control.md", "your-rigs-data.md"]


def _blocks(page: str) -> list[tuple[str, str]]:
    """A page's fenced code blocks in order: (language, code)."""
    text = (DOCS / page).read_text(encoding="utf-8")
    return re.findall(r"^```(\w+)\n(.*?)^```", text, re.MULTILINE | re.DOTALL)


def _run_shell(block: str, where: str) -> None:
    """A `bash` block: one `jaxmr` command a line, run in this process (as the
    installed `jaxmr` script runs `jaxmr._cli.main`), each to exit 0."""
    for line in block.replace("\\\n", " ").splitlines():
        words = shlex.split(line)
        if not words:
            continue
        assert words[0] == "jaxmr", f"{where}: only jaxmr commands run here: {line}"
        assert main(words[1:]) == 0, f"{where}: {line}"


@pytest.mark.parametrize("page", PAGES)
def test_every_code_block_of_the_page_runs(page, tmp_path, monkeypatch):
    """The page's blocks, in order, in an empty directory: the Python blocks as one
    session, the shell blocks through the command line. A warning fails it, as
    everywhere in the suite (the page promises a run within the fitted range)."""
    import matplotlib

    matplotlib.use("Agg")  # a figure a block draws needs no display
    blocks = _blocks(page)
    languages = {language for language, _ in blocks}
    assert "python" in languages and languages <= {"python", "bash"}, languages
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__docs__"}
    for k, (language, code) in enumerate(blocks):
        where = f"docs/{page}, block {k + 1}"
        if language == "bash":
            _run_shell(code, where)
        else:
            exec(compile(code, where, "exec"), namespace)
