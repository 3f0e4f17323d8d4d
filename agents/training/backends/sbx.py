"""The SBX back end of `agents.training.trainer`: PPO from SBX (``sbx-rl``, Stable-Baselines3's API
on JAX), which on the level recipes takes more steps per second than SB3's PPO and learns
what it learns (the measurements: docs/training_profile.md, "SBX").

Only the learner differs from the SB3 back end: the environments, the recipe's keys, the
callbacks, model selection, checkpoints on a schedule and on Ctrl-C/SIGTERM are
`agents.training.backends.sb3.train_with`'s, run with `SbxLearner`. What it writes is what the SB3
back end writes, with one addition:

* **Every model file is an ordinary SB3 PPO file.** The flax network is copied into an SB3
  PPO policy of the same shape (its *twin*: the same MLP; flax keeps a layer's kernel as
  ``(in, out)``, torch's Linear as ``(out, in)``) before each save, so evaluation, ``ship``,
  the leaderboard and loading as data (`agents.evaluation.model_files`) are unchanged, and the
  shipped policy is a torch network like every other.
* **A checkpoint adds ``<stem>.sbx.npz``**: the learner's whole state (both networks'
  parameters, Adam's moments and step, the random keys, the step counters) as plain arrays,
  so ``--resume`` continues exactly and reads nothing but data (no ``--trust-model``).
* **Warm starts run on the twin** (`agents.training.warm_start`: the best constant's bias, or the
  imitation of ``mpc``) and are copied into the flax network.

XLA's multithreaded Eigen is switched off (``XLA_FLAGS``, unless already set) before JAX is
first imported: on these 128-wide layers it was slower than one thread
(docs/training_profile.md). JAX still runs a dispatch thread beside the process's main
one, so SBX uses more than one core.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ...cli_args import MissingExtra, install_hint, missing
from ..recipes import HYPERPARAMS_DIR, ZOO_ONLY_KEYS, parse_policy_kwargs
from ..runs import RunSettings, TrainSettings
from ..schedules import with_schedules
from .sb3 import (
    PROGRESS_MODULES,
    TRAIN_MODULES,
    Sb3Learner,
    _new_model,
    resume_env,
    save_model,
    train_with,
)

SBX_MODULES = ("sbx", "jax", "flax", "optax")
# The recipes when --hyperparams names none: the fast recipe on every level (the file says
# why each budget).
RECIPES = HYPERPARAMS_DIR / "ppo_sbx.yml"
# Every file a run writes is data: the model files are SB3's, the learner state is npz.
RESUME_NEEDS_TRUST = False
# What the learner state is saved as, beside a checkpoint's model file.
STATE_SUFFIX = ".sbx.npz"
XLA_SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
# The policy_kwargs an SBX PPO policy and its SB3 twin both honour, and the activations
# that compute the same function in torch and flax (torch class name -> flax function).
POLICY_KWARGS = ("net_arch", "log_std_init", "ortho_init", "activation_fn")
ACTIVATIONS = {"Tanh": "tanh", "ReLU": "relu", "ELU": "elu", "LeakyReLU": "leaky_relu",
               "SiLU": "silu"}


def check_dependencies(progress_bar: bool) -> None:
    """One line naming the extra to install if SBX training cannot import what it needs."""
    lacking = missing(TRAIN_MODULES + SBX_MODULES + (PROGRESS_MODULES if progress_bar else ()))
    if lacking:
        raise MissingExtra(f"--backend sbx needs {', '.join(lacking)}, not installed: "
                           f"{install_hint('sbx')}")


def _single_threaded_xla() -> None:
    """Switch XLA's Eigen threading off, if JAX is not imported yet and the user set no
    choice of their own."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "jax" not in sys.modules and "xla_cpu_multi_thread_eigen" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {XLA_SINGLE_THREAD}".strip()


def sbx_policy_kwargs(policy_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The recipe's (SB3) policy_kwargs for SBX's PPO policy: the activation as flax's
    function, and SB3's orthogonal initialisation unless the recipe says otherwise (SBX's
    default is off; with it the untrained action head is small, as the warm start
    assumes). ValueError for a keyword the two policies cannot share."""
    import flax.linen as nn

    unknown = sorted(set(policy_kwargs) - set(POLICY_KWARGS))
    if unknown:
        raise ValueError(f"policy_kwargs: {unknown} not supported with --backend sbx "
                         f"(allowed: {list(POLICY_KWARGS)})")
    out = {"ortho_init": True, **policy_kwargs}
    if "activation_fn" in out:
        name = getattr(out["activation_fn"], "__name__", str(out["activation_fn"]))
        if name not in ACTIVATIONS:
            raise ValueError(f"policy_kwargs: activation_fn must be one of "
                             f"{sorted(ACTIVATIONS)} with --backend sbx, got {name}")
        out["activation_fn"] = getattr(nn, ACTIVATIONS[name])
    return out


# ---------------------------------------------------------------------------------------
# the flax network <-> its SB3 twin
# ---------------------------------------------------------------------------------------
def _torch_layers(twin) -> tuple[list, list]:
    """The twin's Linear layers in order: (actor's, critic's), each ending in its head."""
    import torch

    def linears(seq):
        return [m for m in seq if isinstance(m, torch.nn.Linear)]

    policy = twin.policy
    return (linears(policy.mlp_extractor.policy_net) + [policy.action_net],
            linears(policy.mlp_extractor.value_net) + [policy.value_net])


def _flax_layers(params: dict[str, Any], what: str) -> list[dict[str, Any]]:
    """A flax MLP's Dense layers in order (``Dense_0``, ``Dense_1``, ...)."""
    names = sorted((k for k in params if k.startswith("Dense_")), key=lambda k: int(k[6:]))
    if [int(k[6:]) for k in names] != list(range(len(names))):
        raise ValueError(f"the SBX {what} has unexpected layers {sorted(params)}")
    return [params[k] for k in names]


def _pairs(model, twin):
    """(flax Dense, torch Linear) pairs of actor and critic; ValueError if shapes differ."""
    actor = model.policy.actor_state.params["params"]
    critic = model.policy.vf_state.params["params"]
    torch_actor, torch_critic = _torch_layers(twin)
    pairs = []
    for what, dense, linear in (("actor", _flax_layers(actor, "actor"), torch_actor),
                                ("critic", _flax_layers(critic, "critic"), torch_critic)):
        shapes = [tuple(np.shape(d["kernel"]))[::-1] for d in dense]
        if shapes != [tuple(l.weight.shape) for l in linear]:
            raise ValueError(f"the SBX {what} {shapes} does not match the SB3 twin's "
                             f"{[tuple(l.weight.shape) for l in linear]}")
        pairs += [(what, i, lin) for i, lin in enumerate(linear)]
    return pairs


def copy_to_twin(model, twin) -> None:
    """Put the SBX PPO ``model``'s networks into its SB3 PPO ``twin`` (weights, biases,
    log_std) and its step counter."""
    import torch

    params = {"actor": model.policy.actor_state.params["params"],
              "critic": model.policy.vf_state.params["params"]}
    with torch.no_grad():
        for what, i, linear in _pairs(model, twin):
            dense = params[what][f"Dense_{i}"]
            linear.weight.copy_(torch.as_tensor(np.array(dense["kernel"]).T))
            linear.bias.copy_(torch.as_tensor(np.array(dense["bias"])))
        twin.policy.log_std.copy_(torch.as_tensor(np.array(params["actor"]["log_std"])))
    twin.num_timesteps = model.num_timesteps


def copy_from_twin(twin, model) -> None:
    """The reverse of `copy_to_twin`: the SB3 ``twin``'s networks into the SBX ``model``
    (after a warm start trained the twin)."""
    import jax
    import jax.numpy as jnp

    policy = model.policy
    trees = {"actor": jax.tree_util.tree_map(lambda x: x, policy.actor_state.params),
             "critic": jax.tree_util.tree_map(lambda x: x, policy.vf_state.params)}
    for what, i, linear in _pairs(model, twin):
        dense = trees[what]["params"][f"Dense_{i}"]
        dense["kernel"] = jnp.asarray(linear.weight.detach().numpy().T)
        dense["bias"] = jnp.asarray(linear.bias.detach().numpy())
    trees["actor"]["params"]["log_std"] = jnp.asarray(twin.policy.log_std.detach().numpy())
    policy.actor_state = policy.actor_state.replace(params=trees["actor"])
    policy.vf_state = policy.vf_state.replace(params=trees["critic"])


# ---------------------------------------------------------------------------------------
# the learner state, as data
# ---------------------------------------------------------------------------------------
COUNTERS = ("num_timesteps", "_n_updates", "_episode_num")


def _state_tree(model) -> dict[str, Any]:
    policy = model.policy
    return {"actor": policy.actor_state, "critic": policy.vf_state, "key": model.key,
            "policy_key": policy.key, "noise_key": policy.noise_key}


def learner_state(model) -> dict[str, np.ndarray]:
    """The SBX model's whole training state as named arrays (the flax train states' leaves
    under their tree paths, the random keys, the counters)."""
    import jax

    leaves, _ = jax.tree_util.tree_flatten_with_path(_state_tree(model))
    state = {jax.tree_util.keystr(path): np.asarray(leaf) for path, leaf in leaves}
    for name in COUNTERS:
        state[f"counter.{name}"] = np.asarray(int(getattr(model, name, 0)), dtype=np.int64)
    return state


def save_learner_state(model, path: Path) -> Path:
    """`learner_state` as an npz file (written whole: a temporary file, then renamed)."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        # allow_pickle: numpy's default, named so that mypy does not match the arrays to it
        np.savez(f, allow_pickle=True, **learner_state(model))
    tmp.replace(path)
    return path


def load_learner_state(model, path: Path) -> None:
    """Put the state `save_learner_state` wrote into ``model`` (built from the same
    recipe): each array must be where, and of the shape and type, the model expects
    (ValueError naming the first that is not); nothing is unpickled."""
    import jax
    import jax.numpy as jnp

    try:
        with np.load(path, allow_pickle=False) as npz:
            saved = {k: npz[k] for k in npz.files}
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable SBX learner state ({exc})") from None
    leaves, treedef = jax.tree_util.tree_flatten_with_path(_state_tree(model))
    restored = []
    for tree_path, leaf in leaves:
        name = jax.tree_util.keystr(tree_path)
        value = saved.get(name)
        want = np.asarray(leaf)
        # (a fresh train state counts its steps in a Python int, a trained one in int32)
        if value is None or value.shape != want.shape or value.dtype.kind != want.dtype.kind:
            got = "missing" if value is None else f"{value.dtype}{list(value.shape)}"
            raise ValueError(f"{path}: {name} must be {want.dtype}{list(want.shape)} for the "
                             f"run's recipe, got {got}")
        restored.append(jnp.asarray(value))
    tree = jax.tree_util.tree_unflatten(treedef, restored)
    model.policy.actor_state, model.policy.vf_state = tree["actor"], tree["critic"]
    model.key, model.policy.key, model.policy.noise_key = (
        tree["key"], tree["policy_key"], tree["noise_key"])
    for name in COUNTERS:
        value = saved.get(f"counter.{name}")
        if value is None or value.shape != () or value.dtype.kind != "i" or value < 0:
            raise ValueError(f"{path}: counter.{name} must be a non-negative integer")
        setattr(model, name, int(value))


# ---------------------------------------------------------------------------------------
# the learner
# ---------------------------------------------------------------------------------------
class SbxLearner(Sb3Learner):
    """SBX's PPO as the SB3 back end's learner; keeps the SB3 twin that every model file is
    saved from."""

    resume_needs_trust = RESUME_NEEDS_TRUST

    def __init__(self) -> None:
        self.twin = None

    def new_model(self, hyper: dict[str, Any], env, settings: TrainSettings):
        """Make the untrained SBX PPO model and its SB3 twin (see `Sb3Learner.new_model`).

        Raises
        ------
        ValueError
            If the algorithm is not PPO.
        """
        import stable_baselines3
        from sbx import PPO

        if settings.algo != "ppo":
            raise ValueError(f"--algo must be 'ppo' with --backend sbx, got {settings.algo!r}")
        self.twin = _new_model(stable_baselines3.PPO, hyper, env, settings)
        kwargs = with_schedules({k: v for k, v in hyper.items() if k not in ZOO_ONLY_KEYS})
        kwargs.pop("policy", None)
        kwargs["policy_kwargs"] = sbx_policy_kwargs(parse_policy_kwargs(
            kwargs.get("policy_kwargs")))
        model = PPO(hyper.get("policy", "MlpPolicy"), env, seed=settings.seed, verbose=0,
                    **kwargs)
        _pairs(model, self.twin)          # the two networks have the same layers
        return model

    def warm_start(self, model, config, hyper: dict[str, Any], steps: int, seed: int
                   ) -> dict[str, Any]:
        """Warm-start through the SB3 twin, then copy its weights back (see `Sb3Learner.warm_start`)."""
        copy_to_twin(model, self.twin)    # the twin starts from the flax initialisation
        done = super().warm_start(self.twin, config, hyper, steps, seed)
        copy_from_twin(self.twin, model)
        return done

    def save(self, model, path: Path, settings: TrainSettings,
             extra: dict[str, Any] | None = None) -> Path:
        """Save the SB3 twin, holding ``model``'s weights (see `Sb3Learner.save`)."""
        copy_to_twin(model, self.twin)
        return save_model(self.twin, path, settings, extra)

    def checkpoint(self, model, folder: Path, tag: str, settings: TrainSettings) -> Path:
        """Save the twin as a checkpoint and the SBX learner's state beside it."""
        path = self.save(model, folder / f"{tag}_{model.num_timesteps}_steps.zip", settings)
        save_learner_state(model, path.with_suffix(STATE_SUFFIX))
        return path

    def resume(self, checkpoint: Path, env, hyper: dict[str, Any], norm_kw, frame_stack: int,
               settings: TrainSettings, trust: bool):
        """Load ``checkpoint`` and the SBX learner's state beside it (see `Sb3Learner.resume`).

        Raises
        ------
        ValueError
            If the checkpoint has no SBX learner state beside it.
        """
        state = checkpoint.with_suffix(STATE_SUFFIX)
        if not state.is_file():
            raise ValueError(f"--resume: {checkpoint} has no SBX learner state beside it "
                             f"({state.name}); resume the checkpoint an sbx run wrote")
        model = self.new_model(hyper, resume_env(checkpoint, env, norm_kw, frame_stack, trust),
                               settings)
        load_learner_state(model, state)
        return model


def run(settings: RunSettings, hyper: dict[str, Any], run_dir: Path,
        resume: str | Path | None = None, trust: bool = False,
        began: float | None = None) -> Path | None:
    """As `agents.training.backends.sb3.run`, with SBX's PPO learning."""
    _single_threaded_xla()
    return train_with(SbxLearner(), settings, hyper, run_dir, resume, trust, began)


__all__ = ["RECIPES", "RESUME_NEEDS_TRUST", "STATE_SUFFIX", "SbxLearner", "check_dependencies",
           "copy_from_twin", "copy_to_twin", "learner_state", "load_learner_state", "run",
           "save_learner_state", "sbx_policy_kwargs"]
