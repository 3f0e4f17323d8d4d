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
                             log_dir=str(tmp_path), run_name="run").validate().with_recipe(
                                 load_hyperparams(algo, "SaddleTrap-v0", hyper_file))
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


# -- exported policy folders (saddle-export, saddle_env.deploy) -------------------------------
@pytest.fixture(scope="module")
def exported_folder(model_zip, tmp_path_factory):
    """An honest export of the small model, the template of the crafted folders."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from agents.evaluation.export import export_policy

    return export_policy(model_zip, tmp_path_factory.mktemp("exported") / "honest")


def _folder(src: Path, dst: Path, spec=None, graph=None) -> Path:
    """A copy of exported folder ``src`` at ``dst``: ``spec(dict)`` edits policy.json,
    ``graph(onnx.ModelProto)`` edits the graph (policy.json's sha256 follows the edit)."""
    import hashlib
    import shutil

    import onnx

    shutil.copytree(src, dst)
    data = json.loads((dst / "policy.json").read_text())
    if graph is not None:
        model = onnx.load(str(dst / "policy.onnx"))
        graph(model)
        raw = model.SerializeToString()
        (dst / "policy.onnx").write_bytes(raw)
        data["onnx"]["sha256"] = hashlib.sha256(raw).hexdigest()
    if spec is not None:
        spec(data)
    (dst / "policy.json").write_text(json.dumps(data))
    return dst


@pytest.fixture
def no_session(monkeypatch):
    """Records every onnxruntime session made: a crafted folder must make none."""
    ort = pytest.importorskip("onnxruntime")
    made = []
    real = ort.InferenceSession
    monkeypatch.setattr(ort, "InferenceSession", lambda *a, **k: made.append(1) or real(*a, **k))
    return made


def _set(path: str, value):
    def edit(data):
        *parents, last = path.split(".")
        node = data
        for key in parents:
            node = node[key]
        node[last] = value
    return edit


@pytest.mark.parametrize("edit, match", [
    (_set("format", "other"), "format"),
    (_set("format_version", 99), "format_version"),
    (_set("frame_stack", "3"), "frame_stack"),
    (_set("frame_stack", 10 ** 9), "frame_stack"),
    (_set("observation.dim", -1), "observation.dim"),
    (_set("observation.low", [0.0]), "observation.low"),
    (_set("normalizer", {"mean": [0.0] * 5, "var": [-1.0] * 5, "epsilon": 1e-8, "clip": 10.0}),
     "normalizer.var"),
    (_set("normalizer", {"mean": ["__import__('os')"] * 5, "var": [1.0] * 5, "epsilon": 1e-8,
                         "clip": 10.0}), "normalizer.mean"),
    (_set("action.in_graph", "eval"), "action.in_graph"),
    (_set("action.low", [float("nan")]), "action.low"),
    (_set("onnx.file", "../../elsewhere/policy.onnx"), "onnx.file"),
    (_set("onnx.file", "/etc/passwd"), "onnx.file"),
    (_set("onnx.opset", 99), "onnx.opset"),
    (_set("onnx.sha256", "0" * 64), "sha256"),
    (_set("env_kwargs", {"a": {"b": {"c": {"d": {"e": {"f": 1}}}}}}), "env_kwargs"),
])
def test_a_crafted_policy_json_is_a_one_line_error(exported_folder, tmp_path, capsys,
                                                   no_session, edit, match):
    from saddle_env.deploy import Controller, PolicyFolderError

    bad = _folder(exported_folder, tmp_path / "bad", spec=edit)
    with pytest.raises(PolicyFolderError, match=match) as exc:
        Controller.from_dir(bad)
    assert len(str(exc.value).splitlines()) == 1 and str(bad) in str(exc.value)
    code, err = _saddle_eval(capsys, "--policy", str(bad))
    assert code == 2 and match.split(".")[-1] in err.strip().splitlines()[-1]
    assert not no_session


def test_a_positions_only_layout_has_no_velocity_columns_and_is_read(exported_folder, tmp_path):
    # A level whose camera sees positions only (the Lab level) exports vx, vy as null; any
    # other non-integer is still refused.
    from saddle_env.deploy import PolicyFolderError, read_spec

    def camera(data):
        data["observation"]["layout"].update(vx=None, vy=None)

    spec = read_spec(_folder(exported_folder, tmp_path / "camera", spec=camera))
    assert spec.layout["vx"] is None and spec.layout["vy"] is None
    with pytest.raises(PolicyFolderError, match="observation.layout.vx must be int"):
        read_spec(_folder(exported_folder, tmp_path / "bad", spec=_set("observation.layout.vx",
                                                                        "2")))


def test_policy_json_that_is_not_json_or_too_large_is_refused(exported_folder, tmp_path,
                                                              no_session):
    from saddle_env.deploy import Controller, PolicyFolderError

    for name, text, match in (("garbage", "\xff{", "not JSON"), ("list", "[1]", "JSON object"),
                              ("deep", "[" * 100000 + "]" * 100000, "not JSON|JSON object"),
                              ("huge", " " * (2 << 20) + "{}", "larger than")):
        bad = _folder(exported_folder, tmp_path / name)
        (bad / "policy.json").write_text(text)
        with pytest.raises(PolicyFolderError, match=match):
            Controller.from_dir(bad)
    assert not no_session


def _graph_edit(kind):
    """Edits of the honest graph that a reader must refuse."""
    from onnx import TensorProto, helper, numpy_helper

    def custom_op(model):   # an operator from another domain (a custom-op library's)
        node = model.graph.node[-1]
        node.domain = "com.example.evil"
        model.opset_import.append(helper.make_opsetid("com.example.evil", 1))

    def control_flow(model):   # a standard operator that is not an MLP's: a Loop
        node = model.graph.node[-1]
        node.op_type = "Loop"

    def external(model):   # a weight that lives in a file beside (or anywhere)
        t = model.graph.initializer[0]
        t.data_location = TensorProto.EXTERNAL
        del t.external_data[:]
        t.external_data.add(key="location", value="../../../etc/passwd")
        t.ClearField("raw_data")
        t.ClearField("float_data")

    def huge(model):   # a 5M-element constant
        model.graph.initializer.append(numpy_helper.from_array(
            np.zeros(5 << 20, np.float32), "padding"))

    def broken(model):   # an edge nobody produces: onnx.checker refuses it
        model.graph.node[-1].input[0] = "nowhere"

    def renamed(model):
        model.graph.output[0].name = "other"
        model.graph.node[-1].output[0] = "other"

    return {"custom_op": (custom_op, "domain|not allowed"), "loop": (control_flow, "Loop"),
            "external": (external, "external data"), "huge": (huge, "elements|larger than"),
            "broken": (broken, "onnx.checker"), "renamed": (renamed, "output")}[kind]


@pytest.mark.parametrize("kind", ["custom_op", "loop", "external", "huge", "broken", "renamed"])
def test_a_crafted_graph_is_refused_before_it_runs(exported_folder, tmp_path, capsys,
                                                   no_session, kind):
    pytest.importorskip("onnx")
    from saddle_env.deploy import Controller, PolicyFolderError

    edit, match = _graph_edit(kind)
    bad = _folder(exported_folder, tmp_path / kind, graph=edit)
    with pytest.raises(PolicyFolderError, match=match) as exc:
        Controller.from_dir(bad)
    assert len(str(exc.value).splitlines()) == 1
    code, err = _saddle_eval(capsys, "--policy", str(bad))
    assert code == 2 and "policy.onnx" in err.strip().splitlines()[-1]
    assert not no_session


def test_a_graph_that_is_not_onnx_or_is_a_link_is_refused(exported_folder, tmp_path,
                                                          no_session):
    import hashlib

    from saddle_env.deploy import Controller, PolicyFolderError

    garbage = b"\x08\x07" + b"\xff" * 64
    bad = _folder(exported_folder, tmp_path / "garbage",
                  spec=_set("onnx.sha256", hashlib.sha256(garbage).hexdigest()))
    (bad / "policy.onnx").write_bytes(garbage)
    with pytest.raises(PolicyFolderError, match="not an ONNX model|onnx.checker|input"):
        Controller.from_dir(bad)
    linked = _folder(exported_folder, tmp_path / "linked")
    target = tmp_path / "outside.onnx"
    target.write_bytes((linked / "policy.onnx").read_bytes())
    (linked / "policy.onnx").unlink()
    (linked / "policy.onnx").symlink_to(target)
    with pytest.raises(PolicyFolderError, match="symbolic link"):
        Controller.from_dir(linked)
    assert not no_session
    assert Controller.from_dir(exported_folder).act(_obs(1)[0]).shape == (1,)   # the honest one


def test_a_graph_whose_actions_are_not_what_policy_json_says_is_an_error(exported_folder,
                                                                         tmp_path):
    from saddle_env.deploy import Controller

    def two_actions(data):
        data["action"].update(dim=2, low=[-1.0, -1.0], high=[1.0, 1.0])

    bad = _folder(exported_folder, tmp_path / "two", spec=two_actions)
    with pytest.raises(ValueError, match=r"gave actions of shape \(1, 1\).*\(1, 2\)"):
        Controller.from_dir(bad).act(_obs(1)[0])
