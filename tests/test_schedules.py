"""Recipe schedules (agents.training.schedules): ``lin_<x>`` decays to 0 over the run, and a
training run with one ends with PPO's step at (nearly) 0."""

import pytest

pytest.importorskip("stable_baselines3")

from agents.training.schedules import parse_schedule, with_schedules  # noqa: E402


def test_lin_decays_from_its_number_to_zero_and_numbers_pass_through():
    lr = parse_schedule("learning_rate", "lin_3e-4")
    assert lr(1.0) == pytest.approx(3e-4)      # progress remaining 1: the start
    assert lr(0.5) == pytest.approx(1.5e-4)
    assert lr(0.0) == pytest.approx(0.0)
    assert parse_schedule("learning_rate", 1e-3) == 1e-3
    kw = with_schedules({"learning_rate": "lin_1e-3", "clip_range": 0.2, "n_epochs": 4})
    assert callable(kw["learning_rate"]) and kw["clip_range"] == 0.2 and kw["n_epochs"] == 4


@pytest.mark.parametrize("bad", ["3e-4", "lin_", "lin_abc", "lin_-1", "lin_inf",
                                 "exp_3e-4", "__import__('os')"])
def test_anything_else_is_an_error(bad):
    with pytest.raises(ValueError, match="learning_rate"):
        parse_schedule("learning_rate", bad)


def test_a_run_with_a_linear_step_ends_near_zero(tmp_path):
    from agents.training.trainer import TrainSettings, train

    hyper = tmp_path / "ppo.yml"
    hyper.write_text("SaddleTrap-v0:\n  n_envs: 4\n  n_steps: 32\n  batch_size: 64\n"
                     "  n_epochs: 1\n  learning_rate: lin_1e-3\n"
                     "  policy_kwargs: 'dict(net_arch=[16])'\n")
    settings = TrainSettings(env_id="SaddleTrap-v0", hyperparams=str(hyper),
                             total_timesteps=512, eval_freq=256, eval_episodes=2,
                             log_dir=str(tmp_path), run_name="lin", compare_episodes=0,
                             max_episode_steps=20, progress_bar=False)
    run = train(settings)
    rows = (run / "progress.csv").read_text().splitlines()
    col = rows[0].split(",").index("train/learning_rate")
    rates = [float(r.split(",")[col]) for r in rows[1:] if r.split(",")[col]]
    assert rates[0] > rates[-1] and rates[-1] < 1e-3 / 3   # constant 1e-3 fails this
