// Typesets the pages' equations with the KaTeX bundled in docs/assets/katex (nothing is
// loaded from the network). pymdownx.arithmatex (generic mode) wraps each equation in an
// element of class "arithmatex" with \( \) or \[ \] delimiters; Material's document$
// fires on every page load, including instant navigation.
document$.subscribe(({ body }) => {
  renderMathInElement(body, {
    delimiters: [
      { left: "\\[", right: "\\]", display: true },
      { left: "\\(", right: "\\)", display: false },
    ],
    throwOnError: false,
  });
});
