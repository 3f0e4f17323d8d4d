"""Reading model files as data: Stable-Baselines3 zips, observation-normaliser statistics
and replay buffers, without running anything they carry.

A Stable-Baselines3 zip holds JSON (``data``), tensors (``*.pth``) and, inside ``data``,
``:serialized:`` entries: cloudpickles of schedules, spaces and classes. SB3's own loader
unpickles those, and an unpickle runs whatever code the file names. Here:

* the zip is checked first (entry names, count and sizes, so a truncated, oversized or
  path-traversing archive is a clear error);
* ``data`` is parsed as JSON and its ``:serialized:`` entries are never decoded;
* tensors come through ``torch.load(weights_only=True)``, which refuses anything but
  tensors and plain containers;
* the policy network is rebuilt from the algorithm's own ``MlpPolicy`` class, the
  architecture in the plain JSON fields (or the sidecar's hyperparameters, read by
  `agents.evaluation.literal_kwargs`) and the spaces of the environment it was trained on, and its
  weights are loaded into it.

What would need unpickling is refused with `UntrustedFileError`, whose message names
``--trust-model``: the explicit opt-in (``trust=True`` in the API) to SB3's and pickle's own
loaders, for files whose source the user trusts. docs/security.md says what is trusted.
"""

from __future__ import annotations

import io
import json
import os
import re
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

TRUST_FLAG = "--trust-model"
TRUST_HINT = (f"pass {TRUST_FLAG} (trust=True in the API) only if you trust where the file "
              f"came from: unpickling can run any code")


class UntrustedFileError(ValueError):
    """Reading the file would need unpickling (which can run code) and trust was not given."""


def untrusted(path: str | os.PathLike, what: str) -> UntrustedFileError:
    """The error for a file that only ``--trust-model`` may load, saying ``what`` it holds."""
    return UntrustedFileError(f"{path}: {what}; {TRUST_HINT}")


# ---------------------------------------------------------------------------------------
# the archive
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ArchiveLimits:
    """Bounds on a model zip, far above any model this project trains (its largest is
    under 1 MB) and far below what would exhaust memory."""

    max_entries: int = 32
    max_entry_bytes: int = 256 * 1024 ** 2
    max_total_bytes: int = 512 * 1024 ** 2
    max_data_bytes: int = 16 * 1024 ** 2     # the JSON ``data`` entry


# SB3 writes flat names: data, policy.pth, policy.optimizer.pth, pytorch_variables.pth,
# _stable_baselines3_version, system_info.txt. No folders, so no path can leave the zip.
_ENTRY_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_\-]*(\.[A-Za-z0-9_\-]+)*")
_TEXT_ENTRIES = {"data", "_stable_baselines3_version", "system_info.txt"}


@dataclass
class Sb3Archive:
    """What a Stable-Baselines3 zip holds, read without unpickling."""

    path: Path
    data: dict[str, Any]             # the plain JSON fields of ``data``
    serialized: dict[str, dict]      # the fields SB3 pickled: their plain notes only
    params: dict[str, Any]           # state dicts by name: policy, policy.optimizer, ...
    variables: dict[str, Any] | None  # pytorch_variables.pth


def _bad_zip(path: Path, why: str) -> ValueError:
    return ValueError(f"{path}: not a Stable-Baselines3 model file ({why})")


def read_archive(path: str | os.PathLike, limits: ArchiveLimits = ArchiveLimits()) -> Sb3Archive:
    """The JSON fields and tensors of an SB3 zip, checked and read without unpickling;
    ValueError (naming the file) for an archive that is not one, UntrustedFileError for
    tensor files that hold objects."""
    path = Path(path)
    raw: dict[str, bytes] = {}
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
            if len(infos) > limits.max_entries:
                raise _bad_zip(path, f"{len(infos)} entries, more than {limits.max_entries}")
            total = 0
            for info in infos:
                name = info.filename
                if not _ENTRY_NAME.fullmatch(name) or ".." in name:
                    raise _bad_zip(path, f"unexpected entry name {name!r}")
                if name in raw:
                    raise _bad_zip(path, f"entry {name!r} appears twice")
                cap = limits.max_data_bytes if name == "data" else limits.max_entry_bytes
                total += info.file_size
                if info.file_size > cap or total > limits.max_total_bytes:
                    raise _bad_zip(path, f"entry {name!r} is larger than the {cap:,}-byte "
                                         f"limit (or the archive exceeds "
                                         f"{limits.max_total_bytes:,} bytes)")
                with z.open(info) as fh:
                    content = fh.read(cap + 1)  # the header's size may lie
                if len(content) > cap:
                    raise _bad_zip(path, f"entry {name!r} inflates past its stated size")
                raw[name] = content
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError,
            OSError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise _bad_zip(path, str(exc) or type(exc).__name__) from None
    if "data" not in raw or "policy.pth" not in raw:
        raise _bad_zip(path, "no 'data' or no 'policy.pth' entry")
    unknown = [n for n in raw if n not in _TEXT_ENTRIES and not n.endswith(".pth")]
    if unknown:
        raise _bad_zip(path, f"unexpected entries {unknown}")
    try:
        data = json.loads(raw["data"].decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise _bad_zip(path, f"its 'data' entry is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise _bad_zip(path, "its 'data' entry is not a JSON object")
    # SB3 writes plain notes (a space's shape, say) beside each pickle; the pickle is dropped.
    serialized = {k: {n: x for n, x in v.items() if n != ":serialized:"}
                  for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v}
    plain = {k: v for k, v in data.items() if k not in serialized}
    tensors = {name[:-4]: load_tensors(raw[name], f"{path}:{name}")
               for name in raw if name.endswith(".pth")}
    variables = tensors.pop("pytorch_variables", None)
    return Sb3Archive(path, plain, serialized, tensors, variables)


def load_tensors(source: bytes | str | os.PathLike, label: str) -> Any:
    """``torch.load(weights_only=True)`` on the CPU: tensors and plain containers only."""
    import pickle

    import torch

    stream = io.BytesIO(source) if isinstance(source, bytes) else source
    try:
        return torch.load(stream, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise untrusted(label, f"holds objects other than tensors ({first[:160]})") from None
    except Exception as exc:  # a truncated or corrupt tensor file: torch raises many kinds
        raise ValueError(f"{label}: not a readable tensor file ({type(exc).__name__}: "
                         f"{str(exc)[:160]})") from None


# ---------------------------------------------------------------------------------------
# the policy network
# ---------------------------------------------------------------------------------------
# policy_kwargs a rebuilt MlpPolicy may take from a file; anything else (a custom features
# extractor, say) is only available by unpickling.
_POLICY_KWARGS = {"net_arch", "activation_fn", "log_std_init", "ortho_init", "use_sde",
                  "use_expln", "squash_output", "full_std", "clip_mean", "n_critics",
                  "share_features_extractor", "normalize_images"}
_OPTIMIZER_KWARGS = {"optimizer_class", "optimizer_kwargs"}  # training only
MAX_LAYER_WIDTH = 8192
MAX_LAYERS = 16


def _check_net_arch(arch: Any, source: str) -> None:
    layers = arch.values() if isinstance(arch, dict) else [arch]
    for layer in layers:
        if not isinstance(layer, (list, tuple)) or len(layer) > MAX_LAYERS or not all(
                isinstance(w, int) and not isinstance(w, bool) and 1 <= w <= MAX_LAYER_WIDTH
                for w in layer):
            raise ValueError(f"{source}: net_arch must be a list (or dict of lists) of at most "
                             f"{MAX_LAYERS} layer widths in [1, {MAX_LAYER_WIDTH}], got {arch!r}")


def _class_from_note(note: Any, source: str) -> Any:
    """The class an SB3 note names (``"<class 'torch.nn.modules.activation.Tanh'>"``, how
    SB3 writes a class beside its pickle), if it is an allowed activation; never imported by
    the note's own path."""
    from .literal_kwargs import ALLOWED_NAMES, parse_kwargs_string

    m = re.fullmatch(r"<class 'torch\.nn\.modules\.activation\.([A-Za-z]+)'>", str(note))
    if m is None or f"nn.{m.group(1)}" not in ALLOWED_NAMES:
        raise ValueError(f"{source}: activation_fn {str(note)[:80]!r} is not an allowed "
                         f"activation")
    return parse_kwargs_string(f"dict(a=nn.{m.group(1)})", source)["a"]


def policy_kwargs_of(archive: Sb3Archive, sidecar: dict[str, Any] | None) -> dict[str, Any]:
    """The architecture keywords: the zip's plain ``policy_kwargs``; where SB3 had to pickle
    them (an activation or optimiser class), the plain notes it wrote beside the pickle,
    classes matched against an allowlist; failing those, the sidecar's hyperparameters,
    read as data."""
    from .literal_kwargs import parse_kwargs_string

    source = f"{archive.path}: policy_kwargs"
    if "policy_kwargs" in archive.data:
        kwargs = archive.data["policy_kwargs"]
    elif "policy_kwargs" in archive.serialized:
        kwargs = {k: v for k, v in archive.serialized["policy_kwargs"].items()
                  if k != ":type:" and k not in _OPTIMIZER_KWARGS}
        if "activation_fn" in kwargs:
            kwargs["activation_fn"] = _class_from_note(kwargs["activation_fn"], source)
    else:
        hyper = (sidecar or {}).get("hyperparams")
        text = hyper.get("policy_kwargs") if isinstance(hyper, dict) else None
        source = f"{archive.path}: sidecar policy_kwargs"
        kwargs = parse_kwargs_string(text, source) if isinstance(text, str) else (text or {})
    if not isinstance(kwargs, dict):
        raise ValueError(f"{source} must be a dict, got {type(kwargs).__name__}")
    kwargs = {k: v for k, v in kwargs.items() if k not in _OPTIMIZER_KWARGS}
    unknown = sorted(set(kwargs) - _POLICY_KWARGS)
    if unknown:
        raise untrusted(archive.path, f"its policy_kwargs {unknown} need classes that only "
                                      f"unpickling would provide")
    if "net_arch" in kwargs:
        _check_net_arch(kwargs["net_arch"], source)
    for key, value in kwargs.items():
        if key not in ("net_arch", "activation_fn") and (
                isinstance(value, (dict, list, str)) and key != "clip_mean"):
            raise ValueError(f"{source}: {key} must be a number or true/false, got {value!r}")
    return kwargs


def _plain(archive: Sb3Archive, key: str, kind: type | tuple[type, ...], default: Any) -> Any:
    value = archive.data.get(key, default)
    if value is not default and (isinstance(value, bool) and kind is not bool
                                 or not isinstance(value, kind)):
        raise ValueError(f"{archive.path}: data field {key!r} must be "
                         f"{getattr(kind, '__name__', kind)}, got {value!r}")
    return value


def stored_shape(archive: Sb3Archive, space: str) -> tuple[int, ...] | None:
    """The shape SB3 noted in plain text beside a pickled space, if it is readable."""
    shape = archive.serialized.get(space, {}).get("_shape")
    if isinstance(shape, list) and all(isinstance(s, int) and not isinstance(s, bool)
                                       for s in shape):
        return tuple(shape)
    return None


def build_policy(archive: Sb3Archive, algo: str, observation_space: Any, action_space: Any,
                 sidecar: dict[str, Any] | None = None) -> Any:
    """The archive's policy network, rebuilt as ``algo``'s ``MlpPolicy`` for the given spaces
    with its weights loaded (strictly: every tensor must fit), in evaluation mode."""
    import stable_baselines3 as sb3

    cls = getattr(sb3, algo).policy_aliases["MlpPolicy"]
    kwargs = policy_kwargs_of(archive, sidecar)
    if algo in ("PPO", "A2C"):   # on-policy algorithms pass use_sde beside policy_kwargs
        kwargs["use_sde"] = bool(_plain(archive, "use_sde", bool, False))
    want = stored_shape(archive, "observation_space")
    if want is not None and want != tuple(observation_space.shape):
        raise ValueError(f"{archive.path}: the model takes observations of shape {want}, the "
                         f"environment gives {tuple(observation_space.shape)}: evaluate it on "
                         f"the level and options it was trained on (its sidecar)")
    try:
        policy = cls(observation_space, action_space, lambda _progress: 0.0, **kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{archive.path}: cannot build its {algo} policy from "
                         f"{kwargs}: {exc}") from None
    state = archive.params.get("policy")
    if not isinstance(state, dict):
        raise ValueError(f"{archive.path}: policy.pth is not a state dict")
    try:
        policy.load_state_dict(state, strict=True)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise ValueError(f"{archive.path}: its weights do not fit a {algo} MlpPolicy with "
                         f"{kwargs} ({str(exc).splitlines()[0][:200]}); a custom policy "
                         f"class needs {TRUST_FLAG}") from None
    policy.set_training_mode(False)
    return policy


# ---------------------------------------------------------------------------------------
# observation-normaliser statistics
# ---------------------------------------------------------------------------------------
NORMALIZER_KEYS = ("obs_mean", "obs_var", "obs_count", "ret_mean", "ret_var", "ret_count",
                   "clip_obs", "clip_reward", "epsilon", "gamma", "norm_obs", "norm_reward")


def normalizer_state(norm: Any) -> dict[str, Any]:
    """The statistics of an SB3 VecNormalize as JSON-ready data (Box observations)."""
    rms, ret = norm.obs_rms, norm.ret_rms
    if isinstance(rms, dict):
        raise ValueError("normaliser statistics of dict observations are not supported")
    return {"obs_mean": rms.mean.tolist(), "obs_var": rms.var.tolist(),
            "obs_count": float(rms.count), "ret_mean": float(np.asarray(ret.mean)),
            "ret_var": float(np.asarray(ret.var)), "ret_count": float(ret.count),
            "clip_obs": float(norm.clip_obs), "clip_reward": float(norm.clip_reward),
            "epsilon": float(norm.epsilon), "gamma": float(norm.gamma),
            "norm_obs": bool(norm.norm_obs), "norm_reward": bool(norm.norm_reward)}


def save_normalizer(norm: Any, path: str | os.PathLike) -> Path:
    """Write the normaliser ``norm``'s statistics to ``path`` as JSON; returns the path."""
    path = Path(path)
    path.write_text(json.dumps(normalizer_state(norm), indent=1) + "\n")
    return path


def read_normalizer(path: str | os.PathLike, obs_dim: int | None = None) -> dict[str, Any]:
    """Normaliser statistics from JSON, checked: finite, variances >= 0, the right length."""
    path = Path(path)
    try:
        state = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable statistics file ({exc})") from None
    if not isinstance(state, dict) or set(NORMALIZER_KEYS) - set(state):
        raise ValueError(f"{path}: statistics must be a JSON object with {NORMALIZER_KEYS}")
    out: dict[str, Any] = {}
    for key in NORMALIZER_KEYS:
        v = state[key]
        if key.startswith("norm_"):
            if not isinstance(v, bool):
                raise ValueError(f"{path}: {key} must be true or false, got {v!r}")
            out[key] = v
            continue
        try:
            arr = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{path}: {key} must be numeric, got {str(v)[:80]}") from None
        if arr.ndim != (1 if key in ("obs_mean", "obs_var") else 0) or \
                not np.isfinite(arr).all() or (key.endswith(("var", "count", "clip_obs",
                                                             "clip_reward", "epsilon"))
                                               and (arr < 0).any()):
            raise ValueError(f"{path}: {key} must be a finite{' non-negative' if 'mean' not in key else ''} "
                             f"{'list' if arr.ndim else 'number'}, got {str(v)[:80]}")
        out[key] = arr if arr.ndim else float(arr)
    if out["obs_mean"].shape != out["obs_var"].shape or (
            obs_dim is not None and out["obs_mean"].shape != (obs_dim,)):
        raise ValueError(f"{path}: obs_mean and obs_var must have length "
                         f"{obs_dim if obs_dim is not None else 'equal'}, got "
                         f"{out['obs_mean'].shape} and {out['obs_var'].shape}")
    return out


class ObservationNormalizer:
    """Normalises observations as VecNormalize does when not training:
    clip((obs - mean) / sqrt(var + epsilon), ±clip_obs), with saved statistics."""

    def __init__(self, state: dict[str, Any]):
        self.mean = np.asarray(state["obs_mean"], np.float64)
        self.var = np.asarray(state["obs_var"], np.float64)
        self.epsilon = float(state["epsilon"])
        self.clip_obs = float(state["clip_obs"])
        self.norm_obs = bool(state["norm_obs"])

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        """``obs`` normalised and clipped as in training (unchanged if observations are not normalised)."""
        if not self.norm_obs:
            return obs
        return np.clip((obs - self.mean) / np.sqrt(self.var + self.epsilon),
                       -self.clip_obs, self.clip_obs)


def restore_normalizer(norm: Any, state: dict[str, Any]) -> None:
    """Put saved statistics into a live VecNormalize (resuming a run)."""
    norm.obs_rms.mean = np.array(state["obs_mean"], np.float64)
    norm.obs_rms.var = np.array(state["obs_var"], np.float64)
    norm.obs_rms.count = float(state["obs_count"])
    norm.ret_rms.mean = np.float64(state["ret_mean"])
    norm.ret_rms.var = np.float64(state["ret_var"])
    norm.ret_rms.count = float(state["ret_count"])
    for key in ("clip_obs", "clip_reward", "epsilon", "gamma"):
        setattr(norm, key, float(state[key]))
    norm.norm_obs, norm.norm_reward = bool(state["norm_obs"]), bool(state["norm_reward"])


# ---------------------------------------------------------------------------------------
# replay buffers (resuming off-policy runs)
# ---------------------------------------------------------------------------------------
_BUFFER_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones",
                  "timeouts")


def save_replay_buffer(buffer: Any, path: str | os.PathLike) -> Path:
    """An SB3 ReplayBuffer's arrays and position as npz (no pickled objects)."""
    path = Path(path)
    arrays = {k: getattr(buffer, k) for k in _BUFFER_ARRAYS
              if getattr(buffer, k, None) is not None}
    with open(path, "wb") as fh:  # np.savez_compressed appends .npz to a bare name
        np.savez_compressed(fh, pos=np.int64(buffer.pos), full=np.bool_(buffer.full),
                            **arrays)
    return path


def load_replay_buffer(buffer: Any, path: str | os.PathLike) -> None:
    """Fill a freshly made SB3 ReplayBuffer from `save_replay_buffer`'s file."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as f:
            data = {k: f[k] for k in f.files}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable replay buffer ({exc})") from None
    for key in _BUFFER_ARRAYS:
        mine = getattr(buffer, key, None)
        if mine is None:
            continue
        theirs = data.get(key)
        if theirs is None or theirs.shape != mine.shape:
            raise ValueError(f"{path}: {key} has shape "
                             f"{None if theirs is None else theirs.shape}, the run's buffer "
                             f"{mine.shape} (another buffer_size or n_envs?)")
        mine[...] = theirs
    pos = int(data.get("pos", -1))
    if not 0 <= pos <= buffer.buffer_size:
        raise ValueError(f"{path}: pos must lie in [0, {buffer.buffer_size}], got {pos}")
    buffer.pos, buffer.full = pos, bool(data.get("full", False))


__all__ = [
    "TRUST_FLAG",
    "TRUST_HINT",
    "ArchiveLimits",
    "ObservationNormalizer",
    "Sb3Archive",
    "UntrustedFileError",
    "build_policy",
    "load_replay_buffer",
    "load_tensors",
    "normalizer_state",
    "policy_kwargs_of",
    "read_archive",
    "read_normalizer",
    "restore_normalizer",
    "save_normalizer",
    "save_replay_buffer",
    "untrusted",
]
