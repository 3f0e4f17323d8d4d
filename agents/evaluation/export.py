"""``saddle-export MODEL --out DIR``: a trained Stable-Baselines3 model as a folder a small
computer can run without torch (`saddle_env.deploy.Controller`; docs/how-to/export.md).

```
saddle-export agents/models/ppo_storm.zip --out exported/ppo_storm [--trust-model]
```

The model is read by the loader ``saddle-eval`` uses (`agents.evaluation.policies.load_policy`:
as data unless ``--trust-model``), on the level and options its sidecar names. The folder
holds ``policy.onnx``, the policy's deterministic action for a batch of (stacked, normalised)
observations, the clip to the action box (or, for a squashing policy, the rescale to it)
inside the graph; and ``policy.json`` (`saddle_env.deploy.folder` has the schema) with the
observation normaliser beside the graph, applied in float64 before it as evaluation applies
it. The graph is written by torch's TorchScript exporter (``dynamo=False``), which needs
only the ``onnx`` package, not ``onnxscript``, and no network.

Before it reports success the command loads the folder through the runtime's checks and
compares its actions with the model's on observations drawn from the level's box: an export
that does not reproduce the policy to ``TOLERANCE`` is an error, not a folder.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.deploy import folder as F
from saddle_env.envs.observation import layout, observation_space

from ..cli_args import MissingExtra, require
from .evaluate import trained_env
from .model_files import TRUST_FLAG
from .policies import WrappedModel, load_policy, model_sidecar

TOLERANCE = 1e-5     # max |Δaction| between the folder and the model on the check's draws
CHECK_DRAWS = 512    # observations the export checks itself on


def _network(policy: Any) -> tuple[Any, int, Any]:
    """(torch policy, frame stack, normaliser or None) of what `load_policy` returned for a
    model file: a bare SB3 policy, an SB3 model (``--trust-model``), or either wrapped."""
    import torch

    stack, normalizer = 1, None
    if isinstance(policy, WrappedModel):
        stack, normalizer, policy = policy.frame_stack, policy.normalizer, policy.model
    net = policy if isinstance(policy, torch.nn.Module) else getattr(policy, "policy", None)
    if not isinstance(net, torch.nn.Module):
        raise ValueError(f"not a Stable-Baselines3 policy network: {type(policy).__name__}")
    return net, stack, normalizer


def _normalizer_fields(normalizer: Any) -> dict[str, Any] | None:
    """The statistics evaluation normalises with, from the JSON reader's
    `ObservationNormalizer` or (``--trust-model``) an unpickled VecNormalize."""
    if normalizer is None or not getattr(normalizer, "norm_obs", True):
        return None
    rms = getattr(normalizer, "obs_rms", None)
    mean = np.asarray(rms.mean if rms is not None else normalizer.mean, np.float64)
    var = np.asarray(rms.var if rms is not None else normalizer.var, np.float64)
    return {"mean": mean.tolist(), "var": var.tolist(), "epsilon": float(normalizer.epsilon),
            "clip": float(normalizer.clip_obs)}


class _DeterministicAction:
    """Builds the torch module the graph is traced from: SB3's deterministic action, then
    what ``predict`` does to it (a squashing policy's rescale to the box, else a clip)."""

    @staticmethod
    def module(net: Any) -> Any:
        import torch

        low = torch.as_tensor(np.asarray(net.action_space.low, np.float32))
        high = torch.as_tensor(np.asarray(net.action_space.high, np.float32))
        squash = bool(getattr(net, "squash_output", False))

        class Module(torch.nn.Module):
            def __init__(self) -> None:
                super().__init__()
                self.net = net
                self.register_buffer("low", low)
                self.register_buffer("high", high)

            def forward(self, observation: torch.Tensor) -> torch.Tensor:
                action = self.net._predict(observation, deterministic=True)
                action = action.reshape(observation.shape[0], -1)
                if squash:
                    return self.low + 0.5 * (action + 1.0) * (self.high - self.low)
                return torch.maximum(torch.minimum(action, self.high), self.low)

        return Module().eval(), squash


def graph_bytes(net: Any, input_dim: int, opset: int = F.OPSET) -> tuple[bytes, str]:
    """(serialized ONNX model, "clip" or "unscale") of ``net``'s deterministic action for a
    float32 batch of ``input_dim`` columns."""
    import torch

    module, squash = _DeterministicAction.module(net)
    buf = io.BytesIO()
    example = torch.zeros((1, input_dim), dtype=torch.float32)
    with torch.no_grad(), warnings.catch_warnings():
        # the TorchScript exporter announces its deprecation in favour of dynamo, which
        # needs onnxscript; the graph it writes is checked below, whatever it says
        warnings.simplefilter("ignore")
        torch.onnx.export(module, (example,), buf, input_names=[F.INPUT_NAME],
                          output_names=[F.OUTPUT_NAME], opset_version=opset,
                          dynamic_axes={F.INPUT_NAME: {0: "batch"}, F.OUTPUT_NAME: {0: "batch"}},
                          do_constant_folding=True, dynamo=False)
    return buf.getvalue(), ("unscale" if squash else "clip")


def export_policy(model: str | os.PathLike, out: str | os.PathLike, trust: bool = False,
                  opset: int = F.OPSET, seed: int = 0) -> Path:
    """Write ``model``'s exported folder to ``out`` and check it (see the module).

    Parameters
    ----------
    model : str or os.PathLike
        A Stable-Baselines3 model file (``.zip``) with its sidecar.
    out : str or os.PathLike
        The folder to write (created; files in it replaced).
    trust : bool
        Load the model file with its pickles; default: as data.
    opset : int
        The ONNX opset of the graph.
    seed : int
        Seeds the observations the folder is checked on.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ValueError
        If ``model`` is not a ``.zip`` file, ``opset`` is out of range, or the folder's
        actions differ from the model's.
    """
    require("torch", "train", "saddle-export")
    require("onnx", "deploy", "saddle-export")
    require("onnxruntime", "deploy", "saddle-export's check of the folder")
    path = Path(model)
    if not path.is_file() or path.suffix != ".zip":
        raise ValueError(f"MODEL must be a Stable-Baselines3 model file (.zip), got {str(model)!r}")
    if opset not in F.OPSETS:
        raise ValueError(f"--opset must lie in [{F.OPSETS.start}, {F.OPSETS.stop - 1}], got {opset}")
    side = model_sidecar(path) or {}
    env_id, config = trained_env(side)
    policy = load_policy(path, config, trust=trust)
    net, stack, normalizer = _network(policy)
    lay = layout(config)
    raw, in_graph = graph_bytes(net, stack * lay.dim, opset)
    space = observation_space(config)
    steps = side.get("max_episode_steps")
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= 10**7:
        steps = None      # not the sidecar's to break the folder: the level's length applies
    spec = {
        "format": F.FORMAT, "format_version": F.FORMAT_VERSION,
        "env_id": env_id, "env_kwargs": side.get("env_kwargs") or {},
        "options": {k: (list(v) if isinstance(v, tuple) else v)
                    for k, v in config.as_dict().items()},
        "max_episode_steps": steps,
        "observation": {"dim": lay.dim, "low": space.low.tolist(), "high": space.high.tolist(),
                        "layout": {"frame_dim": lay.frame_dim, "frames": lay.frames,
                                   "x": lay.x, "y": lay.y, "vx": lay.vx, "vy": lay.vy,
                                   "omega": lay.omega, "cos": lay.cos, "command": lay.command,
                                   "lab_frame": lay.lab_frame}},
        "frame_stack": stack,
        "normalizer": _normalizer_fields(normalizer),
        "action": {"dim": int(np.prod(net.action_space.shape)),
                   "low": np.asarray(net.action_space.low, float).tolist(),
                   "high": np.asarray(net.action_space.high, float).tolist(),
                   "in_graph": in_graph},
        "onnx": {"file": F.POLICY_ONNX, "opset": opset, "input": F.INPUT_NAME,
                 "output": F.OUTPUT_NAME, "sha256": hashlib.sha256(raw).hexdigest()},
        "source": {"model": path.name, "algo": str(getattr(policy, "algo_name", "")),
                   "trusted_load": bool(trust)},
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / F.POLICY_ONNX).write_bytes(raw)
    (out / F.POLICY_JSON).write_text(json.dumps(spec, indent=1) + "\n")
    worst = max_difference(policy, out, observations(config, CHECK_DRAWS, seed))
    if not worst <= TOLERANCE:
        raise ValueError(f"{out}: the exported graph's actions differ from the model's by "
                         f"{worst:.2e}, more than {TOLERANCE:g}")
    return out


def observations(config: Any, n: int, seed: int = 0) -> np.ndarray:
    """``n`` observations drawn uniformly from the level's declared box (float32), seeded:
    the whole input range a policy can be given, its clipped edges included."""
    rng = np.random.default_rng(seed)
    space = observation_space(config)
    return rng.uniform(space.low, space.high, size=(n, space.shape[0])).astype(np.float32)


def max_difference(policy: Any, folder: str | os.PathLike, obs: np.ndarray) -> float:
    """max |Δaction| between ``policy.predict`` and the exported folder's, on one batch."""
    from saddle_env.deploy import Controller

    controller = Controller.from_dir(folder)
    want = np.asarray(policy.predict(obs, deterministic=True)[0], np.float64).reshape(len(obs), -1)
    got = np.asarray(controller.predict(obs)[0], np.float64).reshape(len(obs), -1)
    return float(np.max(np.abs(want - got)))


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``saddle-export``."""
    p = argparse.ArgumentParser(
        prog="saddle-export",
        description="Export a trained Stable-Baselines3 model file to a folder (policy.onnx + "
                    "policy.json) that saddle_env.deploy.Controller runs with onnxruntime, "
                    "without torch; the folder is checked against the model before success.")
    p.add_argument("model", metavar="MODEL", help="a Stable-Baselines3 model file (.zip) with "
                                                  "its sidecar, as train.py writes them")
    p.add_argument("--out", required=True, metavar="DIR", help="the folder to write")
    p.add_argument("--opset", type=int, default=F.OPSET,
                   help=f"ONNX opset of the graph (default {F.OPSET}; "
                        f"{F.OPSETS.start}-{F.OPSETS.stop - 1})")
    p.add_argument(TRUST_FLAG, action="store_true",
                   help="read a model whose loading needs unpickling (SB3's own loader, "
                        "pickled normaliser statistics): this runs code the file carries; only "
                        "for files you trust (docs/security.md). Default: read as data")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        # the check compares against one-thread actions, as saddle-eval's
        require("torch", "train", "saddle-export").set_num_threads(1)
        out = export_policy(args.model, args.out, trust=args.trust_model, opset=args.opset)
    except (ValueError, OSError, MissingExtra, ImportError) as exc:
        parser.error(str(exc))
    print(f"wrote {out / F.POLICY_ONNX} and {out / F.POLICY_JSON} "
          f"(actions checked against the model to {TOLERANCE:g})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["CHECK_DRAWS", "TOLERANCE", "build_parser", "export_policy", "graph_bytes", "main",
           "max_difference", "observations"]
