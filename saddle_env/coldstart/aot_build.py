"""Build the ahead-of-time compiled kernels: the compiled code of a first `env.step` (the
single env's, the vector env's below 2 x LANES balls on one thread, training's 64, and from
2 x LANES on numba's threads), its `reset`, a first `simulate`, `simulate_batch` and
`predict_batch` (a model-predictive controller's look-ahead) and a first
`saddle_env.lifetimes.predict_lifetimes` of a steel ball, as a C extension module per
set of contact models, so that a fresh process starts without numba's compiling (how long
that takes: docs/coldstart.md).

What is built is numba's own compile of the kernels, not a second implementation: for each
set of contact models a registered level, a one-model environment or `simulate`, or the ion
trap's `simulate_ion` uses (`planned_builds`), a worker process runs
those first calls once with the JIT (`compilation.specialise`'s copies), then links the
compiled code below each entry point into an extension module with `numba.pycc`, whose
entry points take exactly the argument types the JIT was called with and release the GIL
(the batch kernels run on several threads: `compilation.threads.in_threads`). The workers' JIT and pycc
compile for each of `aot.build_targets`' CPUs in turn (on x86-64 the x86-64-v3 level, so
that a wheel serves other CPU models, and x86-64-v4 where the building machine has AVX-512),
told to numba through its CPU variables. The threaded step's module
carries `aot_threads`'s forwarders to numba's threading layer. `saddle_env.compilation.aot`
loads the modules when they were built from the sources in place (a digest of them is in
the manifest), on the same platform and a CPU that can run them, and otherwise leaves every
call to the JIT.

Run by the package's install (setup.py; an install never fails for it) and by
``python -m saddle_env.coldstart.precompile --aot``.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time
import types
import warnings
from concurrent.futures import ProcessPoolExecutor
from datetime import datetime, timezone
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

from ..compilation import aot as _aot
from ..compilation.specialise import specialise, variant_flags

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..scene import ContactModel, Scene

    # The JIT copies the thin callers below call: each caller is rebuilt per build with its
    # copy as its one global (`_build_one`), so these names exist in no module.
    place: Callable[..., None]
    step_scalar: Callable[..., Any]
    step_serial: Callable[..., Any]
    step_parallel: Callable[..., Any]
    integrate_h: Callable[..., Any]
    integrate_batch: Callable[..., None]
    integrate_batch_shared: Callable[..., None]
    integrate_segments: Callable[..., None]


# The package's folders a build depends on: its own modules and the environment's (the
# kernels, the constants they fold in, and the code that picks their arguments), the
# compilation layer, and this folder (the thin callers below are compiled into the build).
# Any change to one of them, even one no kernel reads, retires the build: safe rather than
# clever. The manifest names them for the loader (`aot.source_digest`).
SOURCES = ("", "envs", "compilation", "coldstart")


# The exported entry points call the JIT copies through these thin functions rather than
# being the kernels' own functions: pycc compiles what it exports with numba's default
# error model (Python's: 1/0 raises), while the functions below them keep the kernels' own
# options (numpy's: 1/0 = inf); the call itself costs nothing once LLVM inlines it.
def _place(idx, models, P, Y, balls, cfg, x, y, vx, vy, lab_rest, spin_normal, noise, obs, out):
    place(idx, models, P, Y, balls, cfg, x, y, vx, vy, lab_rest,  # noqa: F821 (set per build)
          spin_normal, noise, obs, out)


def _step_scalar(models, P, scales, Y, balls, cfg, actions, active, tab_fields, ctl_fields,
                 noise, obs, out, buf, ibuf):
    return step_scalar(models, P, scales, Y, balls, cfg, actions, active,  # noqa: F821
                       tab_fields, ctl_fields, noise, obs, out, buf, ibuf)


def _step_serial(models, P, scales, Y, balls, cfg, actions, active, tab_fields, ctl_fields,
                 noise, obs, out, buf, ibuf):
    return step_serial(models, P, scales, Y, balls, cfg, actions, active,  # noqa: F821
                       tab_fields, ctl_fields, noise, obs, out, buf, ibuf)


def _step_parallel(models, P, scales, Y, balls, cfg, actions, active, tab_fields, ctl_fields,
                   noise, obs, out, bufs, ibufs):
    return step_parallel(models, P, scales, Y, balls, cfg, actions, active,  # noqa: F821
                         tab_fields, ctl_fields, noise, obs, out, bufs, ibufs)


def _integrate_h(model, p, prof, y, t0, t_out, tab, ctl, scale, Y_out, stats, h_start, work):
    return integrate_h(model, p, prof, y, t0, t_out, tab, ctl, scale,  # noqa: F821
                       Y_out, stats, h_start, work)


def _integrate_batch(lo, hi, models, P, profiles, Y, t0, t_out, tab, ctl, scales, max_step,
                     active, Y_out, status, t_final, stats):
    integrate_batch(lo, hi, models, P, profiles, Y, t0, t_out, tab, ctl,  # noqa: F821
                    scales, max_step, active, Y_out, status, t_final, stats)


def _integrate_batch_shared(lo, hi, models, P, profiles, Y, t0, t_out, tab, ctl, scales,
                            max_step, active, Y_out, status, t_final, stats):
    integrate_batch_shared(lo, hi, models, P, profiles, Y, t0, t_out, tab,  # noqa: F821
                           ctl, scales, max_step, active, Y_out, status, t_final, stats)


def _integrate_segments(lo, hi, models, P, scales, Y, drives, durations, sample, tab, ctl,
                        t_out, Y_out, N_out, status):
    integrate_segments(lo, hi, models, P, scales, Y, drives, durations,  # noqa: F821
                       sample, tab, ctl, t_out, Y_out, N_out, status)


# module whose JIT copy an export calls → {export name: its thin caller}
_EXPORTS: dict[str, dict[str, Callable[..., Any]]] = {
    "saddle_env.envs.control_step": {"place": _place, "step_scalar": _step_scalar,
                                     "step_serial": _step_serial, "step_parallel": _step_parallel},
    "saddle_env.integrators": {"integrate_h": _integrate_h, "integrate_batch": _integrate_batch},
    "saddle_env.blockstep": {"integrate_batch_shared": _integrate_batch_shared},
    "saddle_env.prediction": {"integrate_segments": _integrate_segments},
}


def _release_gil_in_exports() -> None:
    """Make pycc's wrappers release the GIL around the compiled code, as the JIT's do for a
    ``nogil`` function: the batch kernels run on several Python threads at once
    (`compilation.threads.in_threads`). pycc compiles every export with one set of compiler flags and
    offers no option for it, so its flags class is given the setting (in this build's worker
    process only). Releasing and taking back the GIL is cheap beside a kernel's call."""
    from numba.core.compiler import Flags
    from numba.pycc import compiler

    class _NoGilFlags(Flags):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            # numba types its flags as the Option descriptors that hold them, not their values
            self.release_gil = True  # type: ignore[assignment]

    pycc_compiler: Any = compiler  # Any: its Flags class is replaced, as numba does not expect
    pycc_compiler.Flags = _NoGilFlags


class BuildSpec(TypedDict):
    """What one module is built for (`planned_builds`)."""

    models: list[int]
    resist: bool
    env: list[Any] | None             # [env id, its options]
    contact: ContactModel | None
    mix: bool
    ion: bool
    lifetimes: bool


def planned_builds() -> dict[tuple[str, ...], BuildSpec]:
    """Each module to build, by its `kernels.variant_flags`: the contact models, the
    resistance flag, the environment whose first step uses them (``[id, options]``: a
    registered level, or ``SaddleTrap-v0`` given one contact model where no level has it
    alone), a contact model whose `simulate` does (None if none), whether a batch mixes
    them (a level that draws several models: `simulate_batch` and `predict_batch` over its
    balls), whether they are the ion trap's (`iontrap.simulate_ion`), and whether they are
    the real-saddle model's steel ball (`lifetimes.release_times`: rolling with rolling
    resistance, which no level draws; its droplets use the point's module, built anyway)."""
    from ..envs.engine import contact_uses
    from ..envs.levels import LEVELS
    from ..scene import CONTACT_MODELS, ION_PAUL, ION_RRF, ROLLING

    plan: dict[tuple[str, ...], BuildSpec] = {}

    def module_for(models, resist: bool) -> BuildSpec:
        return plan.setdefault(variant_flags(models, resist),
                               {"models": sorted(models), "resist": resist, "env": None,
                                "contact": None, "mix": False, "ion": False,
                                "lifetimes": False})

    for level in LEVELS:
        models, resist = contact_uses(level.config())
        entry = module_for(models, resist)
        entry["env"] = entry["env"] or [level.id, {}]
        entry["mix"] = entry["mix"] or len(models) > 1
    for contact in CONTACT_MODELS:
        entry = module_for((_example_scene(contact).model_code,), False)
        entry["contact"] = entry["contact"] or contact
        # an environment of this one model (``gym.make("SaddleTrap-v0", contact=...)``)
        entry["env"] = entry["env"] or [LEVELS[0].id, _one_model_options(contact)]
    module_for((ION_RRF, ION_PAUL), False)["ion"] = True   # `iontrap.simulate_ion`
    module_for((ROLLING,), True)["lifetimes"] = True        # `lifetimes.predict_lifetimes`
    return plan


def _one_model_options(contact: ContactModel) -> dict[str, object]:
    """Environment options that draw only balls of the contact model ``contact``."""
    return {"contact": contact, "mu": 0.3} if contact == "coulomb" else {"contact": contact}


def _example_scene(contact: ContactModel) -> Scene:
    """A scene with the contact model ``contact`` (coulomb's needs a friction coefficient)."""
    from ..scene import Scene
    return Scene(contact=contact, mu=0.3) if contact == "coulomb" else Scene(contact=contact)


def _module_name(flags: tuple[str, ...]) -> str:
    return "k_" + ("_".join(f[:-3].lower() for f in flags) or "none")


def _warm_env(spec: BuildSpec, out_dir: str, module_name: str, exports: dict[str, list[str]],
              threaded: list[str], shims: list[str]) -> None:
    """First steps of the level's env and vector env (serial, SIMD blocks, threads), so the
    step functions are compiled with their argument types; their exports listed."""
    import gymnasium as gym

    from ..compilation import aot_threads
    from ..envs import control_step
    from ..lockstep import LANES
    from .profile import first_step

    assert spec["env"] is not None  # the caller checked
    env_id, options = spec["env"]
    first_step(gym.make(env_id, **options))
    # the vector env below 2 x LANES balls (training's 64): SIMD blocks in one thread
    first_step(gym.make_vec(env_id, num_envs=control_step.MIN_BLOCK, **options))
    # and from 2 x LANES on: numba's threads, reached through `aot_threads`'s forwarders
    first_step(gym.make_vec(env_id, num_envs=2 * LANES, **options))
    exports["saddle_env.envs.control_step"] = ["place", "step_scalar", "step_serial",
                                               "step_parallel"]
    threaded.append("saddle_env.envs.control_step.step_parallel")
    shims.append(aot_threads.write_shim(out_dir, module_name))


def _warm_simulator(spec: BuildSpec, exports: dict[str, list[str]]) -> None:
    """First calls of simulate, simulate_batch and predict_batch on one ball of each of the
    module's models; their exports listed."""
    import numpy as np

    from ..prediction import predict_batch
    from ..runner import initial_state
    from ..scene import CONTACT_MODELS
    from ..simulate import simulate, simulate_batch

    # one ball of each model (a mix's batch has rows of several)
    by_code: dict[int, Scene] = {}
    for contact in CONTACT_MODELS:
        scene = _example_scene(contact)
        if scene.model_code in spec["models"]:
            by_code.setdefault(scene.model_code, scene)
    scenes = list(by_code.values())
    width = max(sc.state_size for sc in scenes)
    starts = np.array([np.pad(s, (0, width - len(s))) for s in
                       (initial_state(sc, 0.001, 0.001, omega=30.0) for sc in scenes)])
    if spec["contact"] is not None:
        simulate(scenes[0], starts[0, :scenes[0].state_size], 0.01, omega=30.0)
        exports["saddle_env.integrators"] = ["integrate_h"]
    simulate_batch(scenes * 2, np.concatenate([starts, starts]), 0.01, omega=30.0)
    exports.setdefault("saddle_env.integrators", []).append("integrate_batch")
    simulate_batch(scenes * 2, np.concatenate([starts, starts]), 0.01, omega=30.0,
                   shared_steps=True)
    exports["saddle_env.blockstep"] = ["integrate_batch_shared"]
    # a look-ahead, as a model-predictive controller makes it (agents.control.mpc): the argument
    # types are predict_batch's own, whatever the values
    rows = np.array([sc.model_code for sc in scenes] * 2)
    P = np.array([sc.params() for sc in scenes] * 2)
    from ..kernels import DRIVE_W0, DRIVE_WIDTH

    drives = np.zeros((len(rows), 2, DRIVE_WIDTH))
    drives[:, :, DRIVE_W0] = 30.0
    predict_batch(rows, P, np.concatenate([starts, starts]), drives,
                  np.full((len(rows), 2), 0.01), 0.005)
    exports["saddle_env.prediction"] = ["integrate_segments"]


def _warm_ion(exports: dict[str, list[str]]) -> None:
    """A first ion-trap run; its integrator listed for export."""
    import numpy as np

    from ..iontrap import RRFTrap, simulate_ion
    simulate_ion(RRFTrap(omega=20.0, kappa=1.0), np.array([1e-3, 0.0, 0.0, 0.0]), 0.01)
    exports["saddle_env.integrators"] = ["integrate_h"]


def _warm_lifetimes(exports: dict[str, list[str]]) -> None:
    """A first real-saddle prediction of a steel ball (`lifetimes.release_times`, which runs
    `runner.run_batch` with rolling resistance); its batch integrator listed for export."""
    import numpy as np

    from ..lifetimes.model import LabModel, release_times
    release_times(LabModel(rolling_resistance=1e-3, t_max=0.05), 2.67, 2.51, "steel", 19.0,
                  np.array([1.0]), 2, 0)
    exports.setdefault("saddle_env.integrators", []).append("integrate_batch")


def _export(cc: Any, spec: BuildSpec, exports: dict[str, list[str]],
            argtypes: dict[str, list[str]]) -> None:
    """Each listed function's one compiled signature exported by ``cc`` through a thin
    caller; its argument types recorded in ``argtypes``."""
    from .. import blockstep, integrators, prediction
    from ..envs import control_step

    modules = {"saddle_env.envs.control_step": control_step, "saddle_env.integrators": integrators,
               "saddle_env.prediction": prediction, "saddle_env.blockstep": blockstep}
    for mod_name, names in exports.items():
        space = specialise(frozenset(spec["models"]), bool(spec["resist"]), modules[mod_name])
        for name in names:
            dispatcher = getattr(space, name)
            if len(dispatcher.signatures) != 1:
                raise RuntimeError(f"{mod_name}.{name}: {len(dispatcher.signatures)} compiled "
                                   "signatures, expected exactly the first call's one")
            caller = _EXPORTS[mod_name][name]
            thin = types.FunctionType(caller.__code__, {name: dispatcher}, caller.__name__)
            signature = dispatcher.signatures[0]
            cc.export(name, signature)(thin)
            argtypes[f"{mod_name}.{name}"] = [str(t) for t in signature]


def _build_one(flags: tuple[str, ...], spec: BuildSpec, out_dir: str) -> dict:
    """Compile one module in this (worker) process; return its manifest entry."""
    os.environ[_aot.AOT_ENV] = "0"  # the JIT's copies are what gets built
    # the compile notice is for a user waiting on a first call, not for this build
    logging.getLogger("saddle_env").setLevel(logging.ERROR)
    from numba.pycc import CC

    t0 = time.perf_counter()
    exports: dict[str, list[str]] = {}
    threaded: list[str] = []  # the exports that run on numba's threads (`aot_threads.wire`)
    argtypes: dict[str, list[str]] = {}
    shims: list[str] = []   # C sources linked into the module beside numba's own

    class _CC(CC):
        def _get_mixin_sources(self):
            return [*super()._get_mixin_sources(), *shims]

    cc = _CC(_module_name(flags))
    cc.output_dir = out_dir
    cc.verbose = False
    # The JIT copies below are compiled, and their code optimised, for the CPU numba is told
    # in this worker (`build` sets NUMBA_CPU_NAME and NUMBA_CPU_FEATURES to the build's
    # target); pycc then makes the machine code for that same CPU name and features (by
    # default it would use the name's nominal features alone).
    from numba.core.codegen import AOTCPUCodegen
    target = _aot.machine()
    codegen: Any = AOTCPUCodegen  # Any: a method of numba's is replaced in this worker
    codegen._customize_tm_features = lambda self: target["features"]
    cc.target_cpu = target["cpu"]
    _release_gil_in_exports()
    if spec["env"] is not None:
        _warm_env(spec, out_dir, cc.name, exports, threaded, shims)
    if spec["contact"] is not None or spec["mix"]:
        _warm_simulator(spec, exports)
    if spec["ion"]:
        _warm_ion(exports)
    if spec["lifetimes"]:
        _warm_lifetimes(exports)
    _export(cc, spec, exports, argtypes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc's deprecation notice
        cc.compile()
    return {"name": cc.name, "file": cc.output_file, "flags": list(flags), "exports": exports,
            "argtypes": argtypes, "threaded": threaded,
            "cpu": target["cpu"], "features": target["features"],
            "seconds": round(time.perf_counter() - t0, 1)}


def build(jobs: int, log=print) -> list[dict]:
    """Build every planned module for each of `aot.build_targets` into its folder of this
    package's ``_aot`` (`aot.build_folder`) in up to ``jobs`` worker processes, from the
    sources in place (a source tree, or an install's build folder). Each build's manifest
    is written last, so a build stopped half-way is never used. Returns the manifests."""
    targets = _aot.build_targets()
    # every earlier build is retired until the new one is whole
    (_aot.AOT_DIR / _aot.MANIFEST).unlink(missing_ok=True)
    for level in _aot.UPPER_LEVELS:
        shutil.rmtree(_aot.AOT_DIR / level, ignore_errors=True)
    return [_build_for(target, jobs, log) for target in targets]


def _build_for(target: dict[str, str], jobs: int, log) -> dict:
    """`build` for one CPU ``target``; its manifest."""
    out_dir = _aot.build_folder(target["cpu"])
    out_dir.mkdir(parents=True, exist_ok=True)
    plan = planned_builds()
    jobs = max(1, min(jobs, len(plan)))
    log(f"  for CPU {target['cpu']} ({target['features'] or 'its own features'})")
    t0 = time.perf_counter()
    # numba reads its CPU settings from the environment when it is first imported: the
    # spawned workers inherit these (this process's own JIT keeps its settings)
    saved = {k: os.environ.get(k) for k in _aot.CPU_VARIABLES}
    os.environ.update(zip(_aot.CPU_VARIABLES, (target["cpu"], target["features"])))
    try:
        with tempfile.TemporaryDirectory(dir=out_dir) as tmp, \
                ProcessPoolExecutor(jobs, mp_context=get_context("spawn")) as pool:
            futures = {flags: pool.submit(_build_one, flags, spec, tmp)
                       for flags, spec in plan.items()}
            modules = []
            for fut in futures.values():
                entry = fut.result()
                built_for = {k: entry.pop(k) for k in ("cpu", "features")}
                if built_for != target:
                    raise RuntimeError(f"{entry['name']} was built for {built_for}, "
                                       f"not {target}")
                os.replace(Path(tmp) / entry["file"], out_dir / entry["file"])
                names = ", ".join(n for names in entry["exports"].values() for n in names)
                log(f"  {entry['name']}: {names} ({entry['seconds']:.1f} s)")
                modules.append(entry)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    manifest = {"sources": list(SOURCES), "digest": _aot.source_digest(SOURCES),
                "platform": _aot.platform_tag(),
                **_aot.machine(), **target,
                "built": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                "seconds": round(time.perf_counter() - t0, 1), "modules": modules}
    (out_dir / _aot.MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest
