"""Every figure a user page quotes (the README, CONTRIBUTING and docs/ outside docs/notes/)
names the command that measured it, and every figure's date is a date.

A figure whose command was "not recorded", or whose output was "not kept", either leaves the
user pages (the engineering notes may keep it, dated) or is measured again with a command.
KNOWN_WITHOUT_COMMAND lists the ones still quoted that way, each with where it is quoted;
the list only shrinks: the test fails on a new one, and on one listed that has been fixed.
"""

from __future__ import annotations

import re

import pytest

from agents import figures

NO_COMMAND = re.compile(r"not recorded|output not kept", re.IGNORECASE)

# Quoted on a user page, measured without a kept command. Each awaits a re-measurement by
# the command the store names, into a results file, or leaves its page. (Empty: the last
# eight were measured again or left their pages on 2026-11-29.)
KNOWN_WITHOUT_COMMAND: set[str] = set()


def _store_name(name: str) -> str:
    """The store entry a marker's name reads: itself, or the table that holds the cell."""
    store = figures.figures()
    while name not in store and "." in name:
        name = name.rsplit(".", 1)[0]
    return name


def _quoted_on_user_pages() -> dict[str, set[str]]:
    quoted: dict[str, set[str]] = {}
    for path in figures.rendered_files():
        rel = path.relative_to(figures.REPO_ROOT).as_posix()
        if rel.startswith("docs/notes/"):
            continue
        for m in figures.MARKER.finditer(path.read_text()):
            quoted.setdefault(_store_name(m.group("name")), set()).add(rel)
    return quoted


def _has_command(name: str) -> bool:
    command = str(figures.find_figure(name).get("command") or "")
    return bool(command.strip()) and not NO_COMMAND.search(command)


def test_the_pattern_finds_an_unrecorded_command():
    assert NO_COMMAND.search("not recorded (timed while writing saddle-bench)")
    assert NO_COMMAND.search("/usr/bin/time saddle-bench --quick --out /tmp/b (output not kept)")
    assert not NO_COMMAND.search("python train.py --backend sbx")


def test_every_quoted_figure_has_a_command():
    quoted = _quoted_on_user_pages()
    assert len(quoted) > 100, len(quoted)
    lacking = {n: sorted(pages) for n, pages in quoted.items()
               if not _has_command(n) and n not in KNOWN_WITHOUT_COMMAND}
    assert not lacking, ("figures quoted on user pages without a recorded command (measure "
                         f"them again with one, or move them to docs/notes/): {lacking}")


def test_the_list_of_known_exceptions_only_shrinks():
    quoted = _quoted_on_user_pages()
    fixed = sorted(n for n in KNOWN_WITHOUT_COMMAND if n not in quoted or _has_command(n))
    assert not fixed, f"no longer quoted without a command: take them off the list: {fixed}"


def test_every_date_is_a_date():
    for name, figure in figures.figures().items():
        assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", str(figure["date"])), (name, figure["date"])


@pytest.mark.parametrize("date", ["2026-11-25 to 2026-11-27", "2026-11", "yesterday",
                                  "27 Nov 2026"])
def test_a_store_date_that_is_not_a_date_is_refused(tmp_path, date):
    store = tmp_path / "figures.yml"
    store.write_text(f"x:\n  value: 1\n  unit: s\n  date: {date}\n  machine: m\n  command: c\n")
    with pytest.raises(figures.FigureError, match=r"'x': date .* is not a date"):
        figures.load_store(store)


def test_show_prints_a_table_figure_cell_by_cell(capsys):
    # it stopped with a KeyError on a table's rows (no "mean")
    assert figures.main(["--show", "accuracy-coulomb-tier"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("accuracy-coulomb-tier: a table [")
    assert "\naccuracy-coulomb-tier.rtol-1e-10.coulomb_error = " in out and "  date: " in out
