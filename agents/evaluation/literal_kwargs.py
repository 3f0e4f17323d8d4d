"""Keyword strings from hyperparameter files, read as data: ``"dict(net_arch=[64, 64],
activation_fn=nn.Tanh)"`` (the rl-zoo's form) becomes a dict without running anything.

The string is parsed, never evaluated. What it may hold:

* literals: dicts, lists, tuples, numbers, strings, booleans and None;
* ``dict(key=value, ...)``, the only call, which builds a dict;
* names from `ALLOWED_NAMES` (activation functions and optimizers, e.g. ``nn.Tanh``,
  ``th.optim.Adam``), resolved to the class and never called.

Anything else (another call, an attribute chain such as ``nn.functional.torch.os``, a dunder,
an operator) is a ValueError naming what was found. A zoo file copied from the internet is
therefore data: the worst it can do is fail to parse.
"""

from __future__ import annotations

import ast
from typing import Any

# Class paths a policy_kwargs string may name, by every spelling the zoo's files use. The
# value is (module, attribute), imported only when the name is used.
_ACTIVATIONS = ("Tanh", "ReLU", "ELU", "LeakyReLU", "GELU", "SiLU", "Mish", "Sigmoid",
                "Softplus", "Identity", "SELU", "CELU", "Hardtanh")
_OPTIMIZERS = ("Adam", "AdamW", "RMSprop", "SGD")
ALLOWED_NAMES: dict[str, tuple[str, str]] = {
    **{f"{prefix}.{name}": ("torch.nn", name)
       for prefix in ("nn", "th.nn", "torch.nn") for name in _ACTIVATIONS},
    **{f"{prefix}.{name}": ("torch.optim", name)
       for prefix in ("optim", "th.optim", "torch.optim") for name in _OPTIMIZERS},
    "RMSpropTFLike": ("stable_baselines3.common.sb2_compat.rmsprop_tf_like", "RMSpropTFLike"),
}
MAX_LENGTH = 10_000   # characters: a policy_kwargs string is a line or two
MAX_DEPTH = 20        # nesting of containers


def _dotted(node: ast.expr) -> str | None:
    """``a.b.c`` for a chain of plain names, else None."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    parts.append(node.id)
    return ".".join(reversed(parts))


def _resolve(name: str, source: str) -> Any:
    try:
        module, attr = ALLOWED_NAMES[name]
    except KeyError:
        raise ValueError(f"{source}: {name!r} is not an allowed name; allowed: dict(...) and "
                         f"{', '.join(sorted(n for n in ALLOWED_NAMES if n.startswith('nn.')))}, "
                         f"th.optim.<{'|'.join(_OPTIMIZERS)}>") from None
    import importlib

    return getattr(importlib.import_module(module), attr)


def _value(node: ast.AST, source: str, depth: int) -> Any:
    if depth > MAX_DEPTH:
        raise ValueError(f"{source}: nested deeper than {MAX_DEPTH}")
    if isinstance(node, ast.Constant):
        if isinstance(node.value, (str, int, float, bool)) or node.value is None:
            return node.value
        raise ValueError(f"{source}: unsupported constant {node.value!r}")
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        inner = _value(node.operand, source, depth + 1)
        if isinstance(inner, bool) or not isinstance(inner, (int, float)):
            raise ValueError(f"{source}: a sign applies to numbers only")
        return -inner if isinstance(node.op, ast.USub) else inner
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_value(e, source, depth + 1) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict):
        out = {}
        for k, v in zip(node.keys, node.values):
            if k is None:
                raise ValueError(f"{source}: '**' unpacking is not allowed")
            key = _value(k, source, depth + 1)
            if not isinstance(key, (str, int, float, bool)):
                raise ValueError(f"{source}: dict keys must be strings or numbers")
            out[key] = _value(v, source, depth + 1)
        return out
    if isinstance(node, ast.Call):
        if not (isinstance(node.func, ast.Name) and node.func.id == "dict"):
            what = _dotted(node.func) or type(node.func).__name__
            raise ValueError(f"{source}: only dict(...) may be called, not {what}(...)")
        if node.args or any(k.arg is None for k in node.keywords):
            raise ValueError(f"{source}: dict(...) takes keyword arguments only")
        return {k.arg: _value(k.value, source, depth + 1) for k in node.keywords}
    if isinstance(node, (ast.Name, ast.Attribute)):
        name = _dotted(node)
        if name is None:
            raise ValueError(f"{source}: unsupported expression")
        return _resolve(name, source)
    raise ValueError(f"{source}: unsupported syntax {type(node).__name__}")


def parse_kwargs_string(text: str, source: str = "policy_kwargs") -> dict[str, Any]:
    """The dict a zoo-style keyword string describes (see the module docstring); ValueError,
    naming ``source``, for anything that is not plain data or an allowed name."""
    if not isinstance(text, str):
        raise ValueError(f"{source} must be a string, got {type(text).__name__}")
    if len(text) > MAX_LENGTH:
        raise ValueError(f"{source}: longer than {MAX_LENGTH} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"{source}: not a valid expression: {exc.msg}") from None
    result = _value(tree.body, source, 0)
    if not isinstance(result, dict):
        raise ValueError(f"{source} must describe a dict, got {type(result).__name__}")
    return result


__all__ = ["ALLOWED_NAMES", "parse_kwargs_string"]
