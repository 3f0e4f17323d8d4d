"""The benchmark's compiled peers: other people's ODE solvers on the same equations.

Each peer integrates the benchmark's ball (`saddle_env.workprecision.equations`, one source
for every right-hand side below) with a solver a numerical user would pick, written as
that user would write it:

========================  ==================  =======================================
peer (``--peers`` key)    right-hand side     batch of balls
========================  ==================  =======================================
scipy DOP853 lean         Python floats       —
scipy DOP853 njit         ``numba.njit``      —
numbalsoda DOP853/LSODA   ``numba.cfunc``     a ``numba.prange`` loop, numba's threads
diffrax Dopri8/Tsit5      JAX, ``jax.jit``    ``jax.vmap``
CVODE Adams               ``numba.njit``      —
========================  ==================  =======================================

(scipy and CVODE step in Python or call back into it at every evaluation, so a batch costs
them per ball what one ball does; they are timed on one ball only.)

Every peer meets the simulator's error test: per component, |error| ≤ rtol·(scale + |y|)
with the simulator's state scales (`saddle_env.integrators.state_scale`), i.e. atol =
rtol × scale. Solvers that take a vector atol get it; numbalsoda and diffrax take a scalar,
so they integrate the scaled state z = y/scale with atol = rtol, which is the same test.

The packages come with the ``[peers]`` extra (docs/install.md); a peer whose package is
missing is reported by `missing` and skipped. Every heavy import is inside a function.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..integrators import state_scale
from ..scene import (
    P_DRAG_LINEAR,
    P_DRAG_QUADRATIC,
    P_DRILL,
    P_RESIST,
    P_SURFACE_DRAG,
    P_TILT_FORCE,
    Scene,
)
from .equations import jax_rhs, rolling_rates, slipping_rates


@dataclass(frozen=True)
class Peer:
    """One peer: a solver and method, how its right-hand side is compiled, what it needs."""

    key: str               # the --peers name
    solver: str            # the package that steps: scipy, numbalsoda, diffrax, scikit-sundae
    method: str            # its method's name there
    rhs: str               # python / njit / cfunc / jax
    needs: tuple[str, ...]  # modules to import
    batch: bool            # timed on the batch too

    @property
    def label(self) -> str:
        """The peer's name in the tables and figures."""
        if self.solver == "scipy":
            return f"scipy {self.method} ({self.rhs})"
        return f"{self.solver} {self.method}"


PEERS: tuple[Peer, ...] = (
    Peer("scipy-lean", "scipy", "DOP853", "python", ("scipy",), False),
    Peer("scipy-njit", "scipy", "DOP853", "njit", ("scipy", "numba"), False),
    Peer("numbalsoda-dop853", "numbalsoda", "DOP853", "cfunc", ("numbalsoda",), True),
    Peer("numbalsoda-lsoda", "numbalsoda", "LSODA", "cfunc", ("numbalsoda",), True),
    Peer("diffrax-dopri8", "diffrax", "Dopri8", "jax", ("diffrax", "jax"), True),
    Peer("diffrax-tsit5", "diffrax", "Tsit5", "jax", ("diffrax", "jax"), True),
    Peer("cvode-adams", "scikit-sundae", "CVODE Adams", "njit", ("sksundae",), False),
)
BY_KEY = {p.key: p for p in PEERS}
# "plain" is the slow plain-numpy peer (`saddle_env.workprecision.peer`), run by core.
GROUPS: dict[str, tuple[str, ...]] = {
    "all": ("plain",) + tuple(BY_KEY),
    "compiled": tuple(k for k in BY_KEY if k not in ("scipy-lean",)),
    "scipy": ("plain", "scipy-lean", "scipy-njit"),
    "none": (),
}


def parse_peers(text: str) -> tuple[str, ...]:
    """The peer keys a ``--peers`` value names: a group (all, compiled, scipy, none) or a
    comma-separated list of keys and groups. Raises ValueError naming ``peers``."""
    keys: list[str] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        if part in GROUPS:
            keys += GROUPS[part]
        elif part in BY_KEY or part == "plain":
            keys.append(part)
        else:
            raise ValueError(f"peers: unknown peer {part!r}; choose from "
                             f"{', '.join(list(GROUPS) + ['plain'] + list(BY_KEY))}")
    return tuple(dict.fromkeys(keys))


def missing(peer: Peer) -> str | None:
    """Why ``peer`` cannot run here (the missing package), or None."""
    for module in peer.needs:
        if importlib.util.find_spec(module) is None:
            package = {"sksundae": "scikit-sundae"}.get(module, module)
            return f"{package} is not installed (pip install 'saddle-env[peers]')"
    return None


# ----------------------------------------------------------------------------------------
# The solvers. Each `Solver` is built once per scene (the compile happens on its first call)
# and then solves one ball, `single`, or a batch, `batch`, on an output grid.
# ----------------------------------------------------------------------------------------
class Solver:
    """A peer set up for one scene at constant Ω: ``single(y0, grid, rtol)`` returns the
    states on ``grid`` (len(grid), d) and the number of right-hand-side evaluations (NaN
    when the solver does not say); ``batch(Y0, grid, rtol)`` the states (n, len(grid), d)."""

    def __init__(self, scene: Scene, omega: float) -> None:
        if scene.contact not in ("rolling", "slipping", "point"):
            raise ValueError(f"scene: the peers model rolling, slipping and point balls, "
                             f"not {scene.contact!r}")
        if not math.isfinite(omega):
            raise ValueError(f"omega must be finite, got {omega!r}")
        p = scene.params()
        extra = [name for name, slot in (("drilling friction", P_DRILL), ("air drag", P_DRAG_LINEAR),
                                         ("air drag", P_DRAG_QUADRATIC),
                                         ("surface drag", P_SURFACE_DRAG),
                                         ("rolling resistance", P_RESIST), ("tilt", P_TILT_FORCE))
                 if p[slot] != 0.0]
        if extra:
            raise ValueError(f"scene: the peers' equations have no {extra[0]} (the benchmark's "
                             "scene is conservative)")
        self.rolling = scene.contact == "rolling"
        self.d = scene.state_size
        self.scale = state_scale(scene.params(), scene.model_code)[: self.d].copy()
        # (a, b, R, alpha, g, Ω): what every right-hand side reads.
        self.args = (scene.a, scene.b, scene.radius, scene.alpha, scene.g, float(omega))

    def single(self, y0: np.ndarray, grid: np.ndarray, rtol: float) -> tuple[np.ndarray, float]:
        """One ball from state ``y0``: its states on ``grid`` and the evaluation count."""
        raise NotImplementedError

    def batch(self, Y0: np.ndarray, grid: np.ndarray, rtol: float) -> np.ndarray:
        """The balls of ``Y0`` (n, d): their states on ``grid``, (n, len(grid), d)."""
        raise NotImplementedError(f"{type(self).__name__} has no batch form")


def _python_rates(rolling: bool, args: tuple) -> Callable:
    """The lean right-hand side: the shared equations on Python floats."""
    a, b, R, alpha, g, w = args
    if rolling:
        rates = rolling_rates(math.sqrt)

        def f(t, y):
            x, yy, wx, wy, wz = y.tolist()  # Python floats: far cheaper than numpy scalars
            return np.array(rates(a, b, R, alpha, g, w, 0.0, x, yy, wx, wy, wz))
        return f
    srates = slipping_rates(math.sqrt)

    def fs(t, y):
        x, yy, vx, vy = y.tolist()
        return np.array(srates(a, b, R, g, w, 0.0, x, yy, vx, vy))
    return fs


def _numba_rates(rolling: bool):
    """The shared equations compiled by numba: ``rates(p, y, out)`` with p = (a, b, R,
    alpha, g, Ω), writing dy/dt into out. Inlined wherever it is called from numba."""
    import numba

    if rolling:
        r = numba.njit(rolling_rates(math.sqrt), inline="always")

        @numba.njit(inline="always")
        def rates(p, y, out):
            out[0], out[1], out[2], out[3], out[4] = r(p[0], p[1], p[2], p[3], p[4], p[5], 0.0,
                                                       y[0], y[1], y[2], y[3], y[4])
        return rates
    s = numba.njit(slipping_rates(math.sqrt), inline="always")

    @numba.njit(inline="always")
    def srates(p, y, out):
        out[0], out[1], out[2], out[3] = s(p[0], p[1], p[2], p[4], p[5], 0.0, y[0], y[1], y[2],
                                           y[3])
    return srates


class ScipyLean(Solver):
    """``scipy.integrate.solve_ivp`` DOP853 on the lean Python right-hand side."""

    def __init__(self, scene: Scene, omega: float) -> None:
        super().__init__(scene, omega)
        self.fun = _python_rates(self.rolling, self.args)

    def single(self, y0, grid, rtol):
        """As `Solver.single`."""
        from scipy.integrate import solve_ivp

        sol = solve_ivp(self.fun, (grid[0], grid[-1]), y0, method="DOP853", rtol=rtol,
                        atol=rtol * self.scale, t_eval=grid)
        if sol.status != 0:
            raise RuntimeError(f"scipy DOP853 failed: {sol.message}")
        return sol.y.T, float(sol.nfev)


class ScipyNjit(ScipyLean):
    """``solve_ivp`` DOP853 on the ``njit`` right-hand side (one call into numba per
    evaluation: what compiling the right-hand side alone buys)."""

    def __init__(self, scene: Scene, omega: float) -> None:
        Solver.__init__(self, scene, omega)
        import numba

        rates = _numba_rates(self.rolling)
        d = self.d

        @numba.njit
        def f(t, y, p):
            out = np.empty(d)
            rates(p, y, out)
            return out

        p = np.array(self.args)
        self.fun = lambda t, y: f(t, y, p)


class CvodeAdams(Solver):
    """SUNDIALS CVODE (scikit-sundae), Adams–Moulton for this non-stiff problem, on the
    ``njit`` right-hand side. CVODE's default Newton iteration with a dense
    difference-quotient Jacobian is what scikit-sundae offers; the Jacobian is rarely
    refreshed on a non-stiff problem."""

    def __init__(self, scene: Scene, omega: float) -> None:
        super().__init__(scene, omega)
        import numba

        rates = _numba_rates(self.rolling)
        p = self.args  # a tuple of floats: numba freezes it into the compiled code

        @numba.njit
        def f(t, y, yp):
            rates(p, y, yp)

        self.fun = f

    def single(self, y0, grid, rtol):
        """As `Solver.single`."""
        from sksundae.cvode import CVODE

        solver = CVODE(self.fun, method="Adams", rtol=rtol,
                       atol=rtol * self.scale, max_num_steps=100_000)
        sol = solver.solve(grid, np.asarray(y0, dtype=float))
        if not sol.success:
            raise RuntimeError(f"CVODE failed: {sol.message}")
        return np.asarray(sol.y), float(sol.nfev)


class Numbalsoda(Solver):
    """numbalsoda's DOP853 (Fortran) or LSODA (C++) on a ``numba.cfunc`` right-hand side
    of the scaled state; the batch calls it from a ``numba.prange`` loop."""

    def __init__(self, scene: Scene, omega: float, method: str) -> None:
        super().__init__(scene, omega)
        import numba
        import numbalsoda

        if method not in ("DOP853", "LSODA"):
            raise ValueError(f"method must be DOP853 or LSODA, got {method!r}")
        # data = (a, b, R, alpha, g, Ω, scale_0 … scale_{d-1}); u = y / scale. Scalars
        # throughout: no array is allocated per evaluation.
        if self.rolling:
            r = numba.njit(rolling_rates(math.sqrt), inline="always")

            @numba.cfunc(numbalsoda.lsoda_sig)
            def rhs(t, u, du, data):
                p = numba.carray(data, 11)
                d0, d1, d2, d3, d4 = r(p[0], p[1], p[2], p[3], p[4], p[5], 0.0, u[0] * p[6],
                                       u[1] * p[7], u[2] * p[8], u[3] * p[9], u[4] * p[10])
                du[0], du[1], du[2] = d0 / p[6], d1 / p[7], d2 / p[8]
                du[3], du[4] = d3 / p[9], d4 / p[10]
        else:
            s = numba.njit(slipping_rates(math.sqrt), inline="always")

            @numba.cfunc(numbalsoda.lsoda_sig)
            def rhs(t, u, du, data):
                p = numba.carray(data, 10)
                d0, d1, d2, d3 = s(p[0], p[1], p[2], p[4], p[5], 0.0, u[0] * p[6], u[1] * p[7],
                                   u[2] * p[8], u[3] * p[9])
                du[0], du[1], du[2], du[3] = d0 / p[6], d1 / p[7], d2 / p[8], d3 / p[9]

        self.cfunc = rhs  # keep the compiled function alive while its address is used
        self.funcptr = rhs.address
        self.data = np.concatenate([np.array(self.args), self.scale])
        solve = numbalsoda.dop853 if method == "DOP853" else numbalsoda.lsoda

        @numba.njit
        def one(funcptr, z0, grid, data, rtol):
            usol, ok = solve(funcptr, z0, grid, data, rtol, rtol, 10**7)
            return usol, ok

        @numba.njit(parallel=True)
        def many(funcptr, Z0, grid, data, rtol, out, ok):
            for i in numba.prange(Z0.shape[0]):
                usol, good = solve(funcptr, Z0[i], grid, data, rtol, rtol, 10**7)
                out[i] = usol
                ok[i] = good

        self._one, self._many = one, many

    def single(self, y0, grid, rtol):
        """As `Solver.single`."""
        z, ok = self._one(self.funcptr, np.asarray(y0, dtype=float) / self.scale, grid,
                          self.data, rtol)
        if not ok:
            raise RuntimeError("numbalsoda failed")
        return z * self.scale, math.nan

    def batch(self, Y0, grid, rtol):
        """As `Solver.batch`."""
        Z0 = np.ascontiguousarray(np.asarray(Y0, dtype=float) / self.scale)
        out = np.empty((len(Z0), len(grid), self.d))
        ok = np.zeros(len(Z0), dtype=np.bool_)
        self._many(self.funcptr, Z0, grid, self.data, rtol, out, ok)
        if not ok.all():
            raise RuntimeError(f"numbalsoda failed on {int((~ok).sum())} balls")
        return out * self.scale


class Diffrax(Solver):
    """diffrax's Dopri8 or Tsit5 in float64, the whole solve under ``jax.jit`` (rtol is an
    argument, so one compile serves the sweep); the batch ``jax.vmap``s it over the
    releases. The solve runs on the scaled state, with diffrax's PID step controller."""

    def __init__(self, scene: Scene, omega: float, method: str) -> None:
        super().__init__(scene, omega)
        import diffrax  # noqa: F401  first: a missing diffrax leaves JAX's settings alone
        import jax

        if method not in ("Dopri8", "Tsit5"):
            raise ValueError(f"method must be Dopri8 or Tsit5, got {method!r}")
        # float64 only inside this solver's own calls (`jax.enable_x64` as a context): the
        # process's other JAX code (SBX's float32 networks, say) keeps its setting
        self._x64 = jax.enable_x64
        with self._x64(True):
            self._build(method)

    def _build(self, method: str) -> None:
        """The jitted solves, built under float64."""
        import diffrax
        import jax
        import jax.numpy as jnp

        f = jax_rhs(self.rolling)
        scale = jnp.asarray(self.scale)
        args = tuple(jnp.float64(v) for v in self.args)
        term = diffrax.ODETerm(lambda t, z, a: f(t, z * scale, a) / scale)
        stepper = getattr(diffrax, method)()

        def solve(z0, grid, rtol):
            sol = diffrax.diffeqsolve(
                term, stepper, t0=grid[0], t1=grid[-1], dt0=None, y0=z0, args=args,
                saveat=diffrax.SaveAt(ts=grid),
                stepsize_controller=diffrax.PIDController(rtol=rtol, atol=rtol),
                max_steps=1_000_000, adjoint=diffrax.DirectAdjoint())
            return sol.ys, sol.stats["num_steps"]

        self._one = jax.jit(solve)
        self._many = jax.jit(jax.vmap(solve, in_axes=(0, None, None)))

    def single(self, y0, grid, rtol):
        """As `Solver.single`."""
        with self._x64(True):
            ys, _ = self._one(np.asarray(y0, dtype=float) / self.scale, grid, rtol)
            return np.asarray(ys) * self.scale, math.nan

    def batch(self, Y0, grid, rtol):
        """As `Solver.batch`."""
        with self._x64(True):
            ys, _ = self._many(np.asarray(Y0, dtype=float) / self.scale, grid, rtol)
            return np.asarray(ys) * self.scale


def build(peer: Peer, scene: Scene, omega: float) -> Solver:
    """The peer's solver for ``scene`` at constant ``omega`` [rad/s]."""
    if peer.key == "scipy-lean":
        return ScipyLean(scene, omega)
    if peer.key == "scipy-njit":
        return ScipyNjit(scene, omega)
    if peer.solver == "numbalsoda":
        return Numbalsoda(scene, omega, peer.method)
    if peer.solver == "diffrax":
        return Diffrax(scene, omega, peer.method)
    if peer.key == "cvode-adams":
        return CvodeAdams(scene, omega)
    raise ValueError(f"peer: no solver for {peer.key!r}")
