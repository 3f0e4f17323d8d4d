"""MkDocs hooks: the reference sections that are generated from the code, so they cannot drift.

A page asks for a generated section with an HTML comment on a line of its own:

* ``<!-- generated: env-options -->``: every option of ``saddle_env.envs.EnvConfig``, grouped
  as its docstring groups them, with its type and default read from the dataclass. An option
  that the docstring does not name fails the build.
* ``<!-- generated: cli NAME -->``: the command line NAME (a key of ``CLIS``), read from its
  own argparse parser: usage, description and one table per argument group.
* ``<!-- generated: level-summary -->``: one row per registered task level (Gymnasium's
  registry), and ``<!-- generated: level-summary ID -->`` the same facts for one level as a
  two-column table: action space, observation shape, reward, episode length,
  ``reward_threshold`` and the line that makes it, read from ``gym.spec(ID)`` and from the
  spaces of an environment made from it.
* ``<!-- generated: include FILE -->``: FILE of the repository's top folder (CHANGELOG.md,
  CONTRIBUTING.md) as it is, so the site shows it without a second copy; its links, written
  from the top folder, are made to work from the page: ``docs/X`` to the site's page X, any
  other file of the repository to its address in ``repo_url``.
* ``<!-- generated: public-api -->``: every name of ``saddle_env.__all__``: its kind
  (function, class, constant), its docstring's first line or its value, and for a function
  or class a link to its entry below on the API page.
* ``<!-- generated: lifetimes-calibration -->``, ``lifetimes-validation``,
  ``lifetimes-sizes`` and ``lifetimes-onset-budget``: the real-saddle calibration, its
  held-out check, its size hold-out and its onset budget, from the files the calibration
  ships.
* ``<!-- generated: bench-rolling -->`` and ``bench-targets``: the work-precision benchmark's
  table of settings and of targets, from its shipped run (``docs/figures/bench_results.csv``,
  ``bench_summary.json``; ``saddle_env.workprecision.tables``).

A measured figure in a page's prose is a marker pair, ``<!-- fig NAME -->copy<!-- /fig -->``,
which the hook replaces by the figure's current value from the figure store
(``agents.figures``, ``docs/figures/figures.yml``); an unknown name fails the build.

The engineering notes (``notes/``) are ranked below the user pages in the site's search
(``NOTES_SEARCH_BOOST``, the theme's per-page ``search: boost``): a reader looking up the
observation space should meet the reference first, not a dated measurement.

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


def clone_first_on_path() -> None:
    """Put the clone's folder first on ``sys.path``.

    The hooks read the clone's own ``agents/`` folder as the package ``agents`` (the figure
    store, the command lines' parsers) and its ``train.py``; an install names that folder
    ``saddle_agents``, and only ``python -m mkdocs`` run from the clone's root would have put
    the clone on the path. With the clone first, the ``mkdocs`` console script, run from any
    folder (``-f path/mkdocs.yml``), documents this clone's code. Called on import (the tests
    import these functions) and again in ``on_config``: mkdocs restores ``sys.path`` after it
    has loaded a hook file.
    """
    if sys.path[:1] != [str(ROOT)]:
        sys.path.insert(0, str(ROOT))


clone_first_on_path()
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
        # `train` is the clone's train.py: ROOT is on the path (above)
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
    "saddle-bench": _build_parser("saddle_env.workprecision"),
    "python -m saddle_env.workprecision.profile": _from_main("saddle_env.workprecision.profile"),
    "saddle-reproduce": _build_parser("saddle_env.reproduce.cli"),
    "python -m agents.benchmark": _build_parser("agents.benchmark.run"),
    "python -m agents.benchmark.leaderboard": _build_parser("agents.benchmark.leaderboard"),
    "python -m agents.figures": _build_parser("agents.figures"),
    "python -m agents.remeasure": _build_parser("agents.remeasure"),
    "python -m agents.benchmark.time_to_target": _from_main("agents.benchmark.time_to_target"),
    "python -m agents.benchmark.profile_training": _from_main("agents.benchmark.profile_training"),
    "python -m agents.benchmark.rllib_throughput": _build_parser("agents.benchmark.rllib_throughput"),
    "python -m agents.benchmark.headroom": _from_main("agents.benchmark.headroom"),
    "python -m agents.benchmark.ship": _from_main("agents.benchmark.ship"),
    "python -m agents.benchmark.deploy_latency": _build_parser("agents.benchmark.deploy_latency"),
    "python -m saddle_env.envs.throughput": _from_main("saddle_env.envs.throughput"),
    "python -m saddle_env.coldstart.profile": _build_parser("saddle_env.coldstart.profile"),
    "python -m saddle_env.coldstart.precompile": _build_parser("saddle_env.coldstart.precompile"),
    "python -m saddle_env.rig": _build_parser("saddle_env.rig.__main__"),
    "saddle-lifetimes": _build_parser("saddle_env.lifetimes.cli"),
    "python -m saddle_env.lifetimes.fit": _from_main("saddle_env.lifetimes.fit"),
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


# -- the task levels at a glance -------------------------------------------------------------

def registered_levels() -> list[str]:
    """Every id of Gymnasium's registry that makes a SaddleTrap environment, in registration
    order (importing ``saddle_env`` registers them)."""
    import gymnasium as gym

    import saddle_env  # noqa: F401  (registers the levels)

    return [env_id for env_id, spec in gym.registry.items()
            if str(spec.entry_point).startswith("saddle_env.")]


def level_facts(env_id: str) -> dict[str, str]:
    """What a Gymnasium user looks up first about ``env_id``, as Markdown cells: from its
    registered spec and the spaces of an environment made from it."""
    import gymnasium as gym

    from saddle_env.envs import EnvConfig

    spec = gym.spec(env_id)
    env = gym.make(env_id)
    try:
        action, observation = env.action_space, env.observation_space
        config = env.unwrapped.config
    finally:
        env.close()
    if not isinstance(config, EnvConfig):
        raise RuntimeError(f"{env_id}: its environment has no EnvConfig")
    box = observation
    low, high = float(box.low.min()), float(box.high.max())
    worst = -(config.loss_penalty + config.distance_cost + config.effort_cost)
    steps = spec.max_episode_steps
    seconds = steps * config.control_period if steps else None
    return {
        "id": f"`{env_id}`",
        "action space": f"`{_cell(action)}`",
        "observation shape": f"`{box.shape}` {box.dtype}, in [{low:g}, {high:g}]",
        "reward per step": f"[{worst:g}, 1]",
        "episode": (f"{steps} steps ({seconds:g} s)" if steps else "no time limit"),
        "reward_threshold": "none" if spec.reward_threshold is None else f"{spec.reward_threshold:g}",
        "make it": f'`gym.make("{env_id}")`',
    }


def _level_summary(env_id: str) -> str:
    from saddle_env.envs import LEVEL_IDS, get_level

    return get_level(env_id).summary if env_id in LEVEL_IDS else ""


_IMPORT_LINE = "`import gymnasium as gym; import saddle_env` (registers every level)"


def level_summary_markdown(env_id: str | None = None) -> str:
    """All levels, one row each (a fact every level shares said once, above the table); or
    one level, one fact a row."""
    if env_id is None:
        rows = []
        for level_id in registered_levels():
            facts = level_facts(level_id)
            del facts["make it"]  # the id is the argument of gym.make
            rows.append({"id": facts.pop("id"), "what it is": _cell(_level_summary(level_id)),
                         **facts})
        shared = [k for k in list(rows[0])[2:] if len({r[k] for r in rows}) == 1]
        keys = [k for k in rows[0] if k not in shared]
        lines = ["Every level: " + "; ".join(f"**{k}** {rows[0][k]}" for k in shared) + ".", "",
                 f"| {' | '.join(keys)} |", "|" + "---|" * len(keys)]
        lines += [f"| {' | '.join(r[k] for k in keys)} |" for r in rows]
        return "\n".join([*lines, "", f"Import: {_IMPORT_LINE}. Generated from Gymnasium's "
                           "registry when the site is built."])
    if env_id not in registered_levels():
        raise RuntimeError(f"no registered level {env_id!r}")
    facts = level_facts(env_id)
    lines = [f"| level | `{env_id}` |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in facts.items() if k != "id"]
    lines.append(f"| import | {_IMPORT_LINE} |")
    return "\n".join(lines)


# -- the public API --------------------------------------------------------------------------

# Where the API page renders a public name, when not under ``saddle_env.NAME`` itself (a
# submodule of the same name takes that path: ``saddle_env.simulate`` is also a module).
API_IDENTIFIER = {"simulate": "saddle_env.simulate.simulate"}


def _api_value(value: object) -> str:
    if isinstance(value, (tuple, list)) and value and all(hasattr(v, "id") for v in value):
        return "the registered levels: " + ", ".join(f"`{v.id}`" for v in value)
    if callable(getattr(value, "keys", None)):
        return "by name: " + ", ".join(f"`{k}`" for k in value.keys())
    return f"`{_cell(repr(value))}`"


def public_api() -> list[tuple[str, str, str]]:
    """(name, kind, summary) for each name of ``saddle_env.__all__``, in its order."""
    import inspect

    import saddle_env

    rows = []
    for name in saddle_env.__all__:
        obj = getattr(saddle_env, name)
        if inspect.isclass(obj) or inspect.isfunction(obj):
            kind = "class" if inspect.isclass(obj) else "function"
            summary = _rst_to_markdown((inspect.getdoc(obj) or "").split("\n\n")[0])
        else:
            kind, summary = "constant", _api_value(obj)
        rows.append((name, kind, summary))
    return rows


def public_api_markdown() -> str:
    """One table per kind: the functions, the classes (each linked to its entry on the API
    page), the constants with their values."""
    rows = public_api()
    lines: list[str] = []
    for kind, title, what in (("function", "Functions", "what it does"),
                              ("class", "Classes", "what it is"),
                              ("constant", "Constants", "value")):
        lines += [f"**{title}**", "", f"| name | {what} |", "|---|---|"]
        for name, k, summary in rows:
            if k != kind:
                continue
            if kind == "constant":
                lines.append(f"| `{name}` | {summary} |")
            else:
                target = API_IDENTIFIER.get(name, f"saddle_env.{name}")
                shown = f"{name}()" if kind == "function" else name
                lines.append(f"| [`{shown}`][{target}] | {_cell(summary)} |")
        lines.append("")
    return "\n".join(lines)


# -- files of the top folder as pages ---------------------------------------------------------

INCLUDABLE = ("CHANGELOG.md", "CONTRIBUTING.md")
_MD_LINK = re.compile(r"(?<!!)\[(?P<text>[^\]]*)\]\((?P<target>[^)\s]+)\)")


def _repo_url() -> str:
    text = (ROOT / "mkdocs.yml").read_text()
    m = re.search(r"^repo_url:\s*(\S+)", text, flags=re.MULTILINE)
    if not m:
        raise RuntimeError("mkdocs.yml has no repo_url: the included files' links need it")
    return m.group(1).rstrip("/")


def include_markdown(name: str, page_dir: str = "") -> str:
    """The top folder's file ``name`` for a page in ``docs/page_dir``, its links rewritten."""
    if name not in INCLUDABLE:
        raise RuntimeError(f"include {name!r}: only {', '.join(INCLUDABLE)}")
    up = "../" * len([p for p in page_dir.split("/") if p])

    def relink(m: re.Match) -> str:
        target = m.group("target")
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            return m.group(0)
        path, _, anchor = target.partition("#")
        if path.startswith("docs/"):
            new = up + path[len("docs/"):]
        else:
            new = f"{_repo_url()}/blob/main/{path}"
        return f"[{m.group('text')}]({new}{'#' + anchor if anchor else ''})"

    return _MD_LINK.sub(relink, (ROOT / name).read_text())


# -- the hook --------------------------------------------------------------------------------

def version_markdown() -> str:
    from saddle_env import __version__

    return (f"These pages describe saddle-env {__version__} (`saddle_env.__version__`; "
            "[changes](https://github.com/saddle-env/saddle-env/blob/main/CHANGELOG.md)).")


def generate(what: str, arg: str | None, page_dir: str = "") -> str:
    if what == "version":
        return version_markdown()
    if what == "env-options":
        return env_options_markdown()
    if what == "cli":
        if arg not in CLIS:
            raise RuntimeError(f"no command line {arg!r} in docs/hooks.py's CLIS")
        return cli_markdown(arg)
    if what == "include":
        return include_markdown(arg or "", page_dir)
    if what == "public-api":
        return public_api_markdown()
    if what == "level-summary":
        return level_summary_markdown(arg)
    if what in ("lifetimes-calibration", "lifetimes-validation", "lifetimes-sizes",
                "lifetimes-onset-budget"):
        return lifetimes_markdown(what)
    if what in ("bench-rolling", "bench-targets"):
        return bench_markdown(what)
    raise RuntimeError(f"unknown generated section {what!r}")


def lifetimes_markdown(what: str) -> str:
    """The validation page's tables, from the files the calibration wrote: the shipped
    calibration (saddle_env/lifetimes/calibration.json) and its leave-one-series-out check
    (docs/figures/lifetimes_validation.json)."""
    import json

    from saddle_env.lifetimes import report

    if what == "lifetimes-calibration":
        record = json.loads((ROOT / "saddle_env" / "lifetimes" / "calibration.json").read_text())
        return report.calibration_markdown(record)
    if what in ("lifetimes-sizes", "lifetimes-onset-budget"):
        sizes = json.loads((ROOT / "docs" / "figures" / "lifetimes_sizes.json").read_text())
        return (report.size_holdout_markdown(sizes) if what == "lifetimes-sizes"
                else report.onset_budget_markdown(sizes))
    rows = json.loads((ROOT / "docs" / "figures" / "lifetimes_validation.json").read_text())
    coverage = json.loads((ROOT / "docs" / "figures" / "lifetimes_coverage.json").read_text())
    return report.validation_markdown(rows, coverage)


def bench_markdown(what: str) -> str:
    """The accuracy page's tables, from the shipped run of the work-precision benchmark
    (docs/figures/bench_results.csv and bench_summary.json)."""
    import json

    from saddle_env.workprecision import report, tables

    if what == "bench-rolling":
        return tables.rolling_markdown(report.read_rows(ROOT / "docs" / "figures"
                                                        / "bench_results.csv"))
    summary = json.loads((ROOT / "docs" / "figures" / "bench_summary.json").read_text())
    return tables.targets_markdown(summary)


def expand(markdown: str, page_dir: str = "") -> str:
    return MARKER.sub(lambda m: generate(m.group("what"), m.group("arg"), page_dir), markdown)


# The notes' weight in the search ranking (the user pages' is 1): still found, listed after.
NOTES_SEARCH_BOOST = 0.1


# A page of the docs named by its path in the repository, as help strings, docstrings and
# the levels' descriptions name them (they are read in a terminal too): ``docs/X.md``, with
# an optional anchor. Not when it is part of a longer path or already a link's target.
_DOC_REF = re.compile(r"(?<![\w/.-])docs/(?P<path>[\w./-]+?\.md)(?P<anchor>#[\w-]+)?(?![\w/-])")
_TAG = re.compile(r"(<[^>]*>)")
# Where a reference stays text: inside a link already, and in code blocks (commands to copy).
_NO_LINK_TAGS = frozenset({"a", "pre", "script", "style", "textarea", "title"})


def link_doc_references(html: str, page, files) -> str:
    """Every ``docs/X.md`` in the page's text made a link to page X of the site (its code
    spans included: a link around the path's own text). A path that names no page of the
    site fails the build, as a broken Markdown link does under ``--strict``."""

    def link(m: re.Match) -> str:
        target = files.get_file_from_path(m.group("path"))
        if target is None:
            raise RuntimeError(f"{page.file.src_uri}: docs/{m.group('path')} names no page "
                               "of the site")
        href = target.url_relative_to(page.file) + (m.group("anchor") or "")
        return f'<a href="{href}">{m.group(0)}</a>'

    out: list[str] = []
    inside = 0  # depth of the tags of _NO_LINK_TAGS around this text
    for part in _TAG.split(html):
        if part.startswith("<"):
            tag = re.match(r"<(/?)\s*([A-Za-z][\w-]*)", part)
            if tag and tag.group(2).lower() in _NO_LINK_TAGS and not part.endswith("/>"):
                inside += -1 if tag.group(1) else 1
            out.append(part)
        elif inside or "docs/" not in part:
            out.append(part)
        else:
            out.append(_DOC_REF.sub(link, part))
    return "".join(out)


def on_page_content(html, page, config, files):
    return link_doc_references(html, page, files)


def on_config(config):
    clone_first_on_path()
    return config


def on_page_markdown(markdown, page, config, files):
    from agents import figures

    if page.file.src_uri.startswith("notes/"):
        page.meta.setdefault("search", {"boost": NOTES_SEARCH_BOOST})
    # after the includes: CONTRIBUTING.md states figures too
    markdown = expand(markdown, Path(page.file.src_uri).parent.as_posix().strip("."))
    return figures.render(markdown, keep_markers=False)
