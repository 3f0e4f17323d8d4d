// A figure drawn wider than the page's column (the validation page's eight panels, the
// benchmark's grids) opens at its own size on a click, over the page; a click or Escape
// closes it. Only images shrunk by a third or more get it: the rest are readable as they are.
document$.subscribe(({ body }) => {
  const shrunk = (img) => img.naturalWidth > 1.5 * img.clientWidth;
  const close = () => document.querySelectorAll(".figure-enlarged").forEach((o) => o.remove());
  const open = (img) => {
    const overlay = document.createElement("div");
    overlay.className = "figure-enlarged";
    overlay.setAttribute("role", "dialog");
    overlay.setAttribute("aria-label", img.alt || "figure");
    const big = document.createElement("img");
    big.src = img.src;
    big.alt = img.alt;
    overlay.appendChild(big);
    overlay.addEventListener("click", close);
    document.body.appendChild(overlay);
  };
  const mark = (img) => {
    if (!shrunk(img) || img.classList.contains("figure-enlargeable")) return;
    img.classList.add("figure-enlargeable");
    img.title = img.title || "Click to enlarge";
    img.addEventListener("click", () => open(img));
  };
  body.querySelectorAll("article img").forEach((img) => {
    if (img.complete) mark(img);
    else img.addEventListener("load", () => mark(img));
  });
  document.addEventListener("keydown", (e) => { if (e.key === "Escape") close(); });
});
