// MathJax 3 for the pages and docstrings (pymdownx.arithmatex, generic mode: \(...\)
// and \[...\] inside `arithmatex` elements) and for the notebooks' Markdown cells
// (mkdocs-jupyter keeps their $...$ and $$...$$ as written, inside `jupyter-wrapper`).
window.MathJax = {
  tex: {
    inlineMath: [["\\(", "\\)"], ["$", "$"]],
    displayMath: [["\\[", "\\]"], ["$$", "$$"]],
    processEscapes: true,
    processEnvironments: true,
  },
  options: {
    ignoreHtmlClass: ".*|",
    processHtmlClass: "arithmatex|jupyter-wrapper",
  },
};

// Material's instant navigation swaps pages without a reload: typeset each new one.
document$.subscribe(() => {
  MathJax.startup.output.clearCache();
  MathJax.typesetClear();
  MathJax.texReset();
  MathJax.typesetPromise();
});
