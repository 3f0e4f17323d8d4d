"""What every command line of ``agents/`` shares: one grammar for ``--env-kwargs``, resolving
``--env ID`` plus overrides to a validated `EnvConfig`, reading a Ray ``--address``, and
one-line errors for a missing optional dependency ("extra").

``--env-kwargs`` accepts, in every tool:

* ``key=value`` items (the zoo's ``key:value`` too), each value read as a YAML-flow /
  Python / JSON literal: ``R=0.033``, ``ball_radii=[0.0223,0.033]``, ``contact=slipping``,
  ``observe_angle=true`` or ``True``, ``b=None`` or ``null``; anything else is a string;
* or one JSON object: ``'{"R": 0.033, "ball_radii": [0.0223, 0.033]}'``.

Lists become tuples (the type of the environment's sequence options).
"""

from __future__ import annotations

import ast
import importlib
import json
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from types import ModuleType
from typing import Any

from saddle_env.envs import ENV_ID, EnvConfig, Level, get_level

from . import paths

# The extras of pyproject.toml that each optional module comes with.
EXTRA_OF = {"stable_baselines3": "train", "torch": "train", "yaml": "train", "rich": "train",
            "tensorboard": "train", "tqdm": "plot", "matplotlib": "plot"}


class MissingExtra(ImportError):
    """An optional dependency is not installed; the message names the extra to install."""


def install_hint(extra: str) -> str:
    """The command that adds ``extra``: editable in a source checkout; beside a wheel
    otherwise (saddle-env is not on PyPI: docs/install.md)."""
    if (paths.REPO_ROOT / "pyproject.toml").is_file():
        return f'pip install -e ".[{extra}]"'
    return (f'pip install --find-links DIST "saddle-env[{extra}]" (DIST: the folder of the '
            f'saddle-env wheel; docs/install.md)')


def require(module: str, extra: str | None = None, purpose: str = "this") -> ModuleType:
    """Import ``module`` or raise `MissingExtra` with one line naming the extra."""
    try:
        return importlib.import_module(module)
    except ImportError:
        extra = extra or EXTRA_OF.get(module.split(".")[0], "train")
        raise MissingExtra(f"{purpose} needs {module.split('.')[0]}, which is not installed: "
                           f"{install_hint(extra)}") from None


def missing(modules: Sequence[str]) -> list[str]:
    """The top-level modules among ``modules`` that cannot be imported."""
    out = []
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError:
            out.append(name)
    return out


# --------------------------------------------------------------------------------------
# --env-kwargs
# --------------------------------------------------------------------------------------
_WORDS = {"true": True, "false": False, "null": None, "none": None, "~": None,
          "yes": True, "no": False}


def parse_value(text: str) -> Any:
    """One ``--env-kwargs`` value: a JSON or Python literal (``0.033``, ``[1, 2]``,
    ``"x"``), a YAML word (``true``, ``False``, ``null``, ``None``, ``~``), a YAML flow list
    of such words (``[rolling, slipping]``), else the text itself."""
    text = text.strip()
    for parse in (json.loads, ast.literal_eval):
        try:
            return parse(text)
        except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
            pass
    if text.lower() in _WORDS:
        return _WORDS[text.lower()]
    if text.startswith("[") and text.endswith("]"):  # YAML flow list of bare words
        inner = text[1:-1].strip()
        return [parse_value(part) for part in inner.split(",")] if inner else []
    return text


def _tuples(value: Any) -> Any:
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def parse_env_kwargs(items: Sequence[str] | None) -> dict[str, Any]:
    """``--env-kwargs``: one JSON object, or ``key=value`` (or ``key:value``) items; see the
    module docstring. Raises ValueError naming the item that does not parse."""
    if not items:
        return {}
    if len(items) == 1 and items[0].lstrip().startswith("{"):
        try:
            kw = json.loads(items[0])
        except ValueError as exc:
            raise ValueError(f"--env-kwargs is not valid JSON: {exc}") from None
        if not isinstance(kw, dict):
            raise ValueError("--env-kwargs JSON must be an object")
    else:
        kw = {}
        for item in items:
            eq, colon = item.find("="), item.find(":")
            sep = "=" if eq >= 0 and (colon < 0 or eq < colon) else ":"
            key, found, text = item.partition(sep)
            if not found or not key.strip():
                raise ValueError(f"--env-kwargs items must look like key=value, got {item!r}")
            kw[key.strip()] = parse_value(text)
    return {k: _tuples(v) for k, v in kw.items()}


# --------------------------------------------------------------------------------------
# --env ID + overrides
# --------------------------------------------------------------------------------------
def resolve_env(env_id: str | None, overrides: dict[str, Any] | None = None
                ) -> tuple[Level, EnvConfig]:
    """The level ``env_id`` (default ``SaddleTrap-v0``) and its `EnvConfig` with
    ``overrides`` on top. ValueError (one line, listing the ids) for an unknown id; the
    config's own ValueError/TypeError for a bad option."""
    level = get_level(ENV_ID if env_id is None else env_id)
    return level, level.config(**(overrides or {}))


def level_overrides(level: Level, config: EnvConfig) -> dict[str, Any]:
    """The options of ``config`` that differ from the level's (lists for tuples: JSON)."""
    base = level.config()
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in config.as_dict().items()
            if v != getattr(base, k)}


def saved_settings(cls: type, config: Path, total_timesteps: int | None = None,
                   progress_bar: bool = True, **overrides: Any) -> Any:
    """The settings dataclass ``cls`` of a run from its ``config.json`` (the keys ``cls``
    knows; the recorded hyperparameters are re-read at training time), with a new budget
    and any ``overrides`` that are not None: what ``--resume`` continues with, on either
    backend. Not validated here."""
    saved = json.loads(Path(config).read_text())
    saved.pop("hyperparams_used", None)
    known = {f.name for f in fields(cls)}
    values = {k: v for k, v in saved.items() if k in known}
    if total_timesteps:
        values["total_timesteps"] = total_timesteps
    values.update({key: value for key, value in overrides.items() if value is not None})
    values["progress_bar"] = progress_bar
    return cls(**values)


def parse_address(address: str) -> tuple[str, int] | None:
    """(host, port) of ``--address`` (``HOST:PORT`` or ``ray://HOST:PORT``); None for
    ``auto`` (the cluster this machine joined with ``ray start``)."""
    text = address.strip()
    if text == "auto":
        return None
    bare = text.removeprefix("ray://")
    host, sep, port = bare.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--address must be HOST:PORT (the head's `ray start --head` "
                         f"address, e.g. 10.0.0.1:6379), ray://HOST:PORT or auto; got {address!r}")
    return host.strip("[]"), int(port)


__all__ = ["EXTRA_OF", "MissingExtra", "install_hint", "level_overrides", "missing",
           "parse_address", "parse_env_kwargs", "parse_value", "require", "resolve_env",
           "saved_settings"]
