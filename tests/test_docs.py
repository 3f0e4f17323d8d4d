"""The documentation runs as written: README.md and the user pages under docs/ (docs/notes/,
the dated engineering notes, only have their links checked).

* every command in a ```bash block is one the project knows, and its arguments are accepted
  by the tool's own argument parser (the parsers are imported, not copied); files a command
  reads (a model for saddle-eval, a test file for pytest, an extra for pip) exist;
* every ```python block runs, page by page in one namespace, in bounded time, and prints
  what the page shows after it (a ```text title="Output" block right below); a block that
  cannot run here says why on the line before it (`<!-- skip: reason -->`, or
  `<!-- skip-unless: module:attribute (reason) -->` for an API that is not there yet);
* every repository path the docs mention (docs/..., agents/..., saddle_env/..., tests/...,
  figures/... from inside docs/) exists, and every Markdown link to a local file resolves,
  down to the heading it points at;
* the pages are user docs: no dated section headings, at most 3,000 words a page (the
  physics 6,000), every page in the site's navigation; the README at most 130 lines;
* the generated references cover the code: every `EnvConfig` option, every documented
  command line (docs/hooks.py);
* (slow) every command is run for real, in a temporary folder, with the smallest budget
  its flags allow.
"""

from __future__ import annotations

import argparse
import contextlib
import doctest
import importlib
import importlib.util
import io
import re
import shlex
import signal
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
NOTES = DOCS / "notes"
USER_PAGES = sorted(p for p in DOCS.rglob("*.md") if NOTES not in p.parents)
NOTE_PAGES = sorted(NOTES.glob("*.md"))
PAGES = [ROOT / "README.md", *USER_PAGES]
PENDING: set[str] = set()  # pages another change still has to write (none now)
TOOLS = ("saddle-sim", "saddle-eval", "saddle-export", "saddle-bench", "saddle-reproduce", "saddle-fit",
         "saddle-lifetimes")


def _load_hooks():
    """docs/hooks.py, the site's generator of the reference sections, as a module."""
    spec = importlib.util.spec_from_file_location("saddle_docs_hooks", DOCS / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


HOOKS = _load_hooks()

# The markers on the lines right before a code block that the tests may not run as it stands.
_SKIP = re.compile(r"^<!-- skip: (?P<reason>.+?) -->$")
_SKIP_UNLESS = re.compile(r"^<!-- skip-unless: (?P<module>[\w.]+):(?P<attr>\w+) \((?P<reason>.+?)\) -->$")


def _markers(text: str, start: int) -> list[str]:
    """The HTML-comment lines directly above the block that starts at ``start``."""
    lines = text[:start].splitlines()
    found = []
    while lines and lines[-1].startswith("<!--"):
        found.append(lines.pop())
    return found


def _skip_reason(text: str, start: int) -> tuple[str, bool] | None:
    """Why the block starting at ``start`` is not run, and whether it is not even parsed (an
    API that is not there yet: `skip-unless`); None: run it. `skip` alone: parsed, not run."""
    markers = _markers(text, start)
    for line in markers:
        m = _SKIP_UNLESS.match(line)
        if m:
            try:
                present = hasattr(importlib.import_module(m.group("module")), m.group("attr"))
            except ImportError:
                present = False
            if not present:
                return (f"{m.group('reason')}: {m.group('module')}.{m.group('attr')} "
                        "is not there"), True
    for line in markers:
        m = _SKIP.match(line)
        if m:
            return m.group("reason"), False
    return None


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _text_outside_code(text: str) -> str:
    return re.sub(r"```.*?```", "", text, flags=re.DOTALL)


# A block's printed output, shown right after it: ```text title="Output"; "..." stands for any
# text (doctest's ELLIPSIS), and runs of white space match any white space.
_OUTPUT = re.compile(r'\s*```text title="Output"\n(.*?)```', flags=re.DOTALL)


def _expected_outputs(page: Path) -> dict[int, str]:
    """{k: the output shown for the page's k-th python block} for the blocks that show one."""
    text = _page_text(page)
    found = {}
    for k, m in enumerate(re.finditer(r"```python\n(.*?)```", text, flags=re.DOTALL)):
        shown = _OUTPUT.match(text, m.end())
        if shown:
            found[k] = shown.group(1)
    return found


def _page_text(page: Path) -> str:
    """The page as the site shows it as far as figures go: a block may state a figure of the
    store by its markers (docs/figures/figures.yml), which the site replaces by the value."""
    from agents import figures

    return figures.render(page.read_text(), keep_markers=False)


def _blocks(page: Path, lang: str) -> list[tuple[str, tuple[str, bool] | None]]:
    """The page's ```lang blocks, each with its skip marker (None: none)."""
    text = _page_text(page)
    return [(m.group(1), _skip_reason(text, m.start()))
            for m in re.finditer(rf"```{lang}\n(.*?)```", text, flags=re.DOTALL)]


def _bash_blocks(page: Path) -> list[str]:
    """The bash blocks the tests can parse (all but those for an API not there yet)."""
    return [block for block, skip in _blocks(page, "bash") if not (skip and skip[1])]


def _commands(block: str) -> list[list[str]]:
    """Simple commands of a block: continuation lines joined, comments dropped, split at
    ``&&``, ``;`` and ``|``, redirections removed."""
    out = []
    for line in block.replace("\\\n", " ").splitlines():
        lex = shlex.shlex(line, posix=True, punctuation_chars=True)
        lex.whitespace_split = True
        argv: list[str] = []
        tokens = list(lex)
        i = 0
        while i < len(tokens):
            tok = tokens[i]
            if tok in ("&&", ";", "|", "||"):
                if argv:
                    out.append(argv)
                argv = []
            elif tok in (">", ">>", "<", "2>"):
                i += 1  # skip the file name
            else:
                argv.append(tok)
            i += 1
        if argv:
            out.append(argv)
    return out


def _doc_commands() -> list[tuple[str, int, list[str]]]:
    found = []
    for page in PAGES:
        for k, block in enumerate(_bash_blocks(page)):
            for argv in _commands(block):
                found.append((_rel(page), k, argv))
    return found


COMMANDS = _doc_commands()


def _tool(argv: list[str]) -> tuple[str, list[str]]:
    """(tool name, its arguments) for a documented command; the name is '' if unknown."""
    if argv[0] in TOOLS:
        return argv[0], argv[1:]
    if argv[0] in ("python", "python3"):
        if argv[1:2] == ["train.py"]:
            return "train.py", argv[2:]
        if argv[1:3] == ["-m", "pytest"]:
            return "pytest", argv[3:]
        if argv[1:3] == ["-m", "saddle_env.envs.throughput"]:
            return "env-throughput", argv[3:]
        if argv[1:3] == ["-m", "agents.benchmark.rllib_throughput"]:
            return "rllib-benchmark", argv[3:]
        if argv[1:3] in (["-m", "agents.benchmark"], ["-m", "agents.benchmark.run"]):
            return "benchmark", argv[3:]
        if argv[1:3] == ["-m", "saddle_env.coldstart.profile"]:
            return "compile-profile", argv[3:]
        if argv[1:2] == ["-m"] and f"python -m {argv[2]}" in HOOKS.CLIS:
            return f"python -m {argv[2]}", argv[3:]   # parsed; run only with --help
    if argv[0] == "ray" and argv[1:2] in (["start"], ["stop"], ["status"]):
        return "ray", argv[1:]          # Ray's own CLI (docs/scaling.md): not run by the tests
    if argv[:2] == ["pip", "install"]:
        return "pip", argv[2:]
    if argv[0] in ("python", "python3") and argv[1:3] in (["-m", "build"], ["-m", "twine"]):
        return "packaging", argv[1:]    # the build front end and twine (docs/install.md)
    return "", argv


def _extras() -> set[str]:
    """The optional-dependency groups of pyproject.toml (no tomllib before Python 3.11)."""
    text = (ROOT / "pyproject.toml").read_text()
    section = text.split("[project.optional-dependencies]", 1)[1].split("\n[", 1)[0]
    return set(re.findall(r"^(\w+)\s*=", section, flags=re.MULTILINE))


class _Parsed(Exception):
    pass


def _parser(tool: str) -> argparse.ArgumentParser | None:
    if tool == "saddle-sim":
        from saddle_env.cli import build_parser
    elif tool == "saddle-eval":
        from agents.evaluation.evaluate import build_parser
    elif tool == "saddle-export":
        from agents.evaluation.export import build_parser
    elif tool == "saddle-bench":
        from saddle_env.workprecision import build_parser
    elif tool == "saddle-reproduce":
        from saddle_env.reproduce.cli import build_parser
    elif tool == "train.py":
        sys.path.insert(0, str(ROOT))
        try:
            from train import build_parser
        finally:
            sys.path.remove(str(ROOT))
    elif tool == "rllib-benchmark":
        from agents.benchmark.rllib_throughput import build_parser
    elif tool == "benchmark":
        from agents.benchmark.run import build_parser
    elif tool == "compile-profile":
        from saddle_env.coldstart.profile import build_parser
    elif tool in HOOKS.CLIS:
        return HOOKS.parser_for(tool)
    else:
        return None
    return build_parser()


def _parse(tool: str, args: list[str]) -> argparse.Namespace | None:
    """Parse ``args`` with the tool's own parser; fail the test on a parser error."""
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            parser = _parser(tool)
            if parser is not None:
                return parser.parse_args(args)
            # The env benchmark builds its parser inside main(): stop main() right after
            # its arguments are parsed.
            from saddle_env.envs import throughput

            original = argparse.ArgumentParser.parse_args

            def parse_then_stop(self, a=None, namespace=None):
                raise _Parsed(original(self, a, namespace))

            argparse.ArgumentParser.parse_args = parse_then_stop
            try:
                throughput.main(args)
            finally:
                argparse.ArgumentParser.parse_args = original
    except _Parsed as done:
        return done.args[0]
    except SystemExit as exc:
        if exc.code not in (0, None):
            pytest.fail(f"{tool} {' '.join(args)}: rejected by its parser: {err.getvalue()}")
        return None  # --help
    pytest.fail(f"{tool}: no parser")


def _ids(cases):
    return [f"{page}:{' '.join(argv)[:60]}" for page, _, argv in cases]


def test_the_docs_have_commands():
    assert len(COMMANDS) >= 15
    assert any(_tool(argv)[0] == "train.py" for _, _, argv in COMMANDS)


@pytest.mark.parametrize("page, block, argv", COMMANDS, ids=_ids(COMMANDS))
def test_documented_command_is_accepted(page, block, argv):
    tool, args = _tool(argv)
    assert tool, f"{page}: unknown command {' '.join(argv)!r}: teach tests/test_docs.py about it"
    if tool == "ray":
        return
    if tool == "packaging":  # not run here: .ci/check-wheel builds and checks the wheel
        assert argv[1:] in (["-m", "build"], ["-m", "twine", "check", "dist/*"]), \
            f"{page}: {' '.join(argv)}: only .ci/check-wheel's packaging commands are documented"
        return
    if tool == "pip":
        extras = _extras()
        for arg in args:
            m = re.fullmatch(r"(?:\.|saddle-env)\[([\w,]+)\]", arg)
            if m:
                for extra in m.group(1).split(","):
                    assert extra in extras, f"{page}: pip extra [{extra}] is not in pyproject.toml"
        return
    if tool == "pytest":
        for arg in args:
            if arg.startswith("tests/"):
                assert (ROOT / arg.split("::")[0]).exists(), f"{page}: no such test file {arg}"
        return
    ns = _parse(tool, args)
    if ns is None:
        return
    if tool == "saddle-export":
        assert (ROOT / ns.model).is_file(), f"{page}: saddle-export {ns.model}: no such file"
    if tool == "saddle-eval":
        for spec in ns.policy:
            if spec.endswith(".zip"):
                assert (ROOT / spec).is_file(), f"{page}: saddle-eval --policy {spec}: no such file"
    if tool == "train.py" and ns.hyperparams:
        assert (ROOT / ns.hyperparams).is_file(), f"{page}: no such file {ns.hyperparams}"


# -- paths and links ------------------------------------------------------------------------

_PATH = re.compile(r"(?<![\w/.\-])((?:docs|agents|saddle_env|tests|figures|\.ci)/[\w./*\-]*)")
# Folders the install or a run writes, which the repository ignores (.gitignore's anchored
# entries, e.g. the install's ahead-of-time build saddle_env/_aot/): named in the docs, absent
# from a clone, and absent after an install without a C compiler.
_WRITTEN = tuple(line.strip().lstrip("/") for line in (ROOT / ".gitignore").read_text().splitlines()
                 if line.startswith("/") and line.strip().endswith("/"))


def _mentioned_paths(page: Path) -> list[str]:
    found = set()
    text = page.read_text()
    for m in _PATH.finditer(text):
        p = m.group(1).rstrip(".")
        if p.startswith(_WRITTEN):
            continue
        # placeholders (<algo>, <date>) and run outputs are not repository files
        if "<" in text[m.end():m.end() + 1]:
            continue
        found.add(p)
    return sorted(found)


def _exists(page: Path, path: str) -> bool:
    for base in (page.parent, ROOT):
        if "*" in path:
            if list(base.glob(path)):
                return True
        elif (base / path).exists():
            return True
    return False


PATH_CASES = [(page, p) for page in PAGES for p in _mentioned_paths(page)]


@pytest.mark.parametrize("page, path", PATH_CASES,
                         ids=[f"{_rel(pg)}:{p}" for pg, p in PATH_CASES])
def test_mentioned_repository_path_exists(page, path):
    if path in PENDING and not (ROOT / path).exists():
        pytest.skip(f"{path} is written by another change (see test_pending_pages_exist)")
    assert _exists(page, path), f"{_rel(page)} mentions {path}, which does not exist"


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    h = heading.strip().lower()
    h = re.sub(r"[^\w\- ]", "", h)
    return h.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = _text_outside_code(page.read_text())
    return {_slug(h) for h in re.findall(r"^#{1,6} (.+)$", text, flags=re.MULTILINE)}


_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
LINK_CASES = [(page, target) for page in [*PAGES, *NOTE_PAGES]
              for target in sorted(set(_LINK.findall(_text_outside_code(page.read_text()))))
              if not re.match(r"[a-z]+:", target)]


@pytest.mark.parametrize("page, target", LINK_CASES,
                         ids=[f"{_rel(pg)}:{t}" for pg, t in LINK_CASES])
def test_local_link_resolves(page, target):
    path, _, anchor = target.partition("#")
    dest = (page.parent / path).resolve() if path else page
    rel = dest.relative_to(ROOT).as_posix() if dest.is_relative_to(ROOT) else str(dest)
    if rel in PENDING and not dest.exists():
        pytest.skip(f"{rel} is written by another change (see test_pending_pages_exist)")
    assert dest.exists(), f"{_rel(page)}: link {target} points at nothing"
    if anchor and dest.suffix == ".md":
        assert anchor in _anchors(dest), f"{_rel(page)}: link {target}: no such heading in {rel}"


@pytest.mark.parametrize("page", [*PAGES, *NOTE_PAGES], ids=_rel)
def test_links_are_named_by_title_not_file(page):
    """A link reads as what it leads to ("[Task levels](levels.md)"), not as a file name."""
    named = re.findall(r"\[[^\]]*\.md\]\([^)\s]+\)", _text_outside_code(page.read_text()))
    assert not named, f"{_rel(page)}: links named by their file: {named}"


def _nav_pages() -> set[str]:
    """The pages mkdocs.yml's navigation lists (paths under docs/)."""
    text = (ROOT / "mkdocs.yml").read_text()
    nav = text[text.index("\nnav:"):]
    return set(re.findall(r"([\w./-]+\.md)\s*$", nav, flags=re.MULTILINE))


def test_every_docs_page_is_in_the_site_navigation():
    nav = _nav_pages()
    for page in [*USER_PAGES, *NOTE_PAGES]:
        rel = page.relative_to(DOCS).as_posix()
        assert rel in nav, f"mkdocs.yml's nav does not list {rel}"
    for rel in nav:
        assert (DOCS / rel).is_file(), f"mkdocs.yml's nav lists {rel}, which does not exist"


@pytest.mark.parametrize("name", HOOKS.INCLUDABLE)
def test_top_folder_files_are_site_pages_without_a_copy(name):
    """CHANGELOG.md and CONTRIBUTING.md are on the site through a page that includes them
    (docs/hooks.py), and their links, rewritten for the page, resolve."""
    stubs = [p for p in USER_PAGES if f"<!-- generated: include {name} -->" in p.read_text()]
    assert len(stubs) == 1, f"no page of docs/ (or more than one) includes {name}: {stubs}"
    stub = stubs[0]
    assert len(stub.read_text().splitlines()) == 1, f"{_rel(stub)}: the include and nothing else"
    text = HOOKS.include_markdown(name, stub.parent.relative_to(DOCS).as_posix().strip("."))
    for target in _LINK.findall(_text_outside_code(text)):
        if re.match(r"[a-z]+:", target):
            assert "docs/" not in target, f"{name}: {target} should be a page of the site"
            continue
        path, _, anchor = target.partition("#")
        dest = (stub.parent / path).resolve() if path else stub
        assert dest.is_file(), f"{name} on the site: link {target} points at nothing"
        if anchor:
            assert anchor in _anchors(dest), f"{name} on the site: link {target}: no such heading"


def test_the_supported_python_and_the_repository_are_stated():
    minimum = re.search(r'requires-python = ">=(\d+\.\d+)"', (ROOT / "pyproject.toml").read_text())
    assert minimum, "pyproject.toml has no requires-python"
    for page in ("index.md", "install.md"):
        head = "\n".join((DOCS / page).read_text().splitlines()[:8])
        assert f"Python {minimum.group(1)} or newer" in head, f"docs/{page}: no Python version on top"
    repo = HOOKS._repo_url()
    assert f"]({repo})" in (DOCS / "index.md").read_text()


def test_the_readme_links_into_each_part_of_the_docs():
    readme = (ROOT / "README.md").read_text()
    for part in ("tutorials/", "how-to/", "reference/", "physics.md", "notes/"):
        assert f"(docs/{part}" in readme, f"README.md links nothing under docs/{part}"


# -- the pages are user docs ------------------------------------------------------------------

_DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_no_dated_section_headings_on_user_pages(page):
    """A user page says how things are now: dated sections are the notes' (docs/notes/)."""
    headings = re.findall(r"^#{1,6} .*$", _text_outside_code(page.read_text()), flags=re.MULTILINE)
    dated = [h for h in headings if _DATE.search(h)]
    assert not dated, f"{_rel(page)}: dated headings {dated}: move them to docs/notes/"


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_one_notation_for_the_critical_speed_and_one_unit_for_speeds(page):
    """Ω_crt in prose (`omega_crt` only as a name in code), and speeds in rad/s (rates such
    as a drag coefficient in 1/s), never s⁻¹."""
    prose = re.sub(r"`[^`\n]*`", "", _text_outside_code(page.read_text()))
    for wrong in ("Omega_crt", "omega_crt", "s⁻¹"):
        assert wrong not in prose, f"{_rel(page)}: {wrong!r} in prose"


def _words(page: Path) -> int:
    from agents import figures

    # what a reader reads: a figure's markers are no words
    return len(figures.render(page.read_text(), keep_markers=False).split())


@pytest.mark.parametrize("page", USER_PAGES, ids=_rel)
def test_user_pages_are_short(page):
    limit = 6000 if page.name == "physics.md" else 3000
    assert _words(page) <= limit, f"{_rel(page)}: {_words(page)} words, at most {limit}: split it"


def test_explanations_within_their_budgets():
    assert _words(DOCS / "coldstart.md") <= 1000      # why the first call is fast
    assert _words(DOCS / "training_profile.md") <= 1500  # what makes learning fast here


def test_readme_is_a_front_door():
    from agents import figures

    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 130
    text = figures.render(text, keep_markers=False)  # a figure's markers are no words
    head = text.index("## Headline figures")
    table = text[head:text.index("\n## ", head + 3)]
    for row in table.splitlines():
        if not row.startswith("|") or row.startswith("|---"):
            continue
        for cell in row.strip().strip("|").split("|"):
            words = re.sub(r"\]\([^)]*\)", "]", cell).split()  # a link's target is no word
            assert len(words) <= 25, f"README headline cell of {len(words)} words: {cell!r}"
        assert "](" in row or row.startswith("| |"), f"a headline row links nowhere: {row!r}"


# -- the generated references cover the code --------------------------------------------------

def _long_flags(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings
            if s.startswith("--") and s != "--help"}


def test_every_env_option_is_in_the_generated_table():
    import dataclasses

    from saddle_env.envs import EnvConfig

    placed = [f.name for _, _, fields in HOOKS.env_option_groups() for f in fields]
    assert sorted(placed) == sorted(f.name for f in dataclasses.fields(EnvConfig))
    table = HOOKS.env_options_markdown()
    for name in placed:
        assert f"| `{name}` |" in table
    assert "<!-- generated: env-options -->" in (DOCS / "environment.md").read_text()


def _table_rows(markdown: str) -> list[list[str]]:
    return [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in markdown.splitlines()
            if line.startswith("|") and not line.startswith("|---")]


def _spec_facts(env_id: str) -> dict[str, str]:
    """What the summary tables must say about ``env_id``, read from Gymnasium directly."""
    import gymnasium as gym

    spec = gym.spec(env_id)
    env = gym.make(env_id)
    try:
        return {"action space": f"`{env.action_space}`",
                "observation shape": f"`{env.observation_space.shape}`",
                "episode": f"{spec.max_episode_steps} steps",
                "reward_threshold": f"{spec.reward_threshold:g}"}
    finally:
        env.close()


def test_the_level_summary_has_every_registered_level_as_registered():
    """The environment page's table: one row per id of Gymnasium's registry that makes a
    SaddleTrap environment, each cell as its spec and its spaces say."""
    import gymnasium as gym

    from saddle_env.envs import LEVEL_IDS

    registered = [i for i, spec in gym.registry.items() if "saddle_env" in str(spec.entry_point)]
    assert registered == list(LEVEL_IDS)
    summary = HOOKS.level_summary_markdown()
    shared = summary.split("\n\n")[0]       # "Every level: **key** value; ..."
    header, *rows = _table_rows(summary)
    assert [row[0] for row in rows] == [f"`{i}`" for i in registered]
    for row in rows:
        cells = dict(zip(header, row))
        for key, value in _spec_facts(row[0].strip("`")).items():
            if key in cells:
                assert cells[key].startswith(value), f"{row[0]}: {key} {cells[key]!r}, spec {value!r}"
            else:
                assert f"**{key}** {value}" in shared, f"{row[0]}: {key} {value!r} in neither"
    assert "<!-- generated: level-summary -->" in (DOCS / "environment.md").read_text()


@pytest.mark.parametrize("env_id", HOOKS.registered_levels())
def test_each_level_section_opens_with_its_summary(env_id):
    text = (DOCS / "levels.md").read_text()
    assert f"## {env_id}\n\n<!-- generated: level-summary {env_id} -->\n" in text, \
        f"docs/levels.md: the section {env_id} does not open with its summary table"
    cells = {row[0]: row[1] for row in _table_rows(HOOKS.level_summary_markdown(env_id))}
    for key, value in _spec_facts(env_id).items():
        assert cells[key].startswith(value), f"{env_id}: {key} {cells[key]!r}, spec {value!r}"
    assert cells["make it"] == f'`gym.make("{env_id}")`'


def test_the_api_page_renders_every_public_function_and_class():
    """Each function and class of ``saddle_env.__all__`` has its entry on the API page, at the
    identifier the generated overview links to (a function as the function, not the module
    of the same name), and the tutorials' calls are there too."""
    text = (DOCS / "reference" / "api.md").read_text()
    directives = set(re.findall(r"^::: ([\w.]+)$", text, flags=re.MULTILINE))
    assert "<!-- generated: public-api -->" in text
    for name, kind, _ in HOOKS.public_api():
        if kind == "constant":
            continue
        identifier = HOOKS.API_IDENTIFIER.get(name, f"saddle_env.{name}")
        assert identifier in directives, f"docs/reference/api.md lacks ::: {identifier}"
    assert "saddle_env.simulate" not in directives, "::: saddle_env.simulate renders the module"
    assert "agents.evaluation.evaluate.evaluate_controller" in directives


def test_every_command_line_has_its_generated_reference():
    text = (DOCS / "reference" / "cli.md").read_text()
    for name in HOOKS.CLIS:
        assert f"<!-- generated: cli {name} -->" in text, f"reference/cli.md lacks {name}"


@pytest.mark.parametrize("name", sorted(HOOKS.CLIS))
def test_generated_command_reference_lists_every_flag(name):
    parser = HOOKS.parser_for(name)
    generated = HOOKS.cli_markdown(name)
    for flag in _long_flags(parser):
        if any(a.help is argparse.SUPPRESS for a in parser._actions if flag in a.option_strings):
            continue
        assert f"`{flag}`" in generated, f"{name}: {flag} missing from its reference"


@pytest.mark.parametrize("name", sorted(HOOKS.CLIS))
def test_every_argument_has_help(name):
    """Each flag and positional of every documented command line says what it does, in
    --help and in its generated reference."""
    parser = HOOKS.parser_for(name)
    bare = [a.option_strings[0] if a.option_strings else a.dest for a in parser._actions
            if not isinstance(a, argparse._HelpAction) and a.help is not argparse.SUPPRESS
            and not (a.help or "").strip()]
    assert not bare, f"{name}: {', '.join(bare)} without help text"


def test_every_documented_tool_has_a_reference():
    """A command the docs show is one the reference documents (docs/hooks.py's CLIS)."""
    known = {"saddle-sim": "saddle-sim", "saddle-eval": "saddle-eval",
             "saddle-export": "saddle-export",
             "saddle-bench": "saddle-bench", "saddle-reproduce": "saddle-reproduce",
             "train.py": "train.py", "benchmark": "python -m agents.benchmark",
             "env-throughput": "python -m saddle_env.envs.throughput",
             "rllib-benchmark": "python -m agents.benchmark.rllib_throughput",
             "compile-profile": "python -m saddle_env.coldstart.profile"}
    for page, _, argv in COMMANDS:
        tool, _ = _tool(argv)
        if tool in ("pip", "pytest", "ray", "packaging", ""):
            continue
        assert known.get(tool, tool) in HOOKS.CLIS, f"{page}: {tool} has no reference page"


def test_readme_keeps_the_ci_test_command():
    lines = (ROOT / "README.md").read_text().splitlines()
    i = lines.index("<!-- test-command -->")
    assert lines[i + 1] == "```bash"
    assert lines[i + 2].endswith("python -m pytest")


# -- the Python blocks run --------------------------------------------------------------------

# Pages whose blocks compile what the install's ahead-of-time build does not hold (the vector
# env's threaded step), or load torch and a trained agent: run with the slow checks.
SLOW_PYTHON_PAGES = {"docs/environment.md", "docs/how-to/load-model.md", "docs/how-to/export.md"}
PYTHON_SECONDS = 120  # a page's blocks together


def _python_pages() -> list:
    out = []
    for page in PAGES:
        if not _blocks(page, "python"):
            continue
        marks = [pytest.mark.slow] if _rel(page) in SLOW_PYTHON_PAGES else []
        out.append(pytest.param(page, marks=marks, id=_rel(page)))
    return out


class _TooLong(Exception):
    pass


@pytest.mark.parametrize("page", _python_pages())
def test_python_blocks_run(page, tmp_path, monkeypatch, capsys):
    """A page's Python blocks, in order, in one namespace, from the repository's folder (they
    name its files, e.g. agents/models/), with the caches pointed away from it."""
    _keep_caches_out_of_the_repository(tmp_path, monkeypatch)
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace: dict = {"__name__": f"docs_{page.stem}"}
    skipped = []
    expected = _expected_outputs(page)
    checker = doctest.OutputChecker()
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE

    def too_long(signum, frame):
        raise _TooLong(f"{_rel(page)}: its Python blocks took over {PYTHON_SECONDS} s")

    previous = signal.signal(signal.SIGALRM, too_long)
    signal.alarm(PYTHON_SECONDS)
    try:
        for k, (block, skip) in enumerate(_blocks(page, "python")):
            if skip:
                assert k not in expected, f"{_rel(page)}: block {k} shows an output it never prints"
                skipped.append(f"block {k}: {skip[0]}")
                continue
            capsys.readouterr()
            try:
                # the repository's own pages, not a file from elsewhere
                exec(compile(block, f"{_rel(page)}:python-block-{k}", "exec"), namespace)  # noqa: S102
            except _TooLong:
                raise
            except Exception as exc:  # noqa: BLE001 (any error of a block fails the page)
                pytest.fail(f"{_rel(page)}, Python block {k} raised {exc!r}:\n{block}")
            printed = capsys.readouterr().out
            if k in expected and not checker.check_output(expected[k], printed, flags):
                pytest.fail(f"{_rel(page)}, Python block {k} printed\n{printed}\n"
                            f"where the page shows\n{expected[k]}")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    capsys.readouterr()
    if skipped and len(skipped) == len(_blocks(page, "python")):
        pytest.skip("; ".join(skipped))


# -- running the commands (slow) --------------------------------------------------------------

# Module commands whose output a later command of the same block reads: run them (small).
RUN_IN_BLOCKS = ("python -m saddle_env.calibrate.synthetic",)


def _small(tool: str, args: list[str], tmp: Path) -> list[str]:
    """The documented arguments with the smallest budget their flags allow and every
    output inside ``tmp``."""
    args = [str(tmp / Path(a).name) if a.startswith("/tmp/") else a for a in args]

    def setting(flag: str, value: str) -> None:
        if flag in args:
            args[args.index(flag) + 1] = value
        else:
            args.extend([flag, value])

    if tool == "saddle-eval":
        setting("--episodes", "2")
        setting("--out", str(tmp / "eval"))
        args.extend(["--no-plots", "--no-progress"])
    elif tool == "train.py":
        for flag, value in (("--n-envs", "2"), ("--total-timesteps", "512"),
                            ("--eval-freq", "512"), ("--eval-episodes", "1"),
                            ("--save-freq", "512"), ("--compare-episodes", "2"),
                            ("--log-dir", str(tmp / "runs"))):
            setting(flag, value)
        args.append("--no-progress-bar")
    elif tool == "saddle-bench" and "--replot" not in args:
        args.extend(["--quick", "--quiet", "--no-figures", "--jacobi-periods", "20"])
    elif tool == "saddle-reproduce":
        args.extend(["--quick", "--no-progress"])
    elif tool == "rllib-benchmark":
        for flag, value in (("--seconds", "0.2"), ("--runners", "1"), ("--n-envs", "4"),
                            ("--out", str(tmp / "rllib"))):
            setting(flag, value)
        args.extend(["--no-sync", "--no-figure"])
    elif tool == "env-throughput":
        for flag, value in (("--seconds", "0.02"), ("--num-envs", "16"), ("--sizes", "16"),
                            ("--out", str(tmp / "env"))):
            setting(flag, value)
        args.extend(["--skip-cold", "--no-figure"])
    elif tool == "python -m saddle_env.calibrate.synthetic":
        for flag, value in (("--tracks", "1"), ("--seconds", "0.5")):
            setting(flag, value)
    elif tool == "saddle-fit":
        for flag, value in (("--max-iterations", "2"), ("--out", str(tmp / "fit"))):
            setting(flag, value)
        args.append("--quiet")
    elif tool == "saddle-lifetimes":
        setting("--releases", "2")
    return args


def _main(tool: str):
    if tool == "saddle-sim":
        from saddle_env.cli import main
    elif tool == "saddle-eval":
        from agents.evaluation.evaluate import main
    elif tool == "saddle-export":
        from agents.evaluation.export import main
    elif tool == "saddle-bench":
        from saddle_env.workprecision import main
    elif tool == "saddle-reproduce":
        from saddle_env.reproduce.cli import main
    elif tool == "saddle-fit":
        from saddle_env.calibrate.cli import main
    elif tool == "saddle-lifetimes":
        from saddle_env.lifetimes.cli import main
    elif tool == "env-throughput":
        from saddle_env.envs.throughput import main
    elif tool == "rllib-benchmark":
        from agents.benchmark.rllib_throughput import main
    elif tool == "compile-profile":
        from saddle_env.coldstart.profile import main
    elif tool == "benchmark":
        from agents.benchmark.run import main
    elif tool.startswith("python -m "):
        return importlib.import_module(tool.split()[-1]).main
    elif tool == "train.py":
        sys.path.insert(0, str(ROOT))
        try:
            from train import main
        finally:
            sys.path.remove(str(ROOT))
    else:
        raise AssertionError(f"no entry point known for {tool!r}: add it to _main")
    return main


def _keep_caches_out_of_the_repository(tmp: Path, monkeypatch) -> None:
    """saddle-eval's best-const search caches its result in agents/control/best_const.json: point
    the cache at a copy so that running the docs never edits the repository."""
    import importlib
    import shutil

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp / "cache"))
    for name in ("agents.baselines", "agents.control.best_constant"):
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        for attr in ("CACHE_FILE", "USER_CACHE_FILE"):
            path = getattr(module, attr, None)
            if isinstance(path, Path):
                copy = tmp / "cache" / f"{attr}.json"
                copy.parent.mkdir(parents=True, exist_ok=True)
                if path.is_file():
                    shutil.copy(path, copy)
                monkeypatch.setattr(module, attr, copy)


BLOCKS = [(_rel(page), k, block) for page in PAGES
          for k, (block, skip) in enumerate(_blocks(page, "bash"))
          if not skip and any(_tool(argv)[0] not in ("pip", "pytest", "packaging")
                              for argv in _commands(block))]


@pytest.mark.slow
@pytest.mark.parametrize("page, k, block", BLOCKS, ids=[f"{p}:block{k}" for p, k, _ in BLOCKS])
def test_documented_commands_run(page, k, block, tmp_path, monkeypatch, capsys):
    """Every command of a block, in order, in one temporary folder (a later command may
    read what an earlier one wrote, as in the docs)."""
    commands = _commands(block)
    if any(_tool(a)[0] == "ray" or "--address" in a for a in commands):
        pytest.skip("a Ray cluster's commands (ray start, --address) are not run here")
    if any(_tool(a)[0] == "rllib-benchmark" or "rllib" in a for a in commands):
        pytest.importorskip("ray")
    monkeypatch.chdir(tmp_path)
    _keep_caches_out_of_the_repository(tmp_path, monkeypatch)
    for argv in commands:
        tool, args = _tool(argv)
        if tool in ("pip", "pytest", "packaging"):
            continue
        if (tool.startswith("python -m ") and "--help" not in args
                and tool not in RUN_IN_BLOCKS):
            continue  # documented and parsed above; its own tests run it
        if "--help" in args:
            with pytest.raises(SystemExit) as exc:
                _main(tool)(args)
            assert exc.value.code == 0
            continue
        # /tmp paths of the docs move into tmp_path first; then repository paths become
        # absolute (the clone itself may live under /tmp, as CI's does)
        small = [str(ROOT / a) if a.startswith("agents/") else a
                 for a in _small(tool, args, tmp_path)]
        code = _main(tool)(small)
        assert code in (0, None), f"{page}: {' '.join(argv)} exited with {code}"
    capsys.readouterr()


def test_the_benchmark_tables_come_from_its_shipped_run():
    """The accuracy page's tables are rendered from the benchmark's results, so a changed
    row of the CSV changes the page (no figure typed by hand)."""
    from saddle_env.workprecision import report, tables

    rows = report.read_rows(DOCS / "figures" / "bench_results.csv")
    page = HOOKS.expand((DOCS / "accuracy.md").read_text())
    assert tables.rolling_markdown(rows) in page
    default = tables.select(rows, {"solver": "saddle_env", "label": "dop853 rtol",
                                   "rtol": 1e-10})[0]
    changed = [dict(r, us_per_sim_s=12345.0) if r is default else r for r in rows]
    assert "| 12\u202f345 |" in tables.rolling_markdown(changed)
    with pytest.raises(LookupError, match="no run"):
        tables.select(rows, {"label": "no such setting"})
