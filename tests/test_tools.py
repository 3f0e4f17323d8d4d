"""The command lines as a user meets them: task levels by id (--env), model sidecars, one
--env-kwargs grammar, --json writing nothing, missing extras, help text, the output grid."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import saddle_env as se
from agents.cli_args import parse_env_kwargs
from agents.control import best_constant as BC
from agents.evaluation import evaluate as E
from agents.evaluation import policies as P
from saddle_env.envs import LEVEL_IDS, LEVELS, get_level

ROOT = Path(__file__).resolve().parents[1]
GUSTY = "SaddleTrap-Gusty-v0"


def _eval_json(capsys, *argv):
    assert E.main([*argv, "--json", "--no-progress"]) == 0
    return json.loads(capsys.readouterr().out)


# -- one --env-kwargs grammar ----------------------------------------------------------
@pytest.mark.parametrize("items, expected", [
    (["R=0.033", "contact:slipping", "ball_radii=[0.02,0.03]"],
     {"R": 0.033, "contact": "slipping", "ball_radii": (0.02, 0.03)}),
    (["observe_angle=true", "observe_command=False", "b=null", "rtol=1e-6"],
     {"observe_angle": True, "observe_command": False, "b": None, "rtol": 1e-6}),
    (["contact_models=[rolling, slipping]"], {"contact_models": ("rolling", "slipping")}),
    (['{"R": 0.033, "ball_radii": [0.02, 0.03]}'], {"R": 0.033, "ball_radii": (0.02, 0.03)}),
])
def test_env_kwargs_grammar(items, expected):
    assert parse_env_kwargs(items) == expected


def test_both_tools_share_the_parser():
    import agents.training.trainer as T
    import train

    assert T.parse_env_kwargs is E.parse_env_kwargs is parse_env_kwargs
    ns = train.build_parser().parse_args(["--env-kwargs", "rtol=1e-6"])
    assert parse_env_kwargs(ns.env_kwargs) == {"rtol": 1e-6}  # YAML read "1e-6" as a string


# -- saddle-eval --env ----------------------------------------------------------------
def test_saddle_eval_takes_a_level_id_and_records_it(capsys):
    table = _eval_json(capsys, "--env", GUSTY, "--policy", "const-1.2", "--policy", "zero",
                       "--policy", "random", "--episodes", "3", "--max-episode-steps", "30")
    level = get_level(GUSTY)
    assert table["env_id"] == GUSTY and table["env_kwargs"] == {}
    resolved = json.loads(json.dumps(level.config().as_dict(), default=list))
    assert table["options"] == resolved
    assert [row["policy"] for row in table["policies"]] == ["const-1.2", "zero", "random"]
    # keywords override the level, and only they are listed as overrides
    table = _eval_json(capsys, "--env", GUSTY, "--env-kwargs", "air_force=0.05",
                       "--policy", "const-1.2", "--episodes", "2", "--max-episode-steps", "10")
    assert table["env_kwargs"] == {"air_force": 0.05} and table["options"]["air_force"] == 0.05
    assert table["options"]["obs_history"] == level.options["obs_history"]


def test_saddle_eval_unknown_level_is_one_clear_line(capsys):
    with pytest.raises(SystemExit) as exc:
        E.main(["--env", "SaddleTrap-Nope-v0", "--policy", "const-1.2"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "SaddleTrap-Nope-v0" in err and all(i in err for i in LEVEL_IDS)
    assert "Traceback" not in err


def test_best_const_is_searched_and_cached_per_level(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(BC, "CACHE_FILE", tmp_path / "best.json")
    monkeypatch.setattr(BC, "USER_CACHE_FILE", tmp_path / "user.json")
    monkeypatch.delenv(BC.CACHE_ENV_VAR)       # the default: the first writable file
    real = BC.search_best_constant
    searched = []

    def small(config, episodes, seed, max_episode_steps, progress=False, paired=0):
        searched.append(config)
        assert paired == BC.PAIRED_EPISODES    # the baseline's search is the paired one
        return real(config, 2, seed, 15, paired=4)  # a tiny search: this tests the plumbing

    monkeypatch.setattr(BC, "search_best_constant", small)
    for level in LEVELS:
        table = _eval_json(capsys, "--env", level.id, "--policy", "best-const", "--episodes",
                           "2", "--max-episode-steps", "15")
        row = table["policies"][0]
        assert row["policy"] == "best-const" and 0 < row["omega"] <= level.config().omega_max
    assert len(searched) == len(LEVELS)
    cache = json.loads((tmp_path / "best.json").read_text())
    assert len(cache) == len(LEVELS)        # one entry per level
    # the second time every level is a cache hit
    for level in LEVELS:
        _eval_json(capsys, "--env", level.id, "--policy", "best-const", "--episodes", "1",
                   "--max-episode-steps", "15")
    assert len(searched) == len(LEVELS)


# -- model files, sidecars and the observation pipeline --------------------------------
def _ppo_on(env_id, tmp_path, frame_stack=1, normalize=False, name="model"):
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    env = SaddleTrapSB3VecEnv(num_envs=4, **get_level(env_id).options)
    if normalize:
        env = VecNormalize(env, norm_reward=False)
    if frame_stack > 1:
        env = VecFrameStack(env, frame_stack)
    model = sb3.PPO("MlpPolicy", env, seed=0, n_steps=32, batch_size=64, n_epochs=1)
    model.learn(256)   # moves the normalisation statistics off their start
    path = tmp_path / f"{name}.zip"
    model.save(path)
    if normalize:
        from agents.evaluation.model_files import save_normalizer

        save_normalizer(model.get_vec_normalize_env(), P.vecnormalize_path(path))
    path.with_suffix(".json").write_text(json.dumps(
        {"algo": "PPO", "env_id": env_id, "env_kwargs": {}, "frame_stack": frame_stack,
         "normalize": normalize}))
    return model, env, path


def test_saddle_eval_uses_the_level_a_model_was_trained_on(tmp_path, capsys):
    _, _, path = _ppo_on(GUSTY, tmp_path)
    table = _eval_json(capsys, "--policy", str(path), "--episodes", "2",
                       "--max-episode-steps", "10")
    assert table["env_id"] == GUSTY
    assert table["policies"][0]["kind"] == "PPO"
    # --env still wins (and a model that cannot see that level's observations is refused)
    with pytest.raises(SystemExit):
        E.main(["--env", "SaddleTrap-v0", "--policy", str(path), "--json", "--no-progress"])
    assert "observations of shape" in capsys.readouterr().err


def test_evaluation_stacks_and_normalises_as_training_did(tmp_path):
    """The policy loaded from the file acts on the plain environment's observations exactly
    as the model acted inside VecNormalize + VecFrameStack."""
    model, venv, path = _ppo_on("SaddleTrap-v0", tmp_path, frame_stack=3, normalize=True)
    venv.venv.training = False                  # the VecNormalize: statistics frozen now
    policy = P.load_policy(str(path))
    assert isinstance(policy, P.WrappedModel) and policy.frame_stack == 3
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    raw = SaddleTrapSB3VecEnv(num_envs=4)
    venv.seed(7)
    raw.seed(7)
    wrapped_obs, plain_obs = venv.reset(), raw.reset()
    state, start = None, np.ones(4, bool)
    for _ in range(12):
        want, _ = model.predict(wrapped_obs, deterministic=True)
        got, state = policy.predict(plain_obs, state=state, episode_start=start)
        assert np.array_equal(want, got)
        wrapped_obs, _, done_w, _ = venv.step(want)
        plain_obs, _, done_p, _ = raw.step(got)
        assert np.array_equal(done_w, done_p)
        start = done_p
    table, _ = E.evaluate([str(path)], se.envs.EnvConfig(), episodes=3, seed=0,
                          max_episode_steps=20)
    assert table["policies"][0]["kind"] == "PPO"


def test_the_progress_bar_ends_at_the_steps_taken():
    """PPO collects whole rollouts (n_steps × n_envs = 128 here): asked for 300 steps it
    takes 384, and the bar's total says so instead of ending at 384/300."""
    sb3 = pytest.importorskip("stable_baselines3")
    pytest.importorskip("rich")
    from agents.training.backends.sb3 import progress_callback as _progress_callback
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    model = sb3.PPO("MlpPolicy", SaddleTrapSB3VecEnv(num_envs=2), seed=0, n_steps=64,
                    batch_size=64, n_epochs=1)
    bar = _progress_callback()
    model.learn(300, callback=bar)
    assert model.num_timesteps == 384
    assert bar.pbar.n == bar.pbar.total == model.num_timesteps


# -- --json, help, missing extras -----------------------------------------------------
def test_saddle_sim_help_states_each_default_once():
    from saddle_env.cli import build_parser

    text = build_parser().format_help()
    assert "(default: None)" not in text
    for line in text.splitlines():
        assert line.count("default") <= 1, line
    assert f"(default {se.DEFAULT_RTOL:g})" in text


def _without(modules, code, cwd=ROOT):
    """Run ``code`` in a fresh interpreter where importing any of ``modules`` fails, as
    with the core install only."""
    prelude = "import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in modules)
    return subprocess.run([sys.executable, "-c", prelude + code], capture_output=True,
                          text=True, timeout=300, cwd=cwd)


EXTRAS = ["tqdm", "tqdm.auto", "yaml", "matplotlib", "matplotlib.pyplot", "stable_baselines3",
          "torch", "rich", "tensorboard"]


def test_help_works_with_the_core_install_only():
    for code in ("from agents.evaluation.evaluate import main; main(['--help'])",
                 "import runpy; sys.argv = ['train.py', '--help']; "
                 "runpy.run_path('train.py', run_name='__main__')"):
        proc = _without(EXTRAS, code)
        assert proc.returncode == 0, proc.stderr[-1500:]
        assert "--env" in proc.stdout and "Traceback" not in proc.stderr


def test_a_missing_extra_is_one_line_naming_it(tmp_path):
    train = _without(EXTRAS, "import runpy; sys.argv = ['train.py', '--total-timesteps', '10']; "
                             "runpy.run_path('train.py', run_name='__main__')")
    assert train.returncode == 2 and "Traceback" not in train.stderr
    assert train.stderr.strip().count("\n") == 0 and '.[train]' in train.stderr
    plots = _without(EXTRAS, "from agents.evaluation.evaluate import main; "
                             "main(['--policy', 'const-1.2', '--episodes', '1'])", cwd=tmp_path)
    assert plots.returncode == 2 and '.[plot]' in plots.stderr and "--no-plots" in plots.stderr
    assert "Traceback" not in plots.stderr
    # --json needs no plots; without tqdm there is no bar, and one line says why
    ok = _without(EXTRAS, "from agents.evaluation.evaluate import main; main(['--policy', 'const-1.2', "
                          "'--episodes', '1', '--max-episode-steps', '5', '--json'])",
                  cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr[-1500:]
    assert json.loads(ok.stdout)["policies"][0]["policy"] == "const-1.2"
    assert ok.stderr.strip().count("\n") == 0 and "tqdm" in ok.stderr and '.[plot]' in ok.stderr
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "m.zip").write_bytes(b"PK")
    model = _without(EXTRAS, "from agents.evaluation.evaluate import main; "
                             f"main(['--policy', {str(tmp_path / 'm.zip')!r}, '--json'])")
    assert model.returncode == 2 and '.[train]' in model.stderr
    assert "Traceback" not in model.stderr


# -- simulate's output grid (issue 10, item 8) ------------------------------------------
SCENE = se.Scene()
STATE = se.initial_state(SCENE, 0.01, 0.0, start="lab-rest", omega=20.0)


def test_the_state_at_t_end_is_returned_off_the_grid():
    tr = se.simulate(SCENE, STATE, 0.5, dt_out=1.0)
    assert list(tr.t) == [0.0, 0.5]
    exact = se.simulate(SCENE, STATE, 0.5, dt_out=None)
    assert np.allclose(tr.state[-1], exact.state[-1], rtol=1e-8, atol=1e-12)
    tr = se.simulate(SCENE, STATE, 0.25, dt_out=0.1)
    assert np.allclose(tr.t, [0.0, 0.1, 0.2, 0.25])
    assert list(se.simulate(SCENE, STATE, 0.3, dt_out=0.1).t) == list(np.arange(4) * 0.1)
    batch = se.simulate_batch(SCENE, np.array([STATE, STATE]), 0.25, dt_out=0.1)
    assert np.allclose(batch.t, tr.t) and np.array_equal(batch.n_out, [4, 4])
    assert np.allclose(batch.state[0, -1, :5], tr.state[-1])


def test_a_fixed_step_larger_than_the_output_spacing_is_an_error():
    for call in (lambda: se.simulate(SCENE, STATE, 0.5, method="rk4", dt=0.02, dt_out=0.01),
                 lambda: se.simulate_batch(SCENE, np.array([STATE]), 0.5, method="rk4",
                                           dt=0.02, dt_out=0.01)):
        with pytest.raises(ValueError, match="dt = 0.02 s is larger than dt_out = 0.01 s"):
            call()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", se.accuracy.AccuracyWarning)
        ok = se.simulate(SCENE, STATE, 0.5, method="rk4", dt=0.01, dt_out=0.01)
        assert ok.stats.steps == 50
        se.simulate(SCENE, STATE, 0.5, method="rk4", dt=0.02, dt_out=None)  # no grid to cut


def test_tol_still_works_on_any_grid():
    tr = se.simulate(SCENE, STATE, 0.5, dt_out=0.001, tol=1e-4)
    assert tr.settings.startswith("auto (tol = 0.0001 m)") and len(tr.t) == 501


# -- train.py --env, sidecars, wrappers, model selection --------------------------------
def _train_py(tmp_path, *args):
    import train

    flags = {s for a in train.build_parser()._actions for s in a.option_strings}
    quiet = ["--compare-episodes", "0"] if "--compare-episodes" in flags else []
    return subprocess.run([sys.executable, str(ROOT / "train.py"), "--log-dir", str(tmp_path),
                           "--no-progress-bar", *quiet, *args], capture_output=True, text=True,
                          timeout=300)


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_train_on_a_level_records_it_and_honours_normalize_and_frame_stack(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    hyper = tmp_path / "small.yml"
    # Keyed by the calm level only: a level without an entry of its own falls back to it.
    hyper.write_text("SaddleTrap-v0:\n  n_envs: 2\n  policy: MlpPolicy\n  n_steps: 64\n"
                     "  batch_size: 64\n  n_epochs: 1\n  normalize: true\n  frame_stack: 2\n")
    proc = _train_py(tmp_path, "--env", GUSTY, "--env-kwargs", "air_force=0.1", "--hyperparams",
                     str(hyper), "--total-timesteps", "256", "--eval-freq", "128",
                     "--eval-episodes", "2", "--save-freq", "128", "--run-name", "g")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"no entry for {GUSTY}" in proc.stderr
    run = tmp_path / "g"
    side = json.loads((run / "final_model.json").read_text())
    assert side["env_id"] == GUSTY and side["env_kwargs"] == {"air_force": 0.1}
    assert side["frame_stack"] == 2 and side["normalize"] is True
    assert side["max_episode_steps"] == get_level(GUSTY).max_episode_steps
    for name in ("final_model", "selected_model", "best_model"):
        assert (run / f"{name}.zip").is_file() and (run / f"{name}.vecnormalize.json").is_file()
    selected = json.loads((run / "selected_model.json").read_text())
    evals = np.load(run / "evaluations.npz")
    means = evals["results"].mean(axis=1)
    # one of the best few evaluations (the final model's included), re-evaluated on fresh
    # episodes (agents.training.selection; tests/test_selection.py has the rule itself)
    order = sorted(range(len(means)), key=lambda i: (means[i], evals["timesteps"][i]))
    top = {int(evals["timesteps"][i]) for i in order[-3:]}
    assert selected["selected_at_steps"] in top
    assert int(evals["timesteps"][-1]) >= 256
    # saddle-eval finds the level in the sidecar and feeds the model as training did
    table = _eval_json(capsys, "--policy", str(run / "final_model.zip"), "--episodes", "2",
                       "--max-episode-steps", "10", "--env-kwargs", "air_force=0.1")
    assert table["env_id"] == GUSTY and table["env_kwargs"] == {"air_force": 0.1}
    assert table["policies"][0]["kind"] == "PPO"


def test_train_rejects_an_env_wrapper_and_an_unknown_level(tmp_path):
    pytest.importorskip("stable_baselines3")
    hyper = tmp_path / "w.yml"
    hyper.write_text("SaddleTrap-v0:\n  env_wrapper: gymnasium.wrappers.TimeLimit\n")
    proc = _train_py(tmp_path, "--hyperparams", str(hyper), "--total-timesteps", "64")
    assert proc.returncode == 2 and "env_wrapper" in proc.stderr
    proc = _train_py(tmp_path, "--env", "Nope-v0")
    assert proc.returncode == 2 and "Nope-v0" in proc.stderr and GUSTY in proc.stderr
    assert "Traceback" not in proc.stderr
