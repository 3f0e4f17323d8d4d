"""Files from elsewhere are data: crafted artifacts of every kind the project loads go through
its entry points and either fail with a clear error or load safely, and none runs code.

Every payload here, when unpickled (or evaluated), creates the canary file; each test checks
that the canary is still absent afterwards. docs/security.md describes the rules tested.
"""

from __future__ import annotations

import base64
import io
import json
import pickle
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

sb3 = pytest.importorskip("stable_baselines3")
torch = pytest.importorskip("torch")

from agents.evaluation import evaluate as E  # noqa: E402
from agents.evaluation import policies as P  # noqa: E402
from agents.evaluation.model_files import ArchiveLimits, UntrustedFileError, read_archive  # noqa: E402
from saddle_env.envs import EnvConfig  # noqa: E402
from saddle_env.envs.observation import observation_space  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


class Payload:
    """Unpickling this writes the canary (what an attacker's file would do)."""

    def __init__(self, canary: Path):
        self.canary = str(canary)

    def __reduce__(self):
        return (exec, (f"open({self.canary!r}, 'w').write('ran')",))


@pytest.fixture
def canary(tmp_path):
    path = tmp_path / "canary"
    yield path
    assert not path.exists(), "a crafted file ran code"


def _pickled(canary: Path) -> bytes:
    return pickle.dumps(Payload(canary))


@pytest.fixture(scope="module")
def model_zip(tmp_path_factory):
    """A small, honest PPO model file for the calm level, with its sidecar."""
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    folder = tmp_path_factory.mktemp("model")
    model = sb3.PPO("MlpPolicy", SaddleTrapSB3VecEnv(num_envs=2), n_steps=8, batch_size=16,
                    seed=0, policy_kwargs={"net_arch": [8, 8]}, device="cpu")
    path = folder / "model.zip"
    model.save(path)
    _sidecar(path, {})
    return path


def _sidecar(path: Path, extra: dict) -> None:
    side = {"algo": "ppo", "env_id": "SaddleTrap-v0", "env_kwargs": {}, "frame_stack": 1,
            "normalize": False, **extra}
    path.with_suffix(".json").write_text(json.dumps(side))


def _rewrite(src: Path, dst: Path, change) -> Path:
    """A copy of zip ``src`` at ``dst`` with ``change(entries)`` applied (name -> bytes)."""
    with zipfile.ZipFile(src) as z:
        entries = {n: z.read(n) for n in z.namelist()}
    change(entries)
    with zipfile.ZipFile(dst, "w") as z, warnings.catch_warnings():
        warnings.simplefilter("ignore")   # a crafted duplicate name is the point
        for name, data in entries.items():
            z.writestr(name, data)
    dst.with_suffix(".json").write_text(src.with_suffix(".json").read_text())
    return dst


def _obs(n=64):
    space = observation_space(EnvConfig())
    space.seed(1)
    return np.stack([space.sample() for _ in range(n)])


def _saddle_eval(capsys, *argv):
    """saddle-eval's exit code and stderr; any exception other than its clean exit fails."""
    try:
        code = E.main([*argv, "--json", "--no-progress", "--episodes", "1",
                       "--max-episode-steps", "3"])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


# -- model zips ----------------------------------------------------------------------------
def test_pickles_in_every_serialized_field_are_never_decoded(model_zip, tmp_path, canary,
                                                             capsys):
    payload = base64.b64encode(_pickled(canary)).decode()

    def poison(entries):
        data = json.loads(entries["data"])
        for value in data.values():
            if isinstance(value, dict) and ":serialized:" in value:
                value[":serialized:"] = payload
        data["extra_field"] = {":type:": "<class 'x'>", ":serialized:": payload}
        entries["data"] = json.dumps(data).encode()

    bad = _rewrite(model_zip, tmp_path / "poisoned.zip", poison)
    honest = P.load_policy(str(model_zip), EnvConfig())
    loaded = P.load_policy(str(bad), EnvConfig())   # loads, as data: same network
    obs = _obs()
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0],
                          honest.predict(obs, deterministic=True)[0])
    code, _ = _saddle_eval(capsys, "--policy", str(bad))
    assert code in (0, None)


@pytest.mark.parametrize("entry", ["policy.pth", "policy.optimizer.pth", "pytorch_variables.pth"])
def test_a_tensor_file_holding_a_pickle_is_refused(model_zip, tmp_path, canary, capsys, entry):
    def poison(entries):
        buf = io.BytesIO()
        torch.save({"weights": Payload(canary)}, buf)
        entries[entry] = buf.getvalue()

    bad = _rewrite(model_zip, tmp_path / "poisoned.zip", poison)
    with pytest.raises(UntrustedFileError, match="--trust-model"):
        P.load_policy(str(bad), EnvConfig())
    code, err = _saddle_eval(capsys, "--policy", str(bad))
    assert code == 2 and "--trust-model" in err.strip().splitlines()[-1]   # one line


@pytest.mark.parametrize("name, why", [
    ("../evil.pth", "entry name"), ("/abs.pth", "entry name"), ("dir/policy.pth", "entry name"),
    # zipfile cuts the name at NUL: a duplicate
    ("policy.pth\x00", "entry name|twice"),
])
def test_entries_with_paths_or_unknown_names_are_refused(model_zip, tmp_path, canary, name, why):
    def add(entries):
        entries[name] = _pickled(canary)

    bad = _rewrite(model_zip, tmp_path / "bad.zip", add)
    with pytest.raises(ValueError, match=why):
        P.load_policy(str(bad), EnvConfig())


def test_truncated_oversized_and_duplicated_zips_are_clear_errors(model_zip, tmp_path, canary):
    raw = model_zip.read_bytes()
    for cut in (len(raw) // 2, 100, 0):
        bad = tmp_path / f"cut{cut}.zip"
        bad.write_bytes(raw[:cut])
        bad.with_suffix(".json").write_text(model_zip.with_suffix(".json").read_text())
        with pytest.raises(ValueError, match="not a Stable-Baselines3 model file"):
            P.load_policy(str(bad), EnvConfig())
    with pytest.raises(ValueError, match="larger than"):   # an entry over the size bound
        read_archive(model_zip, ArchiveLimits(max_entry_bytes=1000))
    with pytest.raises(ValueError, match="entries"):
        read_archive(model_zip, ArchiveLimits(max_entries=2))
    # a zip bomb: 64 MB of zeros in a 64 kB entry, over a 16 MB data limit
    bomb = tmp_path / "bomb.zip"
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("data", b"0" * (64 * 1024 ** 2))
        z.writestr("policy.pth", b"")
    assert bomb.stat().st_size < 1024 ** 2
    with pytest.raises(ValueError, match="larger than"):
        read_archive(bomb)
    dup = tmp_path / "dup.zip"
    with zipfile.ZipFile(model_zip) as src, zipfile.ZipFile(dup, "w") as z:
        for n in src.namelist():
            z.writestr(n, src.read(n))
        with pytest.warns(UserWarning):
            z.writestr("data", b"{}")
    with pytest.raises(ValueError, match="twice"):
        read_archive(dup)


def test_a_json_data_entry_of_the_wrong_shape_is_a_clear_error(model_zip, tmp_path):
    for data, match in ((b"[1, 2]", "JSON object"), (b"\xff\xfe", "not JSON"),
                        (json.dumps({"policy_kwargs": {"net_arch": [10 ** 9]}}).encode(),
                         "net_arch"),
                        (json.dumps({"policy_kwargs": {"features_extractor_class": "x"}}
                                    ).encode(), "--trust-model"),
                        (json.dumps({"policy_kwargs": {"log_std_init": "os.system"}}
                                    ).encode(), "log_std_init")):
        bad = _rewrite(model_zip, tmp_path / "bad.zip",
                       lambda entries, d=data: entries.__setitem__("data", d))
        with pytest.raises(ValueError, match=match):
            P.load_policy(str(bad), EnvConfig())


# -- sidecars --------------------------------------------------------------------------------
@pytest.mark.parametrize("side", [
    {"frame_stack": "3"}, {"frame_stack": True}, {"frame_stack": 10 ** 9}, {"normalize": "yes"},
    {"env_kwargs": ["R", 1]}, {"env_id": ["SaddleTrap-v0"]}, {"env_id": "Nope-v9"},
    {"algo": 5}, {"hyperparams": "dict(net_arch=__import__('os'))"},
])
def test_sidecars_with_wrong_types_fail_clearly(model_zip, tmp_path, canary, capsys, side):
    bad = tmp_path / "model.zip"
    bad.write_bytes(model_zip.read_bytes())
    _sidecar(bad, side)
    try:
        P.load_policy(str(bad), EnvConfig())           # loads, or a clear ValueError
    except ValueError as exc:
        assert str(exc)
    code, _ = _saddle_eval(capsys, "--policy", str(bad))
    assert code in (0, 2, None)


def test_pickled_normaliser_statistics_need_trust(model_zip, tmp_path, canary, capsys):
    bad = tmp_path / "model.zip"
    bad.write_bytes(model_zip.read_bytes())
    _sidecar(bad, {"normalize": True})
    P.vecnormalize_path(bad, pickled=True).write_bytes(_pickled(canary))
    with pytest.raises(UntrustedFileError, match="--trust-model"):
        P.load_policy(str(bad), EnvConfig())
    code, err = _saddle_eval(capsys, "--policy", str(bad))
    assert code == 2 and "--trust-model" in err
    # JSON statistics of the wrong shape or values are refused too, not broadcast
    stats = P.vecnormalize_path(bad)
    good = {"obs_mean": [0.0] * 8, "obs_var": [1.0] * 8, "obs_count": 1.0, "ret_mean": 0.0,
            "ret_var": 1.0, "ret_count": 1.0, "clip_obs": 10.0, "clip_reward": 10.0,
            "epsilon": 1e-8, "gamma": 0.99, "norm_obs": True, "norm_reward": False}
    dim = observation_space(EnvConfig()).shape[0]
    for change, match in (({}, "length"), ({"obs_mean": [0.0] * dim, "obs_var": [-1.0] * dim},
                                           "obs_var"),
                          ({"obs_mean": "__import__('os')"}, "numeric"),
                          ({"norm_obs": "yes"}, "norm_obs")):
        stats.write_text(json.dumps({**good, **change}))
        with pytest.raises(ValueError, match=match):
            P.load_policy(str(bad), EnvConfig())


# -- hyperparameter strings ------------------------------------------------------------------
@pytest.mark.parametrize("text", [
    "nn.functional.torch.os.system('touch {c}')",
    "dict(net_arch=[64], activation_fn=nn.Tanh.__init__.__globals__['os'].system('touch {c}'))",
    "dict(a=().__class__.__base__.__subclasses__())",
    "dict(a=open('{c}', 'w'))",
    "dict(a=[open('{c}', 'w') for _ in 'x'])",
    "dict(a=(lambda: open('{c}', 'w'))())",
    "dict(**{{'a': open('{c}', 'w')}})",
    "dict(a=nn.Module.__subclasses__)",
    "dict(a=torch.os.system('touch {c}'))",
    "dict(a=f'{{open(\"{c}\", \"w\")}}')",
])
def test_hyperparameter_strings_are_parsed_not_run(tmp_path, canary, capsys, text):
    import train

    text = text.format(c=canary)
    hyper = tmp_path / "ppo.yml"
    hyper.write_text("SaddleTrap-v0:\n  n_envs: 2\n  policy_kwargs: " + json.dumps(text) + "\n")
    with pytest.raises(SystemExit) as exc:
        train.main(["--hyperparams", str(hyper), "--total-timesteps", "16", "--log-dir",
                    str(tmp_path / "runs"), "--no-progress-bar", "--compare-episodes", "0"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "policy_kwargs" in err and "Traceback" not in err
    # the normalize key is read by the same parser
    hyper.write_text("SaddleTrap-v0:\n  n_envs: 2\n  normalize: " + json.dumps(text) + "\n")
    with pytest.raises(SystemExit):
        train.main(["--hyperparams", str(hyper), "--total-timesteps", "16", "--log-dir",
                    str(tmp_path / "runs"), "--no-progress-bar", "--compare-episodes", "0"])


# -- train.py --resume -----------------------------------------------------------------------
def _run_folder(tmp_path, algo="sac"):
    """A run folder as train.py leaves it, with one checkpoint (made without training)."""
    from dataclasses import asdict

    from agents.training.backends.sb3 import _new_model, _save_checkpoint
    from agents.training.recipes import load_hyperparams
    from agents.training.runs import TrainSettings
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    hyper_file = tmp_path / f"{algo}.yml"
    hyper_file.write_text("SaddleTrap-v0:\n  n_envs: 2\n  learning_starts: 10\n"
                          "  buffer_size: 200\n  policy_kwargs: \"dict(net_arch=[8, 8])\"\n")
    settings = TrainSettings(algo=algo, env_id="SaddleTrap-v0", hyperparams=str(hyper_file),
                             log_dir=str(tmp_path), run_name="run").validate()
    settings.hyperparams_used = load_hyperparams(algo, "SaddleTrap-v0", hyper_file)
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps(asdict(settings), default=list))
    model = _new_model(sb3.SAC, settings.hyperparams_used, SaddleTrapSB3VecEnv(num_envs=2),
                       settings)
    return _save_checkpoint(model, run / "checkpoints", "checkpoint", settings)


def test_resume_reads_checkpoints_as_data_and_refuses_pickles(tmp_path, canary, capsys):
    import train

    ckpt = _run_folder(tmp_path)
    assert ckpt.with_suffix(".replay.npz").is_file()
    # a pickled replay buffer beside the checkpoint (instead of the npz) is refused
    ckpt.with_suffix(".replay.npz").unlink()
    ckpt.with_suffix(".replay.pkl").write_bytes(_pickled(canary))
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(ckpt), "--total-timesteps", "20", "--no-progress-bar"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--trust-model" in err and "Traceback" not in err
    # a payload in the checkpoint's tensors: refused, even before the buffer is looked at
    def poison(entries):
        buf = io.BytesIO()
        torch.save(Payload(canary), buf)
        entries["policy.pth"] = buf.getvalue()

    poisoned = _rewrite(ckpt, ckpt.with_name("checkpoint_0_steps.zip"), poison)
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(poisoned), "--total-timesteps", "20", "--no-progress-bar"])
    assert exc.value.code == 2 and "--trust-model" in capsys.readouterr().err


def test_resume_as_data_restores_weights_optimiser_and_buffer(tmp_path):
    from agents.training.backends.sb3 import _resume
    from agents.training.recipes import load_hyperparams
    from agents.training.runs import TrainSettings
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    ckpt = _run_folder(tmp_path)
    settings = TrainSettings(algo="sac", hyperparams=str(tmp_path / "sac.yml")).validate()
    hyper = load_hyperparams("sac", "SaddleTrap-v0", tmp_path / "sac.yml")
    trusted = sb3.SAC.load(ckpt, device="cpu")
    safe = _resume(sb3.SAC, ckpt, SaddleTrapSB3VecEnv(num_envs=2), hyper, None, 1, settings,
                   trust=False)
    for name, tensor in trusted.policy.state_dict().items():
        assert torch.equal(tensor, safe.policy.state_dict()[name]), name
    assert torch.equal(trusted.log_ent_coef, safe.log_ent_coef)
    assert trusted.actor.optimizer.state_dict()["param_groups"] == \
        safe.actor.optimizer.state_dict()["param_groups"]


# -- the leaderboard -------------------------------------------------------------------------
def test_the_leaderboard_ranks_others_agents_as_data_and_skips_what_needs_trust(
        model_zip, tmp_path, canary, capsys):
    from agents.benchmark import leaderboard as lb

    models = tmp_path / "submitted"
    models.mkdir()
    payload = base64.b64encode(_pickled(canary)).decode()

    def poison_data(entries):
        data = json.loads(entries["data"])
        data["policy_class"][":serialized:"] = payload
        entries["data"] = json.dumps(data).encode()

    def poison_tensors(entries):
        buf = io.BytesIO()
        torch.save(Payload(canary), buf)
        entries["policy.pth"] = buf.getvalue()

    _rewrite(model_zip, models / "a_data.zip", poison_data)
    _rewrite(model_zip, models / "b_tensors.zip", poison_tensors)
    specs = lb.policy_specs("SaddleTrap-v0", models)
    assert [Path(s).name for s in specs[len(lb.BASELINE_POLICIES):]] == ["a_data.zip",
                                                                         "b_tensors.zip"]
    row, _ = lb.evaluate_policy("SaddleTrap-v0", specs[-2], 1, 0, progress=False)
    assert row["kind"] == "PPO"
    with pytest.raises(UntrustedFileError):
        lb.evaluate_policy("SaddleTrap-v0", specs[-1], 1, 0, progress=False)


def test_shipped_models_load_as_data_and_act_as_sb3_loads_them():
    """Every shipped agent loads without --trust-model, and its actions are bit-identical to
    those of SB3's own (unpickling) loader."""
    from agents.evaluation.evaluate import trained_env

    shipped = sorted((ROOT / "agents" / "models").glob("*.zip"))
    assert shipped
    for path in shipped:
        _, config = trained_env(P.model_sidecar(path))
        space = observation_space(config)
        space.seed(0)
        obs = np.stack([space.sample() for _ in range(256)])
        safe = P.load_policy(str(path), config)
        trusted = P.load_policy(str(path), config, trust=True)
        assert np.array_equal(safe.predict(obs, deterministic=True)[0],
                              trusted.predict(obs, deterministic=True)[0]), path.name


# -- RLlib checkpoints (the [rllib] extra's environment) -------------------------------------
def _rllib_checkpoint(folder: Path, module: object, weights: bytes) -> Path:
    from agents.evaluation.rllib_policy import CHECKPOINT_MARKER, SIDECAR, WEIGHTS_FILE

    folder.mkdir()
    (folder / CHECKPOINT_MARKER).write_text("{}")
    (folder / SIDECAR).write_text(json.dumps({"backend": "rllib", "algo": "ppo",
                                              "env_id": "SaddleTrap-v0", "env_kwargs": {},
                                              "module": module}))
    (folder / WEIGHTS_FILE).write_bytes(weights)
    return folder


def test_rllib_checkpoints_are_read_as_data(tmp_path, canary, capsys):
    pytest.importorskip("ray")
    from agents.evaluation.rllib_policy import load_policy

    buf = io.BytesIO()
    torch.save({"w": Payload(canary)}, buf)
    module = {"fcnet_hiddens": [8, 8], "fcnet_activation": "tanh", "vf_share_layers": False}
    bad = _rllib_checkpoint(tmp_path / "payload", module, buf.getvalue())
    with pytest.raises(UntrustedFileError, match="--trust-model"):
        load_policy(bad)
    code, err = _saddle_eval(capsys, "--policy", str(bad))
    assert code == 2 and "--trust-model" in err.strip().splitlines()[-1]
    for cfg, match in (({**module, "fcnet_hiddens": [10 ** 9]}, "fcnet_hiddens"),
                       ({**module, "fcnet_activation": "os.system"}, "fcnet_activation"),
                       ({**module, "model_class": "x"}, "module")):
        folder = _rllib_checkpoint(tmp_path / f"cfg{len(list(tmp_path.iterdir()))}", cfg, b"")
        with pytest.raises(ValueError, match=match):
            load_policy(folder)
    # RLlib's own (pickled) files only with trust; without the weights file: refused
    bare = _rllib_checkpoint(tmp_path / "bare", module, b"")
    (bare / "policy_weights.pt").unlink()
    with pytest.raises(UntrustedFileError, match="--trust-model"):
        load_policy(bare)
