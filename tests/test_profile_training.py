"""agents.benchmark.profile_training: the timers see each piece of an SB3 run (a tiny SAC run: the
off-policy path) and the shares add up to the wall time."""

import pytest

pytest.importorskip("stable_baselines3")

from agents.benchmark import profile_training as P  # noqa: E402


def test_a_tiny_sac_run_is_split_into_its_pieces(tmp_path):
    recipe = tmp_path / "sac.yml"
    recipe.write_text("SaddleTrap-v0:\n  n_envs: 4\n  learning_starts: 64\n  batch_size: 32\n"
                      "  train_freq: 4\n  gradient_steps: 1\n  buffer_size: 1000\n"
                      "  policy_kwargs: 'dict(net_arch=[16])'\n")
    result = P.profile_training("SaddleTrap-v0", 400, 200, str(recipe), algo="sac")
    rows = {r["category"]: r for r in result["rows"]}
    assert set(rows) == set(P.CATEGORIES)
    assert rows["gradient updates"]["calls"] >= (400 - 64) // 16      # one per 4 x 4 steps
    assert rows["env stepping"]["calls"] >= 100 and rows["policy forward"]["calls"] >= 100
    assert rows["evaluation + selection"]["calls"] >= 2 and rows["start-up"]["calls"] >= 2
    assert rows["advantages (GAE)"]["calls"] == 0                     # off-policy: none
    assert sum(r["seconds"] for r in result["rows"]) == pytest.approx(result["wall"], abs=0.05)
    assert result["path"] == "sb3-sac" and result["total_timesteps"] >= 400
    # the recipe and the counts the run resolved from it, as its config.json recorded them
    assert result["n_envs"] == 4 and result["eval_freq"] == 200
    assert result["hyperparams"]["batch_size"] == "32"
    md = P.markdown(result["rows"], result["wall"], "t")
    assert "| gradient updates |" in md


@pytest.mark.slow   # about 20 s: JAX's compiles and two evaluations
def test_a_tiny_sbx_run_is_split_into_its_pieces(tmp_path):
    """The SBX path: JAX's rollout forward, SB3's buffer, SBX's train, the twin's saves."""
    pytest.importorskip("sbx")
    recipe = tmp_path / "ppo.yml"
    recipe.write_text("SaddleTrap-v0:\n  n_envs: 4\n  n_steps: 32\n  batch_size: 64\n"
                      "  n_epochs: 1\n  policy_kwargs: 'dict(net_arch=[16])'\n")
    result = P.profile_training("SaddleTrap-v0", 256, 128, str(recipe), backend="sbx")
    rows = {r["category"]: r for r in result["rows"]}
    assert set(rows) == set(P.CATEGORIES)
    assert rows["gradient updates"]["calls"] == 2                  # 256 steps = 2 rollouts
    assert rows["advantages (GAE)"]["calls"] == 2
    assert rows["env stepping"]["calls"] >= 64 and rows["policy forward"]["calls"] >= 64
    assert rows["evaluation + selection"]["calls"] >= 2 and rows["start-up"]["calls"] >= 2
    assert sum(r["seconds"] for r in result["rows"]) == pytest.approx(result["wall"], abs=0.05)
    assert result["path"] == "sbx-ppo"
