"""The docs site builds with warnings as errors, and renders in a real browser (both slow:
CI runs them; tests/test_docs.py checks the pages' links, anchors and navigation in the
default suite).

* `mkdocs build --strict`, the console script run from another folder with `-f`: a broken
  link or anchor, a page missing from the navigation, a missing API object (mkdocstrings) or
  an undocumented `EnvConfig` option (docs/hooks.py) fails it;
* the site as the README's `mkdocs serve` serves it from the clone's root, on localhost,
  opened in Debian's headless Chromium through
  its chromedriver (selenium): the home page, the environment reference and the physics
  page render, the equations are typeset by the bundled KaTeX (no raw TeX left), nothing is
  requested from another host, a search for "critical speed" lists the physics page, and one for
  "observation space" lists the user pages before the engineering notes.
  Screenshots go to a folder the test prints.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from html.parser import HTMLParser
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytest.importorskip("mkdocs", reason="the [docs] extra is not installed")
pytest.importorskip("material", reason="the [docs] extra is not installed")


# The docs' commands as the README and CONTRIBUTING give them: the `mkdocs` console script of
# this interpreter's environment, not `python -m mkdocs` (which puts the current folder on the
# path and so hid a hook that imported a package the install does not have).
MKDOCS = str(Path(sys.executable).with_name("mkdocs"))


def _clean_env() -> dict[str, str]:
    """The environment without PYTHONPATH: nothing but the hooks themselves may put the clone
    on the path."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return {**env, "NO_MKDOCS_2_WARNING": "1"}


def _build(site: Path, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """`mkdocs build --strict`, run in ``cwd``; from any folder but the clone's, with
    ``-f`` naming the clone's mkdocs.yml."""
    config = [] if cwd == ROOT else ["-f", str(ROOT / "mkdocs.yml")]
    return subprocess.run([MKDOCS, "build", "--strict", "--quiet", *config,
                           "--site-dir", str(site)],
                          check=False, cwd=cwd, capture_output=True, text=True, timeout=600,
                          env=_clean_env())


@pytest.fixture(scope="module")
def built_site(tmp_path_factory) -> Path:
    """The site built once for this module's checks, from another folder, as `mkdocs build
    --strict -f path/to/mkdocs.yml` (the browser test below runs `mkdocs serve` from the
    clone's root)."""
    where = tmp_path_factory.mktemp("docs-build")
    elsewhere = where / "elsewhere"
    elsewhere.mkdir()
    done = _build(where / "site", cwd=elsewhere)
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stdout}\n{done.stderr}"
    return where / "site"


@pytest.mark.slow  # 14-18 s on the 2-core machine; tests/test_docs.py checks links and anchors fast
def test_the_site_builds_with_warnings_as_errors(built_site):
    site = built_site
    for page in ("index.html", "environment/index.html", "physics/index.html",
                 "reference/cli/index.html", "reference/api/index.html",
                 "notes/index.html", "search/search_index.json", "changelog/index.html",
                 "contributing/index.html"):
        assert (site / page).is_file(), f"the site has no {page}"
    env = (site / "environment" / "index.html").read_text()
    assert "obs_history" in env and "air_force_tau" in env     # the generated options table
    cli = (site / "reference" / "cli" / "index.html").read_text()
    assert "--total-timesteps" in cli and "--policy" in cli    # the generated command lines
    api = (site / "reference" / "api" / "index.html").read_text()
    assert "saddle_env.simulate" in api                       # mkdocstrings
    assert 'id="agents.evaluation.evaluate.evaluate_controller"' in api
    home = (site / "index.html").read_text()
    assert 'class="md-source"' in home and "github.com/saddle-env/saddle-env" in home
    assert 'data-md-component="source"' not in home  # would ask GitHub's API for its stars
    # nothing is loaded from another host: no CDN, no web fonts
    for html in site.rglob("*.html"):
        text = html.read_text()
        for remote in ("cdn.jsdelivr", "unpkg.com", "fonts.googleapis", "fonts.gstatic",
                       "cdnjs", "polyfill.io"):
            assert remote not in text, f"{html.relative_to(site)} loads from {remote}"


# -- the API page as rendered -------------------------------------------------------------------

class _Tables(HTMLParser):
    """Every table of a page as rows of cell texts (whitespace collapsed)."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list[list[list[str]]] = []
        self._row: list[str] | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append([])
        elif tag == "tr" and self.tables:
            self._row = []
            self.tables[-1].append(self._row)
        elif tag in ("td", "th") and self._row is not None:
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None and self._row is not None:
            self._row.append(" ".join("".join(self._cell).split()))
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def _api_rows(site: Path, column: str) -> list[tuple[str, str]]:
    """(name, cell of ``column``) for every row of the API page's parameter, attribute and
    return tables."""
    parser = _Tables()
    parser.feed((site / "reference" / "api" / "index.html").read_text())
    rows = []
    for table in parser.tables:
        if table and column in table[0] and "Name" in table[0]:
            i = table[0].index(column)
            rows += [(r[0], r[i]) for r in table[1:] if len(r) > i]
    return rows


def _is_sentence(text: str) -> bool:
    """A description, not a type: a full stop, a dash or a colon between words, or more
    words than the longest type written here ("sequence of str or (str, policy) pairs")."""
    return (text.endswith(".") or ". " in text or " — " in text or " : " in text
            or len(text.split()) > 8)


@pytest.mark.slow
def test_no_type_cell_of_the_api_page_holds_a_sentence(built_site):
    # the one-line `x, y : float — description` form put its description in the Type column
    rows = _api_rows(built_site, "Type")
    assert len(rows) > 100, f"the API page has {len(rows)} typed rows"
    assert _is_sentence("float — contact point [m], rotating (saddle) coordinates.")
    sentences = [(name, cell) for name, cell in rows if _is_sentence(cell)]
    assert not sentences, f"Type cells holding a description: {sentences}"


@pytest.mark.slow
def test_scene_b_default_agrees_in_the_signature_and_the_table(built_site):
    html = (built_site / "reference" / "api" / "index.html").read_text()
    start = html.index('id="saddle_env.Scene"')
    parser = _Tables()
    parser.feed(html[start:html.index("</table>", start)])
    table = parser.tables[0]
    default = table[0].index("Default")
    rows = {r[0]: r[default] for r in table[1:]}
    assert rows["a"] == "0.159" and rows["b"] == "None", rows
    signature = html[html.index("doc-signature", start):]
    signature = re.sub(r"<[^>]+>", "", signature[:signature.index("</pre>")])
    assert re.search(r"\bb: float \| None = None", signature), signature


@pytest.mark.slow
def test_long_signatures_wrap(built_site):
    # the [docs] extra brings the formatter (ruff) that wraps them at mkdocs.yml's width
    html = (built_site / "reference" / "api" / "index.html").read_text()
    start = html.index('id="saddle_env.simulate.simulate"')
    block = html[html.index("doc-signature", start):]
    text = re.sub(r"<[^>]+>", "", block[:block.index("</pre>")])
    lines = text.strip().splitlines()
    assert len(lines) > 10 and max(map(len, lines)) <= 88, lines


@pytest.mark.slow
def test_every_docs_page_reference_is_a_link(built_site):
    # help strings (the command-line page), docstrings (the API page) and the levels'
    # descriptions name pages as docs/X.md: on the site each is a link to X
    levels = (built_site / "levels" / "index.html").read_text()
    assert '<a href="../leaderboard/">docs/leaderboard.md</a>' in levels
    for html in built_site.rglob("*.html"):
        text = re.sub(r"<pre.*?</pre>|<a\b.*?</a>", "", html.read_text(), flags=re.DOTALL)
        text = re.sub(r"<[^>]+>", "", text)
        bare = re.findall(r"docs/[\w./-]+\.md", text)
        assert not bare, f"{html.relative_to(built_site)}: {bare} not links"


# -- in a browser (slow) -----------------------------------------------------------------------

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def served_site(tmp_path):
    """The README's command, `mkdocs serve` in the clone's root, on 127.0.0.1 (a free port)
    for the test's length."""
    port = _free_port()
    log = (tmp_path / "serve.log").open("w")
    server = subprocess.Popen([MKDOCS, "serve", "--strict", "-a", f"127.0.0.1:{port}"],
                              cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=_clean_env())
    url = f"http://127.0.0.1:{port}"

    def up() -> bool:
        if server.poll() is not None:
            raise AssertionError(f"mkdocs serve stopped:\n{(tmp_path / 'serve.log').read_text()}")
        try:
            with urllib.request.urlopen(url + "/", timeout=2) as answer:
                return answer.status == 200
        except OSError:
            return False

    try:
        _wait(up, seconds=300, what="mkdocs serve to answer")
        yield url
    finally:
        server.terminate()
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        log.close()


@pytest.fixture
def browser(tmp_path):
    webdriver = pytest.importorskip("selenium.webdriver")
    if not (CHROMIUM and CHROMEDRIVER):
        pytest.skip("needs Debian's chromium and chromium-driver (apt-get install -y chromium "
                    "chromium-driver; .ci/run installs them)")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync",
                 "--window-size=1280,1000", f"--user-data-dir={tmp_path / 'profile'}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"performance": "ALL"})
    service = webdriver.ChromeService(executable_path=CHROMEDRIVER)
    driver = webdriver.Chrome(options=options, service=service)
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()


def _wait(condition, seconds: float = 30.0, what: str = "the page"):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out after {seconds} s waiting for {what}")


def _hosts_requested(driver) -> set[str]:
    import json
    from urllib.parse import urlparse

    hosts = set()
    for entry in driver.get_log("performance"):
        message = json.loads(entry["message"])["message"]
        if message.get("method") == "Network.requestWillBeSent":
            url = message["params"]["request"]["url"]
            if url.startswith("http"):
                hosts.add(urlparse(url).hostname)
    return hosts


@pytest.mark.slow
def test_the_site_renders_in_a_browser(served_site, browser, capsys):
    from selenium.webdriver.common.by import By

    shots = Path(tempfile.gettempdir()) / "saddle-env-docs-screenshots"
    shutil.rmtree(shots, ignore_errors=True)
    shots.mkdir(parents=True)
    with capsys.disabled():
        print(f"\nscreenshots of the docs site: {shots}")

    def visit(path: str, heading: str, shot: str) -> None:
        browser.get(served_site + path)
        h1 = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "article h1"),
                   what=f"the heading of {path}")
        assert heading in h1[0].text, f"{path}: heading {h1[0].text!r}"
        browser.save_screenshot(str(shots / shot))

    visit("/", "saddle-env", "home.png")
    # the home page's equation is typeset too
    _wait(lambda: browser.find_elements(By.CSS_SELECTOR, ".arithmatex .katex"),
          what="KaTeX on the home page")

    visit("/environment/", "The environment", "environment.png")
    assert browser.find_elements(By.ID, "all-options"), "the env reference has no options"
    options_table = browser.find_element(By.ID, "all-options")
    browser.execute_script("arguments[0].scrollIntoView();", options_table)
    assert "obs_history" in browser.find_element(By.TAG_NAME, "article").text
    browser.save_screenshot(str(shots / "environment-options.png"))

    visit("/physics/", "The physics", "physics.png")
    # every equation typeset by KaTeX: each arithmatex element holds KaTeX's output, and no
    # TeX source is left on the page as text
    maths = browser.find_elements(By.CSS_SELECTOR, ".arithmatex")
    assert len(maths) >= 15, f"the physics page has {len(maths)} equations"
    _wait(lambda: all(m.find_elements(By.CSS_SELECTOR, ".katex") for m in maths),
          what="KaTeX to typeset every equation")
    assert not browser.find_elements(By.CSS_SELECTOR, ".katex-error")
    text = browser.find_element(By.TAG_NAME, "article").text
    for tex in ("\\frac", "\\Omega", "\\mathbf", "\\sqrt", "$$"):
        assert tex not in text, f"raw TeX {tex!r} left on the physics page"
    crt = browser.find_element(By.XPATH, "//*[contains(@class, 'arithmatex')][contains(., 'crt')]")
    browser.execute_script("arguments[0].scrollIntoView({block: 'center'});", crt)
    browser.save_screenshot(str(shots / "physics-equations.png"))

    # a figure drawn wider than the column opens at its own size on a click
    # (docs/assets/javascripts/enlarge.js): the validation page's eight panels
    visit("/validation/", "Real saddles", "validation.png")
    figure = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "article img.figure-enlargeable"),
                   what="an enlargeable figure on the validation page")[0]
    browser.execute_script("arguments[0].scrollIntoView({block: 'center'});", figure)
    figure.click()
    big = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, ".figure-enlarged img"),
                what="the enlarged figure")[0]
    assert big.size["width"] > 1.5 * figure.size["width"], (big.size, figure.size)
    browser.save_screenshot(str(shots / "validation-figure-enlarged.png"))
    browser.find_element(By.CSS_SELECTOR, ".figure-enlarged").click()
    _wait(lambda: not browser.find_elements(By.CSS_SELECTOR, ".figure-enlarged"),
          what="the enlarged figure to close")

    # search, in the browser's own index (no server): "critical speed" (Ω_crt) lists the
    # physics page
    browser.get(served_site + "/")
    _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "label.md-header__button[for='__search']")
          or browser.find_elements(By.CSS_SELECTOR, "input.md-search__input"), what="search box")
    box = browser.find_element(By.CSS_SELECTOR, "input.md-search__input")
    box.click()
    box.send_keys("critical speed")
    results = _wait(lambda: [a.get_attribute("href") for a in
                             browser.find_elements(By.CSS_SELECTOR, ".md-search-result__link")],
                    what="search results for critical speed")
    time.sleep(2.0)  # let the result list paint before the screenshot
    browser.save_screenshot(str(shots / "search-critical-speed.png"))
    from urllib.parse import urlparse

    pages = {urlparse(href).path for href in results}
    assert "/physics/" in pages, f"search for critical speed: {sorted(pages)}"

    # the engineering notes rank below the user pages (docs/hooks.py's NOTES_SEARCH_BOOST)
    browser.get(served_site + "/")
    box = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "input.md-search__input"),
                what="search box")[0]
    box.click()
    box.send_keys("observation space")
    _wait(lambda: browser.find_elements(By.CSS_SELECTOR, ".md-search-result__link"),
          what="search results for observation space")
    time.sleep(2.0)  # the list is filled in as the index answers
    ranked: list[str] = []
    for a in browser.find_elements(By.CSS_SELECTOR, ".md-search-result__link"):
        path = urlparse(a.get_attribute("href")).path
        if path not in ranked:
            ranked.append(path)
    assert "/environment/" in ranked[:8], f"search for observation space: {ranked}"
    assert not [p for p in ranked[:8] if p.startswith("/notes/")], \
        f"search for observation space: notes among the first pages {ranked[:8]}"

    hosts = _hosts_requested(browser)
    assert hosts <= {"127.0.0.1"}, f"the site requested other hosts: {hosts}"
    assert len(list(shots.glob("*.png"))) == 8
