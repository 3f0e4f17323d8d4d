"""Shared test helpers (not physics: only evaluation of the shared kernels, and the
processes and signals the run and stop tests need)."""

from __future__ import annotations

import os
import signal

import numpy as np

from saddle_env import kernels as K
from saddle_env.compilation.specialise import _jit_of
from saddle_env.scene import Scene


def jit_copy(fn):
    """The numba JIT copy behind an entry point of `compilation.specialise`'s namespace: the
    function itself, or the JIT copy an installed ahead-of-time build stands in for."""
    return _jit_of.get(id(fn), fn)


def padded(state: np.ndarray) -> np.ndarray:
    out = np.zeros(K.STATE_WIDTH)
    out[: len(state)] = state
    return out


def centre_state(scene: Scene, state: np.ndarray) -> np.ndarray:
    """(c_x, c_y, ċ_x, ċ_y) of the exact model for a state vector."""
    y = padded(state)
    p = scene.params()
    geo = K.geometry(p[0], p[1], p[2], y[0], y[1])
    vx, vy = K.contact_velocity(scene.model_code, p, y)
    J1x, J1y, J2x, J2y = geo[7], geo[8], geo[10], geo[11]
    return np.array([geo[4], geo[5], J1x * vx + J2x * vy, J1y * vx + J2y * vy])


def rhs(scene: Scene, state: np.ndarray, omega: float | np.ndarray = 0.0, t: float = 0.0) -> np.ndarray:
    prof = np.zeros(K.DRIVE_WIDTH)
    if np.isscalar(omega):
        prof[0] = omega
    else:
        prof[: len(omega)] = omega
    dy = np.zeros(K.STATE_WIDTH)
    K.rhs(scene.model_code, scene.params(), prof, t, padded(state), dy, False)
    return dy[: scene.state_size]


def fd_linearisation(scene: Scene, omega: float, spin_z: float = 0.0, eps: float = 1e-7) -> np.ndarray:
    """4x4 matrix of the exact model linearised at the saddle point, in centre coordinates
    (x_c, y_c, ẋ_c, ẏ_c), by central differences of the right-hand side."""
    n = scene.state_size
    eq = np.zeros(n)
    if scene.rolling:
        eq[4] = spin_z
    idx = [0, 1, 2, 3]  # the spin about the vertical is a constant of the linear motion
    F = np.zeros((4, 4))
    T = np.zeros((4, 4))
    for col, i in enumerate(idx):
        step = eps * (scene.a if i < 2 else (1.0 if not scene.rolling else 1.0))
        yp, ym = eq.copy(), eq.copy()
        yp[i] += step
        ym[i] -= step
        F[:, col] = (rhs(scene, yp, omega)[idx] - rhs(scene, ym, omega)[idx]) / (2 * step)
        T[:, col] = (centre_state(scene, yp) - centre_state(scene, ym)) / (2 * step)
    return T @ F @ np.linalg.inv(T)


def assert_matches_lab_frame(traj, ref: dict, rolling: bool) -> None:
    """A trajectory equals the laboratory-frame reference's (tests/reference_lab_frame.py):
    positions to 1e-9 m, velocities and N/mg to 1e-8, a rolling ball's spin to 1e-7 rad/s."""
    assert np.max(np.abs(traj.x - ref["x"])) < 1e-9
    assert np.max(np.abs(traj.y - ref["y"])) < 1e-9
    assert np.max(np.abs(traj.vx - ref["vx"])) < 1e-8
    assert np.max(np.abs(traj.vy - ref["vy"])) < 1e-8
    assert np.max(np.abs(traj.N_over_mg - ref["N_over_mg"])) < 1e-8
    if rolling:
        assert np.max(np.abs(traj.state[:, 2:] - ref["w"])) < 1e-7


def batch_and_singles(scenes: list[Scene], t_end: float = 1.0, omega: float = 25.0):
    """The same balls (each released at (3, 1) mm) run as one `simulate_batch` and one by one
    with `simulate`: (batch result, single trajectories)."""
    from saddle_env import initial_state, simulate, simulate_batch

    states = np.zeros((len(scenes), 5))
    for i, sc in enumerate(scenes):
        states[i, : sc.state_size] = initial_state(sc, 0.003, 0.001)
    batch = simulate_batch(scenes, states, t_end, omega=omega)
    return batch, [simulate(sc, states[i, : sc.state_size], t_end, omega=omega)
                   for i, sc in enumerate(scenes)]


def coulomb_case(seed: int, *, t_end: float, time_varying: bool, static_ratio: float = 1.0,
                 min_transitions: int = 2, rtol: float = 1e-10):
    """A random coulomb scene (a != b) and start that the PRODUCTION run keeps trapped with at
    least ``min_transitions`` stick/slip transitions, for the comparisons with the lab-frame
    reference: ``(scene, profile, q0, v0, spin, trajectory)``. mu_static = static_ratio * mu;
    the search costs production runs only, each a few ms."""
    from reference_lab_frame import body_geometry

    from saddle_env import OmegaProfile, initial_state, simulate

    z = np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(seed)
    for _ in range(60):
        a = rng.uniform(0.15, 0.17)
        b = rng.uniform(0.17, 0.22)
        R = rng.uniform(0.008, 0.03)
        alpha = float(rng.choice([0.4, 2 / 3]))
        mu = rng.uniform(0.03, 0.15)
        sc = Scene(contact="coulomb", mu=mu, mu_static=static_ratio * mu, a=a, b=b, R=R,
                   alpha=alpha)
        if time_varying:
            profile = OmegaProfile(rng.uniform(20, 24), rng.uniform(-2, 2), rng.uniform(0, 2),
                                   rng.uniform(3, 8), rng.uniform(0, 6))
        else:
            profile = OmegaProfile(rng.uniform(20, 24))
        q0 = rng.uniform(-0.006, 0.006, 2)
        # half of "at rest in the lab" (a bounded orbit), and the rolling spin of that
        # velocity plus a kick: the ball starts slipping
        c, J, n = body_geometry(a, b, R, *q0)
        v0 = 0.5 * np.linalg.solve(J.T @ J, J.T @ (-profile(0.0) * np.cross(z, c)))
        spin = np.cross(n, J @ v0) / R + rng.uniform(-6, 6, 3) * [1, 1, 0.3]
        s0 = initial_state(sc, *q0, *v0, spin=spin)
        try:
            tr = simulate(sc, s0, t_end, omega=profile, dt_out=0.01, rtol=rtol)
        except Exception:  # noqa: BLE001, S112 -- a run production refuses (step budget): next
            continue
        if (tr.event is None and np.max(np.hypot(tr.x, tr.y)) < 0.03
                and len(tr.transitions) >= min_transitions):
            return sc, profile, q0, v0, spin, tr
    raise AssertionError("no trapped run with enough transitions found")



def sigterm_after_first_checkpoint(cmd: list[str], run, timeout: float = 240):
    """Start ``cmd`` (a train.py run writing to the folder ``run``), send SIGTERM once it
    has written a regular checkpoint, and return its (stdout, stderr) after it exits 0."""
    import signal
    import subprocess
    import time

    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + timeout
    while time.time() < deadline and not list((run / "checkpoints").glob("checkpoint_*.zip")):
        time.sleep(0.5)
        assert proc.poll() is None, proc.communicate()[1][-2000:]
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err[-2000:]
    return out, err


def compiled_in_fresh_process(code: str, env: dict, timeout: float = 600,
                              cwd: str | None = None) -> list[str]:
    """The functions numba compiles while a fresh interpreter runs ``code`` (with ``env``, in
    ``cwd``, whose packages it imports first),
    by name, in order. The probe compiles one lambda of its own last, so a listener that saw
    nothing shows up as a list without it rather than as an empty list."""
    import json
    import subprocess
    import sys

    probe = ("import json\n"
             "from numba.core import event\n"
             "seen = []\n"
             "class L(event.Listener):\n"
             "    def on_start(self, ev): seen.append(ev.data['dispatcher'].py_func.__qualname__)\n"
             "    def on_end(self, ev): pass\n"
             "event.register('numba:compile', L())\n"
             + code + "\n"
             "import numba\n"
             "numba.njit(lambda x: x + 1)(1)\n"
             "print(json.dumps(seen))\n")
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                         timeout=timeout, cwd=cwd)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def gone_within(pid: int, seconds: float) -> bool:
    """Whether process ``pid`` ends within ``seconds``; if not, it is killed (no litter)."""
    import os
    import signal
    import time

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    os.kill(pid, signal.SIGKILL)
    return False


class SignalledWhileFreed:
    """Sends SIGTERM from its ``__del__``: Python runs the handler there and drops what it
    raises (as when numba frees an LLVM object mid-compile)."""

    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):              # the handler runs on one of these bytecodes
            pass
