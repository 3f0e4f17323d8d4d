"""``saddle-export`` and the torch-free runtime (`saddle_env.deploy`): every shipped model's
exported folder reproduces the model's deterministic actions to 1e-5, the runtime keeps the
frame history of a stacking policy as evaluation does, imports no torch, and ``saddle-eval``
evaluates a folder as it evaluates the model file. Crafted folders: tests/test_hostile_files.py.

Observations come from two sources, both on the model's own level: drawn uniformly from the
declared observation box (every input the policy can be given, clipped edges included), and
met by stepping the level's vector environment with uniformly random actions (what a rig
shows). The default suite checks 2,000 box draws per model (no environment: nothing to
compile); the slow one 10,000, 5,000 of each kind.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sb3 = pytest.importorskip("stable_baselines3")
torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from agents.evaluation import evaluate as E  # noqa: E402
from agents.evaluation import export as X  # noqa: E402
from agents.evaluation import policies as P  # noqa: E402
from saddle_env.deploy import Controller  # noqa: E402
from saddle_env.deploy import folder as F  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "agents" / "models").glob("*.zip"))   # SB3 files (RLlib's are folders)
TOLERANCE = 1e-5


@pytest.fixture(autouse=True)
def _one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)     # as saddle-eval and saddle-export run the model
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Every shipped model exported once: {model name: folder}."""
    root = tmp_path_factory.mktemp("exported")
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return {path.stem: X.export_policy(path, root / path.stem) for path in SHIPPED}
    finally:
        torch.set_num_threads(previous)


def level_observations(config, n: int, seed: int, envs: int = 32) -> np.ndarray:
    """``n`` observations met on the level with uniformly random actions (next-step
    autoreset starts new episodes where balls are lost)."""
    from saddle_env.envs.vector import SaddleTrapVectorEnv

    rng = np.random.default_rng(seed)
    env = SaddleTrapVectorEnv(num_envs=envs, **config.as_dict())
    obs, _ = env.reset(seed=seed)
    out = [obs]
    while sum(len(o) for o in out) < n:
        obs, *_ = env.step(rng.uniform(-1, 1, size=(envs, 1)).astype(np.float32))
        out.append(obs)
    env.close()
    return np.concatenate(out)[:n].astype(np.float32)


def _worst(path: Path, folder: Path, box: int, met: int, seed: int) -> float:
    _, config = E.trained_env(P.model_sidecar(path))
    obs = X.observations(config, box, seed)
    if met:
        obs = np.concatenate([obs, level_observations(config, met, seed)])
    return X.max_difference(P.load_policy(str(path), config), folder, obs)


def test_there_are_shipped_models_to_export():
    assert len(SHIPPED) >= 5


@pytest.mark.parametrize("name", [p.stem for p in SHIPPED])
def test_exported_actions_equal_the_models(exported, name):
    worst = _worst(ROOT / "agents" / "models" / f"{name}.zip", exported[name], 2000, 0, 1)
    assert worst <= TOLERANCE, f"{name}: max |Δaction| {worst:.2e}"


@pytest.mark.slow
@pytest.mark.parametrize("name", [p.stem for p in SHIPPED])
def test_exported_actions_equal_the_models_on_10000_observations(exported, name):
    worst = _worst(ROOT / "agents" / "models" / f"{name}.zip", exported[name], 5000, 5000, 2)
    print(f"{name}: max |Δaction| {worst:.2e}")
    assert worst <= TOLERANCE, f"{name}: max |Δaction| {worst:.2e}"


def test_the_folder_says_what_the_graph_needs(exported):
    spec = F.read_spec(exported["ppo_capture"])
    side = P.model_sidecar(ROOT / "agents" / "models" / "ppo_capture.zip")
    assert spec.env_id == side["env_id"] == "SaddleTrap-Capture-v0"
    assert spec.normalizer is not None and len(spec.normalizer["mean"]) == spec.observation_dim
    assert spec.action_in_graph == "clip" and spec.opset == F.OPSET
    assert F.read_spec(exported["sac_default"]).action_in_graph == "unscale"   # tanh-squashed
    assert F.read_spec(exported["ppo_storm"]).normalizer is None
    # the exporter's own graph passes the runtime's checks (operators, sizes, checker)
    F.read_graph(spec)


def test_act_keeps_the_history_of_a_stacking_policy(tmp_path):
    """A model trained on 3 stacked, normalised frames: `act`, step by step with its own
    history, gives the actions evaluation's pipeline gives with the stack in its state."""
    from stable_baselines3.common.vec_env import VecFrameStack

    from agents.evaluation.model_files import save_normalizer
    from saddle_env.envs import EnvConfig
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    env = VecFrameStack(SaddleTrapSB3VecEnv(num_envs=2), 3)
    model = sb3.PPO("MlpPolicy", env, n_steps=8, batch_size=16, seed=0, device="cpu",
                    policy_kwargs={"net_arch": [16, 16]})
    path = tmp_path / "stacked.zip"
    model.save(path)
    path.with_suffix(".json").write_text(json.dumps(
        {"algo": "ppo", "env_id": "SaddleTrap-v0", "env_kwargs": {}, "frame_stack": 3,
         "normalize": True}))
    dim = env.observation_space.shape[0] // 3
    rng = np.random.default_rng(0)

    class Stats:   # what save_normalizer reads from a VecNormalize
        class obs_rms:
            mean, var, count = rng.normal(0, 0.3, dim), rng.uniform(0.01, 2, dim), 10.0

        class ret_rms:
            mean, var, count = 0.0, 1.0, 1.0

        clip_obs, clip_reward, epsilon, gamma, norm_obs, norm_reward = 3.0, 10.0, 1e-8, .99, \
            True, False

    save_normalizer(Stats, P.vecnormalize_path(path))
    folder = X.export_policy(path, tmp_path / "out")
    assert F.read_spec(folder).frame_stack == 3
    reference = P.load_policy(str(path), EnvConfig())
    controller = Controller.from_dir(folder)
    obs = X.observations(EnvConfig(), 12, seed=3)
    state, acted, predicted = None, [], []
    for k, o in enumerate(obs):
        if k == 7:          # a new episode: both forget the frames before it
            controller.reset()
        acted.append(controller.act(o))
        a, state = reference.predict(o[None], state=state, episode_start=np.array([k in (0, 7)]))
        predicted.append(a[0])
    assert np.max(np.abs(np.array(acted) - np.array(predicted))) <= TOLERANCE
    # the history matters: the same observation after other frames gives another action
    fresh = Controller.from_dir(folder)
    assert np.max(np.abs(fresh.act(obs[5]) - acted[5])) > 1e-4
    # a batch through predict, the stack in its state, agrees with act row by row
    batch, batch_state, rows = Controller.from_dir(folder), None, []
    for k in range(7):
        a, batch_state = batch.predict(np.stack([obs[k], obs[k]]), state=batch_state,
                                       episode_start=np.array([k == 0, k == 0]))
        rows.append(a)
    assert np.max(np.abs(np.array(rows)[:, 0] - np.array(acted[:7]))) <= TOLERANCE


def test_act_on_single_frames_keeps_the_levels_history(exported):
    """On a level whose observation is 8 frames, `act` given only each step's newest frame
    (a camera's view) builds the environment's own history: the same actions as `act` on
    the environment's whole observation, over episodes and a reset."""
    import gymnasium as gym

    import saddle_env  # noqa: F401  (registers the levels)

    spec = F.read_spec(exported["ppo_gusty"])
    frame_dim, frames = spec.layout["frame_dim"], spec.layout["frames"]
    assert frames > 1
    whole, framed = Controller.from_dir(exported["ppo_gusty"]), \
        Controller.from_dir(exported["ppo_gusty"])
    env = gym.make(spec.env_id)
    for episode in range(2):
        obs, _ = env.reset(seed=10 + episode)
        whole.reset()
        framed.reset()
        for _ in range(30):
            a, b = whole.act(obs), framed.act(obs[:frame_dim])
            assert np.array_equal(framed._history, obs) and np.array_equal(a, b)
            obs, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                break
    env.close()
    with pytest.raises(ValueError, match="one frame"):
        whole.act(obs[:3])


def test_the_runtime_imports_no_torch(exported):
    """A fresh interpreter loads a folder and acts without torch ever being imported."""
    folder = exported["ppo_capture"]
    code = (
        "import sys, numpy as np\n"
        "import saddle_env.deploy as D\n"
        f"c = D.Controller.from_dir({str(folder)!r})\n"
        "a = c.act(np.zeros(c.spec.observation_dim, np.float32))\n"
        "assert a.shape == (1,) and np.isfinite(a).all(), a\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('torch', 'stable_baselines3', 'jax'))\n"
        "assert not bad, bad\n"
        "print('ok')\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


def test_saddle_env_imports_without_onnxruntime_and_says_which_extra(exported):
    code = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('onnxruntime', 'onnx'):\n"
        "            raise ImportError(name)\n"
        "sys.meta_path.insert(0, Block())\n"
        "import saddle_env, saddle_env.deploy\n"
        "try:\n"
        f"    saddle_env.deploy.Controller.from_dir({str(exported['ppo_storm'])!r})\n"
        "except ImportError as exc:\n"
        "    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "saddle-env[deploy]" in done.stdout and len(done.stdout.strip().splitlines()) == 1


def test_saddle_eval_evaluates_an_exported_folder_as_its_model(exported, capsys):
    """The folder's row equals the model file's (same episodes, same actions), on the level
    policy.json names; its kind says it is the exported graph."""
    rows = []
    for spec in (str(exported["ppo_storm"]), str(ROOT / "agents/models/ppo_storm.zip")):
        assert E.main(["--policy", spec, "--json", "--no-progress", "--episodes", "3",
                       "--max-episode-steps", "40"]) == 0
        table = json.loads(capsys.readouterr().out)
        assert table["env_id"] == "SaddleTrap-Storm-v0"
        rows.append(table["policies"][0])
    assert rows[0]["kind"] == "ONNX" and rows[1]["kind"] == "PPO"
    for key in ("trapping_time", "return", "effort"):
        assert rows[0][key] == pytest.approx(rows[1][key], rel=1e-4, abs=1e-6), key


def test_saddle_eval_warns_when_a_folder_runs_on_another_level(exported, capsys):
    assert E.main(["--policy", str(exported["ppo_gusty"]), "--env", "SaddleTrap-Storm-v0",
                   "--json", "--no-progress", "--episodes", "1", "--max-episode-steps", "2"]) == 0
    assert "trained on SaddleTrap-Gusty-v0" in capsys.readouterr().err
    # a level whose observations have another shape is refused, as for the model file
    with pytest.raises(SystemExit):
        E.main(["--policy", str(exported["ppo_gusty"]), "--env", "SaddleTrap-v0", "--json",
                "--no-progress", "--episodes", "1"])
    assert "shape (64,)" in capsys.readouterr().err


def test_a_leaderboard_entry_of_a_folder_changes_with_the_folder(exported, tmp_path):
    import shutil

    from agents.benchmark import leaderboard as lb

    copy = Path(shutil.copytree(exported["ppo_storm"], tmp_path / "ppo_storm"))
    before = lb.policy_key(str(copy))
    assert before.startswith("ppo_storm@") and before == lb.policy_key(str(exported["ppo_storm"]))
    X.export_policy(ROOT / "agents/models/ppo_gusty.zip", copy)   # another policy, same name
    assert lb.policy_key(str(copy)) != before


def test_export_refuses_what_is_not_a_model_file(tmp_path, capsys):
    for arg, match in (("mpc", "model file"), (str(tmp_path), "model file")):
        with pytest.raises(SystemExit) as exc:
            X.main([arg, "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and match in err and "Traceback" not in err
    with pytest.raises(SystemExit):
        X.main([str(SHIPPED[0]), "--out", str(tmp_path / "o"), "--opset", "7"])
    assert "--opset" in capsys.readouterr().err


def test_the_latency_benchmark_reports_both_policies(capsys):
    from agents.benchmark import deploy_latency

    assert deploy_latency.main(["--calls", "20", "--warmup", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result["rows"]) == {"Controller.act (onnxruntime)", "SB3 predict (torch)"}
    assert all(0 < r["median_us"] <= r["p99_us"] for r in result["rows"].values())
    assert result["peer_over_controller"] > 0 and result["threads"] == 1
