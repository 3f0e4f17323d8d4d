"""Output folder, cache, progress bars and batched sweeps shared by the figure functions.

Every figure function receives one `Context`. It writes through it so that

* files appear atomically (written to a temporary name, then renamed): an interrupted run
  leaves finished figures intact and no half-written file behind;
* sweeps are cached as ``.npz`` files in ``<out>/cache/``, keyed by a hash of the sweep's
  parameters (and this package's version), so a re-run skips them;
* ``summary.json`` is updated after every figure, merged with what is already there, so
  ``--only`` refreshes a subset of the numbers without losing the rest.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import __version__
from ..jobs.files import atomic_open
from ..scene import Scene
from ..simulate import simulate_batch

# Bump when a cached sweep's meaning changes without a change of its parameters.
CACHE_VERSION = 1
# Balls per call of simulate_batch: large enough to keep both numba threads busy, small
# enough for the progress bar to move and for Ctrl-C to be honoured between chunks.
CHUNK = 256


def _jsonable(value: Any) -> Any:
    """Plain-Python form of numpy scalars/arrays (and inf/nan as strings) for JSON."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else str(v)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


@dataclass
class Context:
    """Where and how the figures are produced.

    Attributes
    ----------
    out : Path
        Output folder (PNG, CSV, summary.json, cache/).
    quick : bool
        Small grids and short runs (CI), same figures.
    use_cache : bool
        Read cached sweeps (they are always written).
    progress : bool
        Show tqdm progress bars.
    written : list of Path
        Files written so far (for the final listing).
    """

    out: Path
    quick: bool = False
    use_cache: bool = True
    progress: bool = True
    written: list[Path] = field(default_factory=list)

    # -- files -----------------------------------------------------------------------------
    def write_csv(self, name: str, columns: Mapping[str, npt.ArrayLike],
                  comments: Sequence[str] = ()) -> Path:
        """Write ``<out>/<name>.csv``: ``#`` comment lines, a header row, then the columns."""
        cols = {k: np.asarray(v) for k, v in columns.items()}
        lengths = {len(v) for v in cols.values()}
        if len(lengths) != 1:
            raise ValueError(f"{name}: columns have different lengths {sorted(lengths)}")
        path = self.out / f"{name}.csv"
        with atomic_open(path) as fh:
            for line in comments:
                fh.write(f"# {line}\n")
            w = csv.writer(fh)
            w.writerow(cols)
            for row in zip(*cols.values()):
                w.writerow([_fmt(v) for v in row])
        self.written.append(path)
        return path

    def save_png(self, fig: Any, name: str) -> Path:
        """Save a matplotlib figure as ``<out>/<name>.png`` and close it.

        Rendered at dpi 100 and reduced to a 128-colour palette (Pillow, which matplotlib
        depends on): line plots lose nothing visible and the files shrink about fourfold,
        which keeps the committed gallery small.
        """
        import io

        import matplotlib.pyplot as plt
        from PIL import Image

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        buf.seek(0)
        img = Image.open(buf).convert("RGB").quantize(colors=128,
                                                       method=Image.Quantize.FASTOCTREE)
        path = self.out / f"{name}.png"
        with atomic_open(path, "wb") as fh:
            img.save(fh, format="PNG", optimize=True)
        self.written.append(path)
        return path

    def update_summary(self, entries: Mapping[str, Any]) -> None:
        """Merge ``entries`` into ``<out>/summary.json`` (created if missing)."""
        path = self.out / "summary.json"
        data: dict[str, Any] = {}
        if path.exists():
            try:
                data = json.loads(path.read_text())
            except json.JSONDecodeError:
                data = {}
        data.update(_jsonable(entries))
        data["_meta"] = {"saddle_env_version": __version__, "quick": self.quick,
                         "note": "each entry names the initial-velocity convention it used: "
                                 "'rotating-rest' = at rest on the saddle, 'lab-rest' = "
                                 "placed at rest in the laboratory (saddle_env.initial_state)"}
        with atomic_open(path) as fh:
            json.dump(data, fh, indent=2, sort_keys=True)
            fh.write("\n")
        if path not in self.written:
            self.written.append(path)

    # -- cache ----------------------------------------------------------------------------
    def cached(self, name: str, params: Mapping[str, Any],
               compute: Callable[[], Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
        """Arrays from ``<out>/cache/<name>-<hash>.npz`` if present, else ``compute()`` (saved).

        The hash covers ``params`` (everything the sweep depends on), the cache format
        version and the package version.
        """
        key = json.dumps({"name": name, "params": _jsonable(params), "v": CACHE_VERSION,
                          "pkg": __version__}, sort_keys=True)
        digest = hashlib.sha1(key.encode()).hexdigest()[:12]
        path = self.out / "cache" / f"{name}-{digest}.npz"
        if self.use_cache and path.exists():
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        result = {k: np.asarray(v) for k, v in compute().items()}
        with atomic_open(path, "wb") as fh:
            # allow_pickle: numpy's default, named so that mypy does not match the arrays to it
            np.savez_compressed(fh, allow_pickle=True, **result)
        return result

    # -- progress and batched simulation ------------------------------------------------------
    def bar(self, total: int, desc: str, unit: str = "ball") -> Any:
        """A tqdm progress bar (on stderr; hidden with ``progress=False``)."""
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit, leave=False,
                    disable=not self.progress, dynamic_ncols=True)

    def run_batch(self, scenes: Scene | Sequence[Scene], states: np.ndarray, t_end: float,
                  omega: np.ndarray | float, desc: str, **kwargs: Any
                  ) -> tuple[np.ndarray, np.ndarray]:
        """`simulate_batch` in chunks with a progress bar; returns (status, t_final).

        ``status`` is 0 (ran to ``t_end``), 1 (detached) or 2 (escaped the rim); negative
        codes are integration failures. No intermediate output is kept (``dt_out=None``).
        """
        states = np.asarray(states, dtype=float)
        n = len(states)
        omega_arr = np.broadcast_to(np.asarray(omega, dtype=float), (n,))
        scene_list = [scenes] * n if isinstance(scenes, Scene) else list(scenes)
        status = np.zeros(n, dtype=np.int64)
        t_final = np.zeros(n)
        with self.bar(n, desc) as bar:
            for i0 in range(0, n, CHUNK):
                sl = slice(i0, min(n, i0 + CHUNK))
                res = simulate_batch(scene_list[sl], states[sl], t_end,
                                     omega=np.ascontiguousarray(omega_arr[sl]), dt_out=None,
                                     **kwargs)
                status[sl], t_final[sl] = res.status, res.t_final
                bar.update(sl.stop - sl.start)
        return status, t_final


def _fmt(v: Any) -> Any:
    """Compact CSV cells: floats with 10 significant digits, the rest as is."""
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.10g}"
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return int(v)
    return v
