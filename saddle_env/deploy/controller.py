"""`Controller`: an exported policy folder run with onnxruntime, numpy and nothing heavier.

The observation pipeline is the one evaluation applies to a model file
(`agents.evaluation.policies.WrappedModel`), step for step, so the actions agree: each raw
observation is normalised in float64 and cast to float32, then the last ``frame_stack``
frames are stacked oldest first with zero frames before an episode's first, then the graph
gives the final action (clipped or unscaled to the action box inside the graph).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..envs.observation import stack_frames
from .folder import (
    INPUT_NAME,
    OUTPUT_NAME,
    POLICY_ONNX,
    PolicyFolderError,
    PolicySpec,
    _require,
    read_graph,
    read_spec,
)


class Controller:
    """An exported policy (``saddle-export``'s folder) as a controller.

    ``act(observation)`` takes one raw observation of the level and returns the action
    (``(action_dim,)`` float32). Where the level's observation is a history of frames
    (``obs_history`` k > 1, as on the Gusty, Storm and Capture levels), it takes either the
    whole observation, as the environment gives it, or one frame, as a rig's camera gives
    it: then it keeps the level's history itself (newest first, an episode's first frame
    repeated k times). It also keeps the policy's own frame stack (``frame_stack``, a
    training wrapper). `reset` starts a new episode. ``predict`` is Stable-Baselines3's
    signature, for batches of whole observations (evaluation): the frame stack travels in
    ``state``, restarted where ``episode_start`` is true.
    """

    row_independent = False   # like a model file: evaluated on fixed-size batches

    def __init__(self, spec: PolicySpec, session: Any):
        self.spec = spec
        self.session = session
        self.name = str(spec.folder)
        self.kind = "ONNX"     # saddle-eval's "kind" column
        norm = spec.normalizer
        # (mean, sqrt(var + epsilon), clip) in float64, as evaluation normalises
        self._norm: tuple[np.ndarray, np.ndarray, float] | None = None if norm is None else (
            np.asarray(norm["mean"], np.float64),
            np.sqrt(np.asarray(norm["var"], np.float64) + norm["epsilon"]), float(norm["clip"]))
        self._stack: np.ndarray | None = None
        self._history: np.ndarray | None = None   # the level's frames, newest first
        from gymnasium import spaces

        self.observation_space = spaces.Box(np.asarray(spec.observation_low, np.float32),
                                            np.asarray(spec.observation_high, np.float32),
                                            dtype=np.float32)
        self.action_space = spaces.Box(np.asarray(spec.action_low, np.float32),
                                       np.asarray(spec.action_high, np.float32),
                                       dtype=np.float32)

    @classmethod
    def from_dir(cls, folder: str | os.PathLike, threads: int = 1) -> Controller:
        """Check an exported folder and load its graph.

        The check is `saddle_env.deploy.folder`'s: schema, graph, sizes. The graph runs on the
        CPU.

        Parameters
        ----------
        folder : str or os.PathLike
            A folder ``saddle-export`` wrote.
        threads : int
            onnxruntime's intra- and inter-op threads; default one: the same actions on any
            machine, and no thread pool to share a small computer's cores.

        Returns
        -------
        Controller
            The controller.

        Raises
        ------
        ValueError
            If ``threads`` is not a positive integer.
        PolicyFolderError
            If the folder fails the check, onnxruntime cannot load its graph, or the graph
            does not run (or gives a non-finite action) on an observation inside its box.
        """
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"threads must be a positive integer, got {threads!r}")
        spec = read_spec(folder)
        raw = read_graph(spec)
        ort = _require("onnxruntime")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = threads
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.log_severity_level = 3   # errors only: the checks above speak for the folder
        try:
            session = ort.InferenceSession(raw, sess_options=options,
                                           providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime's own errors, for a graph it cannot build
            raise PolicyFolderError(f"{spec.folder}: {POLICY_ONNX} does not load in "
                                    f"onnxruntime ({_one_line(exc)})") from None
        controller = cls(spec, session)
        controller._probe()
        return controller

    def _probe(self) -> None:
        """Run the graph once on an observation inside its box (zeros, clipped into it): a
        graph that passes every static check can still fail only when run (a damaged index
        or shape), or give non-finite actions; such a folder is refused here, by name, not
        at the first step of a rig."""
        spec = self.spec
        obs = np.clip(np.zeros(spec.observation_dim), spec.observation_low,
                      spec.observation_high).astype(np.float32)
        try:
            action, _ = self.predict(obs)
        except Exception as exc:  # onnxruntime's errors, or `_run`'s check of the output
            raise PolicyFolderError(f"{spec.folder}: {POLICY_ONNX} does not run on an "
                                    f"observation inside its box ({_one_line(exc)})") from None
        if not np.all(np.isfinite(action)):
            raise PolicyFolderError(f"{spec.folder}: {POLICY_ONNX} gives a non-finite action "
                                    "for an observation inside its box")

    # -- the pipeline ---------------------------------------------------------------------
    def _normalise(self, obs: np.ndarray) -> np.ndarray:
        if self._norm is None:
            return obs
        mean, std, clip = self._norm
        return np.clip((obs - mean) / std, -clip, clip).astype(np.float32)

    def _run(self, inputs: np.ndarray) -> np.ndarray:
        actions = self.session.run([OUTPUT_NAME], {INPUT_NAME: inputs})[0]
        want = (len(inputs), self.spec.action_dim)
        if actions.shape != want or actions.dtype != np.float32:
            raise ValueError(f"{self.spec.folder}: policy.onnx gave actions of shape "
                             f"{actions.shape} ({actions.dtype}), policy.json says {want} float32")
        return actions

    def _check(self, obs: np.ndarray, name: str) -> None:
        if obs.shape[-1] != self.spec.observation_dim or obs.ndim > 2:
            raise ValueError(f"{name} must have shape ({self.spec.observation_dim},) or "
                             f"(n, {self.spec.observation_dim}), got {obs.shape}")

    def reset(self) -> None:
        """Start a new episode: `act` forgets the frames it has seen."""
        self._stack = None
        self._history = None

    def _level_history(self, frame: np.ndarray) -> np.ndarray:
        """The level's observation after ``frame``: as the environment's engine pushes it."""
        d = frame.shape[0]
        if self._history is None:
            self._history = np.tile(frame, self.spec.layout["frames"])
        else:
            self._history[d:] = self._history[:-d].copy()
            self._history[:d] = frame
        return self._history.copy()

    def act(self, observation: Any) -> np.ndarray:
        """The action for one raw observation, or for one frame of a level whose observation is a
        history.

        Parameters
        ----------
        observation : array_like
            ``(observation_dim,)``, or one frame ``(frame_dim,)`` (the controller keeps the
            level's history).

        Returns
        -------
        numpy.ndarray
            The action, float32 ``(action_dim,)``.
        """
        obs = np.asarray(observation, dtype=np.float32)
        frame_dim = self.spec.layout["frame_dim"]
        if obs.ndim == 1 and self.spec.layout["frames"] > 1 and obs.shape[0] == frame_dim:
            obs = self._level_history(obs)
        elif obs.ndim != 1 or obs.shape[0] != self.spec.observation_dim:
            one_frame = f" or one frame ({frame_dim},)" if self.spec.layout["frames"] > 1 else ""
            raise ValueError(f"observation must be one observation of shape "
                             f"({self.spec.observation_dim},){one_frame}, got {obs.shape}; "
                             "use predict for batches")
        action, self._stack = self.predict(obs, state=self._stack,
                                           episode_start=np.array([self._stack is None]))
        return action

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """Stable-Baselines3's ``predict``: actions for one observation or a batch.

        Always deterministic: the exported graph is the policy's deterministic action.

        Parameters
        ----------
        observation : array_like
            One whole observation or a batch of them.
        state : numpy.ndarray, optional
            The frame stack, as returned by the previous call (None when the policy stacks no
            frames).
        episode_start : array_like, optional
            True where an episode starts: its frame stack restarts.
        deterministic : bool
            Ignored (always deterministic).

        Returns
        -------
        actions : numpy.ndarray
            The actions.
        state : numpy.ndarray or None
            The frame stack, for the next call.
        """
        obs = np.asarray(observation, dtype=np.float32)
        self._check(obs, "observation")
        single = obs.ndim == 1
        batch = self._normalise(obs.reshape(1, -1) if single else obs)
        k = self.spec.frame_stack
        if k > 1:
            inputs, state = stack_frames(batch, state, episode_start, k)
        else:
            inputs = np.ascontiguousarray(batch, dtype=np.float32)
        actions = self._run(inputs)
        return (actions[0] if single else actions), state


def _one_line(exc: BaseException, limit: int = 160) -> str:
    """An exception's type and the first line of its message, cut to ``limit`` characters
    (a `PolicyFolderError` is one line)."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"[:limit]


__all__ = ["Controller"]
