"""Controllers the user names: ``path/to/file.py:ClassName`` or ``package.module:ClassName``.

This is the one place where `agents` runs code that is not its own, and it runs only code a
user named on the command line or passed in Python, the way ``python file.py`` would: a
class is imported from the file or module the spec names and built, with no arguments or
with ``--policy-kwargs``. Files that merely arrive (model files, sidecars, recipes) are
still read as data (`agents.evaluation.model_files`); nothing here is reached from them.

The class follows Stable-Baselines3's protocol, as every baseline does::

    class MyController:
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            ...                      # observation: (obs_dim,) or (n, obs_dim) float32
            return action, state     # action: (1,) or (n, 1) in [-1, 1]

If its ``__init__`` takes a ``config`` parameter, it gets the level's `EnvConfig` (so a
subclass of `agents.control.controllers.Controller` works as it is). Its row in a table is
named by a ``name`` attribute the class defines itself, else by the class's name.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import json
import re
import sys
from pathlib import Path
from typing import Any

from saddle_env.envs import EnvConfig

# A spec: what to import, a colon, a class name. What to import is a file ending in .py or a
# dotted module name; a colon anywhere else (a Windows drive, an RLlib folder) is no spec.
_SPEC = re.compile(r"^(?P<source>.+?):(?P<cls>[A-Za-z_]\w*)$")
_MODULE = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


def is_controller_spec(spec: str) -> bool:
    """Whether ``spec`` names a user's class (``file.py:Class`` or ``module:Class``)."""
    m = _SPEC.match(str(spec))
    if not m:
        return False
    source = m.group("source")
    return source.endswith(".py") or bool(_MODULE.match(source))


def _import(source: str) -> Any:
    if source.endswith(".py"):
        path = Path(source).expanduser().resolve()
        if not path.is_file():
            raise ValueError(f"--policy {source}: no such file")
        # A module name of its own per file, so two files with one stem do not collide.
        digest = hashlib.sha256(str(path).encode()).hexdigest()[:8]
        stem = re.sub(r"\W", "_", path.stem)
        name = f"saddle_user_{stem}_{digest}"
        if name in sys.modules:
            return sys.modules[name]
        spec = importlib.util.spec_from_file_location(name, path)
        if spec is None or spec.loader is None:
            raise ValueError(f"--policy {source}: cannot be imported as a Python file")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[name]
            raise
        return module
    try:
        return importlib.import_module(source)
    except ModuleNotFoundError as exc:
        raise ValueError(f"--policy {source}: no module {exc.name!r} on the Python path") from None


def controller_label(cls: type) -> str:
    """The name a user's controller has in a table."""
    own = cls.__dict__.get("name")
    return own if isinstance(own, str) and own else cls.__name__


def load_controller(spec: str, config: EnvConfig | None = None,
                    kwargs: dict[str, Any] | None = None) -> Any:
    """Import and build the class ``spec`` names (see the module's docstring), with
    ``kwargs`` and, if it takes one, ``config``. Raises ValueError naming the spec when
    the file, module or class is missing, when the class cannot be built from these
    arguments, or when what it builds has no callable ``predict``."""
    m = _SPEC.match(str(spec))
    if not m or not is_controller_spec(spec):
        raise ValueError(f"--policy {spec!r}: expected path/to/file.py:ClassName or "
                         "package.module:ClassName")
    module = _import(m.group("source"))
    cls = getattr(module, m.group("cls"), None)
    if not inspect.isclass(cls):
        raise ValueError(f"--policy {spec}: {m.group('source')} has no class "
                         f"{m.group('cls')!r}")
    kwargs = dict(kwargs or {})
    try:
        takes_config = "config" in inspect.signature(cls).parameters
    except (TypeError, ValueError):    # a class whose signature cannot be read
        takes_config = False
    if takes_config and "config" not in kwargs:
        kwargs["config"] = config if config is not None else EnvConfig()
    try:
        controller: Any = cls(**kwargs)
    except TypeError as exc:
        raise ValueError(f"--policy {spec}: {cls.__name__}({', '.join(kwargs)}) failed: {exc} "
                         "(pass its arguments with --policy-kwargs '{\"name\": value}')") from None
    if not callable(getattr(controller, "predict", None)):
        raise ValueError(f"--policy {spec}: {cls.__name__} has no method predict(observation, "
                         "state=None, episode_start=None, deterministic=True)")
    if "name" not in vars(controller) and "name" not in cls.__dict__:
        try:
            controller.name = controller_label(cls)
        except AttributeError:      # a class with __slots__ or a read-only name keeps its own
            pass
    return controller


def source_digest(spec: str) -> str | None:
    """A digest of the file a ``file.py:Class`` spec names (None for a module spec): a
    leaderboard row made from an edited file is evaluated afresh."""
    m = _SPEC.match(str(spec))
    if not m or not m.group("source").endswith(".py"):
        return None
    path = Path(m.group("source")).expanduser()
    return hashlib.sha256(path.read_bytes()).hexdigest()[:12] if path.is_file() else None


def parse_policy_kwargs(text: str | None) -> dict[str, Any] | None:
    """``--policy-kwargs``: a JSON object (read as data), or None when not given. Raises
    ValueError saying what is wrong."""
    if text is None:
        return None
    try:
        kwargs = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"--policy-kwargs: not JSON ({exc})") from None
    if not isinstance(kwargs, dict):
        raise ValueError("--policy-kwargs: expected a JSON object such as '{\"gain\": 2}', "
                         f"got {text!r}")
    return kwargs
