"""The ``best-const`` baseline: the constant saddle speed with the longest mean trapping time
on seeded episodes of a config's own start distribution, found by a grid search on
`SEARCH_EPISODES` episodes, its choice then checked against the grid's next best speeds
(`PAIRED_TOP` in all) on `PAIRED_EPISODES` further episodes, the same for every speed
(`paired_comparison`: a speed that beats it there by more than two standard errors of the
paired difference replaces it; the speeds it cannot tell apart are recorded as ``ties``),
and cached. ``mpc``'s reference speed and
the training warm start's target are the grid's own winner (``paired=0``).

The cache (``agents/control/best_const.json``, or ``~/.cache/saddle-env/best_const.json`` if the
package folder is not writable) is keyed by a hash of every option that changes a
constant-speed run, plus the search's episodes, seed and episode length: each task level
(`saddle_env.LEVELS`) and each set of overrides gets its own entry.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from saddle_env.envs import DEFAULT_EPISODE_STEPS, EnvConfig
from saddle_env.jobs.files import write_text_atomically
from saddle_env.linear import critical_omega

from ..seeds import SEARCH_SEED
from .controllers import ConstantSpeed, critical_speed
from .rollout import run_episodes

CACHE_FILE = Path(__file__).with_name("best_const.json")
USER_CACHE_FILE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / \
    "saddle-env" / "best_const.json"
CACHE_ENV_VAR = "SADDLE_ENV_BEST_CONST_CACHE"   # a file: where new searches are written
SEARCH_EPISODES = 64
SEARCH_STEP = 1.0         # coarse grid [rad/s], then refined by SEARCH_STEP / 4 around the best
TIME_TIE = 0.01           # mean trapping times within this fraction of the episode tie
PAIRED_EPISODES = 512     # the paired comparison of the grid's best speeds (search_best_constant)
PAIRED_TOP = 5
# Options that do not change a constant-speed run (the search always runs in target mode).
_NOT_IN_KEY = ("action_mode", "loss_penalty", "distance_cost", "effort_cost")


def _search_key(config: EnvConfig, episodes: int, seed: int, max_episode_steps: int,
                paired: int = 0) -> str:
    # Only the options away from their defaults: a new option (at its default) leaves every
    # cached search valid instead of silently orphaning it.
    default = EnvConfig()
    d = {k: v for k, v in config.as_dict().items()
         if k not in _NOT_IN_KEY and v != getattr(default, k)}
    if config.action_mode == "voltage":  # the one mode whose constant runs differ
        d["action_mode"] = "voltage"
    if config.position_noise == config.velocity_noise == config.omega_noise == 0:
        d.pop("obs_frame", None)  # the frame matters only through the noise draws
    d.update(episodes=episodes, seed=seed, steps=max_episode_steps, grid=SEARCH_STEP)
    if paired:     # (a grid-only search keeps the key it always had)
        d.update(paired=paired, paired_top=PAIRED_TOP)
    text = json.dumps(d, sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _constant_runs(c: EnvConfig, speeds: np.ndarray, seeds: np.ndarray, max_episode_steps: int,
                   top: float, progress: bool = False) -> dict[str, np.ndarray]:
    """Every speed on the same episodes (``seeds``), in one batch: `run_episodes`'s arrays,
    speed j's episodes at rows j·len(seeds) .. (j + 1)·len(seeds) − 1."""
    n = len(seeds)
    action = np.repeat(2.0 * np.asarray(speeds) / top - 1.0, n)

    def act(obs: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return action[idx]

    return run_episodes(c, act, np.tile(seeds, len(speeds)), max_episode_steps=max_episode_steps,
                        row_independent=True, progress=progress)


def _search_config(config: EnvConfig) -> tuple[EnvConfig, float]:
    """The config a constant speed runs in, and its top speed [rad/s]: a constant target
    speed; a voltage-driven motor keeps its own dynamics (a constant voltage: its action
    maps to the steady speed as a target's does when K·V_max is omega_max)."""
    mode = "voltage" if config.action_mode == "voltage" else "target"
    c = EnvConfig.from_kwargs(**dict(config.as_dict(), action_mode=mode))
    return c, (c.motor_gain * c.voltage_max if mode == "voltage" else c.omega_max)


def paired_comparison(config: EnvConfig, speeds: list[float], episodes: int = PAIRED_EPISODES,
                      seed: int = SEARCH_SEED + SEARCH_EPISODES,
                      max_episode_steps: int = DEFAULT_EPISODE_STEPS,
                      incumbent: float | None = None) -> dict[str, Any]:
    """The constant ``speeds`` on the same ``episodes`` seeded episodes (seeds ``seed ..``;
    by default the ones after the grid's), told apart by paired differences.

    The winner is ``incumbent`` (one of ``speeds``: the grid's choice) unless the speed with
    the highest mean beats it by more than two standard errors of their paired difference;
    without an incumbent, the speed with the highest mean. For every speed: its mean, its
    mean difference from the winner on the same episodes and that difference's standard
    error; ``ties`` are the speeds within two standard errors of the winner (the winner
    included): on these episodes they cannot be told apart from it.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 2:
        raise ValueError(f"episodes must be an integer >= 2, got {episodes!r}")
    if not speeds:
        raise ValueError("speeds must name at least one speed")
    if incumbent is not None and incumbent not in speeds:
        raise ValueError(f"incumbent must be one of speeds {speeds}, got {incumbent!r}")
    c, top = _search_config(config)
    seeds = np.arange(episodes) + seed
    res = _constant_runs(c, np.asarray(speeds, dtype=float), seeds, max_episode_steps, top)
    times = res["time"].reshape(len(speeds), episodes)
    means = times.mean(axis=1)

    def paired(j: int, k: int) -> tuple[float, float]:
        d = times[j] - times[k]
        return float(d.mean()), float(d.std(ddof=1) / math.sqrt(episodes))

    win = lead = int(np.argmax(means))
    if incumbent is not None:
        win = speeds.index(incumbent)
        gain, se = paired(lead, win)
        if not gain > 2.0 * se:
            lead = win
        win = lead
    rows, ties = [], []
    for j, w in enumerate(speeds):
        diff, se = paired(j, win)
        rows.append({"omega": float(w), "mean_time": float(means[j]), "difference": diff,
                     "se": se})
        if j == win or abs(diff) <= 2.0 * se:
            ties.append(float(w))
    return {"episodes": episodes, "seed": seed, "omega": float(speeds[win]),
            "mean_time": float(means[win]), "incumbent": incumbent, "speeds": rows,
            "ties": sorted(ties)}


def search_best_constant(config: EnvConfig, episodes: int = SEARCH_EPISODES,
                         seed: int = SEARCH_SEED, max_episode_steps: int = DEFAULT_EPISODE_STEPS,
                         progress: bool = False, paired: int = 0) -> dict[str, Any]:
    """Search Ω for the longest mean trapping time on ``episodes`` seeded episodes.

    Every speed runs on the same episodes (seeds ``seed .. seed + episodes − 1``) of the
    config's own start distribution (randomised balls and disturbances included): a grid
    of step ``SEARCH_STEP`` from 0.9·Ω_crt (of the smallest Ω_crt) to ``omega_max``, then
    a grid four times finer around the best. Speeds whose mean trapping time lies within
    ``TIME_TIE`` of the episode length of the best tie; among them the one with the
    smallest mean distance from the centre wins.

    ``paired`` > 0: the grid's choice and the grid's next best speeds (`PAIRED_TOP` in all)
    are then run on ``paired`` further episodes (the seeds after the grid's); the grid's
    choice stays unless one of them beats it there by more than two standard errors of the
    paired difference (`paired_comparison`, recorded as ``paired``, with the speeds it
    cannot tell apart from the winner).

    Returns a dict: ``omega`` [rad/s], ``k`` (= omega / Ω_crt of the nominal ball),
    ``mean_time`` [s], ``kept`` (fraction kept for the whole episode), ``mean_r`` [m] (the
    three on the grid's episodes) and ``grid`` (every speed tried with its scores).
    """
    c, top = _search_config(config)
    lows = [critical_omega(s) for s in c.extreme_scenes()]
    lo = 0.9 * min(w for w in lows if math.isfinite(w)) if any(map(math.isfinite, lows)) else 1.0
    seeds = np.arange(episodes) + seed
    results: dict[float, dict[str, float]] = {}

    def run(speeds: np.ndarray) -> None:
        speeds = np.array([w for w in np.round(speeds, 6) if w not in results and 0 <= w <= top])
        if len(speeds) == 0:
            return
        res = _constant_runs(c, speeds, seeds, max_episode_steps, top, progress)
        for j, w in enumerate(speeds):
            sl = slice(j * episodes, (j + 1) * episodes)
            results[float(w)] = {"mean_time": float(res["time"][sl].mean()),
                                 "kept": float(res["kept"][sl].mean()),
                                 "mean_r": float(res["mean_r"][sl].mean())}

    def best() -> float:
        top = max(v["mean_time"] for v in results.values())
        tied = [w for w, v in results.items()
                if v["mean_time"] >= top - TIME_TIE * max_episode_steps * c.control_period]
        return min(tied, key=lambda w: (results[w]["mean_r"], w))

    run(np.append(np.arange(math.floor(lo), top, SEARCH_STEP), top))
    w0 = best()
    run(w0 + SEARCH_STEP / 4 * np.array([-3, -2, -1, 1, 2, 3]))
    w = best()
    extra: dict[str, Any] = {}
    if paired:
        ranked = sorted(results, key=lambda v: results[v]["mean_time"], reverse=True)
        speeds = [w] + [v for v in ranked if v != w][:PAIRED_TOP - 1]
        extra["paired"] = paired_comparison(config, speeds, paired, seed + episodes,
                                            max_episode_steps, incumbent=w)
        w = extra["paired"]["omega"]
    wc = critical_speed(config)
    return {"omega": w, "k": w / wc, **results[w], "episodes": episodes, "seed": seed, **extra,
            "grid": [{"omega": k, **v} for k, v in sorted(results.items())]}


def _read_cache(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def cached_best_constant(config: EnvConfig, episodes: int = SEARCH_EPISODES,
                         seed: int = SEARCH_SEED, max_episode_steps: int = DEFAULT_EPISODE_STEPS,
                         paired: int = 0) -> dict[str, Any] | None:
    """`best_constant`'s cached result, or None where it would have to search."""
    key = _search_key(config, episodes, seed, max_episode_steps, paired)
    override = os.environ.get(CACHE_ENV_VAR)
    for path in (CACHE_FILE, USER_CACHE_FILE, *((Path(override),) if override else ())):
        hit = _read_cache(path).get(key)
        if hit is not None:
            return hit
    return None


def best_constant(config: EnvConfig, episodes: int = SEARCH_EPISODES, seed: int = SEARCH_SEED,
                  max_episode_steps: int = DEFAULT_EPISODE_STEPS, recompute: bool = False,
                  paired: int = 0) -> dict[str, Any]:
    """`search_best_constant`, cached by config in ``agents/control/best_const.json`` (or, if that
    is not writable, in ``~/.cache/saddle-env/best_const.json``; new searches go only to the
    file named by ``$SADDLE_ENV_BEST_CONST_CACHE`` when it is set). ``paired``: the grid's
    best speeds compared on that many further episodes (the ``best-const`` baseline's
    search, `best_const`); 0, the grid alone (``mpc``'s reference speed and the warm
    start's target)."""
    if not recompute:
        hit = cached_best_constant(config, episodes, seed, max_episode_steps, paired)
        if hit is not None:
            return hit
    key = _search_key(config, episodes, seed, max_episode_steps, paired)
    result = search_best_constant(config, episodes, seed, max_episode_steps, paired=paired)
    entry = {k: v for k, v in result.items() if k != "grid"}
    default = EnvConfig()
    entry["config"] = {k: v for k, v in config.as_dict().items()
                       if k not in _NOT_IN_KEY and v != getattr(default, k)}
    if config.action_mode == "voltage":   # in the key too (`_search_key`)
        entry["config"]["action_mode"] = "voltage"
    entry = json.loads(json.dumps(entry))  # as it reads back from the cache
    # SADDLE_ENV_BEST_CONST_CACHE names the one file new searches go to (the test suite
    # points it at a temporary file, so that tests never edit the shipped cache).
    override = os.environ.get(CACHE_ENV_VAR)
    for path in (Path(override),) if override else (CACHE_FILE, USER_CACHE_FILE):
        try:
            data = _read_cache(path)
            data[key] = entry
            write_text_atomically(path, json.dumps(data, indent=1, sort_keys=True) + "\n")
            break
        except OSError:
            continue
    return entry


def best_const(config: EnvConfig,
               max_episode_steps: int = DEFAULT_EPISODE_STEPS) -> ConstantSpeed:
    """The ``best-const`` baseline (searches on first use; see `best_constant`), for episodes
    of ``max_episode_steps`` control steps (a level's own length): the grid's `PAIRED_TOP`
    best speeds compared on `PAIRED_EPISODES` further episodes, the best mean there."""
    omega = best_constant(config, max_episode_steps=max_episode_steps,
                          paired=PAIRED_EPISODES)["omega"]
    return ConstantSpeed(config, omega, "best-const")


__all__ = ["CACHE_ENV_VAR", "CACHE_FILE", "PAIRED_EPISODES", "PAIRED_TOP", "SEARCH_EPISODES",
           "SEARCH_SEED", "USER_CACHE_FILE", "best_const", "best_constant", "cached_best_constant",
           "paired_comparison", "search_best_constant"]
