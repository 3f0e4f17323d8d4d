"""python -m agents.remeasure: every quick figure's command, from a fixed table, re-run in one
step; the results file it writes is kept, and the store's entries that read it are re-dated
with the machine they ran on. A results-file figure then agrees with its file."""

from __future__ import annotations

import datetime
import json
import sys

import pytest

from agents import figures, remeasure

STORE = """\
# a comment that stays
made:
  what: a figure read from the file the command writes
  source: out.json
  key: value
  unit: s
  date: 2026-01-01
  machine: elsewhere
  command: python -m agents.remeasure --only fake

typed:
  value: 3
  unit: s
  date: 2026-01-02
  machine: elsewhere
  command: c
"""


def _fake(value: float, timeout_s: float = 60.0) -> remeasure.Measurement:
    """A command that writes {"value": value} as a results file."""
    code = f"import json, sys; json.dump({{'value': {value}}}, open(sys.argv[1] + '/r.json', 'w'))"
    return remeasure.Measurement("fake", ("{python}", "-c", code, "{out}"), "r.json", "out.json",
                                 timeout_s)


def test_a_measurement_rewrites_its_file_and_redates_its_figures(tmp_path):
    store = tmp_path / "figures.yml"
    store.write_text(STORE)
    names = remeasure.remeasure(store=store, measurements=[_fake(2.5)], root=tmp_path)
    assert names == ["made"]
    assert json.loads((tmp_path / "out.json").read_text()) == {"value": 2.5}
    text = store.read_text()
    today = datetime.date.today().isoformat()
    assert text.startswith("# a comment that stays\n")
    made, typed = text.split("\ntyped:")
    assert f"  date: {today}" in made and "  machine: " + remeasure.machine().split(",")[0] in made
    assert "date: 2026-01-02" in typed and "machine: elsewhere" in typed   # not its file


def test_a_results_file_figure_agrees_with_its_file(tmp_path, monkeypatch):
    # the store reads the value from the file the command wrote, whatever it was before
    store = tmp_path / "docs" / "figures.yml"
    store.parent.mkdir()
    store.write_text(STORE.replace("source: out.json", "source: docs/out.json"))
    fake = remeasure.Measurement("fake", _fake(7.25).argv, "r.json", "docs/out.json")
    remeasure.remeasure(store=store, measurements=[fake], root=tmp_path)
    monkeypatch.setattr(figures, "REPO_ROOT", tmp_path)
    loaded = figures.load_store(store, figures.LEADERBOARD)
    assert loaded["made"]["value"] == 7.25 == json.loads((tmp_path / "docs/out.json").read_text())["value"]


def test_every_shipped_results_file_figure_reads_its_file():
    # each measurement's results file is in the repository, and the store's figures read it
    store = figures.figures()
    for m in remeasure.MEASUREMENTS:
        assert (figures.REPO_ROOT / m.keep_as).is_file(), m.keep_as
        readers = [n for n, f in store.items() if f.get("source") == m.keep_as]
        assert readers, f"no figure reads {m.keep_as}"
        # the recorded command is the re-measuring one, or the tool it runs (the module it
        # names, or saddle-bench, the work-precision module's console script)
        tools = {"agents.remeasure", m.argv[2]}
        if m.argv[2] == "saddle_env.workprecision":
            tools.add("saddle-bench")
        for name in readers:
            assert any(t in store[name]["command"] for t in tools), (name, tools)


def test_a_failing_or_slow_command_is_an_error_and_keeps_nothing(tmp_path):
    store = tmp_path / "figures.yml"
    store.write_text(STORE)
    failing = remeasure.Measurement("fake", ("{python}", "-c", "raise SystemExit(3)"), "r.json",
                                    "out.json")
    with pytest.raises(RuntimeError, match="fake: .* exited 3 without r.json"):
        remeasure.remeasure(store=store, measurements=[failing], root=tmp_path)
    slow = remeasure.Measurement("fake", ("{python}", "-c", "import time; time.sleep(5)"),
                                 "r.json", "out.json", timeout_s=0.5)
    with pytest.raises(RuntimeError, match="over 0.5 s, not a quick figure"):
        remeasure.remeasure(store=store, measurements=[slow], root=tmp_path)
    assert store.read_text() == STORE and not (tmp_path / "out.json").exists()


def test_only_names_a_measurement_of_the_table(tmp_path):
    with pytest.raises(ValueError, match=r"only must name measurements of \['fake'\], got \['nope'\]"):
        remeasure.remeasure(["nope"], store=tmp_path / "x.yml", measurements=[_fake(1.0)])
    with pytest.raises(SystemExit):
        remeasure.main(["--only", "nope"])


def test_the_table_runs_fixed_argument_lists():
    # never a string from a file: each command is an argument list of the table, {python}
    # and {out} its only substitutions
    for m in remeasure.MEASUREMENTS:
        assert isinstance(m.argv, tuple) and all(isinstance(a, str) for a in m.argv)
        assert m.timeout_s <= 60 or m.long  # a quick one is under a minute
    argv = remeasure._argv(_fake(1.0), tmp := __import__("pathlib").Path("/x"))
    assert argv[0] == sys.executable and argv[-1] == str(tmp)


def test_the_long_measurements_run_only_when_asked(tmp_path):
    # the default re-measures the quick figures; --long adds those that take minutes, and
    # every file a run keeps is copied and re-dates the figures that read it
    store = tmp_path / "figures.yml"
    store.write_text(STORE + "\nother:\n  source: copy.json\n  key: value\n  unit: s\n"
                     "  date: 2026-01-01\n  machine: elsewhere\n  command: c\n")
    quick = _fake(1.0)
    long = remeasure.Measurement("slow", _fake(4.0).argv, "r.json", "out.json", long=True,
                                 also=(("r.json", "copy.json"),))
    names = remeasure.remeasure(store=store, measurements=[quick, long], root=tmp_path)
    assert names == ["made"] and json.loads((tmp_path / "out.json").read_text())["value"] == 1.0
    assert not (tmp_path / "copy.json").exists()
    names = remeasure.remeasure(store=store, measurements=[quick, long], root=tmp_path, long=True)
    assert names == ["made", "made", "other"]
    assert json.loads((tmp_path / "copy.json").read_text())["value"] == 4.0
    assert json.loads((tmp_path / "out.json").read_text())["value"] == 4.0
    assert remeasure.remeasure(["slow"], store=store, measurements=[quick, long],
                               root=tmp_path) == ["made", "other"]   # --only runs it too
    assert {"throughput", "bench"} <= {m.name for m in remeasure.MEASUREMENTS if m.long}
