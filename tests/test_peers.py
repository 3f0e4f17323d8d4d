"""The work-precision benchmark's compiled peers (saddle_env.workprecision.peers) and the
one source of their equations (saddle_env.workprecision.equations), the JAX right-hand side
included: each agrees with the simulator's kernels and trajectories. A peer whose package
is not installed (the [peers] extra) is skipped, naming the package."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from saddle_env import Scene
from saddle_env import kernels as K
from saddle_env.workprecision.core import Case, centre_xy, max_distance, reference
from saddle_env.workprecision.equations import rolling_rates, slipping_rates
from saddle_env.workprecision.peers import BY_KEY, PEERS, Peer, build, missing, parse_peers
from saddle_env.workprecision.report import merge_rounds, peer_comparison, summarize


def _states(contact: str, n: int = 50, seed: int = 3):
    """Random scenes, Ω, Ω̇ and states; the kernels' rates at each (drive row with a ramp)."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        sc = Scene(a=rng.uniform(0.1, 0.3), b=rng.uniform(0.08, 0.3), R=0.02,
                   alpha=rng.uniform(0.3, 0.7), contact=contact)
        om, omd, t = rng.uniform(-30, 30), rng.uniform(-5, 5), rng.uniform(0, 3)
        drive = np.zeros(K.DRIVE_WIDTH)
        drive[K.DRIVE_W0], drive[K.DRIVE_RATE] = om - omd * t, omd  # Ω(t) = om, Ω̇ = omd
        y = np.zeros(K.STATE_WIDTH)
        y[:2] = rng.uniform(-0.04, 0.04, 2)
        y[2:sc.state_size] = rng.uniform(-3, 3, sc.state_size - 2)
        dy = np.zeros(K.STATE_WIDTH)
        K.rhs(sc.model_code, sc.params(), drive, t, y, dy, False)
        yield sc, om, omd, y[:sc.state_size], dy[:sc.state_size]


def _shared(sc, om, omd, y, sqrt=math.sqrt):
    if sc.rolling:
        return rolling_rates(sqrt)(sc.a, sc.b, sc.radius, sc.alpha, sc.g, om, omd, *y)
    return slipping_rates(sqrt)(sc.a, sc.b, sc.radius, sc.g, om, omd, *y)


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_shared_equations_agree_with_the_kernels(contact):
    worst = max(float(np.max(np.abs(np.array(_shared(sc, om, omd, y)) - dy) / (np.abs(dy) + 1e-3)))
                for sc, om, omd, y, dy in _states(contact))
    assert worst < 1e-13, worst


@pytest.fixture(autouse=True)
def _jax_precision_restored():
    """JAX's float64 setting as it was before each test: it is global, a diffrax peer turns
    it on, and SBX's tests (tests/test_sbx_backend.py) fail on float64 where they expect
    float32."""
    jax = sys.modules.get("jax")
    before = bool(jax.config.read("jax_enable_x64")) if jax is not None else False
    yield
    if (jax := sys.modules.get("jax")) is not None:
        jax.config.update("jax_enable_x64", before)


@pytest.fixture
def x64():
    """JAX in float64 for one test (restored by `_jax_precision_restored`)."""
    jax = pytest.importorskip("jax", reason="jax is not installed (pip install 'saddle-env[peers]')")
    jax.config.update("jax_enable_x64", True)
    return jax


@pytest.mark.parametrize("contact", ["rolling", "slipping"])
def test_jax_rhs_agrees_with_the_kernels_under_jit_and_vmap(contact, x64):
    jax = x64
    import jax.numpy as jnp

    from saddle_env.workprecision.equations import jax_rhs

    f = jax.jit(jax_rhs(contact == "rolling"))
    cases = list(_states(contact, n=20))
    worst = 0.0
    for sc, om, omd, y, dy in cases:
        if omd != 0.0:  # the JAX right-hand side is the benchmark's: constant Ω
            drive = np.zeros(K.DRIVE_WIDTH)
            drive[K.DRIVE_W0] = om
            full = np.zeros(K.STATE_WIDTH)
            full[:len(y)] = y
            out = np.zeros(K.STATE_WIDTH)
            K.rhs(sc.model_code, sc.params(), drive, 0.0, full, out, False)
            dy = out[:len(y)]
        args = (sc.a, sc.b, sc.radius, sc.alpha, sc.g, om)
        got = np.asarray(f(0.0, jnp.asarray(y), args))
        assert got.dtype == np.float64
        worst = max(worst, float(np.max(np.abs(got - dy) / (np.abs(dy) + 1e-3))))
    assert worst < 1e-13, worst
    # vmap over states of one scene: row by row the same as the single call.
    sc, om = cases[0][0], cases[0][1]
    args = (sc.a, sc.b, sc.radius, sc.alpha, sc.g, om)
    Y = np.array([c[3] for c in cases])
    many = np.asarray(jax.vmap(jax_rhs(contact == "rolling"), in_axes=(None, 0, None))(0.0, Y, args))
    one = np.array([np.asarray(f(0.0, jnp.asarray(row), args)) for row in Y])
    np.testing.assert_allclose(many, one, rtol=1e-12, atol=1e-14 * np.abs(one).max())


def _need(peer: Peer) -> None:
    why = missing(peer)
    if why is not None:
        pytest.skip(f"peer {peer.key}: {why}")


# The rtol each peer needs for 1e-9 m over 10 s on the benchmark's case (CVODE's Adams
# method a decade tighter than the Runge-Kutta codes; LSODA two).
RTOL = {"cvode-adams": 1e-12, "numbalsoda-lsoda": 1e-12}
CASE = Case()


@pytest.fixture(scope="module")
def references():
    return {tier: reference(CASE, tier) for tier in ("rolling", "slipping")}


@pytest.mark.parametrize("tier", ["rolling", "slipping"])
@pytest.mark.parametrize("key", [p.key for p in PEERS])
def test_peer_trajectory_matches_the_simulator_to_1e_9_m(key, tier, references):
    peer = BY_KEY[key]
    _need(peer)
    sc = CASE.scene(tier)
    states, _ = build(peer, sc, CASE.omega).single(CASE.state(tier), CASE.grid(),
                                                   RTOL.get(key, 1e-11))
    assert states.shape == (len(CASE.grid()), sc.state_size)
    error = max_distance(centre_xy(sc, states), references[tier])
    assert error < 1e-9, f"{peer.label}, {tier}: {error:.2e} m from the simulator over 10 s"


@pytest.mark.slow  # numba compiles a prange loop, JAX a vmap: 10-20 s each
@pytest.mark.parametrize("key", [p.key for p in PEERS if p.batch])
def test_batch_form_is_the_single_ball_run_ball_by_ball(key):
    peer = BY_KEY[key]
    _need(peer)
    case = Case(t_end=1.0)
    sc = case.scene("rolling")
    solver = build(peer, sc, case.omega)
    Y0 = np.array([case.state("rolling", case.x0 * f, case.y0) for f in (0.8, 1.0, 1.2)])
    many = solver.batch(Y0, case.grid(), 1e-9)
    for y0, got in zip(Y0, many):
        one, _ = solver.single(y0, case.grid(), 1e-9)
        # A vmap steps every ball with the whole batch's step sizes: close, not equal.
        np.testing.assert_allclose(got, one, rtol=0, atol=1e-9 * np.abs(one).max())
    assert not np.allclose(many[0], many[2])  # three releases, three trajectories


def test_peers_solve_the_models_they_have():
    with pytest.raises(ValueError, match="scene"):
        build(BY_KEY["scipy-lean"], Scene(contact="coulomb", mu=0.1), 20.0)
    with pytest.raises(ValueError, match="scene: the peers' equations have no drilling friction"):
        build(BY_KEY["scipy-lean"], Scene(drilling_friction=0.5), 20.0)
    with pytest.raises(ValueError, match="omega"):
        build(BY_KEY["scipy-lean"], Scene(), math.nan)


def test_peer_selection_and_missing_packages():
    assert parse_peers("none") == ()
    assert parse_peers("all")[0] == "plain" and set(parse_peers("all")) == {"plain", *BY_KEY}
    assert "scipy-lean" not in parse_peers("compiled")
    assert parse_peers("plain, diffrax-tsit5,plain") == ("plain", "diffrax-tsit5")
    with pytest.raises(ValueError, match="peers: unknown peer 'fortran77'"):
        parse_peers("plain,fortran77")
    ghost = Peer("ghost", "ghostpkg", "RK", "cfunc", ("no_such_module_here",), False)
    assert "no_such_module_here is not installed" in missing(ghost)
    assert missing(BY_KEY["scipy-lean"]) is None


def _row(solver, label, error, cost, batch=math.nan, peer=""):
    return {"tier": "rolling", "solver": solver, "label": label, "peer": peer, "rhs": "",
            "status": "ok", "error_m": error, "model_error_m": error, "us_per_sim_s": cost,
            "batch_us_per_ball_sim_s": batch, "method": "m", "kind": "adaptive", "rtol": error,
            "dt": math.nan, "max_step": math.nan, "batch_n": 1024.0, "batch_threads": 2.0,
            "compile_s": 1.5, "batch_compile_s": math.nan}


def test_peer_comparison_picks_each_solvers_cheapest_setting_meeting_the_error():
    rows = [_row("saddle_env", "dop853 rtol", 5e-7, 30.0, 40.0),
            _row("saddle_env", "dop853 rtol", 5e-10, 70.0, 80.0),
            _row("numbalsoda", "numbalsoda DOP853", 2e-6, 10.0, 12.0, "numbalsoda-dop853"),
            _row("numbalsoda", "numbalsoda DOP853", 8e-7, 20.0, 22.0, "numbalsoda-dop853"),
            _row("numbalsoda", "numbalsoda DOP853", 9e-10, 56.0, 60.0, "numbalsoda-dop853"),
            _row("scipy", "scipy DOP853", 1e-10, 9000.0),
            _row("diffrax", "diffrax Tsit5", 1e-5, 5.0, 6.0, "diffrax-tsit5")]
    out = peer_comparison(rows)
    one = out["one_ball"]
    assert one["1e-6"]["project"]["time"] == 30.0
    assert one["1e-6"]["numbalsoda-dop853"]["time"] == 20.0  # not 10: that misses 1e-6 m
    assert one["1e-6"]["numbalsoda-dop853"]["time_vs_project"] == pytest.approx(20 / 30)
    assert one["1e-9"]["numbalsoda-dop853"]["time_vs_project"] == pytest.approx(56 / 70)
    assert one["1e-9"]["plain"]["time_vs_project"] == pytest.approx(9000 / 70)
    assert one["1e-9"]["fastest"]["peer"] == "numbalsoda-dop853"
    assert one["1e-6"]["plain"]["time"] == 9000.0  # its one setting meets both errors
    assert "diffrax-tsit5" not in one["1e-6"]  # its one setting meets neither
    assert out["batch"]["1e-9"]["numbalsoda-dop853"]["time"] == 60.0
    assert "plain" not in out["batch"]["1e-9"]  # no batch form
    assert peer_comparison([r for r in rows if r["solver"] == "saddle_env"]) == {}
    # The speed-up target stays against scipy on the plain-numpy model, not its lean peers.
    lean = _row("scipy", "scipy DOP853 (python)", 1e-10, 500.0, peer="scipy-lean")
    lean["method"] = "DOP853"
    assert summarize(rows + [lean])["target_speedup"]["scipy_dop853"]["us_per_sim_s"] == 9000.0


def test_a_numba_function_without_a_module_compiles_under_the_compile_notice():
    """numbalsoda's import compiles a jitclass getter whose __module__ is None: the project's
    compile listener (saddle_env.compilation.notice) must let it through."""
    import numba

    from saddle_env.compilation import notice

    notice.install()
    ns: dict = {}
    exec("def f(x):\n    return x + 1.0\n", ns)  # exec'd code: __module__ is None
    f = ns["f"]
    f.__module__ = None
    assert numba.njit(f)(1.0) == 2.0


def test_rounds_are_merged_into_the_comparison():
    rows = [_row("saddle_env", "dop853 rtol", 5e-10, 70.0, 80.0),
            _row("numbalsoda", "numbalsoda DOP853", 9e-10, 56.0, 60.0, "numbalsoda-dop853"),
            _row("diffrax", "diffrax Tsit5", 9e-10, 50.0, 70.0, "diffrax-tsit5")]
    peers = peer_comparison(rows)
    assert peers["one_ball"]["1e-9"]["fastest"]["peer"] == "diffrax-tsit5"  # by the sweep
    merge_rounds(peers, {"one_ball": {"1e-9": {"project": 40.0, "numbalsoda-dop853": 20.0,
                                               "diffrax-tsit5": 60.0}}})
    level = peers["one_ball"]["1e-9"]
    assert level["numbalsoda-dop853"]["time_vs_project_rounds"] == pytest.approx(0.5)
    assert level["project"]["time_rounds"] == 40.0
    assert level["fastest_rounds"] == {"peer": "numbalsoda-dop853", "label": "numbalsoda DOP853",
                                       "time_vs_project": pytest.approx(0.5)}
    assert "time_rounds" not in peers["batch"]["1e-9"]["project"]  # no batch rounds given


@pytest.mark.slow  # a quick benchmark run with one compiled peer: about a minute
def test_bench_runs_a_compiled_peer_and_its_rounds(tmp_path):
    from saddle_env.workprecision import main as bench_main

    _need(BY_KEY["numbalsoda-dop853"])
    assert bench_main(["--quick", "--quiet", "--tiers", "rolling", "--peers",
                       "numbalsoda-dop853", "--jacobi-periods", "0", "--out", str(tmp_path),
                       "--no-figures"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    level = summary["peers"]["one_ball"]["1e-9"]
    assert level["numbalsoda-dop853"]["error_m"] <= 1e-9
    assert level["numbalsoda-dop853"]["time_rounds"] > 0
    assert summary["peers"]["batch"]["1e-9"]["numbalsoda-dop853"]["threads"] >= 1
    assert summary["peers_run"]["skipped"] == {}


def test_the_profile_splits_each_solvers_time_into_parts_that_add_up(tmp_path):
    # python -m saddle_env.workprecision.profile: the right-hand side, the stepping and the
    # call from Python, for the simulator and numbalsoda, at a loose tolerance (quick)
    pytest.importorskip("numbalsoda", reason="numbalsoda is not installed (the [peers] extra)")
    from saddle_env.workprecision import profile

    res = profile.profile(rtol=1e-6, rounds=1)
    for who in ("ours", "peer"):
        r = res[who]
        assert r["rhs_evals"] > 1000  # a 10 s run at rtol 1e-6: about 2,400 calls
        assert 0 < r["rhs_ns_per_call"] < 1e4
        parts = r["rhs_us_per_sim_s"] + r["stepping_us_per_sim_s"] + r["call_us_per_sim_s"]
        assert parts == pytest.approx(r["us_per_sim_s"], rel=1e-9)
        assert r["rhs_us_per_sim_s"] > 0 and r["call_us_per_sim_s"] > 0
    assert res["ours"]["steps"] * 12 + 1 == res["ours"]["rhs_evals"]  # DOP853: 12 per step
    assert res["peer_over_ours"] == pytest.approx(
        res["peer"]["us_per_sim_s"] / res["ours"]["us_per_sim_s"])


@pytest.mark.parametrize("argv, message", [(["--rtol", "0"], "--rtol must be in"),
                                           (["--rounds", "0"], "--rounds must be at least 1")])
def test_the_profile_refuses_bad_arguments_by_name(argv, message, capsys):
    from saddle_env.workprecision import profile

    with pytest.raises(SystemExit) as err:
        profile.main(argv)
    assert err.value.code == 2 and message in capsys.readouterr().err


def test_a_diffrax_peer_solves_in_float64_and_leaves_jax_in_float32():
    """The diffrax peer turns float64 on only inside its own calls: the process's other JAX
    code (SBX's float32 networks) keeps its setting, before and after a solve."""
    pytest.importorskip("diffrax", reason="diffrax is not installed (pip install 'saddle-env[peers]')")
    import jax
    import jax.numpy as jnp

    from saddle_env import Scene
    from saddle_env.workprecision import peers

    jax.config.update("jax_enable_x64", False)
    peer = next(p for p in peers.PEERS if p.key == "diffrax-tsit5")
    solver = peers.build(peer, Scene(a=0.159, R=0.02, contact="rolling"), 30.0)
    assert jnp.zeros(1).dtype == jnp.float32
    y0 = np.zeros(len(solver.scale))
    y0[:2] = 0.005, 0.0025                              # at rest, off the centre
    ys, _ = solver.single(y0, np.linspace(0.0, 0.1, 3), 1e-10)
    assert ys.dtype == np.float64 and np.all(np.isfinite(ys))
    assert jnp.zeros(1).dtype == jnp.float32
