"""The SBX back end (agents.training.backends.sbx): its network copied into SB3's acts identically,
its learner state round-trips as data, and train.py --backend sbx trains, checkpoints on
SIGTERM, resumes and writes model files that load as SB3's."""

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("sbx")

from helpers import sigterm_after_first_checkpoint  # noqa: E402

from agents.training.backends import sbx as sbx_backend  # noqa: E402
from agents.training.runs import TrainSettings  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SMALL = {"n_envs": 4, "n_steps": 32, "batch_size": 64, "n_epochs": 2, "gamma": 0.99,
         "policy_kwargs": "dict(net_arch=dict(pi=[16, 8], vf=[12]), log_std_init=-1.5)"}


def _learner(seed=0, hyper=SMALL):
    from agents.training.backends.sb3 import make_vec_env, wrap_env

    settings = TrainSettings(backend="sbx", env_id="SaddleTrap-v0", seed=seed).validate()
    env = wrap_env(make_vec_env(4, seed, settings.environment()[1], 50), {}, 1)
    learner = sbx_backend.SbxLearner()
    return learner, learner.new_model(dict(hyper), env, settings), settings


def _perturbed(model, seed):
    """``model`` with every parameter moved by noise, as training would move it (without
    compiling a training step: this file's default tests stay quick)."""
    import jax

    rng = np.random.default_rng(seed)

    def move(x):
        return x + rng.normal(scale=0.3, size=np.shape(x)).astype(np.asarray(x).dtype)

    policy = model.policy
    policy.actor_state = policy.actor_state.replace(
        params=jax.tree_util.tree_map(move, policy.actor_state.params))
    policy.vf_state = policy.vf_state.replace(
        params=jax.tree_util.tree_map(move, policy.vf_state.params))
    model.num_timesteps = 4096
    return model


def _observations(model, n=500):
    shape = model.observation_space.shape
    return np.random.default_rng(1).normal(size=(n, *shape)).astype(np.float32) * 3


def _values(model, twin, obs):
    import torch

    flax_v = np.asarray(model.policy.vf_state.apply_fn(model.policy.vf_state.params, obs))
    with torch.no_grad():
        torch_v = twin.policy.predict_values(torch.as_tensor(obs)).numpy()
    return flax_v.ravel(), torch_v.ravel()


def test_the_twin_acts_as_the_sbx_network_and_a_warm_start_comes_back():
    learner, model, _ = _learner()
    _perturbed(model, 0)                      # away from the initial weights
    twin = learner.twin
    sbx_backend.copy_to_twin(model, twin)
    obs = _observations(model)
    a, _ = model.predict(obs, deterministic=True)
    b, _ = twin.predict(obs, deterministic=True)
    assert np.abs(a - b).max() < 1e-5
    flax_v, torch_v = _values(model, twin, obs)
    assert np.abs(flax_v - torch_v).max() < 1e-4
    assert twin.num_timesteps == model.num_timesteps == 4096
    assert float(twin.policy.log_std.detach()[0]) == pytest.approx(
        float(np.asarray(model.policy.actor_state.params["params"]["log_std"])[0]))
    # the reverse: a warm start written into the twin's action head reaches the flax network
    from agents.training.warm_start import apply_warm_start

    apply_warm_start(twin, 0.3)
    sbx_backend.copy_from_twin(twin, model)
    head = model.policy.actor_state.params["params"]["Dense_2"]["bias"]
    assert np.allclose(np.asarray(head), 0.3)
    a, _ = model.predict(obs, deterministic=True)
    b, _ = twin.predict(obs, deterministic=True)
    assert np.abs(a - b).max() < 1e-5


def test_the_learner_state_round_trips_as_data_and_refuses_what_does_not_fit(tmp_path):
    learner, model, _ = _learner()
    _perturbed(model, 1)
    path = sbx_backend.save_learner_state(model, tmp_path / "s.sbx.npz")
    saved = sbx_backend.learner_state(model)
    assert any("opt_state" in k for k in saved), "Adam's moments are part of the state"
    assert saved["counter.num_timesteps"] == 4096
    _, fresh, _ = _learner(seed=5)
    assert not all(np.array_equal(saved[k], v)
                   for k, v in sbx_backend.learner_state(fresh).items())
    sbx_backend.load_learner_state(fresh, path)
    back = sbx_backend.learner_state(fresh)
    assert back.keys() == saved.keys()
    assert all(np.array_equal(saved[k], back[k]) for k in saved)
    assert fresh.num_timesteps == model.num_timesteps
    # a state of another shape (another recipe's network) is refused by name
    _, other, _ = _learner(hyper={**SMALL, "policy_kwargs": "dict(net_arch=[16, 16])"})
    with pytest.raises(ValueError, match="must be f"):
        sbx_backend.load_learner_state(other, path)
    # an object array would need unpickling: refused, not run
    bad = dict(saved)
    bad["['key']"] = np.array([object()], dtype=object)
    np.savez(tmp_path / "bad.sbx.npz", **bad)
    with pytest.raises(ValueError, match="not a readable SBX learner state"):
        sbx_backend.load_learner_state(fresh, tmp_path / "bad.sbx.npz")


def test_settings_and_policy_kwargs_the_back_end_cannot_honour_are_refused():
    with pytest.raises(ValueError, match="--algo must be one of \\['ppo'\\] with --backend sbx"):
        TrainSettings(backend="sbx", algo="sac").validate()
    with pytest.raises(ValueError, match="optimizer_class"):
        sbx_backend.sbx_policy_kwargs({"net_arch": [8], "optimizer_class": object})
    import flax.linen as nn
    import torch

    kw = sbx_backend.sbx_policy_kwargs({"activation_fn": torch.nn.ReLU})
    assert kw == {"activation_fn": nn.relu, "ortho_init": True}
    with pytest.raises(ValueError, match="activation_fn must be one of"):
        sbx_backend.sbx_policy_kwargs({"activation_fn": torch.nn.GELU})


@pytest.mark.slow
def test_train_py_backend_sbx_checkpoints_on_sigterm_and_resumes_as_data(tmp_path):
    recipe = tmp_path / "ppo_small.yml"
    recipe.write_text("SaddleTrap-v0:\n" + "".join(
        f"  {k}: {json.dumps(v) if isinstance(v, str) else v}\n" for k, v in SMALL.items())
        + "  warm_start: best-const\n  normalize: true\n")
    cmd = [sys.executable, str(ROOT / "train.py"), "--backend", "sbx", "--log-dir",
           str(tmp_path), "--env", "SaddleTrap-v0", "--hyperparams", str(recipe),
           "--total-timesteps", "400000", "--eval-freq", "1000", "--eval-episodes", "2",
           "--save-freq", "1000", "--max-episode-steps", "100", "--compare-episodes", "0",
           "--no-progress-bar", "--run-name", "sbx", "--env-kwargs", "action_mode=target"]
    run = tmp_path / "sbx"
    # stopped once training has produced a regular checkpoint
    out, err = sigterm_after_first_checkpoint(cmd, run)
    ckpt, = (run / "checkpoints").glob("interrupted_*_steps.zip")
    assert ckpt.with_suffix(".sbx.npz").is_file() and "--resume" in out
    assert ckpt.with_suffix(".vecnormalize.json").is_file()
    assert not list(run.rglob("*.pkl"))
    assert json.loads((run / "warm_start.json").read_text())["warm_start"] == "best-const"
    done = int(ckpt.stem.split("_")[1])
    resumed = subprocess.run([sys.executable, str(ROOT / "train.py"), "--resume", str(ckpt),
                              "--total-timesteps", str(done + 256), "--no-progress-bar"],
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    from agents.evaluation.model_files import read_archive
    from agents.evaluation.policies import load_policy

    steps = read_archive(run / "final_model.zip").data["num_timesteps"]
    assert done + 256 <= steps <= done + 256 + 128      # whole rollouts of 4 x 32
    for name in ("final_model", "selected_model", "best_model"):
        assert json.loads((run / f"{name}.json").read_text())["algo"] == "ppo"
    policy = load_policy(run / "selected_model.zip")   # an SB3 file, read as data
    import gymnasium as gym

    import saddle_env  # noqa: F401
    env = gym.make("SaddleTrap-v0", max_episode_steps=100)
    obs, _ = env.reset(seed=0)
    action, _ = policy.predict(obs, deterministic=True)
    assert action.shape == env.action_space.shape and np.all(np.isfinite(action))


def test_the_sbx_recipes_are_the_fast_recipe_but_for_the_budget_and_rollout_shape():
    """Each SBX entry is ppo.yml's fast recipe but for its budget and how its rollout of
    n_envs x n_steps samples is shaped (Storm's: more balls, fewer steps), never its size;
    Capture's and Lab's also decay the learning rate to 0 and select their model on more
    validation episodes; Lab's starts from the imitation of mpc, with a third of the step;
    RealSaddle's trains on whole episodes (its balls are lost late, not in the first
    seconds)."""
    from agents.training.recipes import load_hyperparams
    from saddle_env.envs import LEVEL_IDS

    fast = load_hyperparams("ppo", "SaddleTrap-Capture-v0")
    free = ("n_timesteps", "n_envs", "n_steps")
    for level in LEVEL_IDS:
        ours = load_hyperparams("ppo", level, sbx_backend.RECIPES)
        theirs = fast if level != "SaddleTrap-v0" else load_hyperparams("ppo", level)
        if level in ("SaddleTrap-Capture-v0", "SaddleTrap-Lab-v0"):
            schedule = ours.pop("learning_rate")          # "lin_3e-4": from the fast step to 0
            step = theirs["learning_rate"]
            if level == "SaddleTrap-Lab-v0":              # the imitation's warm start
                assert (ours.pop("warm_start"), theirs["warm_start"]) == ("mpc", "best-const")
                assert ours.pop("imitation")["rounds"] >= 1
                theirs = {k: v for k, v in theirs.items() if k != "warm_start"}
                step = step / 3
            assert schedule.startswith("lin_") and float(schedule[4:]) == pytest.approx(step)
            assert (ours.pop("eval_freq"), ours.pop("eval_episodes")) == (499_200, 256)
            theirs = {k: v for k, v in theirs.items() if k != "learning_rate"}
        if level == "SaddleTrap-RealSaddle-v0":
            steps = ours.pop("train_episode_steps")
            assert steps == gym.spec(level).max_episode_steps > theirs["train_episode_steps"]
            theirs = {k: v for k, v in theirs.items() if k != "train_episode_steps"}
        assert {k: v for k, v in ours.items() if k not in free} == \
               {k: v for k, v in theirs.items() if k not in free}, level
        assert ours["n_envs"] * ours["n_steps"] == theirs["n_envs"] * theirs["n_steps"], level
