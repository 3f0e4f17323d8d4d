"""MkDocs hooks: the reference sections that are generated from the code, so they cannot drift.

A page asks for a generated section with an HTML comment on a line of its own:

* ``<!-- generated: env-options -->``: every option of ``saddle_env.envs.EnvConfig``, grouped
  as its docstring groups them, with its type and default read from the dataclass. An option
  that the docstring does not name fails the build.
* ``<!-- generated: cli NAME -->``: the command line NAME (a key of ``CLIS``), read from its
  own argparse parser: usage, description and one table per argument group.
* ``<!-- generated: version -->``: the version these pages describe, ``saddle_env.__version__``
  (pyproject.toml reads the same).

The same functions serve the tests (tests/test_docs.py), which check that every documented
command line has a page section and that the generated text matches the parsers.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import re
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"^<!-- generated: (?P<what>[\w-]+)(?: (?P<arg>[^>]*?))? -->$", re.MULTILINE)


# -- command lines ---------------------------------------------------------------------------

class _Captured(Exception):
    """Raised by the patched ``parse_args`` to hand back a parser built inside ``main``."""


def _from_main(module: str) -> Callable[[], argparse.ArgumentParser]:
    """A parser that ``module.main`` builds for itself: call ``main`` with ``parse_args``
    patched to stop it there, before it does anything."""

    def build() -> argparse.ArgumentParser:
        main = importlib.import_module(module).main
        original = argparse.ArgumentParser.parse_args

        def capture(self, args=None, namespace=None):
            raise _Captured(self)

        argparse.ArgumentParser.parse_args = capture
        try:
            main([])
        except _Captured as done:
            return done.args[0]
        finally:
            argparse.ArgumentParser.parse_args = original
        raise RuntimeError(f"{module}.main() returned without parsing its arguments")

    return build


def _build_parser(module: str) -> Callable[[], argparse.ArgumentParser]:
    def build() -> argparse.ArgumentParser:
        if module == "train":
            sys.path.insert(0, str(ROOT))
            try:
                return importlib.import_module("train").build_parser()
            finally:
                sys.path.remove(str(ROOT))
        return importlib.import_module(module).build_parser()

    return build


# Every command line the docs document: its name as typed, and how to get its parser.
CLIS: dict[str, Callable[[], argparse.ArgumentParser]] = {
    "train.py": _build_parser("train"),
    "saddle-eval": _build_parser("agents.evaluation.evaluate"),
    "saddle-export": _build_parser("agents.evaluation.export"),
    "saddle-fit": _build_parser("saddle_env.calibrate.cli"),
    "python -m saddle_env.calibrate.synthetic": _build_parser("saddle_env.calibrate.synthetic"),
    "saddle-sim": _build_parser("saddle_env.cli"),
    "saddle-bench": _build_parser("saddle_env.bench"),
    "saddle-reproduce": _build_parser("saddle_env.reproduce.cli"),
    "python -m agents.benchmark": _build_parser("agents.benchmark.run"),
    "python -m agents.benchmark.leaderboard": _build_parser("agents.benchmark.leaderboard"),
    "python -m agents.benchmark.time_to_target": _from_main("agents.benchmark.time_to_target"),
    "python -m agents.benchmark.profile_training": _from_main("agents.benchmark.profile_training"),
    "python -m agents.benchmark.rllib_throughput": _build_parser("agents.benchmark.rllib_throughput"),
    "python -m agents.benchmark.headroom": _from_main("agents.benchmark.headroom"),
    "python -m agents.benchmark.ship": _from_main("agents.benchmark.ship"),
    "python -m agents.benchmark.deploy_latency": _build_parser("agents.benchmark.deploy_latency"),
    "python -m saddle_env.envs.benchmark": _from_main("saddle_env.envs.benchmark"),
    "python -m saddle_env.compilation.profile": _build_parser("saddle_env.compilation.profile"),
    "python -m saddle_env.compilation.precompile": _build_parser("saddle_env.compilation.precompile"),
    "python -m saddle_env.rig": _build_parser("saddle_env.rig.__main__"),
}


def parser_for(name: str) -> argparse.ArgumentParser:
    parser = CLIS[name]()
    parser.prog = name
    return parser


def _cell(text: str) -> str:
    """One table cell: one line, no column breaks, no stray HTML (`const-<K>`)."""
    text = " ".join(str(text).split()).replace("|", "\\|")
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _option_cell(action: argparse.Action) -> str:
    if not action.option_strings:
        return f"`{action.metavar or action.dest}`"
    names = ", ".join(f"`{s}`" for s in action.option_strings)
    if action.nargs == 0:
        return names
    metavar = action.metavar or (action.dest.upper() if action.choices is None else None)
    if isinstance(metavar, tuple):
        metavar = " ".join(metavar)
    if metavar:
        suffix = {"*": f" [{metavar} ...]", "+": f" {metavar} [...]", "?": f" [{metavar}]"}
        names += f" `{suffix.get(action.nargs, ' ' + metavar).strip()}`"
    return names


def _default_cell(action: argparse.Action) -> str:
    default = action.default
    if action.nargs == 0 or default is None or default is argparse.SUPPRESS:
        return ""
    if isinstance(default, (list, tuple)) and not default:
        return ""
    if isinstance(default, Path):
        default = default.as_posix()
    return f"`{_cell(default)}`" if str(default) else '`""`'


def _help_cell(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    text = ""
    if action.help and action.help is not argparse.SUPPRESS:
        formatter = parser._get_formatter()
        # the default has its own column: drop what ArgumentDefaultsHelpFormatter appends
        text = re.sub(r"\s*\(default: [^()]*\)$", "", formatter._expand_help(action))
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        text += f" (one of: {', '.join(f'`{c}`' for c in action.choices)})"
    return _cell(text)


def cli_markdown(name: str) -> str:
    """The reference of one command line, from its parser."""
    parser = parser_for(name)
    usage = parser.format_usage().strip()
    lines = ["```text", usage, "```", ""]
    if parser.description:
        lines += [parser.description.strip(), ""]
    for group in parser._action_groups:
        actions = [a for a in group._group_actions
                   if a.help is not argparse.SUPPRESS and not isinstance(a, argparse._HelpAction)]
        if not actions:
            continue
        title = group.title or "arguments"
        lines += [f"**{title[0].upper() + title[1:]}**", ""]
        if group.description:
            lines += [group.description.strip(), ""]
        lines += ["| argument | default | what it does |", "|---|---|---|"]
        for action in actions:
            lines.append(f"| {_option_cell(action)} | {_default_cell(action)} "
                         f"| {_help_cell(parser, action)} |")
        lines.append("")
    if parser.epilog:
        lines += [parser.epilog.strip(), ""]
    return "\n".join(lines)


# -- the environment's options ---------------------------------------------------------------

def _rst_to_markdown(text: str) -> str:
    return re.sub(r"``(.+?)``", r"`\1`", " ".join(text.split()))


def env_option_groups() -> list[tuple[str, str, list[dataclasses.Field]]]:
    """(group title, its text, its fields) in the order of ``EnvConfig``'s docstring: a
    field belongs to the first paragraph that names it as ``name``. Raises if a field is
    named nowhere, so a new option cannot reach the docs undocumented."""
    from saddle_env.envs import EnvConfig

    paragraphs = [p for p in (EnvConfig.__doc__ or "").split("\n\n") if p.strip()][1:]
    fields = {f.name: f for f in dataclasses.fields(EnvConfig)}
    placed: set[str] = set()
    groups = []
    for paragraph in paragraphs:
        spans = re.findall(r"``(.+?)``", paragraph, flags=re.DOTALL)
        names = [n for span in spans for n in re.split(r"[,\s]+", span)]
        named = list(dict.fromkeys(n for n in names if n in fields and n not in placed))
        if not named:
            continue
        placed.update(named)
        head = paragraph.strip().partition(":")[0]
        title = re.sub(r"\s*\(.*", "", head).strip()
        groups.append((title, _rst_to_markdown(paragraph), [fields[n] for n in named]))
    missing = sorted(set(fields) - placed)
    if missing:
        raise RuntimeError(f"EnvConfig's docstring does not describe {', '.join(missing)}: "
                           "name each option as ``name`` in the paragraph of its group")
    return groups


def _type_cell(field: dataclasses.Field) -> str:
    t = field.type if isinstance(field.type, str) else getattr(field.type, "__name__", str(field.type))
    return f"`{_cell(t.replace(' | ', ' or '))}`"


def env_options_markdown() -> str:
    from saddle_env.envs import EnvConfig

    default = EnvConfig()
    intro = (f"Generated from `saddle_env.envs.EnvConfig` ({len(dataclasses.fields(EnvConfig))} "
             "options): the names, types and defaults are the dataclass's, the text its "
             "docstring's. The defaults are those of `SaddleTrap-v0`; each level overrides "
             "some ([levels](levels.md)).")
    lines = [intro, ""]
    for title, text, fields in env_option_groups():
        lines += [f"### {title}", "", text, "", "| option | type | default |", "|---|---|---|"]
        for f in fields:
            lines.append(f"| `{f.name}` | {_type_cell(f)} | `{_cell(repr(getattr(default, f.name)))}` |")
        lines.append("")
    return "\n".join(lines)


# -- the hook --------------------------------------------------------------------------------

def version_markdown() -> str:
    from saddle_env import __version__

    return (f"These pages describe saddle-env {__version__} (`saddle_env.__version__`; "
            "[changes](https://github.com/saddle-env/saddle-env/blob/main/CHANGELOG.md)).")


def generate(what: str, arg: str | None) -> str:
    if what == "version":
        return version_markdown()
    if what == "env-options":
        return env_options_markdown()
    if what == "cli":
        if arg not in CLIS:
            raise RuntimeError(f"no command line {arg!r} in docs/hooks.py's CLIS")
        return cli_markdown(arg)
    raise RuntimeError(f"unknown generated section {what!r}")


def expand(markdown: str) -> str:
    return MARKER.sub(lambda m: generate(m.group("what"), m.group("arg")), markdown)


def on_page_markdown(markdown, page, config, files):
    return expand(markdown)
