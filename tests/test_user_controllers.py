"""Your own controller, evaluated like any other: ``saddle-eval --policy file.py:Class``, the
Python call `evaluate_controller`, and a leaderboard row, all on the same seeded episodes as
the baselines beside them."""

import json
import textwrap

import numpy as np
import pytest

from agents.benchmark import leaderboard as lb
from agents.evaluation import evaluate as E
from agents.evaluation.user_code import is_controller_spec, load_controller
from saddle_env.envs import EnvConfig

# A controller that holds the starting speed (action 0 in acceleration mode): the same
# actions as the `zero` baseline, so its row must equal zero's episode for episode.
HOLD = textwrap.dedent('''
    import numpy as np

    class Hold:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            obs = np.asarray(observation)
            n = 1 if obs.ndim == 1 else len(obs)
            return np.zeros((n, 1), dtype=np.float32), state

    class Push:
        """A constant action, given when it is built."""
        name = "push"

        def __init__(self, action=0.0, config=None):
            self.action = float(action)
            self.got_config = config

        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            obs = np.asarray(observation)
            n = 1 if obs.ndim == 1 else len(obs)
            return np.full((n, 1), self.action, dtype=np.float32), state

    class NoPredict:
        pass
''')
STEPS = ["--max-episode-steps", "60"]


@pytest.fixture
def controllers(tmp_path):
    path = tmp_path / "my_controllers.py"
    path.write_text(HOLD)
    return path


def _eval(capsys, *argv):
    try:
        code = E.main([*argv, "--json", "--no-progress", "--episodes", "4", *STEPS])
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_class_from_a_file_is_evaluated_on_the_baselines_episodes(controllers, capsys):
    code, out, err = _eval(capsys, "--policy", f"{controllers}:Hold", "--policy", "zero",
                           "--policy", "const-1.5")
    assert code == 0, err
    rows = {r["policy"]: r for r in json.loads(out)["policies"]}
    assert set(rows) == {"Hold", "zero", "const-1.5"}
    assert rows["Hold"]["kind"] == "controller" and rows["zero"]["kind"] == "baseline"
    # Same actions on the same episodes: the same numbers, to the last digit.
    for key in ("trapping_time", "kept", "return", "effort"):
        assert rows["Hold"][key] == rows["zero"][key], key
    assert rows["const-1.5"]["effort"] != rows["Hold"]["effort"]  # the table tells rows apart


def test_policy_kwargs_build_the_class_and_config_is_passed_to_it(controllers, capsys):
    code, out, err = _eval(capsys, "--policy", f"{controllers}:Push", "--policy-kwargs",
                           '{"action": 1.0}')
    assert code == 0, err
    (row,) = json.loads(out)["policies"]
    assert row["policy"] == "push" and row["effort"]["mean"] == pytest.approx(1.0)
    built = load_controller(f"{controllers}:Push", EnvConfig(omega_max=50.0), {"action": 0.5})
    assert built.action == 0.5 and built.got_config == EnvConfig(omega_max=50.0)


@pytest.mark.parametrize("spec, args, message", [
    ("{dir}/missing.py:Hold", [], "no such file"),
    ("{path}:Absent", [], "has no class 'Absent'"),
    ("{path}:NoPredict", [], "has no method predict"),
    ("{path}:Hold", ["--policy-kwargs", '{"gain": 2}'], "Hold(gain) failed"),
    ("{path}:Push", ["--policy-kwargs", "[1, 2]"], "expected a JSON object"),
    ("{path}:Push", ["--policy-kwargs", "{gain"], "not JSON"),
    ("no_such_module_here:Hold", [], "no module 'no_such_module_here'"),
])
def test_a_bad_controller_is_a_clear_error_before_any_episode(controllers, capsys, spec, args,
                                                               message):
    spec = spec.format(dir=controllers.parent, path=controllers)
    code, _, err = _eval(capsys, "--policy", spec, *args)
    assert code == 2 and message in err and "Traceback" not in err, err


def test_policy_kwargs_without_a_class_to_build_is_refused(capsys):
    code, _, err = _eval(capsys, "--policy", "zero", "--policy-kwargs", "{}")
    assert code == 2 and "no --policy names a controller class" in err


def test_a_spec_is_told_from_names_and_paths():
    assert is_controller_spec("a/b/ctrl.py:Mine") and is_controller_spec("pkg.mod:Mine")
    for not_a_class in ("const-1.2", "mpc", "runs/ppo/model.zip", "C:\\runs\\model.zip",
                        "runs/x:y/final", "ctrl.py:", "ctrl.py:1abc"):
        assert not is_controller_spec(not_a_class), not_a_class


def test_the_python_call_puts_an_object_beside_the_baselines():
    class Hold:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            obs = np.atleast_2d(observation)
            return np.zeros((len(obs), 1), dtype=np.float32), state

    table = E.evaluate_controller(Hold(), episodes=3, baselines=("zero", "const-1.5"),
                                  max_episode_steps=60)
    names = [row["policy"] for row in table["policies"]]
    assert names == ["Hold", "zero", "const-1.5"] and table["episodes"] == 3
    assert table["policies"][0]["trapping_time"] == table["policies"][1]["trapping_time"]
    with pytest.raises(TypeError, match="predict"):
        E.evaluate_controller(object(), episodes=1)


def test_the_leaderboard_adds_a_row_for_a_controller(controllers, tmp_path, monkeypatch):
    monkeypatch.setattr(lb, "BASELINE_POLICIES", ("zero",))
    empty = tmp_path / "models"
    empty.mkdir()
    rc = lb.main(["--episodes", "2", "--levels", "SaddleTrap-v0", "--out", str(tmp_path),
                  "--models", str(empty), "--no-progress", "--policy", f"{controllers}:Hold"])
    assert rc == 0
    data = json.loads((tmp_path / "leaderboard.json").read_text())
    rows = data["levels"]["SaddleTrap-v0"]["policies"]
    assert [r["policy"] for r in rows][-1].endswith("my_controllers.py:Hold")
    assert rows[-1]["key"].startswith("my_controllers.py:Hold@")  # keyed by the file's digest
    assert rows[-1]["trapping_time"] == rows[0]["trapping_time"]
