"""The documentation runs as written: README.md and docs/*.md.

* every command in a ```bash block is one the project knows, and its arguments are accepted
  by the tool's own argument parser (the parsers are imported, not copied); files a command
  reads (a model for saddle-eval, a test file for pytest, an extra for pip) exist;
* every repository path the docs mention (docs/..., agents/..., saddle_env/..., tests/...,
  figures/... from inside docs/) exists, and every Markdown link to a local file resolves,
  down to the heading it points at;
* the flag lists written out in prose match the parsers (saddle-sim's table, train.py's list);
* (slow) every command is run for real, in a temporary folder, with the smallest budget
  its flags allow.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PENDING: set[str] = set()  # pages another change still has to write (none now)
TOOLS = ("saddle-sim", "saddle-eval", "saddle-bench", "saddle-reproduce")


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _text_outside_code(text: str) -> str:
    return re.sub(r"```.*?```", "", text, flags=re.S)


def _bash_blocks(page: Path) -> list[str]:
    return re.findall(r"```bash\n(.*?)```", page.read_text(), flags=re.S)


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
        if argv[1:3] == ["-m", "saddle_env.envs.benchmark"]:
            return "env-benchmark", argv[3:]
        if argv[1:3] == ["-m", "agents.benchmark.rllib_throughput"]:
            return "rllib-benchmark", argv[3:]
        if argv[1:3] == ["-m", "agents.benchmark.run"]:
            return "benchmark", argv[3:]
        if argv[1:3] == ["-m", "saddle_env.compilation.profile"]:
            return "compile-profile", argv[3:]
    if argv[0] == "ray" and argv[1:2] in (["start"], ["stop"], ["status"]):
        return "ray", argv[1:]          # Ray's own CLI (docs/scaling.md): not run by the tests
    if argv[:2] == ["pip", "install"]:
        return "pip", argv[2:]
    return "", argv


def _extras() -> set[str]:
    """The optional-dependency groups of pyproject.toml (no tomllib before Python 3.11)."""
    text = (ROOT / "pyproject.toml").read_text()
    section = text.split("[project.optional-dependencies]", 1)[1].split("\n[", 1)[0]
    return set(re.findall(r"^(\w+)\s*=", section, flags=re.M))


class _Parsed(Exception):
    pass


def _parser(tool: str) -> argparse.ArgumentParser | None:
    if tool == "saddle-sim":
        from saddle_env.cli import build_parser
    elif tool == "saddle-eval":
        from agents.evaluation.evaluate import build_parser
    elif tool == "saddle-bench":
        from saddle_env.bench import build_parser
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
        from saddle_env.compilation.profile import build_parser
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
            from saddle_env.envs import benchmark

            original = argparse.ArgumentParser.parse_args

            def parse_then_stop(self, a=None, namespace=None):
                raise _Parsed(original(self, a, namespace))

            argparse.ArgumentParser.parse_args = parse_then_stop
            try:
                benchmark.main(args)
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
    return {_slug(h) for h in re.findall(r"^#{1,6} (.+)$", text, flags=re.M)}


_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
LINK_CASES = [(page, target) for page in PAGES
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


def test_every_docs_page_is_linked_from_the_readme():
    readme = (ROOT / "README.md").read_text()
    for page in PAGES[1:]:
        assert f"({_rel(page)})" in readme, f"README.md does not link {_rel(page)}"


# -- flag lists written out in prose ----------------------------------------------------------

def _long_flags(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings
            if s.startswith("--") and s != "--help"}


def test_saddle_sim_flag_table_matches_its_parser():
    text = (ROOT / "docs" / "simulator.md").read_text()
    rows = [line for line in text.splitlines() if line.startswith("| `--")]
    documented = {f for row in rows for f in re.findall(r"`(--[A-Za-z][\w-]*)", row)}
    assert documented == _long_flags(_parser("saddle-sim"))


def test_train_flag_list_matches_its_parser():
    text = (ROOT / "docs" / "agents.md").read_text()
    start = text.index("`train.py` (at the repository root)")
    paragraph = text[start:text.index("\n\n", start)]
    documented = set(re.findall(r"`(--[A-Za-z][\w-]*)", paragraph))
    assert documented == _long_flags(_parser("train.py"))


def test_readme_keeps_the_ci_test_command():
    lines = (ROOT / "README.md").read_text().splitlines()
    i = lines.index("<!-- test-command -->")
    assert lines[i + 1] == "```bash"
    assert lines[i + 2].endswith("python -m pytest")


# -- running the commands (slow) --------------------------------------------------------------

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
    elif tool == "env-benchmark":
        for flag, value in (("--seconds", "0.02"), ("--num-envs", "16"), ("--sizes", "16"),
                            ("--out", str(tmp / "env"))):
            setting(flag, value)
        args.extend(["--skip-cold", "--no-figure"])
    return args


def _main(tool: str):
    if tool == "saddle-sim":
        from saddle_env.cli import main
    elif tool == "saddle-eval":
        from agents.evaluation.evaluate import main
    elif tool == "saddle-bench":
        from saddle_env.bench import main
    elif tool == "saddle-reproduce":
        from saddle_env.reproduce.cli import main
    elif tool == "env-benchmark":
        from saddle_env.envs.benchmark import main
    elif tool == "rllib-benchmark":
        from agents.benchmark.rllib_throughput import main
    elif tool == "compile-profile":
        from saddle_env.compilation.profile import main
    else:
        sys.path.insert(0, str(ROOT))
        try:
            from train import main
        finally:
            sys.path.remove(str(ROOT))
    return main


def _keep_caches_out_of_the_repository(tmp: Path, monkeypatch) -> None:
    """saddle-eval's best-const search caches its result in agents/best_const.json: point
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


BLOCKS = [(_rel(page), k, block) for page in PAGES for k, block in enumerate(_bash_blocks(page))
          if any(_tool(argv)[0] not in ("pip", "pytest") for argv in _commands(block))]


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
        if tool in ("pip", "pytest"):
            continue
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
