"""Per-call latency of an exported controller (`saddle_env.deploy.Controller.act`) against
its peer in the same run: the same model's ``predict`` on torch, both on one thread.

```
python -m agents.benchmark.deploy_latency [--model agents/models/ppo_storm.zip] [--calls 5000]
```

The model is exported into a temporary folder (``saddle-export``'s code), then each policy
acts on the same ``--calls`` single observations drawn from the level's box, one call at a
time as a rig's loop calls it, after ``--warmup`` untimed calls. Printed: median and 99th
percentile per call [µs] and the peer's median over the controller's (a ratio, so that the
figure carries over between machines better than the microseconds do). ``--json`` prints
the figures as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT_MODEL = "agents/models/ppo_storm.zip"


def per_call_us(call: Callable[[np.ndarray], Any], obs: np.ndarray, warmup: int) -> np.ndarray:
    """Wall time of ``call(obs[i])`` for each row [µs], after ``warmup`` untimed calls."""
    for i in range(min(warmup, len(obs))):
        call(obs[i])
    out = np.empty(len(obs))
    clock = time.perf_counter_ns
    for i, o in enumerate(obs):
        t0 = clock()
        call(o)
        out[i] = clock() - t0
    return out / 1000.0


def measure(model: str | Path, calls: int = 5000, warmup: int = 200, seed: int = 0
            ) -> dict[str, Any]:
    """The figures `main` prints, for ``model`` (an SB3 model file with its sidecar)."""
    import torch

    from saddle_env.deploy import Controller

    from ..evaluation.evaluate import trained_env
    from ..evaluation.export import export_policy, observations
    from ..evaluation.policies import load_policy, model_sidecar

    torch.set_num_threads(1)   # the peer on one thread, as the controller's onnxruntime
    env_id, config = trained_env(model_sidecar(model) or {})
    obs = observations(config, calls, seed)
    with tempfile.TemporaryDirectory() as tmp:
        folder = export_policy(model, Path(tmp) / "exported")
        controller = Controller.from_dir(folder, threads=1)
        peer = load_policy(str(model), config)
        rows = {}
        with torch.no_grad():
            for name, call in (("Controller.act (onnxruntime)", controller.act),
                               ("SB3 predict (torch)",
                                lambda o: peer.predict(o, deterministic=True))):
                us = per_call_us(call, obs, warmup)
                rows[name] = {"median_us": float(np.median(us)),
                              "p99_us": float(np.percentile(us, 99))}
    import onnxruntime

    ctrl, sb3 = rows["Controller.act (onnxruntime)"], rows["SB3 predict (torch)"]
    return {"model": str(model), "env_id": env_id, "calls": calls, "warmup": warmup,
            "threads": 1, "date": time.strftime("%Y-%m-%d", time.gmtime()),
            "onnxruntime": onnxruntime.__version__, "torch": torch.__version__,
            "rows": rows, "peer_over_controller": sb3["median_us"] / ctrl["median_us"]}


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m agents.benchmark.deploy_latency``."""
    p = argparse.ArgumentParser(
        prog="python -m agents.benchmark.deploy_latency",
        description="Per-call latency (median, p99, µs, one thread) of an exported controller "
                    "(onnxruntime) beside the same model's SB3 predict on torch.")
    p.add_argument("--model", default=DEFAULT_MODEL, help=f"model file (default {DEFAULT_MODEL})")
    p.add_argument("--calls", type=int, default=5000, help="timed calls per policy (default 5000)")
    p.add_argument("--warmup", type=int, default=200, help="untimed calls first (default 200)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.calls < 1 or args.warmup < 0:
        parser.error(f"--calls must be >= 1 and --warmup >= 0, got {args.calls}, {args.warmup}")
    try:
        result = measure(args.model, args.calls, args.warmup)
    except (ValueError, OSError, ImportError) as exc:
        parser.error(str(exc))
    if args.json:
        sys.stdout.write(json.dumps(result, indent=1) + "\n")
        return 0
    print(f"{result['model']} on {result['env_id']}, {result['calls']} calls, one thread, "
          f"{result['date']} (onnxruntime {result['onnxruntime']}, torch {result['torch']})")
    print(f"{'policy':<30} {'median [µs]':>12} {'p99 [µs]':>10}")
    for name, row in result["rows"].items():
        print(f"{name:<30} {row['median_us']:>12.1f} {row['p99_us']:>10.1f}")
    print(f"SB3 predict / Controller.act (medians): {result['peer_over_controller']:.1f}×")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
