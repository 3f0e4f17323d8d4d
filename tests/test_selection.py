"""One sample per comparison and the model selection (agents.training.selection, issue 44):
a curve and its reference lines are measured on one recorded episode set, and the shipped
network is the best of the top few re-evaluated on fresh episodes."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agents.control.rollout import episode_set, same_episodes
from agents.seeds import COMPARE_SEED, MAX_EVAL_EPISODES, RESELECT_SEED, TEST_SEED, VALIDATION_SEED
from saddle_env.envs import EnvConfig

ROOT = Path(__file__).resolve().parents[1]


def test_an_episode_set_names_seed_count_length_and_options():
    config = EnvConfig()
    a = episode_set(config, VALIDATION_SEED, 64, 500)
    same_episodes(a, episode_set(EnvConfig(), VALIDATION_SEED, 64, 500), "twins")
    others = [episode_set(config, VALIDATION_SEED + 1, 64, 500),
              episode_set(config, VALIDATION_SEED, 63, 500),
              episode_set(config, VALIDATION_SEED, 64, 400),
              episode_set(EnvConfig(R=config.R * 1.1), VALIDATION_SEED, 64, 500)]
    for field, other in zip(("seed", "episodes", "max_episode_steps", "options"), others):
        with pytest.raises(ValueError, match=f"different episodes: {field}"):
            same_episodes(a, other, "curve and line")
    with pytest.raises(ValueError, match="not recorded"):
        same_episodes(a, None, "curve and line")
    with pytest.raises(ValueError, match="episodes must be an integer >= 1"):
        episode_set(config, 0, 0)


def test_the_seed_ranges_of_selection_never_meet_each_other_or_the_test_set():
    validation = range(VALIDATION_SEED, VALIDATION_SEED + MAX_EVAL_EPISODES)
    fresh = range(RESELECT_SEED, RESELECT_SEED + MAX_EVAL_EPISODES)
    assert validation.stop <= fresh.start and fresh.stop <= TEST_SEED < COMPARE_SEED
    from agents.training.runs import TrainSettings

    with pytest.raises(ValueError, match="--eval-episodes must be at most"):
        TrainSettings(env_id="SaddleTrap-v0", eval_episodes=MAX_EVAL_EPISODES + 1).validate()
    from agents.training.selection import fresh_set, report_set

    settings = [TrainSettings(env_id="SaddleTrap-v0", eval_episodes=256, seed=s).validate()
                for s in (0, 1, 99, 243)]
    n = 4 * 256                                     # FRESH_FACTOR x eval_episodes
    fresh = [fresh_set(s) for s in settings]
    report = [report_set(s) for s in settings]
    assert [f["seed"] for f in fresh] == [RESELECT_SEED + k * 2 * n for k in (0, 1, 99, 243)]
    assert [r["seed"] for r in report] == [f["seed"] + n for f in fresh]
    assert {f["episodes"] for f in fresh + report} == {n}
    assert report[-1]["seed"] + n <= TEST_SEED      # the last seed allowed still fits
    with pytest.raises(ValueError, match=r"must end before the test set.*\[0, 243\]"):
        fresh_set(TrainSettings(env_id="SaddleTrap-v0", eval_episodes=256, seed=244).validate())


def test_evaluate_records_the_episode_set_it_ran():
    from agents.evaluation.evaluate import evaluate

    config = EnvConfig()
    table, _ = evaluate(["zero"], config, 3, 77, max_episode_steps=5, examples=0)
    assert table["episode_set"] == episode_set(config, 77, 3, 5)


def _settings(tmp_path, episodes=4):
    from agents.training.runs import TrainSettings

    s = TrainSettings(env_id="SaddleTrap-v0", eval_episodes=episodes, log_dir=str(tmp_path),
                      max_episode_steps=10).validate()
    return s


def test_the_rule_keeps_the_top_few_and_ships_the_best_on_fresh_episodes(tmp_path, monkeypatch):
    """With made-up scores: the in-run maximum (the old rule's pick) loses on the fresh
    episodes to a later candidate, which is shipped and scored once more on the report
    episodes, the score its sidecar records; a snapshot that falls out of the top few is
    deleted."""
    from agents.training import selection

    in_run = {100: 5.0, 200: 9.0, 300: 7.0, 400: 6.0, 500: 8.0}
    fresh = {200: 6.5, 300: 7.5, 500: 7.0}
    report = {300: 7.2}
    report_seed = RESELECT_SEED + 4 * 4         # the fresh set's 4 x 4 episodes come first
    seen_sets = []

    def fake_score(path, settings, episodes):
        seen_sets.append(episodes["seed"])
        steps = int(Path(path).stem.split("_")[1]) if "snapshot" in str(path) else None
        table = {RESELECT_SEED: fresh, report_seed: report}.get(episodes["seed"], in_run)
        value = table[steps]
        return {"mean_return": value, "mean_trapping_time": value / 10,
                "returns": np.full(4, value), "trapping_times": np.full(4, value / 10)}

    monkeypatch.setattr(selection, "score", fake_score)
    run = tmp_path / "run"
    run.mkdir()
    sel = selection.Selection(run, _settings(tmp_path), top=3)

    def save(path):
        path.write_bytes(b"model")
        path.with_suffix(".json").write_text(json.dumps({"algo": "ppo"}))

    for steps in in_run:
        sel.offer(steps, save)
    kept = sorted(p.name for p in (run / "candidates").glob("*.zip"))
    assert kept == ["snapshot_200_steps.zip", "snapshot_300_steps.zip", "snapshot_500_steps.zip"]
    assert not (run / "candidates" / "snapshot_400_steps.json").exists()
    assert json.loads((run / "best_model.json").read_text()) == {"algo": "ppo"}
    assert sel.choose() == run / "selected_model.zip"
    side = json.loads((run / "selected_model.json").read_text())
    assert side["selected_at_steps"] == 300 and side["validation_mean_return"] == 7.2
    assert side["fresh_mean_return"] == 7.5 and side["validation_seed"] == report_seed
    assert side["in_run_mean_return"] == 7.0
    record = json.loads((run / "selection.json").read_text())
    assert record["max_rule_at_steps"] == 200 and record["selected_at_steps"] == 300
    assert record["validation_episodes"]["seed"] == VALIDATION_SEED
    assert record["fresh_episodes"]["seed"] == RESELECT_SEED
    assert record["report_episodes"]["seed"] == report_seed
    assert record["report_mean_return"] == 7.2
    assert seen_sets == [VALIDATION_SEED] * 5 + [RESELECT_SEED] * 3 + [report_seed]
    curve = np.load(run / "evaluations.npz")
    assert list(curve["timesteps"]) == list(in_run) and curve["results"].shape == (5, 4)
    assert json.loads((run / "curve_episodes.json").read_text()) == record["validation_episodes"]


def test_a_reference_line_from_other_episodes_is_refused(tmp_path):
    from agents.training.run_report import plot_learning_curve

    run = tmp_path / "run"
    run.mkdir()
    config = EnvConfig()
    curve_set = episode_set(config, VALIDATION_SEED, 2, 10)
    (run / "curve_episodes.json").write_text(json.dumps(curve_set))
    np.savez(run / "evaluations.npz", timesteps=np.array([10, 20]),
             results=np.ones((2, 2)), trapping_times=np.full((2, 2), 0.1))
    ok = {"episode_set": curve_set, "policies": {"best-const": 0.15}}
    assert plot_learning_curve(run, ok).is_file()
    for other in (episode_set(config, COMPARE_SEED, 2, 10), episode_set(config, VALIDATION_SEED, 3, 10)):
        with pytest.raises(ValueError, match="different episodes"):
            plot_learning_curve(run, {"episode_set": other, "policies": {"best-const": 0.15}})


def test_reference_lines_drawn_ahead_are_read_only_for_the_curves_own_episodes(tmp_path):
    """compile_ahead draws the curve's lines on the other core while the run trains; the run's
    end reads them if they are for its curve's episodes, and draws them again if not."""
    from agents.training.compile_ahead import draw_curve_references
    from agents.training.run_report import CURVE_REFERENCES, curve_references

    settings = _settings(tmp_path, episodes=3)
    _, config = settings.environment()
    run = tmp_path / "run"
    run.mkdir()
    curve_set = episode_set(config, VALIDATION_SEED, 3, 10)
    (run / "curve_episodes.json").write_text(json.dumps(curve_set))
    draw_curve_references(settings.env_id, run, wait_s=0.0)
    drawn = json.loads((run / CURVE_REFERENCES).read_text())
    same_episodes(curve_set, drawn["episode_set"], "drawn ahead")
    assert set(drawn["policies"]) == {"best-const", "mpc"}
    marked = dict(drawn, policies={"best-const": -1.0, "mpc": -2.0})   # not a real score
    (run / CURVE_REFERENCES).write_text(json.dumps(marked))
    assert curve_references(run, settings)["policies"] == marked["policies"]     # read
    stale = dict(marked, episode_set=episode_set(config, VALIDATION_SEED, 2, 10))
    (run / CURVE_REFERENCES).write_text(json.dumps(stale))
    again = curve_references(run, settings)                                       # redrawn
    assert again["policies"] == drawn["policies"] and again["episode_set"] == curve_set


def test_time_to_target_refuses_a_curve_from_other_episodes_than_its_targets(tmp_path,
                                                                             monkeypatch):
    pytest.importorskip("stable_baselines3")
    from agents.benchmark import time_to_target as ttt

    def train_on(seed_of_curve):
        def fake_train(settings):
            run = tmp_path / "runs" / settings.run_name
            run.mkdir(parents=True, exist_ok=True)
            (run / "evaluations_wall.csv").write_text(
                "timesteps,wall_seconds,mean_return,mean_trapping_time\n100,1.5,10.0,0.1\n")
            (run / "curve_episodes.json").write_text(json.dumps(episode_set(
                settings.environment()[1], seed_of_curve, settings.eval_episodes or 2,
                settings.max_episode_steps)))
            return run
        return fake_train

    kw = dict(eval_episodes=2, final_episodes=0, max_episode_steps=10, log=lambda *_: None)
    monkeypatch.setattr("agents.training.trainer.train", train_on(VALIDATION_SEED))
    summary = ttt.run("SaddleTrap-v0", [0], None, tmp_path, label="a", **kw)
    assert summary["targets"]["episode_set"]["seed"] == VALIDATION_SEED
    monkeypatch.setattr("agents.training.trainer.train", train_on(VALIDATION_SEED + 1))
    with pytest.raises(ValueError, match="seed 0's validation curve .* different episodes"):
        ttt.run("SaddleTrap-v0", [0], None, tmp_path, label="b", **kw)


@pytest.mark.slow
def test_a_run_scores_its_curve_on_the_episodes_evaluate_runs(tmp_path):
    """End to end (tiny budget): the curve's score of the selected snapshot is what the
    evaluation tool gives the shipped file on the validation episodes, and its recorded
    fresh and report scores what it gives on the re-selection and report episodes."""
    pytest.importorskip("stable_baselines3")
    from agents.evaluation.evaluate import evaluate
    from agents.evaluation.policies import load_policy

    proc = subprocess.run([sys.executable, str(ROOT / "train.py"), "--log-dir", str(tmp_path),
                           "--env", "SaddleTrap-v0", "--compare-episodes", "0",
                           "--eval-episodes", "3", "--eval-freq", "256", "--save-freq", "4096",
                           "--no-progress-bar", "--max-episode-steps", "40", "--n-envs", "4",
                           "--total-timesteps", "1024", "--run-name", "r"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = tmp_path / "r"
    record = json.loads((run / "selection.json").read_text())
    assert len(record["candidates"]) == 3
    pick = next(c for c in record["candidates"]
                if c["steps"] == record["selected_at_steps"])
    config = EnvConfig()
    policy = load_policy(run / "selected_model.zip", config)
    pick["report_mean_return"] = record["report_mean_return"]
    for episodes, key in ((record["validation_episodes"], "mean_return"),
                          (record["fresh_episodes"], "fresh_mean_return"),
                          (record["report_episodes"], "report_mean_return")):
        _, details = evaluate([("m", policy)], config, episodes["episodes"], episodes["seed"],
                              max_episode_steps=episodes["max_episode_steps"], examples=0)
        assert float(np.mean(details["m"]["return"])) == pytest.approx(pick[key], rel=1e-9)
    side = json.loads((run / "selected_model.json").read_text())
    assert side["validation_mean_return"] == record["report_mean_return"]
    curve = np.load(run / "evaluations.npz")
    i = list(curve["timesteps"]).index(pick["steps"])
    assert float(curve["results"][i].mean()) == pytest.approx(pick["mean_return"], rel=1e-9)


def test_selection_bias_compares_the_rules_on_unseen_episodes(tmp_path, monkeypatch):
    """agents.benchmark.selection_bias: each rule's recorded score against the same
    network's score on unseen episodes (COMPARE_SEED), per run and as mean ± SE, the SE
    with the unseen set's own (shared by the runs) added in quadrature."""
    from agents.benchmark import selection_bias as sb
    from agents.training import selection

    settings = _settings(tmp_path)
    runs = []
    for seed, (max_steps, new_steps) in enumerate([(200, 300), (400, 400)]):
        run = tmp_path / f"r{seed}"
        (run / "candidates").mkdir(parents=True)
        (run / "config.json").write_text(json.dumps({"env_id": "SaddleTrap-v0",
                                                     "eval_episodes": 4,
                                                     "max_episode_steps": 10}))
        cands = []
        for steps in (200, 300, 400):
            (run / "candidates" / f"snapshot_{steps}_steps.zip").write_bytes(b"")
            cands.append({"steps": steps, "mean_return": steps / 10.0,
                          "mean_trapping_time": steps / 100.0,
                          "fresh_mean_return": steps / 10.0 - 5,
                          "fresh_mean_trapping_time": steps / 100.0 - 0.05})
        (run / "selection.json").write_text(json.dumps(
            {"candidates": cands, "max_rule_at_steps": max_steps,
             "selected_at_steps": new_steps, "fresh_episodes": selection.fresh_set(settings)}))
        runs.append(run)
    unseen_seeds = []

    report_seed = selection.report_set(settings)["seed"]

    def fake_score(path, s, episodes):
        unseen_seeds.append(episodes["seed"])
        steps = int(Path(path).stem.split("_")[1])
        if episodes["seed"] == report_seed:      # the runs predate the report set
            return {"mean_return": steps / 10.0 - 5.5, "mean_trapping_time": steps / 100.0}
        times = steps / 100.0 - 0.1 + np.array([-0.3, 0.3])    # SE 0.3 on the unseen set
        return {"mean_return": steps / 10.0 - 6, "mean_trapping_time": float(times.mean()),
                "returns": np.full(2, steps / 10.0 - 6), "trapping_times": times}

    monkeypatch.setattr(selection, "score", fake_score)
    rows = sb.run_rows(runs[0], 8) + sb.run_rows(runs[1], 8)
    assert set(unseen_seeds) == {COMPARE_SEED, report_seed} and settings.eval_episodes == 4
    assert unseen_seeds.count(report_seed) == 2          # the shipped network, once a run
    by_rule = {(r["run"], r["rule"]): r for r in rows}
    assert by_rule[("r0", "max")]["bias_trapping_time"] == pytest.approx(0.1)
    assert by_rule[("r0", "top-k re-evaluated")]["set_offset_trapping_time"] == \
        pytest.approx(0.05)
    assert by_rule[("r0", "top-k re-evaluated")]["bias_trapping_time"] == pytest.approx(0.05)
    assert by_rule[("r0", "top-k re-evaluated")]["selected_at_steps"] == 300
    reported = by_rule[("r0", "top-k, report score")]
    assert reported["selected_at_steps"] == 300
    assert reported["recorded_trapping_time"] == pytest.approx(3.0)
    assert reported["bias_trapping_time"] == pytest.approx(0.1)
    assert reported["unseen_se_trapping_time"] == pytest.approx(0.3)
    summary = {e["rule"]: e for e in sb.summarise(rows)}
    assert summary["max"]["runs"] == 2
    assert summary["top-k re-evaluated"]["bias_return"]["mean"] == pytest.approx(1.0)
    assert summary["max"]["bias_return"]["se"] == pytest.approx(0.0)
    # both runs' biases are 0.1 (spread 0): the SE is the unseen set's own
    assert summary["top-k, report score"]["bias_trapping_time"]["mean"] == pytest.approx(0.1)
    assert summary["top-k, report score"]["bias_trapping_time"]["se"] == pytest.approx(0.3)
    assert "top-k re-evaluated" in sb.markdown(sb.summarise(rows))
