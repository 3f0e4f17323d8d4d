"""The exported policy folder, read as data: ``policy.json`` checked against its schema and
``policy.onnx`` checked before any runtime sees it.

A folder written by ``saddle-export`` (`agents.evaluation.export`) holds

* ``policy.onnx``: the network, observation in, final action out (clipping or unscaling to
  the action box is in the graph);
* ``policy.json``: what the graph needs around it: the level and its options, the observation
  layout, the frame stack, the observation normaliser (applied before the graph, in float64,
  exactly as evaluation applies it), the action box and the ONNX opset.

A folder from elsewhere is data (docs/security.md): every field of ``policy.json`` is checked
by hand (no schema dependency) and every bound is explicit; the graph must pass
``onnx.checker``, use only the operators an export produces (`ALLOWED_OPS`, standard domain),
carry its tensors inside the file (no external data at all) and stay within `Limits`. Any
violation is a `PolicyFolderError` with one line naming the folder and the field.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

POLICY_JSON = "policy.json"
POLICY_ONNX = "policy.onnx"
FORMAT = "saddle-env-policy"
FORMAT_VERSION = 1
OPSET = 17                      # what `saddle-export` writes
OPSETS = range(13, 22)          # what a reader accepts (onnxruntime >= 1.17 runs them)
INPUT_NAME, OUTPUT_NAME = "observation", "action"
# The operators an exported MLP policy is made of (torch's exporter, opset 13-21): matrix
# products, the activations SB3 allows (agents.evaluation.literal_kwargs), the clip or
# rescale of the action, and the shape bookkeeping of a dynamic batch (SB3's Gaussian
# builds its mean as zeros of the batch's shape plus the network's output: ConstantOfShape,
# Expand). No control flow, no random numbers, no custom domains.
ALLOWED_OPS = frozenset({
    "Gemm", "MatMul", "Add", "Sub", "Mul", "Div", "Neg", "Sqrt",
    "Tanh", "Relu", "LeakyRelu", "Elu", "Selu", "Sigmoid", "Softplus", "Softsign", "Exp",
    "Clip", "Min", "Max", "Cast", "Constant", "Identity",
    "Reshape", "Flatten", "Squeeze", "Unsqueeze", "Shape", "Gather", "Slice", "Concat",
    "ConstantOfShape", "Expand",
})
STANDARD_DOMAINS = ("", "ai.onnx")


@dataclass(frozen=True)
class Limits:
    """Bounds on what a folder may hold: far above an exported policy of this project (the
    shipped ones are under 200 kB), far below what would exhaust a small computer."""

    json_bytes: int = 1 << 20          # policy.json
    onnx_bytes: int = 64 << 20         # policy.onnx
    tensor_elements: int = 4 << 20     # any one initializer or constant
    nodes: int = 1000
    frame_stack: int = 64
    observation_dim: int = 1024        # one frame's columns
    action_dim: int = 16


LIMITS = Limits()


class PolicyFolderError(ValueError):
    """An exported policy folder that cannot be used as it is; the message names the folder
    and the field or file at fault, on one line."""


@dataclass(frozen=True)
class PolicySpec:
    """A checked ``policy.json``. ``normalizer``: None, or ``mean``, ``var`` (frame-length
    lists), ``epsilon`` and ``clip`` of clip((obs − mean) / sqrt(var + epsilon), ±clip)."""

    folder: Path
    env_id: str
    env_kwargs: dict[str, Any]
    options: dict[str, Any]
    max_episode_steps: int | None
    layout: dict[str, Any]
    observation_dim: int
    observation_low: list[float]
    observation_high: list[float]
    frame_stack: int
    normalizer: dict[str, Any] | None
    action_dim: int
    action_low: list[float]
    action_high: list[float]
    action_in_graph: str
    opset: int
    onnx_sha256: str
    source: dict[str, Any]

    @property
    def input_dim(self) -> int:
        """Columns the graph takes: ``frame_stack`` frames, oldest first."""
        return self.frame_stack * self.observation_dim


# ---------------------------------------------------------------------------------------
# policy.json
# ---------------------------------------------------------------------------------------
def _fail(folder: Path, what: str) -> PolicyFolderError:
    return PolicyFolderError(f"{folder}: {what}")


def _get(d: dict[str, Any], key: str, kind: type | tuple[type, ...], folder: Path,
         where: str, optional: bool = False) -> Any:
    if key not in d:
        if optional:
            return None
        raise _fail(folder, f"{POLICY_JSON}: {where}{key} is missing")
    value = d[key]
    if optional and value is None:
        return None
    if isinstance(value, bool) and kind is not bool or not isinstance(value, kind):
        name = kind.__name__ if isinstance(kind, type) else "/".join(k.__name__ for k in kind)
        raise _fail(folder, f"{POLICY_JSON}: {where}{key} must be {name}, got "
                            f"{json.dumps(value)[:80]}")
    return value


def _int(d: dict[str, Any], key: str, low: int, high: int, folder: Path, where: str = "",
         optional: bool = False) -> Any:
    value = _get(d, key, int, folder, where, optional)
    if value is not None and not low <= value <= high:
        raise _fail(folder, f"{POLICY_JSON}: {where}{key} must lie in [{low}, {high}], "
                            f"got {value}")
    return value


def _floats(d: dict[str, Any], key: str, n: int, folder: Path, where: str,
            finite: bool = True, nonneg: bool = False) -> list[float]:
    value = _get(d, key, list, folder, where)
    ok = len(value) == n and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                 for v in value)
    if ok and finite:
        ok = all(math.isfinite(v) for v in value)
    if ok and nonneg:
        ok = all(v >= 0 for v in value)
    if not ok:
        kind = ("finite " if finite else "") + ("non-negative " if nonneg else "")
        raise _fail(folder, f"{POLICY_JSON}: {where}{key} must be a list of {n} {kind}numbers, "
                            f"got {json.dumps(value)[:80]}")
    return [float(v) for v in value]


def _number(d: dict[str, Any], key: str, folder: Path, where: str) -> float:
    """A finite, non-negative number."""
    value = _get(d, key, (int, float), folder, where)
    if not math.isfinite(value) or value < 0:
        raise _fail(folder, f"{POLICY_JSON}: {where}{key} must be a finite non-negative "
                            f"number, got {value}")
    return float(value)


def _json_plain(value: Any, depth: int = 0) -> bool:
    """JSON of numbers, strings, booleans, null, lists and string-keyed objects, not deep."""
    if depth > 4:
        return False
    if value is None or isinstance(value, (bool, int, float, str)):
        return not isinstance(value, float) or math.isfinite(value)
    if isinstance(value, list):
        return all(_json_plain(v, depth + 1) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _json_plain(v, depth + 1) for k, v in value.items())
    return False


def _load_policy_json(folder: Path, limits: Limits) -> dict[str, Any]:
    """The folder's ``policy.json`` as a JSON object of the right format (size, encoding and
    ``format`` checked)."""
    path = folder / POLICY_JSON
    try:
        size = path.stat().st_size
    except OSError:
        raise _fail(folder, f"no {POLICY_JSON}: not an exported policy folder") from None
    if size > limits.json_bytes:
        raise _fail(folder, f"{POLICY_JSON} is {size} bytes, larger than {limits.json_bytes}")
    try:
        data = json.loads(path.read_bytes().decode("utf-8"),
                          parse_constant=lambda c: float("nan"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _fail(folder, f"{POLICY_JSON} is not JSON ({str(exc)[:120]})") from None
    if not isinstance(data, dict):
        raise _fail(folder, f"{POLICY_JSON} must be a JSON object")
    if data.get("format") != FORMAT:
        raise _fail(folder, f"{POLICY_JSON}: format must be {FORMAT!r}, got "
                            f"{json.dumps(data.get('format'))[:80]}")
    return data


def _observation(data: dict[str, Any], folder: Path, limits: Limits
                 ) -> tuple[int, list[float], list[float], dict[str, Any]]:
    """``observation``: its size, bounds and layout, checked."""
    obs = _get(data, "observation", dict, folder, "")
    dim = _int(obs, "dim", 1, limits.observation_dim, folder, "observation.")
    low = _floats(obs, "low", dim, folder, "observation.", finite=False)
    high = _floats(obs, "high", dim, folder, "observation.", finite=False)
    layout = _get(obs, "layout", dict, folder, "observation.")
    for key in ("frame_dim", "frames", "omega", "x", "y"):
        _int(layout, key, 0, limits.observation_dim, folder, "observation.layout.")
    # vx, vy are null on a level whose camera sees positions only (the Lab level)
    for key in ("cos", "command", "vx", "vy"):
        _int(layout, key, 0, limits.observation_dim, folder, "observation.layout.", optional=True)
    _get(layout, "lab_frame", bool, folder, "observation.layout.")
    if layout["frame_dim"] * layout["frames"] != dim:
        raise _fail(folder, f"{POLICY_JSON}: observation.layout frame_dim × frames must equal "
                            f"observation.dim {dim}")
    return dim, low, high, layout


def _normalizer(data: dict[str, Any], dim: int, folder: Path) -> dict[str, Any] | None:
    """``normalizer`` (optional): the observation's mean, variance, epsilon and clip."""
    norm = _get(data, "normalizer", dict, folder, "", optional=True)
    if norm is not None:
        where = "normalizer."
        norm = {"mean": _floats(norm, "mean", dim, folder, where),
                "var": _floats(norm, "var", dim, folder, where, nonneg=True),
                "epsilon": _number(norm, "epsilon", folder, where),
                "clip": _number(norm, "clip", folder, where)}
        if min(norm["var"]) + norm["epsilon"] <= 0:
            raise _fail(folder, f"{POLICY_JSON}: normalizer var + epsilon must be positive")
    return norm


def _action(data: dict[str, Any], folder: Path, limits: Limits
            ) -> tuple[int, list[float], list[float], str]:
    """``action``: its size, bounds and what the graph does to it, checked."""
    act = _get(data, "action", dict, folder, "")
    adim = _int(act, "dim", 1, limits.action_dim, folder, "action.")
    alow = _floats(act, "low", adim, folder, "action.")
    ahigh = _floats(act, "high", adim, folder, "action.")
    if any(lo > hi for lo, hi in zip(alow, ahigh)):
        raise _fail(folder, f"{POLICY_JSON}: action.low must not exceed action.high")
    in_graph = _get(act, "in_graph", str, folder, "action.")
    if in_graph not in ("clip", "unscale"):
        raise _fail(folder, f"{POLICY_JSON}: action.in_graph must be 'clip' or 'unscale', got "
                            f"{json.dumps(in_graph)[:40]}")
    return adim, alow, ahigh, in_graph


def _onnx(data: dict[str, Any], folder: Path) -> tuple[int, str]:
    """``onnx``: the graph file's fixed name and tensor names; its opset and sha256."""
    onnx_info = _get(data, "onnx", dict, folder, "")
    if onnx_info.get("file") != POLICY_ONNX:
        raise _fail(folder, f"{POLICY_JSON}: onnx.file must be {POLICY_ONNX!r} (a file in the "
                            f"folder, never a path), got {json.dumps(onnx_info.get('file'))[:80]}")
    if onnx_info.get("input") != INPUT_NAME or onnx_info.get("output") != OUTPUT_NAME:
        raise _fail(folder, f"{POLICY_JSON}: onnx.input and onnx.output must be "
                            f"{INPUT_NAME!r} and {OUTPUT_NAME!r}")
    opset = _int(onnx_info, "opset", OPSETS.start, OPSETS.stop - 1, folder, "onnx.")
    sha = _get(onnx_info, "sha256", str, folder, "onnx.")
    if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise _fail(folder, f"{POLICY_JSON}: onnx.sha256 must be 64 lower-case hex digits")
    return opset, sha


def read_spec(folder: str | os.PathLike, limits: Limits = LIMITS) -> PolicySpec:
    """``policy.json`` of ``folder``, checked field by field (see the module).

    Parameters
    ----------
    folder : str or os.PathLike
        A folder ``saddle-export`` wrote.
    limits : Limits
        The size limits the folder must keep to.

    Returns
    -------
    PolicySpec
        The folder's description of the policy.

    Raises
    ------
    PolicyFolderError
        Naming the folder and the field, if the file is missing, too large, not JSON, or a
        field is missing or out of range.
    """
    folder = Path(folder)
    data = _load_policy_json(folder, limits)
    _int(data, "format_version", FORMAT_VERSION, FORMAT_VERSION, folder)
    env_id = _get(data, "env_id", str, folder, "")
    if len(env_id) > 100:
        raise _fail(folder, f"{POLICY_JSON}: env_id is longer than 100 characters")
    env_kwargs = _get(data, "env_kwargs", dict, folder, "")
    options = _get(data, "options", dict, folder, "")
    for key, value in (("env_kwargs", env_kwargs), ("options", options)):
        if not _json_plain(value):
            raise _fail(folder, f"{POLICY_JSON}: {key} must hold plain, finite JSON values")
    steps = _int(data, "max_episode_steps", 1, 10**7, folder, optional=True)
    dim, low, high, layout = _observation(data, folder, limits)
    stack = _int(data, "frame_stack", 1, limits.frame_stack, folder)
    norm = _normalizer(data, dim, folder)
    adim, alow, ahigh, in_graph = _action(data, folder, limits)
    opset, sha = _onnx(data, folder)
    source = _get(data, "source", dict, folder, "", optional=True) or {}
    if not _json_plain(source):
        raise _fail(folder, f"{POLICY_JSON}: source must hold plain, finite JSON values")
    return PolicySpec(folder, env_id, env_kwargs, options, steps, layout, dim, low, high, stack,
                      norm, adim, alow, ahigh, in_graph, opset, sha, source)


# ---------------------------------------------------------------------------------------
# policy.onnx
# ---------------------------------------------------------------------------------------
def read_graph(spec: PolicySpec, limits: Limits = LIMITS) -> bytes:
    """The bytes of ``policy.onnx``, checked (see the module); what a runtime may load."""
    folder = spec.folder
    path = folder / POLICY_ONNX
    if path.is_symlink():
        raise _fail(folder, f"{POLICY_ONNX} is a symbolic link; it must be a file in the folder")
    try:
        size = path.stat().st_size
    except OSError:
        raise _fail(folder, f"no {POLICY_ONNX}") from None
    if size > limits.onnx_bytes:
        raise _fail(folder, f"{POLICY_ONNX} is {size} bytes, larger than {limits.onnx_bytes}")
    raw = path.read_bytes()
    if hashlib.sha256(raw).hexdigest() != spec.onnx_sha256:
        raise _fail(folder, f"{POLICY_ONNX} does not match onnx.sha256 of {POLICY_JSON} "
                            "(changed or truncated after export)")
    check_graph(raw, spec, limits)
    return raw


def check_graph(raw: bytes, spec: PolicySpec, limits: Limits = LIMITS) -> None:
    """Raise `PolicyFolderError` unless the serialized model ``raw`` is a standard-operator
    graph, self-contained and within ``limits``, with the input and output ``spec`` names."""
    folder = spec.folder
    onnx = _require("onnx")
    from onnx import TensorProto

    try:
        model = onnx.load_model_from_string(raw)
    except Exception as exc:  # protobuf raises its own DecodeError and others
        raise _fail(folder, f"{POLICY_ONNX} is not an ONNX model ({type(exc).__name__})") \
            from None
    graph = model.graph
    if len(model.functions):
        raise _fail(folder, f"{POLICY_ONNX} defines local functions; only standard operators "
                            "are allowed")
    for imp in model.opset_import:
        if imp.domain not in STANDARD_DOMAINS:
            raise _fail(folder, f"{POLICY_ONNX} imports operator domain {imp.domain[:40]!r}; "
                                "only the standard one is allowed")
        if imp.version not in OPSETS:
            raise _fail(folder, f"{POLICY_ONNX}: opset {imp.version} outside "
                                f"[{OPSETS.start}, {OPSETS.stop - 1}]")
    if len(graph.node) > limits.nodes:
        raise _fail(folder, f"{POLICY_ONNX} has {len(graph.node)} nodes, more than "
                            f"{limits.nodes}")
    tensors = list(graph.initializer) + list(graph.sparse_initializer)
    for node in graph.node:
        if node.domain not in STANDARD_DOMAINS or node.op_type not in ALLOWED_OPS:
            raise _fail(folder, f"{POLICY_ONNX}: operator {node.domain + '.' if node.domain else ''}"
                                f"{node.op_type[:40]} is not allowed (standard MLP operators "
                                "only)")
        for attr in node.attribute:
            if attr.g.node or attr.graphs:
                raise _fail(folder, f"{POLICY_ONNX}: node {node.name[:40]!r} holds a subgraph")
            if attr.HasField("t"):
                tensors.append(attr.t)
    for t in tensors:
        if t.data_location == TensorProto.EXTERNAL or len(t.external_data):
            raise _fail(folder, f"{POLICY_ONNX}: tensor {t.name[:40]!r} refers to external "
                                "data; an exported policy carries all its tensors inside")
        elements = math.prod(t.dims) if hasattr(t, "dims") else 0
        if elements > limits.tensor_elements:
            raise _fail(folder, f"{POLICY_ONNX}: tensor {t.name[:40]!r} has {elements} "
                                f"elements, more than {limits.tensor_elements}")
    try:
        onnx.checker.check_model(model, full_check=True)
    except Exception as exc:  # onnx raises ValidationError and, on shape inference, others
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise _fail(folder, f"{POLICY_ONNX} fails onnx.checker: {first[:160]}") from None
    ins = [i for i in graph.input if i.name not in {t.name for t in graph.initializer}]
    if [i.name for i in ins] != [INPUT_NAME] or [o.name for o in graph.output] != [OUTPUT_NAME]:
        raise _fail(folder, f"{POLICY_ONNX} must take one input {INPUT_NAME!r} and give one "
                            f"output {OUTPUT_NAME!r}")
    for value, want, label in ((ins[0], spec.input_dim, "input"),
                               (graph.output[0], spec.action_dim, "output")):
        ttype = value.type.tensor_type
        dims = ttype.shape.dim
        # the input's width must be stated; the exporter leaves the output's symbolic (a
        # reshape), which the controller checks on every call
        fixed = dims[1].HasField("dim_value") if len(dims) == 2 else False
        if ttype.elem_type != TensorProto.FLOAT or len(dims) != 2 or \
                (fixed and dims[1].dim_value != want) or (label == "input" and not fixed):
            raise _fail(folder, f"{POLICY_ONNX}: its {label} must be float32 of shape "
                                f"(batch, {want}) as {POLICY_JSON} says")


def _require(module: str) -> Any:
    """Import an optional dependency of the runtime, or one line naming the extra."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(f"saddle_env.deploy needs {module}, which is not installed: "
                          'pip install "saddle-env[deploy]"') from None


__all__ = ["ALLOWED_OPS", "FORMAT", "FORMAT_VERSION", "INPUT_NAME", "LIMITS", "OPSET",
           "OUTPUT_NAME", "POLICY_JSON", "POLICY_ONNX", "Limits", "PolicyFolderError",
           "PolicySpec", "check_graph", "read_graph", "read_spec"]
