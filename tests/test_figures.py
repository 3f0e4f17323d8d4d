"""The figure store (agents/figures.py, docs/figures/figures.yml): every figure the
README or a page states is rendered from it, a stale copy or an unknown name fails."""

from __future__ import annotations

import re

import pytest

from agents import figures


def test_every_figure_carries_unit_date_machine_and_command():
    for name, figure in figures.figures().items():
        for key in ("value", *figures.REQUIRED):
            assert key in figure, f"{name} lacks {key}"
        assert figure["date"] and figure["machine"] and figure["command"], name


def test_store_entry_without_a_date_is_refused(tmp_path):
    store = tmp_path / "figures.yml"
    store.write_text("x:\n  value: 1\n  unit: s\n  machine: m\n  command: c\n")
    with pytest.raises(figures.FigureError, match="'x' lacks date"):
        figures.load_store(store)


@pytest.mark.parametrize("path", figures.rendered_files(), ids=lambda p: p.name)
def test_rendered_copy_is_current(path):
    text = path.read_text()
    assert figures.render(text) == text, (
        f"{path.name}: a figure's copy is stale; run python -m agents.figures --write")


def test_readme_states_its_figures_from_the_store():
    readme = (figures.REPO_ROOT / "README.md").read_text()
    names = {m.group("name") for m in figures.MARKER.finditer(readme)}
    assert {"main-job-seconds", "vector-env-1024", "lb.Storm.shipped", "lb.Lab.best-const"} <= names


def test_stale_and_unknown_copies_are_caught():
    stale = "took <!-- fig main-job-seconds -->1<!-- /fig --> s"
    assert figures.render(stale) != stale
    assert figures.render(stale, keep_markers=False) == \
        f"took {figures.render_figure('main-job-seconds')} s"
    with pytest.raises(figures.FigureError, match="unknown figure 'no-such'"):
        figures.render("<!-- fig no-such -->1<!-- /fig -->")


def test_rounding_only_formats_the_stored_value():
    figure = {"value": {"mean": 9.348514, "low": 9.240666, "high": 9.451963}}
    assert figures.format_figure(figure, [".2f"]) == "9.35 [9.24, 9.45]"
    assert figures.format_figure(figure, ["mean", ".1f"]) == "9.3"
    assert figures.format_figure({"value": [6744, 6799]}, [",d"]) == "6,744–6,799"
    assert figures.format_figure({"value": 1.9e-8}, [".1e"]) == "1.9e-8"   # as texts write it
    assert figures.format_figure({"value": -0.18}, ["+.2f"]) == "\u22120.18"    # a difference
    assert figures.format_figure({"value": {"mean": 0.02, "se": 0.09}}, ["+.2f"]) == "+0.02 ± 0.09"


def test_leaderboard_figures_match_the_leaderboard_page():
    """The generated leaderboard page and the store read the same file: Lab's best constant
    speed, the figure the rig's how-to quotes, is the one the page's table heads."""
    page = (figures.REPO_ROOT / "docs" / "leaderboard.md").read_text()
    lab = page[page.index("## SaddleTrap-Lab-v0"):]
    omega = figures.render_figure("lb.Lab.best-const.omega")
    assert re.search(rf"best-const, Ω = {re.escape(omega)} ", lab)


def test_check_exits_1_on_a_stale_file(monkeypatch, tmp_path, capsys):
    page = tmp_path / "page.md"
    page.write_text("<!-- fig lb.date -->1999-01-01<!-- /fig -->\n")
    monkeypatch.setattr(figures, "rendered_files", lambda: [page])
    monkeypatch.setattr(figures, "REPO_ROOT", tmp_path)
    assert figures.main(["--check"]) == 1
    assert "stale: page.md" in capsys.readouterr().out
    assert figures.main(["--write"]) == 0
    assert figures.main(["--check"]) == 0


# A run's result as the texts wrote them: an interval "9.35 [9.24, 9.45]", a share "36 %",
# a rate "6,744 steps/s", a duration "13.9 min".
RESULT = re.compile(r"\[\s*[-+]?\d[\d.,]*\s*,\s*[-+]?\d|\d\s?%|steps/s|\d\s?min\b")


def test_level_texts_keep_no_results_of_runs():
    from saddle_env.envs import LEVELS

    for level in LEVELS:
        for text in (level.summary, level.models, level.why_hard):
            found = RESULT.search(text)
            assert not found, (f"{level.id}: {text[max(0, found.start() - 40):found.end() + 20]!r} "
                               "looks like a result of a run: it belongs on the leaderboard or in "
                               "docs/notes/, linked from the text")


def test_recipe_comments_keep_no_results_of_runs():
    for path in sorted((figures.REPO_ROOT / "agents" / "hyperparams").glob("*.yml")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            comment = line.partition("#")[2] if "#" in line else ""
            found = RESULT.search(comment)
            assert not found, f"{path.name}:{number}: {line!r} looks like a result of a run"


def test_the_site_shows_the_value_without_its_markers():
    import importlib.util
    from types import SimpleNamespace

    spec = importlib.util.spec_from_file_location("figures_test_hooks",
                                                  figures.REPO_ROOT / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = SimpleNamespace(file=SimpleNamespace(src_uri="how-to/x.md"), meta={})
    out = hooks.on_page_markdown("took <!-- fig main-job-seconds -->1<!-- /fig --> s", page, {}, None)
    assert out == f"took {figures.render_figure('main-job-seconds')} s"
    with pytest.raises(figures.FigureError):
        hooks.on_page_markdown("<!-- fig no-such -->1<!-- /fig -->", page, {}, None)


def _table(text: str, heading: str) -> list[list[str]]:
    start = text.index(heading)
    end = text.find("\n## ", start + 3)
    rows = [r for r in text[start:end if end > 0 else None].splitlines()
            if r.startswith("|") and not r.startswith("|---")]
    return [r.strip().strip("|").split("|") for r in rows[1:]]   # without the header row


# A measurement typed by hand: a decimal, or a number with a unit.
TYPED = re.compile(r"\d\.\d|\d\s?(%|s\b|M\b|×|m\b)")


@pytest.mark.parametrize("heading, columns", [("## Task levels", slice(2, None)),
                                              ("## Headline figures", slice(1, 2))])
def test_readme_tables_take_every_measured_cell_from_the_store(heading, columns):
    readme = (figures.REPO_ROOT / "README.md").read_text()
    for cells in _table(readme, heading):
        for cell in cells[columns]:
            typed = TYPED.search(figures.MARKER.sub("", cell))
            assert not typed, f"README {heading!r}: {cell.strip()!r} types a figure by hand"


def test_a_text_dates_a_figure_from_the_store():
    text = "<!-- fig main-job-seconds date -->1999-01-01<!-- /fig -->"
    assert figures.render(text, keep_markers=False) == figures.figures()["main-job-seconds"]["date"]


def test_lab_best_constant_voltage_is_the_leaderboard_speed_over_the_motor_gain():
    """The rig's how-to and tests/test_rig_loop.py hold the saddle at this voltage: the
    leaderboard's best constant speed on the Lab level, not a speed typed beside it."""
    from saddle_env.envs import level_config

    omega = figures.figures()["lb.Lab.best-const.omega"]["value"]
    volts = figures.figures()["lab-best-const-voltage"]["value"]
    assert volts * level_config("SaddleTrap-Lab-v0").motor_gain == pytest.approx(omega)
    rig = (figures.REPO_ROOT / "docs" / "how-to" / "rig.md").read_text()
    assert "constant_voltage(rig.config, <!-- fig lab-best-const-voltage -->" in rig


def _store(tmp_path, monkeypatch, entries):
    """A figure store in ``tmp_path`` (the repository root for its sources) holding
    ``entries``, name -> the entry's own lines (its unit among them), each dated and
    attributed alike; its path."""
    store = tmp_path / "figures.yml"
    store.write_text("".join(f"{name}:\n{body}  date: 2026-01-01\n  machine: m\n  command: c\n"
                             for name, body in entries.items()))
    monkeypatch.setattr(figures, "REPO_ROOT", tmp_path)
    return store


def test_a_ratio_and_a_list_position_of_a_results_file(tmp_path, monkeypatch):
    (tmp_path / "r.json").write_text('{"paths": [{"x": 6.0}, {"x": 2.0}]}')
    store = _store(tmp_path, monkeypatch, {
        "ratio": "  source: r.json\n  key: paths.0.x\n  over: paths.1.x\n  unit: x\n",
        "missing": "  source: r.json\n  key: paths.2.x\n  unit: x\n"})
    with pytest.raises(figures.FigureError, match="has no key 'paths.2.x'"):
        figures.load_store(store)
    store.write_text(store.read_text().split("missing:")[0])
    assert figures.load_store(store)["ratio"]["value"] == 3.0


def test_a_scaled_interval_scales_its_mean_and_ends(tmp_path, monkeypatch):
    (tmp_path / "r.json").write_text('{"kept": {"mean": 0.5, "low": 0.25, "high": 0.75}}')
    store = _store(tmp_path, monkeypatch,
                   {"kept": "  source: r.json\n  key: kept\n  scale: 100\n  unit: '%'\n"})
    assert figures.load_store(store)["kept"]["value"] == {"mean": 50.0, "low": 25.0,
                                                          "high": 75.0}


def test_one_value_per_seed_reads_as_a_list():
    assert figures.format_figure({"value": [150, 85, 66]}, ["d"]) == "150, 85, 66"


def test_readme_headline_dates_come_from_the_store():
    """The 'measured by' column dates each figure through a date marker, so a re-measurement
    moves the date with the value."""
    readme = (figures.REPO_ROOT / "README.md").read_text()
    for cells in _table(readme, "## Headline figures"):
        for cell in cells[1:]:
            typed = re.search(r"\b20\d\d-\d\d-\d\d\b", figures.MARKER.sub("", cell))
            assert not typed, f"README headline cell {cell.strip()!r} types a date by hand"


def test_a_table_figure_is_named_cell_by_cell(monkeypatch):
    table = {"value": {"rk4-1ms": {"error": 1.2e-5, "us": 631}}, "unit": "m; µs",
             "date": "2026-01-01", "machine": "m", "command": "c"}
    monkeypatch.setattr(figures, "figures", lambda: {"t": table})
    assert figures.render_figure("t.rk4-1ms.error", ".1e") == "1.2e-5"
    assert figures.render_figure("t.rk4-1ms.us") == "631"
    assert figures.render_figure("t.rk4-1ms.us", "date") == "2026-01-01"
    assert figures.find_figure("t.rk4-1ms.us")["command"] == "c"
    with pytest.raises(figures.FigureError, match="'t' has no cell 'rk4-1ms.steps'"):
        figures.render_figure("t.rk4-1ms.steps")
    with pytest.raises(figures.FigureError, match="unknown figure 'u.x'"):
        figures.render_figure("u.x")


@pytest.mark.parametrize("heading", ["| setting | coulomb error", "| tol [m] | picked"])
def test_accuracy_tables_take_every_measured_cell_from_the_store(heading):
    page = (figures.REPO_ROOT / "docs" / "accuracy.md").read_text()
    rows = _table(page, heading)
    assert len(rows) >= 4
    for cells in rows:
        for cell in cells[1:]:
            assert figures.MARKER.fullmatch(cell.strip()), \
                f"accuracy.md {heading!r}: {cell.strip()!r} is typed, not a store figure"


def test_a_results_key_that_holds_a_dot(tmp_path, monkeypatch):
    """saddle-reproduce's summary.json names its balls R=2.23cm: the dotted path finds them."""
    results = tmp_path / "r.json"
    results.write_text('{"omega_crt": {"R=2.23cm": {"theory": 13.1}, "R=2": {"x": 1}}}')
    monkeypatch.setattr(figures, "REPO_ROOT", tmp_path)
    assert figures._lookup(results, "omega_crt.R=2.23cm.theory") == 13.1
    with pytest.raises(figures.FigureError, match="has no key 'omega_crt.R=2.5cm.theory'"):
        figures._lookup(results, "omega_crt.R=2.5cm.theory")


def test_reproduce_figures_come_from_the_shipped_summary():
    """The paper pages' model outputs are read from saddle-reproduce's shipped summary.json."""
    store = figures.figures()
    assert store["paper-omega-crt-rolling-2.65"]["source"] == "docs/figures/reproduce_summary.json"
    assert figures.render_figure("paper-omega-crt-rolling-2.65") == "13.593"
    assert figures.render_figure("paper-precession-excess-1mm") == "14.8"   # 150.62 - 135.83


def _bench_csv(path):
    """A bench.csv of two tiers at rtol 1e-10 (default cap, and a capped row to skip)."""
    cols = "tier,solver,method,rtol,dt,max_step,us_per_sim_s,steps,error_m,phase_changes," \
           "slipping_share\n"
    path.write_text(cols
                    + "rolling,saddle_env,dop853,1e-10,,,40,500,2e-10,,\n"
                    + "rolling,saddle_env,dop853,1e-10,,100,1,1,1,,\n"
                    + "coulomb,saddle_env,dop853,1e-10,,,500,3000,3e-10,82,0.25\n")


def test_a_derivation_reads_a_csv_results_file(tmp_path, monkeypatch):
    _bench_csv(tmp_path / "bench.csv")
    rows = figures.read_source(tmp_path / "bench.csv")
    assert rows[0]["us_per_sim_s"] == 40.0 and rows[0]["tier"] == "rolling"
    assert rows[0]["phase_changes"] != rows[0]["phase_changes"]   # a blank cell is nan
    store = _store(tmp_path, monkeypatch, {
        "steps": "  source: bench.csv\n  derive: coulomb-steps\n  unit: steps\n",
        "ratio": "  source: bench.csv\n  derive: coulomb-steps-ratio\n  unit: x\n"})
    loaded = figures.load_store(store)
    assert loaded["steps"]["value"] == {"switching": 3000.0, "rolling": 500.0}
    assert loaded["ratio"]["value"] == 6.0


def test_the_coulomb_tier_derivations_pick_the_default_capped_rows(tmp_path):
    _bench_csv(tmp_path / "bench.csv")
    rows = figures.read_source(tmp_path / "bench.csv")
    assert figures.DERIVED["coulomb-steps"](rows)["rolling"] == 500.0   # not the capped row
    # the phases and the tables read tolerances the two-row file lacks: the shipped run has them
    shipped = figures.read_source(figures.REPO_ROOT / "docs/figures/coulomb_tier/bench.csv")
    phases = figures.DERIVED["coulomb-phases"](shipped)
    assert phases["changes_least"] <= phases["changes"] <= phases["changes_most"]
    assert 0 < phases["slipping_percent"] < 100
    table = figures.DERIVED["coulomb-tier"](shipped)
    low, high = figures.DERIVED["coulomb-cost-ratio"](shipped)
    ratios = [table[k]["coulomb_us"] / table[k]["rolling_us"]
              for k in ("rtol-1e-8", "rtol-1e-10", "rtol-1e-11")]
    assert (low, high) == (min(ratios), max(ratios))


def test_bench_cell_reads_one_row_or_a_ratio_of_two(tmp_path, monkeypatch):
    """``derive: bench-cell`` takes its row from the store's args (YAML reads 1e-10 as a
    string), skips the uncapped row, and divides by the ``over`` row."""
    _bench_csv(tmp_path / "bench.csv")
    store = _store(tmp_path, monkeypatch, {
        "us": "  source: bench.csv\n  derive: bench-cell\n  unit: x\n"
              "  args: {column: us_per_sim_s, row: {tier: rolling, method: dop853, rtol: 1e-10}}\n",
        "ratio": "  source: bench.csv\n  derive: bench-cell\n  unit: x\n"
                 "  args: {column: error_m, row: {tier: coulomb, method: dop853, rtol: 1e-10},\n"
                 "         over: {tier: rolling, method: dop853, rtol: 1e-10}}\n"})
    loaded = figures.load_store(store)
    assert loaded["us"]["value"] == 40.0   # the default-cap row, not the uncapped one
    assert loaded["ratio"]["value"] == pytest.approx(1.5)
    rows = figures.read_source(tmp_path / "bench.csv")
    uncapped = {"tier": "rolling", "method": "dop853", "rtol": 1e-10, "max_step": 100}
    assert figures.bench_cell(rows, "us_per_sim_s", uncapped) == 1.0


def test_bench_cell_refuses_a_setting_without_exactly_one_row(tmp_path):
    _bench_csv(tmp_path / "bench.csv")
    rows = figures.read_source(tmp_path / "bench.csv")
    with pytest.raises(figures.FigureError, match="0 rows"):
        figures.bench_cell(rows, "us_per_sim_s", {"tier": "rolling", "method": "rk4", "dt": 1e-3})
    with pytest.raises(figures.FigureError, match="2 rows"):
        figures.bench_cell(rows + rows[:1], "us_per_sim_s",
                           {"tier": "rolling", "method": "dop853", "rtol": 1e-10})


def test_the_default_figures_read_the_shipped_bench_run():
    """docs/accuracy.md's "Why the defaults" from bench_results.csv: the derived figures agree
    with the rows they are made of."""
    rows = figures.read_source(figures.REPO_ROOT / "docs/figures/bench_results.csv")
    us = {r: figures._rolling_dop853(rows, "us_per_sim_s", r) for r in (1e-11, 1e-10, 1e-7)}
    extra = figures.DERIVED["bench-dop853-rtol11-extra-percent"](rows)
    assert extra == pytest.approx(100 * (us[1e-11] / us[1e-10] - 1))
    saving = figures.DERIVED["bench-looser-max-saving"](rows)
    assert saving >= us[1e-10] / us[1e-7]   # the cheapest looser row is at least as cheap
    low, high = figures.DERIVED["bench-looser-error-ratio"](rows)
    assert 1 < low <= high
    linear = figures.DERIVED["bench-linear-tier-cost"](rows)
    assert linear["default_over_linear"] > 1 and linear["batch_us_per_ball"] > 0
    store = figures.figures()
    for name in ("bench-dop853-default-us", "bench-env-default-saving", "coulomb-error-default"):
        assert store[name]["source"] == "docs/figures/bench_results.csv"
