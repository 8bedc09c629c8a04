"""MkDocs hook: the formulas as MathML, written at build time, so that the site needs
no network and no script to show them (an offline lab PC shows them as a connected one
does; every current browser renders MathML).

The pages and docstrings write TeX between `\\(...\\)` and `\\[...\\]`, which
`pymdownx.arithmatex` (generic mode) wraps in `arithmatex` elements; the notebooks'
Markdown cells keep their `$...$` and `$$...$$` as written. Both become MathML by
`latex2mathml`. A formula it cannot convert, or with a command it does not know,
fails the build with the page and the formula named.
"""

import html
import re

from latex2mathml.converter import convert

# pymdownx.arithmatex (generic): `<span class="arithmatex">\(...\)</span>` inline and
# `<div class="arithmatex">\[...\]</div>` displayed; the TeX is HTML-escaped.
_ARITHMATEX = re.compile(
    r'<(?P<tag>span|div) class="arithmatex">\s*\\[(\[](?P<tex>.*?)\\[)\]]\s*</(?P=tag)>',
    re.DOTALL,
)
# A notebook's Markdown cell, as mkdocs-jupyter (nbconvert) renders it: its HTML holds
# no `<div>` of its own, so the cell ends at the first `</div>`.
_MARKDOWN_CELL = re.compile(
    r'(<div class="jp-RenderedHTMLCommon jp-RenderedMarkdown[^>]*>)(.*?)(</div>)',
    re.DOTALL,
)
_DOLLARS = re.compile(r"\$\$(?P<block>.+?)\$\$|\$(?P<inline>[^$\n]+?)\$", re.DOTALL)
# Escaped characters that latex2mathml leaves as written inside `\text{...}`.
_TEXT_ESCAPES = re.compile(r"\\([_%&$#{}])")


def mathml(tex: str, display: bool, where: str = "") -> str:
    """`tex` (TeX, not escaped) as a MathML element, inline or displayed."""
    try:
        out = convert(tex.strip(), display="block" if display else "inline")
    except Exception as error:  # latex2mathml raises its own exception types
        raise ValueError(
            f"{where}: cannot convert the formula {tex!r}: {error}"
        ) from error
    out = re.sub(
        r"(<mtext>)(.*?)(</mtext>)",
        lambda m: m[1] + _TEXT_ESCAPES.sub(r"\1", m[2]) + m[3],
        out,
    )
    # latex2mathml writes a command it does not know as text (`<mi>\foo</mi>`): a
    # typo or a macro it lacks would show on the page as written.
    unknown = re.findall(r">[^<]*?(\\[A-Za-z]+)", out)
    if unknown:
        raise ValueError(
            f"{where}: the formula {tex!r} uses {', '.join(unknown)}, which latex2mathml "
            "does not know"
        )
    return out


def render(content: str, where: str = "", notebook: bool = False) -> str:
    """A page's HTML with its formulas as MathML."""

    def arithmatex(m: re.Match) -> str:
        return mathml(html.unescape(m["tex"]), m["tag"] == "div", where)

    content = _ARITHMATEX.sub(arithmatex, content)
    if notebook:

        def dollars(m: re.Match) -> str:
            block = m["block"] is not None
            tex = m["block"] if block else m["inline"]
            return mathml(html.unescape(tex), block, where)

        content = _MARKDOWN_CELL.sub(
            lambda m: m[1] + _DOLLARS.sub(dollars, m[2]) + m[3], content
        )
    return content


def on_page_content(html_content: str, page, config, files) -> str:
    source = page.file.src_uri
    return render(html_content, source, notebook=source.endswith(".ipynb"))
