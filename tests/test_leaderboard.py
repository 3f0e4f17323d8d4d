"""The leaderboard command: per level, every baseline and shipped agent on a frozen test set,
written as Markdown + JSON + survival PNGs; levels.md generated from the registry."""

import json
from pathlib import Path

import pytest

from agents.benchmark import leaderboard as lb
from saddle_env.envs import LEVELS

ROOT = Path(__file__).resolve().parents[1]


def test_levels_page_is_generated_from_the_registry():
    text = lb.levels_markdown()
    assert (ROOT / "docs" / "levels.md").read_text() == text, \
        "docs/levels.md is stale: run python -m agents.benchmark.leaderboard --levels-doc"
    for level in LEVELS:
        assert f"## {level.id}" in text and level.why_hard in text


def _board(best, mpc, episodes=1000):
    def row(key, t, kept, **extra):
        return {"key": key, "policy": key, "kind": "baseline", **extra,
                "trapping_time": dict(zip(("mean", "low", "high"), t)),
                "kept": dict(zip(("mean", "low", "high"), kept))}
    return {"SaddleTrap-RealSaddle-v0": {
        "episodes": episodes, "episode_length_s": 60.0,
        "policies": [row("best-const", best, (0.0, 0.0, 0.004), omega=8.0),
                     row("mpc", mpc, (0.4, 0.37, 0.43))]}}


def test_the_real_saddle_section_answers_from_the_board():
    """Feedback is said to beat the constant only where the intervals part; nothing is said
    before the level is on the board."""
    lid = "SaddleTrap-RealSaddle-v0"
    assert lb._answer(lid, {}, "2026-11-28") == []
    text = "\n".join(lb._answer(lid, _board((20.0, 19.5, 20.5), (38.0, 37.0, 39.0)),
                                 "2026-11-28"))
    assert "1,000 test episodes (60 s each" in text and "2026-11-28" in text
    assert "20.00 [19.50, 20.50] s" in text and "38.00 [37.00, 39.00] s" in text
    assert "1.90 times as long, its interval clear of the constant's" in text
    assert "figures/realsaddle_episodes.png" in text
    close = "\n".join(lb._answer(lid, _board((20.0, 19.0, 21.0), (20.5, 19.8, 21.2)), "d"))
    assert "Not measurably" in close and "times as long" not in close
    assert lb._answer("SaddleTrap-Lab-v0", _board((1, 0, 2), (3, 2, 4)), "d") == []


def test_a_small_leaderboard_has_every_baseline_with_intervals(tmp_path):
    rc = lb.main(["--episodes", "3", "--seed", "5", "--levels", "SaddleTrap-v0", "--out",
                  str(tmp_path), "--no-progress"])
    assert rc == 0
    data = json.loads((tmp_path / "leaderboard.json").read_text())
    table = data["levels"]["SaddleTrap-v0"]
    names = [row["policy"] for row in table["policies"]]
    assert names[:len(lb.BASELINE_POLICIES)] == list(lb.BASELINE_POLICIES)
    assert table["episodes"] == 3 and table["seed"] == 5 and table["env_id"] == "SaddleTrap-v0"
    for row in table["policies"]:
        t = row["trapping_time"]
        assert 0.0 <= t["low"] <= t["mean"] <= t["high"] <= 10.0
    md = (tmp_path / "leaderboard.md").read_text()
    assert "## SaddleTrap-v0" in md and "seeds 5–7" in md
    assert all(name in md for name in lb.BASELINE_POLICIES)
    png = tmp_path / "figures" / "leaderboard_SaddleTrap-v0.png"
    assert png.is_file() and png.read_bytes()[:4] == b"\x89PNG"


def _fake_result(spec):
    """A row and two episodes for ``spec``, as `evaluate_policy` returns them."""
    import numpy as np

    cell = {"mean": 0.5, "low": 0.4, "high": 0.6}
    row = {"policy": spec, "kind": "baseline",
           **{k: cell for k in ("trapping_time", "kept", "detach", "escape",
                                "mean_distance_mm", "effort", "return")}}
    return row, {"time": np.array([1.0, 10.0]), "kept": np.array([False, True])}


def test_resume_keeps_finished_policies_and_an_interrupt_keeps_what_finished(tmp_path,
                                                                             monkeypatch):
    first, second = LEVELS[1].id, LEVELS[2].id
    calls = []

    def fake(env_id, spec, episodes, seed, progress=True, trust=False, policy_kwargs=None):
        calls.append((env_id, spec))
        if env_id == second and spec == "const-1.0":
            raise KeyboardInterrupt
        return _fake_result(spec)

    monkeypatch.setattr(lb, "evaluate_policy", fake)
    monkeypatch.setattr(lb, "shipped_agents", lambda env_id, models_dir=None: [])
    args = ["--episodes", "2", "--levels", first, second, "--out", str(tmp_path),
            "--no-progress"]
    assert lb.main(args) == 130
    data = json.loads((tmp_path / "leaderboard.json").read_text())
    assert [r["policy"] for r in data["levels"][first]["policies"]] == list(lb.BASELINE_POLICIES)
    assert [r["policy"] for r in data["levels"][second]["policies"]] == ["zero", "random"]
    assert data["episode_results"][first]["mpc"]["time"] == [1.0, 10.0]
    calls.clear()
    assert lb.main(args + ["--resume"]) == 130
    assert calls == [(second, "const-1.0")]  # everything that finished was kept
    assert (tmp_path / "figures" / f"leaderboard_{first}.png").is_file()
    # interrupted again, before it reaches the second level: that level's finished
    # policies stay in the file for the next resume
    monkeypatch.setattr(lb, "evaluate_policy", lambda *a, **k: (_ for _ in ()).throw(
        KeyboardInterrupt))
    data = json.loads((tmp_path / "leaderboard.json").read_text())
    data["levels"][first]["policies"].pop()            # first level now has work to do
    (tmp_path / "leaderboard.json").write_text(json.dumps(data))
    assert lb.main(args + ["--resume"]) == 130
    data = json.loads((tmp_path / "leaderboard.json").read_text())
    assert [r["policy"] for r in data["levels"][second]["policies"]] == ["zero", "random"]


def test_a_retrained_model_is_a_new_entry(tmp_path):
    model = tmp_path / "m.zip"
    model.write_bytes(b"one")
    key = lb.policy_key(str(model))
    model.write_bytes(b"two")
    assert lb.policy_key(str(model)) != key and key.startswith("m.zip@")
    assert lb.policy_key("mpc") == "mpc"


def test_shipped_agents_are_found_by_their_sidecar(tmp_path):
    for name, side in (("a", {"env_id": "SaddleTrap-Gusty-v0"}),
                       ("b", {"env_id": "SaddleTrap-Gusty-v0", "env_kwargs": {"R": 0.02}}),
                       ("c", {"env_id": "SaddleTrap-v0"})):
        (tmp_path / f"{name}.zip").write_bytes(b"")
        (tmp_path / f"{name}.json").write_text(json.dumps(side))
    assert lb.shipped_agents("SaddleTrap-Gusty-v0", tmp_path) == [tmp_path / "a.zip"]


def test_delay_blind_mpc_runs_where_a_level_is_late_and_nowhere_else(tmp_path):
    """What ignoring a delay costs is on the board of a level with one (the Lab level's
    camera), and the other levels do not pay for a row that equals mpc there."""
    from saddle_env.envs import get_level

    for level in LEVELS:
        c = get_level(level.id).config()
        specs = lb.policy_specs(level.id, tmp_path)
        assert specs[:len(lb.BASELINE_POLICIES)] == list(lb.BASELINE_POLICIES)
        assert ("mpc-blind" in specs) == (c.obs_delay > 0 or c.action_delay > 0), level.id
    assert "mpc-blind" in lb.policy_specs("SaddleTrap-Lab-v0", tmp_path)


def test_bad_arguments_give_one_line_errors(capsys):
    with pytest.raises(SystemExit):
        lb.main(["--episodes", "0"])
    with pytest.raises(SystemExit):
        lb.main(["--levels", "SaddleTrap-v9"])
    err = capsys.readouterr().err
    assert "--episodes must be >= 1" in err and "registered levels" in err


def test_updating_one_level_keeps_the_others_on_the_board(tmp_path, monkeypatch):
    first, second = LEVELS[1].id, LEVELS[2].id

    def fake(env_id, spec, episodes, seed, progress=True, trust=False, policy_kwargs=None):
        return _fake_result(spec)

    monkeypatch.setattr(lb, "evaluate_policy", fake)
    monkeypatch.setattr(lb, "shipped_agents", lambda env_id, models_dir=None: [])
    common = ["--episodes", "2", "--out", str(tmp_path), "--no-progress"]
    assert lb.main(common + ["--levels", second, first]) == 0
    data = json.loads((tmp_path / "leaderboard.json").read_text())
    data["episode_results"][second]["old_agent.zip@0123"] = {"time": [1.0], "kept": [False]}
    (tmp_path / "leaderboard.json").write_text(json.dumps(data))
    assert lb.main(common + ["--levels", second, "--resume"]) == 0
    data = json.loads((tmp_path / "leaderboard.json").read_text())
    # episodes of a policy no longer on the board (a retrained agent's old file) leave
    assert set(data["episode_results"][second]) == {
        r["key"] for r in data["levels"][second]["policies"]}
    assert data["order"] == [first, second]                  # the registry's order
    assert set(data["levels"]) == {first, second}
    page = (tmp_path / "leaderboard.md").read_text()
    assert f"## {first}" in page and f"## {second}" in page
    assert f"figures/leaderboard_{first}.png" in page


def test_a_shipped_model_is_named_by_its_path_in_the_repository(tmp_path):
    """The results name a model file inside the repository from its root, not from one
    machine's folders; a baseline or a file elsewhere stays as given."""
    from agents.benchmark.leaderboard import MODELS_DIR, shown_spec

    assert shown_spec(str(MODELS_DIR / "ppo_gusty.zip")) == "agents/models/ppo_gusty.zip"
    assert shown_spec("mpc") == "mpc"
    elsewhere = str(tmp_path / "mine.zip")
    assert shown_spec(elsewhere) == elsewhere


def test_a_results_file_is_written_whole_or_not_at_all(tmp_path):
    """The leaderboard's, the benchmark's and the figures' files go through
    `saddle_env.jobs.files`: a stop in the middle of a write keeps the previous file (what
    ``--resume`` reads) and leaves no temporary file."""
    from saddle_env.jobs.files import atomic_open, write_text_atomically

    path = tmp_path / "leaderboard.json"
    write_text_atomically(path, '{"old": 1}\n')
    with pytest.raises(KeyboardInterrupt), atomic_open(path) as fh:
        fh.write('{"new": ')
        raise KeyboardInterrupt
    assert path.read_text() == '{"old": 1}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["leaderboard.json"]
    assert path.stat().st_mode & 0o777 == 0o644


def _committed_board() -> dict:
    return json.loads((lb.DOCS / "leaderboard.json").read_text())


def test_every_shipped_agent_is_on_the_board_at_or_above_the_trivial_policies():
    """A shipped agent that loses to doing nothing (zero), to random actions or to holding
    one speed (a const-K row, best-const) on its own level's test set is not shipped."""
    board = _committed_board()
    for level in LEVELS:
        agents = [lb.shown_spec(str(p)) for p in lb.shipped_agents(level.id)]
        if not agents:
            continue
        rows = {r["policy"]: r for r in board["levels"][level.id]["policies"]}
        trivial = {name: r["trapping_time"]["mean"] for name, r in rows.items()
                   if name in ("zero", "random", "best-const") or name.startswith("const-")}
        assert {"zero", "best-const"} <= set(trivial), level.id
        best_name = max(trivial, key=trivial.get)
        for agent in agents:
            assert agent in rows, f"{agent} is shipped for {level.id} but not on the board"
            mean = rows[agent]["trapping_time"]["mean"]
            assert mean >= trivial[best_name], \
                f"{agent} ({mean:.3f} s) is below {best_name} ({trivial[best_name]:.3f} s)"


def test_no_constant_beats_best_const_beyond_its_interval():
    """``best-const`` is searched on other episodes than the test set: a listed constant may
    beat it by chance, but not by more than best-const's own interval."""
    for lid, table in _committed_board()["levels"].items():
        rows = {r["policy"]: r for r in table["policies"]}
        high = rows["best-const"]["trapping_time"]["high"]
        for name, row in rows.items():
            if name.startswith("const-"):
                assert row["trapping_time"]["mean"] <= high, (lid, name)
