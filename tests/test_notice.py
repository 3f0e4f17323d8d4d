"""A compile of saddle_env's code that takes more than a moment says so, once
(saddle_env/compilation/notice.py)."""

from __future__ import annotations

import logging
import time
from types import SimpleNamespace

from saddle_env.compilation import notice as _notice


def _event(module, name="step_serial"):
    f = SimpleNamespace(__module__=module, __qualname__=name)
    return SimpleNamespace(data={"dispatcher": SimpleNamespace(py_func=f)})


def test_a_long_compile_is_announced_once_with_its_name(caplog, monkeypatch):
    monkeypatch.setattr(_notice, "NOTICE_AFTER", 0.05)
    caplog.set_level(logging.INFO, logger="saddle_env")
    outer = _event("saddle_env.envs.control_step")
    inner = _event("saddle_env.integrators", "integrate_h")
    _notice._start(outer)
    _notice._start(inner)  # a callee compiled inside it: no second notice
    time.sleep(0.3)
    _notice._end(inner)
    _notice._end(outer)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "saddle_env.envs.control_step.step_serial" in warnings[0].getMessage()
    assert "once" in warnings[0].getMessage()
    assert any("compiled saddle_env.envs.control_step.step_serial in" in r.getMessage()
               for r in caplog.records if r.levelno == logging.INFO)


def test_a_short_compile_and_other_packages_say_nothing(caplog, monkeypatch):
    monkeypatch.setattr(_notice, "NOTICE_AFTER", 0.2)
    caplog.set_level(logging.INFO, logger="saddle_env")
    quick = _event("saddle_env.kernels", "rhs")
    _notice._start(quick)
    _notice._end(quick)
    monkeypatch.setattr(_notice, "NOTICE_AFTER", 0.01)
    other = _event("someone_else.module", "f")
    _notice._start(other)
    time.sleep(0.1)
    _notice._end(other)
    time.sleep(0.3)  # past the quick compile's threshold: its timer was cancelled
    assert caplog.records == []
