"""train.py end to end: train, save, load, interrupt, resume."""

import json
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from helpers import sigterm_after_first_checkpoint  # noqa: E402

from agents.training.trainer import parse_env_kwargs, parse_policy_kwargs  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# The calm level and no closing comparison: the tests check the machinery, not learning
# (the main job's level warm-starts from a best-constant search and compares with mpc).
FAST = ["--env", "SaddleTrap-v0", "--compare-episodes", "0", "--eval-episodes", "2",
        "--eval-freq", "1000", "--save-freq", "1000", "--no-progress-bar",
        "--max-episode-steps", "100"]


def _train(tmp_path, *args, timeout=300):
    return subprocess.run([sys.executable, str(ROOT / "train.py"), "--log-dir", str(tmp_path),
                           *FAST, *args], capture_output=True, text=True, timeout=timeout)


def test_ppo_trains_saves_loads_and_evaluates(tmp_path):
    proc = _train(tmp_path, "--algo", "ppo", "--n-envs", "4", "--total-timesteps", "2048",
                  "--run-name", "ppo", "--env-kwargs", "R=0.033", "omega0_range=[18,22]")
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = tmp_path / "ppo"
    for name in ("config.json", "final_model.zip", "final_model.json", "best_model.zip",
                 "evaluations.npz", "progress.csv", "learning_curve.png", "learning_curve.csv"):
        assert (run / name).is_file(), name
    assert list(run.glob("events.out.tfevents*")), "no TensorBoard log"
    sidecar = json.loads((run / "final_model.json").read_text())
    assert sidecar["env_kwargs"] == {"R": 0.033, "omega0_range": [18, 22]}
    import gymnasium as gym
    from stable_baselines3 import PPO

    import saddle_env  # noqa: F401
    model = PPO.load(run / "final_model.zip", device="cpu")
    assert model.num_timesteps >= 2048
    env = gym.make("SaddleTrap-v0", R=0.033, omega0_range=(18.0, 22.0))
    obs, _ = env.reset(seed=0)
    total = 0.0
    for _ in range(50):
        action, _ = model.predict(obs, deterministic=True)
        obs, r, te, tr, _ = env.step(action)
        total += r
        if te or tr:
            break
    assert np.isfinite(total)


def test_sigterm_saves_a_checkpoint_and_resume_continues(tmp_path):
    cmd = [sys.executable, str(ROOT / "train.py"), "--log-dir", str(tmp_path), *FAST,
           "--algo", "sac", "--n-envs", "2", "--total-timesteps", "200000", "--run-name", "sac",
           "--hyperparams", str(_small_sac(tmp_path))]
    run = tmp_path / "sac"
    # stopped once training has produced a regular checkpoint
    out, err = sigterm_after_first_checkpoint(cmd, run)
    ckpts = list((run / "checkpoints").glob("interrupted_*_steps.zip"))
    assert len(ckpts) == 1 and "--resume" in out
    ckpt = ckpts[0]
    assert ckpt.with_suffix(".replay.npz").is_file()  # off-policy: the replay buffer too
    assert not list(run.rglob("*.pkl"))                # nothing a resume would unpickle
    done_steps = int(ckpt.stem.split("_")[1])
    assert 1000 <= done_steps < 200000
    resumed = subprocess.run([sys.executable, str(ROOT / "train.py"), "--resume", str(ckpt),
                              "--total-timesteps", str(done_steps + 600), "--no-progress-bar"],
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    # resumed as data (no --trust-model): the step counter carried on
    from agents.evaluation.model_files import read_archive
    steps = read_archive(run / "final_model.zip").data["num_timesteps"]
    assert done_steps + 600 <= steps <= done_steps + 700


def _small_sac(tmp_path):
    path = tmp_path / "sac_small.yml"
    path.write_text("SaddleTrap-v0:\n  n_envs: 2\n  policy: MlpPolicy\n  learning_starts: 200\n"
                    "  batch_size: 64\n  buffer_size: 10000\n  train_freq: 4\n  gradient_steps: 1\n"
                    "  policy_kwargs: \"dict(net_arch=[32, 32])\"\n")
    return path


def test_sigterm_raises_stop_or_only_sets_the_flag_when_deferred():
    import os

    from agents.training.runs import Stop, sigterm_stops
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Stop), sigterm_stops() as requested:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)           # the handler runs at the next bytecode; never reached
    assert requested.is_set()
    # deferred (the RLlib loop: Ray's compiled wait turns a raised Stop into SystemError)
    with sigterm_stops(deferred=True) as requested:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
        assert requested.is_set()
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_stop_python_dropped_inside_a_del_is_raised_at_the_next_step():
    """A SIGTERM whose handler runs inside a ``__del__`` (CI: numba freeing an LLVM object
    mid-compile) has its Stop printed and dropped by Python; the run trained on until the
    test's timeout. The per-step check raises it again, and only once it was dropped."""
    import gc

    from helpers import SignalledWhileFreed

    from agents.training.backends.sb3 import _lost_stop_callback
    from agents.training.runs import Stop, sigterm_stops

    with pytest.raises(Stop), sigterm_stops() as requested:
        check = _lost_stop_callback(requested)
        assert check._on_step() is True         # no signal yet: training goes on
        SignalledWhileFreed()                    # freed here; its Stop is dropped
        gc.collect()
        assert requested.is_set()               # the run would have gone on from here
        check._on_step()


def test_a_stop_during_a_save_comes_after_the_files_are_whole(tmp_path, monkeypatch, set_sigint):
    """SIGTERM or Ctrl-C while a checkpoint or the selected model is being written waits
    for the save to finish (it used to break torch's zip writer mid-file, whose RuntimeError
    then crashed the run instead of checkpointing), and is raised as itself after it."""
    import os

    from agents.training.backends import sb3 as sb3_backend
    from agents.training.runs import Stop, sigterm_stops, stops_held
    written = []

    class Model:
        def save(self, path):
            os.kill(os.getpid(), signal.SIGTERM)     # the stop comes in the middle of a save
            time.sleep(0.05)                         # its handler runs here
            Path(path).write_bytes(b"whole")
            written.append(Path(path).name)

        def get_vec_normalize_env(self):
            return None

    monkeypatch.setattr(sb3_backend, "write_sidecar", lambda *a: written.append("sidecar"))
    # Ctrl-C's handler as in a foreground terminal, whatever this process inherited (under
    # nohup or `cmd &` SIGINT comes ignored, and the code rightly leaves it so: next test).
    set_sigint(signal.default_int_handler)
    with pytest.raises(Stop), sigterm_stops():
        sb3_backend.save_model(Model(), tmp_path / "m.zip", None)
    assert written == ["m.zip", "sidecar"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(KeyboardInterrupt), sigterm_stops(), stops_held():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
        written.append("after Ctrl-C")
    assert written[-1] == "after Ctrl-C"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.fixture
def set_sigint():
    """Set SIGINT's handler for one test; the one the process had comes back after it."""
    before = signal.getsignal(signal.SIGINT)
    yield lambda handler: signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGINT, before)


def test_an_ignored_ctrl_c_stays_ignored_around_a_save(set_sigint):
    """A run started with SIGINT ignored (nohup, `cmd &` in a script) keeps it ignored while
    saving: holding stops must not install a handler the user's shell had turned off."""
    import os

    from agents.training.runs import sigterm_stops, stops_held
    set_sigint(signal.SIG_IGN)
    with sigterm_stops(), stops_held():
        os.kill(os.getpid(), signal.SIGINT)      # ignored: nothing is raised
        time.sleep(0.05)
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_checkpoints_are_valid_sb3_archives(tmp_path):
    proc = _train(tmp_path, "--algo", "td3", "--n-envs", "2", "--total-timesteps", "2200",
                  "--run-name", "td3")
    assert proc.returncode == 0, proc.stderr[-2000:]
    for ckpt in (tmp_path / "td3" / "checkpoints").glob("checkpoint_*.zip"):
        with zipfile.ZipFile(ckpt) as z:
            assert "policy.pth" in z.namelist()


@pytest.mark.parametrize("args, message", [
    (["--algo", "dqn"], "invalid choice"),
    (["--env-kwargs", "novalue"], "key=value"),
    (["--env-kwargs", "wind=3"], "unknown SaddleTrap option"),
    (["--total-timesteps", "0"], "must be a positive integer"),
    (["--resume", "nowhere.zip"], "--resume"),
    (["--hyperparams", "missing.yml"], "hyperparams file not found"),
])
def test_bad_arguments_exit_2(tmp_path, args, message):
    proc = _train(tmp_path, *args, timeout=120)
    assert proc.returncode == 2 and message in proc.stderr
    assert "Traceback" not in proc.stderr


def test_recipe_of_must_name_a_level():
    from agents.training.runs import TrainSettings

    with pytest.raises(ValueError, match="--recipe-of must be a level id"):
        TrainSettings(recipe_of="SaddleTrap-Nowhere-v0").validate()
    assert TrainSettings(env_id="SaddleTrap-Gusty-v0",
                         recipe_of="SaddleTrap-Capture-v0").validate().recipe_of


def test_parsers():
    assert parse_env_kwargs(["R=0.033", "contact:slipping", "ball_radii=[0.02,0.03]"]) == {
        "R": 0.033, "contact": "slipping", "ball_radii": (0.02, 0.03)}
    pk = parse_policy_kwargs("dict(net_arch=dict(pi=[64, 64], vf=[32]), log_std_init=-1.0)")
    assert pk == {"net_arch": {"pi": [64, 64], "vf": [32]}, "log_std_init": -1.0}
    with pytest.raises(ValueError, match="unsupported syntax"):
        parse_policy_kwargs("__import__('os').system('true') or dict()")
    with pytest.raises(ValueError, match="unsupported syntax"):
        parse_policy_kwargs("[x for x in ()]")
    with pytest.raises(ValueError, match="only dict"):
        parse_policy_kwargs("open('x')")


def _train_py():
    import importlib.util

    spec = importlib.util.spec_from_file_location("train_cli", ROOT / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_setting_is_declared_once_and_every_flag_reaches_it():
    """train.py's flags take their defaults from TrainSettings and land in the field of
    their name: parsing nothing gives the dataclass's defaults, and a flag given a value
    unlike its default puts that value, and only that one, in its field."""
    from dataclasses import asdict, fields

    from agents.training.runs import TrainSettings

    cli = _train_py()
    parser = cli.build_parser()
    assert cli.settings_from_args(parser.parse_args([])) == TrainSettings().validate()
    given = {"algo": ("--algo", "sac", "sac"), "env_id": ("--env", "SaddleTrap-Gusty-v0", None),
             "seed": ("--seed", "7", 7), "n_envs": ("--n-envs", "3", 3),
             "total_timesteps": ("--total-timesteps", "999", 999),
             "hyperparams": ("--hyperparams", "x.yml", "x.yml"),
             "recipe_of": ("--recipe-of", "SaddleTrap-Storm-v0", "SaddleTrap-Storm-v0"),
             "log_dir": ("--log-dir", "elsewhere", "elsewhere"),
             "run_name": ("--run-name", "r", "r"), "eval_freq": ("--eval-freq", "5", 5),
             "eval_episodes": ("--eval-episodes", "6", 6), "save_freq": ("--save-freq", "8", 8),
             "max_episode_steps": ("--max-episode-steps", "9", 9),
             "torch_threads": ("--torch-threads", "2", 2),
             "compare_episodes": ("--compare-episodes", "0", 0),
             "progress_bar": ("--no-progress-bar", None, False),
             "env_kwargs": ("--env-kwargs", "R=0.03", {"R": 0.03}),
             "backend": ("--backend", "rllib", "rllib"),
             "num_env_runners": ("--num-env-runners", "3", 3),
             "address": ("--address", "10.0.0.1:6379", "10.0.0.1:6379"),
             "num_cpus": ("--num-cpus", "2", 2)}
    settable = {f.name for f in fields(TrainSettings)} - {"hyperparams_used", "device"}
    assert set(given) == settable          # a new setting needs a flag (and a line here)
    base = asdict(TrainSettings())
    for name, (flag, value, want) in given.items():
        argv = [flag] if value is None else [flag, value]
        if name in ("num_env_runners", "address", "num_cpus"):
            argv += ["--backend", "rllib"]
        got = asdict(cli.settings_from_args(parser.parse_args(argv)))
        assert got[name] == (value if want is None else want), name
        changed = {k for k in base if got[k] != base[k]}
        # besides the flag's own field: the back end it needs, and what validate() fills
        assert changed <= {name, "backend", "max_episode_steps", "num_env_runners"}, name


def test_a_recipe_sets_the_model_selection_and_the_command_line_wins():
    """``eval_freq`` and ``eval_episodes`` in a recipe set the model selection's evaluations
    (Capture's SBX entry: 256 episodes every 499,200 steps); the flags win; without either,
    20 evaluations of DEFAULT_EVAL_EPISODES episodes. Neither reaches the algorithm."""
    from agents.training.recipes import ZOO_ONLY_KEYS
    from agents.training.runs import DEFAULT_EVAL_EPISODES, TrainSettings

    recipe = {"n_envs": 256, "n_timesteps": 6e6, "eval_freq": 499200, "eval_episodes": 256}
    settings = TrainSettings(backend="sbx").validate().with_recipe(recipe)
    assert (settings.eval_freq, settings.eval_episodes) == (499_200, 256)
    settings = TrainSettings(backend="sbx", eval_freq=1000, eval_episodes=8).validate(
        ).with_recipe(recipe)
    assert (settings.eval_freq, settings.eval_episodes) == (1000, 8)
    settings = TrainSettings(backend="sbx").validate().with_recipe({"n_timesteps": 6e6})
    assert (settings.eval_freq, settings.eval_episodes) == (300_000, DEFAULT_EVAL_EPISODES)
    assert {"eval_freq", "eval_episodes"} <= ZOO_ONLY_KEYS


def test_the_seam_runs_any_back_end_and_closes_a_finished_run(tmp_path, monkeypatch):
    """A back end is a module with check_dependencies, RESUME_NEEDS_TRUST and run: the seam
    checks the settings, fills them from the recipe, saves config.json in the run folder,
    and draws the curve and compares only when the run finished."""
    import types

    from agents.training import runs
    from agents.training import trainer as training

    calls = []
    fake = types.SimpleNamespace(
        RESUME_NEEDS_TRUST=True, check_dependencies=lambda progress_bar: calls.append("deps"),
        run=lambda settings, hyper, run_dir, resume, trust, began: (
            calls.append(("run", settings.n_envs, settings.total_timesteps, hyper["n_envs"]))
            or outcome))
    monkeypatch.setitem(training.BACKENDS, "fake", fake)
    monkeypatch.setitem(runs.BACKEND_ALGOS, "fake", ("ppo",))
    monkeypatch.setitem(runs.DEFAULT_N_ENVS, "fake", 5)
    monkeypatch.setattr(training, "plot_learning_curve", lambda d: calls.append("curve"))
    monkeypatch.setattr(training, "compare", lambda d, s, m: calls.append(("compare", m)))
    settings = runs.TrainSettings(backend="fake", env_id="SaddleTrap-v0", log_dir=str(tmp_path),
                                  run_name="r", compare_episodes=3)
    outcome = tmp_path / "model"
    run_dir = training.train(settings)
    saved = json.loads((run_dir / "config.json").read_text())
    assert saved["backend"] == "fake" and saved["n_envs"] == calls[1][3] == calls[1][1]
    assert calls == ["deps", calls[1], "curve", ("compare", outcome)]
    outcome = None                                   # interrupted: no curve, no comparison
    calls.clear()
    training.train(runs.TrainSettings(backend="fake", env_id="SaddleTrap-v0",
                                      log_dir=str(tmp_path), run_name="r2"))
    assert [c if isinstance(c, str) else c[0] for c in calls] == ["deps", "run"]
    ckpt = run_dir / "checkpoints" / "c.zip"
    ckpt.parent.mkdir()
    ckpt.write_bytes(b"")
    with pytest.raises(ValueError, match="--trust-model"):
        training.train(settings, resume=ckpt)        # this back end resumes from pickles
    with pytest.raises(ValueError, match="--algo must be one of"):
        training.train(runs.TrainSettings(backend="fake", algo="sac"))


def test_shipped_models_load_and_act_in_the_task_they_were_trained_on():
    import gymnasium as gym

    import saddle_env  # noqa: F401
    from agents.evaluation.policies import load_policy
    from saddle_env.envs import level_config
    models = sorted((ROOT / "agents" / "models").glob("*.zip"))
    assert {m.stem for m in models} >= {"sac_default", "ppo_gusty",
                                        "ppo_capture", "ppo_storm", "ppo_slippery"}
    for path in models:
        side = json.loads(path.with_suffix(".json").read_text())
        env_id = side.get("env_id", "SaddleTrap-v0")
        kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in side["env_kwargs"].items()}
        policy = load_policy(str(path), level_config(env_id, **kwargs))
        env = gym.make(env_id, **kwargs)
        obs, _ = env.reset(seed=0)
        for _ in range(20):
            action, _ = policy.predict(obs, deterministic=True)
            obs, _, term, trunc, _ = env.step(np.asarray(action, dtype=np.float32).reshape(1))
            assert env.observation_space.contains(obs)
            if term or trunc:
                break


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_a_finished_run_compares_the_agent_with_best_const_and_mpc(tmp_path):
    proc = _train(tmp_path, "--n-envs", "4", "--total-timesteps", "1024", "--run-name", "cmp",
                  "--compare-episodes", "3")
    assert proc.returncode == 0, proc.stderr[-2000:]
    table = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
    assert [row["policy"].rsplit("/", 1)[-1] for row in table["policies"]] == \
        ["selected_model.zip", "best-const", "mpc"]
    assert table["seed"] == 3_000_000 and table["episodes"] == 3
    assert table["env_id"] == "SaddleTrap-v0"
    assert "best-const" in proc.stdout and "mpc" in proc.stdout  # printed, not only saved


def test_the_main_job_trains_on_a_level_where_learning_shows():
    from agents.training.trainer import MAIN_JOB_ENV_ID, TrainSettings, load_hyperparams

    assert TrainSettings().env_id == MAIN_JOB_ENV_ID != "SaddleTrap-v0"
    hyper = load_hyperparams("ppo", MAIN_JOB_ENV_ID)
    assert hyper["warm_start"] == "best-const" and float(hyper["n_timesteps"]) <= 5e6


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_a_run_warm_started_by_imitating_mpc_records_it_and_can_select_it(tmp_path):
    hyper = tmp_path / "ppo.yml"
    hyper.write_text("SaddleTrap-Storm-v0:\n  n_envs: 4\n  n_steps: 64\n  batch_size: 64\n"
                     "  policy_kwargs: 'dict(log_std_init=-2.0)'\n  warm_start: mpc\n"
                     "  imitation: {rounds: 2, episodes: 4, epochs: 2}\n")
    proc = _train(tmp_path, "--env", "SaddleTrap-Storm-v0", "--hyperparams", str(hyper),
                  "--total-timesteps", "256", "--eval-freq", "100000", "--run-name", "imit")
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = tmp_path / "imit"
    record = json.loads((run / "warm_start.json").read_text())
    assert record["warm_start"] == "mpc" and record["seconds"] > 0
    assert [r["driver"] for r in record["rounds"]] == ["mpc", "network"]
    # The imitating network was evaluated before RL: a snapshot at step 0 is on the curve.
    assert np.load(run / "evaluations.npz")["timesteps"][0] == 0


def test_a_stop_inside_the_model_loader_stays_a_stop(monkeypatch):
    """SIGTERM can land while a snapshot is being read back for its evaluation; the loader's
    catch-all for corrupt tensor files must not turn the run's Stop into a load error (the run
    would then exit with a usage error instead of checkpointing)."""
    import torch

    from agents.evaluation.model_files import load_tensors
    from agents.training.runs import Stop

    def interrupted(*args, **kwargs):
        raise Stop()

    monkeypatch.setattr(torch, "load", interrupted)
    with pytest.raises(Stop):
        load_tensors(b"any bytes", "snapshot.zip:policy.pth")
