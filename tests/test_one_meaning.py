"""One argument, one meaning, outside the simulator's own calls (tests/test_api.py covers
`simulate` and `simulate_batch`, tests/test_prediction.py `predict_batch`): every
sequence-valued option of the environment and of `saddle-sim` has one length, or is a set
whose length means nothing but its size; any other is refused by name, never reinterpreted.
"""

import numpy as np
import pytest

from saddle_env.cli import main
from saddle_env.envs import EnvConfig

# The pairs: (low, high) and nothing else, whatever the length given.
PAIRS = ["omega0_range", "a_range", "mu_range"]


def _config(**kw):
    if "mu_range" in kw:
        kw.setdefault("contact", "coulomb")
    return EnvConfig(**kw)


@pytest.mark.parametrize("name", PAIRS)
@pytest.mark.parametrize("value", [(0.1,), (0.1, 0.12, 0.14), [], np.array([0.1, 0.12]), 0.1])
def test_a_range_option_is_a_pair_or_refused_by_name(name, value):
    with pytest.raises(ValueError, match=rf"^{name} must be a \(low, high\) pair"):
        _config(**{name: value})


@pytest.mark.parametrize("name, value", [("omega0_range", (18.0, 22.0)),
                                         ("a_range", (0.14, 0.16)), ("mu_range", (0.01, 0.1))])
def test_a_pair_is_low_and_high(name, value):
    assert getattr(_config(**{name: value}), name) == value


@pytest.mark.parametrize("name, value, message", [
    ("ball_radii", 0.02, "ball_radii must be None or a tuple of radii"),
    ("ball_radii", np.array([0.02, 0.03]), "ball_radii must be None or a tuple of radii"),
    ("ball_radii", (), "ball_radii must be None or a non-empty tuple"),
    ("contact_models", "coulomb", "contact_models must be None or a tuple from"),
    ("contact_models", (), "contact_models must be a non-empty tuple"),
])
def test_a_set_option_is_a_non_empty_tuple_or_refused_by_name(name, value, message):
    with pytest.raises(ValueError, match=f"^{message}"):
        _config(**{name: value})


@pytest.mark.parametrize("radii", [(0.0223,), (0.0223, 0.0265), (0.0223, 0.0265, 0.033)])
def test_a_set_of_any_size_is_a_set_to_draw_from(radii):
    # two radii are two balls to draw from, not a (low, high) range
    assert _config(ball_radii=radii).ball_radii == radii


@pytest.mark.parametrize("args, flag", [
    (["--omega", "20", "21"], "21"),            # a second speed is not a ramp's rate
    (["--spin", "1", "2"], "--spin"),            # (WX, WY, WZ): three, or refused
])
def test_saddle_sim_takes_one_meaning_per_flag(args, flag, capsys):
    with pytest.raises(SystemExit) as stop:
        main([*args, "--t-end", "0.01"])
    assert stop.value.code == 2
    assert flag in capsys.readouterr().err

