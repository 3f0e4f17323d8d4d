"""The benchmark suite: cells, resume, one JSON per run, and the rliable report generated
from result files alone (tiny budgets; the real runs are committed under benchmark_data/)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("rliable")
pytest.importorskip("sb3_contrib")

from agents.benchmark import run as B  # noqa: E402
from agents.benchmark.report import references  # noqa: E402

GUSTY, STORM = "SaddleTrap-Gusty-v0", "SaddleTrap-Storm-v0"


@pytest.mark.slow
def test_a_real_cell_writes_its_result_and_a_rerun_skips_it(tmp_path, monkeypatch, capsys):
    args = ["--only", f"{GUSTY}/recurrent-ppo/3", "--budget", "64", "--episodes", "3",
            "--out", str(tmp_path)]
    assert B.main(args) == 0
    path = B.result_path(tmp_path, GUSTY, "recurrent-ppo", 3)
    data = json.loads(path.read_text())
    assert data["level"] == GUSTY and data["seed"] == 3 and data["steps_done"] >= 64
    assert len(data["episode_times"]) == 3 and data["test"]["episodes"] == 3
    t = data["trapping_time"]
    assert 0.0 <= t["low"] <= t["mean"] <= t["high"] <= 10.0
    assert data["versions"]["sb3-contrib"] and not list(tmp_path.rglob("*.tmp"))

    def must_not_run(*a, **k):
        raise AssertionError("a finished cell was run again")

    monkeypatch.setattr(B, "run_cell", must_not_run)
    assert B.main(args) == 0
    assert "already have results" in capsys.readouterr().err


@pytest.mark.slow
def test_the_fast_recipe_row_trains_through_train_and_evaluates_the_selected_network(
        tmp_path, monkeypatch):
    """ppo-fast runs the Capture recipe (warm start, wrappers, normalisation, selection) on
    another level through agents.training.trainer.train, and the test set sees its network. Its run
    folder is temporary, or kept where agents.benchmark.time_to_target --reuse reads it untrained."""
    import tempfile

    from agents.benchmark import time_to_target

    assert B.ALGOS["ppo-fast"].recipe_of == "SaddleTrap-Capture-v0"
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    result = B.run_cell(GUSTY, "ppo-fast", 1, budget=100, episodes=3)
    rollout = 64 * 256                            # the recipe's balls x steps per rollout
    assert result["steps_done"] == rollout and result["hyperparameters"]["n_envs"] == 64
    assert result["hyperparameters"]["train_episode_steps"] == 150
    assert len(result["episode_times"]) == 3
    assert not list(tmp_path.glob("saddle-benchmark-*"))   # the run folder was temporary

    kept = tmp_path / "kept"
    again = B.run_cell(GUSTY, "ppo-fast", 1, budget=100, episodes=3, keep_runs=str(kept))
    assert again["episode_times"] == result["episode_times"]    # the same run, kept
    monkeypatch.setattr("agents.training.trainer.train", lambda *a, **k: pytest.fail("trained"))
    summary = time_to_target.run(GUSTY, [1], None, kept / GUSTY, label="ppo-fast",
                                 final_episodes=0, log=lambda *_: None, reuse=True,
                                 recipe_of="SaddleTrap-Capture-v0")
    assert summary["seeds"][0]["timesteps"] == rollout


def test_the_sbx_row_is_the_fast_recipe_row_with_another_learner():
    fast, sbx = B.ALGOS["ppo-fast"], B.ALGOS["ppo-fast-sbx"]
    assert (sbx.recipe_of, sbx.budget, sbx.n_envs) == (fast.recipe_of, fast.budget, fast.n_envs)
    assert (fast.backend, sbx.backend) == ("sb3", "sbx")


@pytest.mark.slow
def test_the_sbx_row_trains_through_the_sbx_back_end(tmp_path, monkeypatch):
    """ppo-fast-sbx runs the same recipe as ppo-fast (the same keys, rollout, selection)
    through `train.py --backend sbx`; the test set sees the selected network."""
    pytest.importorskip("sbx")
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    result = B.run_cell(GUSTY, "ppo-fast-sbx", 1, budget=100, episodes=3)
    assert result["steps_done"] == 64 * 256 and result["library"] == "sbx.PPO"
    fast = B.run_cell(GUSTY, "ppo-fast", 1, budget=100, episodes=3)
    assert result["hyperparameters"] == {**fast["hyperparameters"],
                                         "n_timesteps": result["hyperparameters"]["n_timesteps"]}
    assert len(result["episode_times"]) == 3 and "sbx-rl" in result["versions"]


def _fake_cell(level, algo, seed, budget=None, episodes=B.TEST_EPISODES, **_):
    rng = np.random.default_rng(hash((level, algo, seed)) % 2 ** 32)
    mean = {"ppo": 8.0, "sac": 5.0}[algo] + rng.normal(0, 0.3)
    return {"level": level, "algo": algo, "seed": seed, "budget_steps": 10,
            # seed 2 is the median run by time (2 min); its load is not the median load
            "train_wall_s": {0: 300.0, 1: 60.0, 2: 120.0}.get(seed, 1.0),
            "test": {"seed": 0, "episodes": episodes},
            "trapping_time": {"mean": mean, "low": mean - 0.1, "high": mean + 0.1},
            "kept": {"mean": mean / 10}, "return": {"mean": 50 * mean},
            "load_average_at_end": [{0: 2.0, 1: 3.0, 2: 7.0}.get(seed, 1.0), 0.0, 0.0]}


def test_a_killed_suite_resumes_where_it_stopped(tmp_path, monkeypatch):
    calls, killed = [], []

    def fake(level, algo, seed, **kw):
        calls.append((level, algo, seed))
        if len(calls) == 3 and not killed:
            killed.append(True)
            raise KeyboardInterrupt              # Ctrl-C in the third cell
        return _fake_cell(level, algo, seed)

    monkeypatch.setattr(B, "run_cell", fake)
    argv = ["--levels", GUSTY, STORM, "--algos", "ppo", "sac", "--seeds", "0", "1",
            "--out", str(tmp_path)]
    assert B.main(argv) == 130
    assert len(list(tmp_path.rglob("seed*.json"))) == 2
    first = list(calls)
    calls.clear()
    assert B.main(argv) == 0
    assert len(calls) == 8 - 2 and not set(calls) & set(first[:2])   # finished cells kept
    assert len(list(tmp_path.rglob("seed*.json"))) == 8


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_the_report_is_generated_from_the_result_files(tmp_path, monkeypatch, capsys):
    import agents.benchmark.report as R

    monkeypatch.setattr(R, "REPS", 300)   # fewer bootstrap draws: the same code, faster
    results = tmp_path / "results"
    for lv in (GUSTY, STORM):
        for algo in ("ppo", "sac"):
            for seed in (0, 1, 2):
                cell = _fake_cell(lv, algo, seed)
                if algo == "sac":
                    del cell["load_average_at_end"]   # runs from before the load was recorded
                B.write_result(results, cell)
    docs = tmp_path / "docs"
    docs.mkdir()
    assert B.main(["--report", "--out", str(results), "--docs", str(docs)]) == 0
    md = (docs / "benchmark.md").read_text()
    assert f"### {GUSTY}" in md and "| ppo | 3 (0, 1, 2)" in md and "IQM" in md
    assert "**Why 3 seeds.**" in md
    # cells without a result are marked: rows no level ran, and a level with no cell at all
    capture = "SaddleTrap-Capture-v0"
    assert "| tqc | *not run* (0 of 3) |" in md.split(f"### {GUSTY}")[1]
    assert f"### {capture}" in md and f"| `{capture}` |" in md
    assert "| ppo | *not run* (0 of 3) |" in md.split(f"### {capture}")[1]
    # the median run's wall time with the load it ran under; none recorded, none shown
    assert "| 10 steps | 2.0 min (7.0) |" in md and "| 10 steps | 2.0 min |" in md
    for fig in ("benchmark_aggregates.png", "benchmark_profiles.png"):
        assert (docs / "figures" / fig).read_bytes()[:4] == b"\x89PNG"
    capsys.readouterr()
    assert B.main(["--report", "--json", "--out", str(results)]) == 0
    data = json.loads(capsys.readouterr().out)
    refs = references()
    for lv in (GUSTY, STORM):
        for algo in ("ppo", "sac"):
            row = data["levels"][lv][algo]
            assert row["seeds"] == 3 and row["iqm_ci"][0] <= row["iqm"] <= row["iqm_ci"][1]
            # the score's normalisation: random 0, the upper reference 1
            ref = refs[lv]
            want = (row["trapping_time_mean"] - ref["random"]) / (ref[ref["upper"]]
                                                                  - ref["random"])
            assert row["mean"] == pytest.approx(want)
        # ppo (about 8 s) beats best-const on Storm (6.06 s) in every run; sac (5 s) never
        assert data["levels"][lv]["sac"]["p_improve_mpc"] == 0.0
    assert data["levels"][STORM]["ppo"]["p_improve_best-const"] == 1.0
    assert data["across_levels"]["ppo"]["seeds"] == 3
    # the compute the seeds cost: 300 + 60 + 120 s per row and level, on two levels
    assert data["provenance"]["training_s"] == {"ppo": 960.0, "sac": 960.0}
    assert data["provenance"]["seeds"] == [0, 1, 2]
    assert data["levels"][GUSTY]["ppo"]["load_at_end_median_run"] == 7.0
    assert data["levels"][GUSTY]["sac"]["load_at_end_median_run"] is None
    assert data["missing"][capture]["ppo"] == [0, 1, 2] and "ppo" not in data["missing"][GUSTY]
    assert "SaddleTrap-v0" not in data["missing"]   # the calm level is not benchmarked
    # A level one row has run and the other not is left out of the aggregates, which
    # compare the rows on the same levels (it used to drop the other row instead).
    for seed in (0, 1, 2):
        B.write_result(results, _fake_cell(capture, "sac", seed))
    capsys.readouterr()
    assert B.main(["--report", "--json", "--out", str(results)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["across_levels_levels"] == [GUSTY, STORM]
    assert set(data["across_levels"]) == {"ppo", "sac"}
    assert data["across_levels"]["sac"]["levels"] == [GUSTY, STORM]
    assert data["levels"][capture]["sac"]["seeds"] == 3
    assert B.main(["--report", "--out", str(results), "--docs", str(docs)]) == 0
    assert f"(left out: `{capture}`)" in (docs / "benchmark.md").read_text()


def test_bad_cells_are_one_line_errors(capsys):
    for argv, needle in ((["--only", "Nope-v0/ppo/0"], "Nope-v0"),
                         (["--only", f"{GUSTY}/dqn/0"], "unknown algorithm"),
                         (["--only", f"{GUSTY}/ppo"], "LEVEL/ALGO/SEED"),
                         (["--algos", "dqn"], "unknown")):
        with pytest.raises(SystemExit) as exc:
            B.main(argv)
        assert exc.value.code == 2 and needle in capsys.readouterr().err


def test_the_recurrent_adapter_acts_as_sb3s_own_recurrent_loop():
    """RecurrentPPO is evaluated through `RecurrentPolicy` in padded batches of 100 balls;
    its trapping times must equal SB3's documented single-episode loop (state passed back,
    episode_start only on the first step). An untrained LSTM already makes actions that
    depend on its state, so a wrong state layout or a reset at the wrong step shows."""
    import gymnasium as gym
    import torch
    from sb3_contrib import RecurrentPPO

    from agents.evaluation.evaluate import evaluate
    from saddle_env.envs import get_level

    torch.manual_seed(0)
    level = get_level(GUSTY)
    env = gym.make(GUSTY)
    model = RecurrentPPO("MlpLstmPolicy", env, seed=0, device="cpu",
                         policy_kwargs={"lstm_hidden_size": 16})
    seeds = list(range(5000, 5006))
    table, details = evaluate([("rec", B.RecurrentPolicy(model))], level.config(), len(seeds),
                              seeds[0], max_episode_steps=120, examples=0, env_id=GUSTY)
    batched = np.asarray(details[table["policies"][0]["policy"]]["time"])
    alone = []
    for seed in seeds:
        single = gym.make(GUSTY, max_episode_steps=120)
        obs, _ = single.reset(seed=seed)
        state, start, done = None, np.ones(1, dtype=bool), False
        while not done:
            action, state = model.predict(obs[None], state=state, episode_start=start,
                                          deterministic=True)
            start[:] = False
            obs, _, terminated, truncated, info = single.step(action[0])
            done = terminated or truncated
        alone.append(info["time"])
    np.testing.assert_allclose(batched, alone, atol=1e-6)


def test_two_cells_run_as_tasks_on_a_local_ray(tmp_path):
    pytest.importorskip("ray")
    argv = ["--levels", GUSTY, "--algos", "ppo", "--seeds", "0", "1", "--budget", "64",
            "--episodes", "2", "--out", str(tmp_path), "--address", "local"]
    assert B.main(argv) == 0
    for seed in (0, 1):
        data = json.loads(B.result_path(tmp_path, GUSTY, "ppo", seed).read_text())
        assert data["seed"] == seed and data["steps_done"] >= 64


def test_the_clairvoyant_reference_is_at_or_above_mpc_and_every_shipped_agent():
    """benchmark_data/references.json (the clairvoyant on each level's test set) against the
    committed leaderboard, episode by episode: never shorter than mpc or a shipped agent."""
    from pathlib import Path

    from agents.benchmark import leaderboard as lb

    root = Path(__file__).resolve().parents[1]
    refs = json.loads((root / "benchmark_data" / "references.json").read_text())["levels"]
    board = json.loads((root / "docs" / "leaderboard.json").read_text())
    assert set(refs) == set(board["levels"])
    for lid, ref in refs.items():
        clair = np.asarray(ref["episode_times"])
        assert len(clair) == ref["episodes"] and ref["seed"] == board["seed"]
        rows = board["levels"][lid]["policies"]
        rivals = [r["key"] for r in rows if r["policy"] == "mpc" or r["policy"].endswith(".zip")]
        # mpc, and every agent shipped for the level (a level may have none yet: the Lab's)
        agents = [lb.shown_spec(str(p)) for p in lb.shipped_agents(lid)]
        assert len(rivals) == 1 + len(agents) and "mpc" in [r["policy"] for r in rows], lid
        for key in rivals:
            theirs = np.asarray(board["episode_results"][lid][key]["time"][:len(clair)])
            assert np.all(clair >= theirs - 1e-5), (lid, key)
        full = board["levels"][lid]["episode_length_s"]   # 10 s, 60 on the real saddle
        lost = int(np.sum(clair < full - 1e-9))
        assert ref["doomed"] == lost / len(clair)
        assert ref["doomed_ci"]["low"] - 1e-12 <= ref["doomed"] <= ref["doomed_ci"]["high"]


def test_a_rows_intervals_do_not_depend_on_the_other_rows(monkeypatch):
    """Each row's bootstrap has its own seeded stream: adding a row or reordering the rows
    leaves the others' intervals as they were (a shared stream moved them in the second
    decimal whenever the benchmark gained a row)."""
    import agents.benchmark.report as R

    monkeypatch.setattr(R, "REPS", 200)
    rng = np.random.default_rng(0)
    a, b = rng.uniform(0, 1, (3, 2)), rng.uniform(0, 1, (3, 2))
    alone = R._aggregates({"ppo": a})
    np.random.seed(7)                        # whatever the global stream was
    assert R._aggregates({"sac": b, "ppo": a})["ppo"] == alone["ppo"]
    assert R._aggregates({"ppo": a, "sac": b})["ppo"] == alone["ppo"]
    assert R._improvement(a, b[:1]) == R._improvement(a, b[:1])
    assert np.random.randint(1 << 30) == np.random.RandomState(7).randint(1 << 30)  # given back
