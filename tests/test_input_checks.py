"""The simulator's entry points check their inputs once per call, in one place
(`saddle_env.runner.check_run` / `check_batch`): the same bad input gets the same message
from every entry point, with or without ``tol=``, and each ball's state is checked once."""

import math

import numpy as np
import pytest

from saddle_env import Scene, initial_state, runner, simulate, simulate_batch

BAD = [
    (dict(state=np.zeros(4)), "length 5"),
    (dict(state=np.array([0.01, 0.0, 0.0, 0.0, math.nan])), "must be finite"),
    (dict(omega=math.nan), "omega must be finite"),
    (dict(force=(1.0,)), "force must be a pair"),
    (dict(t_end=-1.0), "t_end must be > 0"),
    (dict(dt_out=0.0), "dt_out must be > 0"),
]


def _call(entry, tol, state=None, **kw):
    sc = Scene()
    state = initial_state(sc, 0.01, 0.0) if state is None else state
    call = dict(t_end=1.0, tol=tol)
    call.update(kw)
    if entry == "batch":
        t_end = call.pop("t_end")
        return simulate_batch(sc, np.array([state, state]), t_end, **call)
    t_end = call.pop("t_end")
    return simulate(sc, state, t_end, **call)


@pytest.mark.parametrize("kwargs, message", BAD)
@pytest.mark.parametrize("entry", ["single", "batch"])
@pytest.mark.parametrize("tol", [None, 1e-5])
def test_a_bad_input_gets_one_message_from_every_entry(kwargs, message, entry, tol):
    with pytest.raises(ValueError, match=message):
        _call(entry, tol, **kwargs)


def test_a_batch_checks_every_row_with_tol_too():
    # the pilot runs on a few rows; the checks still cover them all, before any pilot
    sc = Scene()
    rows = np.array([initial_state(sc, 0.01, 0.0)] * 5)
    rows[1, 4] = math.inf
    for tol in (None, 1e-5):
        with pytest.raises(ValueError, match=r"states\[1\] must be finite"):
            simulate_batch(sc, rows, 1.0, tol=tol)


@pytest.mark.parametrize("tol", [None, 1e-5])
def test_each_state_is_checked_once_per_call(monkeypatch, tol):
    calls = []
    check = runner.check_state

    def counted(scene, state, name="state"):
        calls.append(name)
        return check(scene, state, name)

    monkeypatch.setattr(runner, "check_state", counted)
    sc = Scene()
    y0 = initial_state(sc, 0.01, 0.0)
    simulate(sc, y0, 0.5, tol=tol)
    assert calls == ["state"]
    calls.clear()
    simulate_batch([sc] * 3, np.array([y0] * 3), 0.5, tol=tol)
    assert calls == ["states[0]", "states[1]", "states[2]"]
    calls.clear()
    # one Scene for every ball: the rows are checked together, none by itself
    simulate_batch(sc, np.array([y0] * 3), 0.5, tol=tol)
    assert calls == []
