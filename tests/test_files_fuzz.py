"""Property tests over files that come from elsewhere: track CSVs
(`saddle_env.calibrate.tracks`) and exported policy folders (`saddle_env.deploy`).

Every drawn input either reads or is refused with the reader's own ValueError (`TrackError`,
`PolicyFolderError`) in one line that names the file; nothing else is raised, nothing runs
past a deadline, and nothing is written beside the input. `tests/test_hostile_files.py` holds
the crafted cases; these are drawn. The default suite draws a few dozen examples per test
(a few seconds each); the ``slow`` variants draw many more.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from saddle_env.calibrate.tracks import (
    COLUMNS,
    MAX_POSITION,
    MIN_POSITIONS,
    Track,
    TrackError,
    parse_track,
    read_track,
    write_track,
)

# A deadline far above any honest read (milliseconds) that still catches a hang.
_FAST = settings(max_examples=60, deadline=timedelta(seconds=20), derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
_LONG = settings(max_examples=1000, deadline=timedelta(seconds=20),
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


# -- track CSVs -------------------------------------------------------------------------------

CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-0.2, 0.2).map(repr),
    st.sampled_from(["", " ", "nan", "NaN", "inf", "-inf", "1e309", "0x10", "1_000", "1,5",
                     "\"1\"", "#", "None", "true", "1e-400", "\u00a0"]),
    st.text(alphabet="0123456789.eE+-naifx #\"\t", max_size=8),
)
HEADERS = st.lists(st.sampled_from([*COLUMNS, "T", " x ", "X", "z", "", "#t", "t,x"]),
                   max_size=8)


@st.composite
def track_texts(draw) -> str:
    header = draw(HEADERS)
    width = st.integers(max(len(header) - 1, 0), len(header) + 1)
    rows = draw(st.lists(width.flatmap(lambda n: st.lists(CELLS, min_size=n, max_size=n)),
                         max_size=12))
    lines = [",".join(header)] + [",".join(r) for r in rows]
    if draw(st.booleans()):
        lines.insert(draw(st.integers(0, len(lines))), "# " + draw(st.text(max_size=10)))
    newline = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    return draw(st.sampled_from(["", "\ufeff"])) + newline.join(lines)


def _check_track_outcome(read, source: str) -> None:
    try:
        track = read()
    except TrackError as exc:
        message = str(exc)
        assert source in message and "\n" not in message, message
        return
    assert isinstance(track, Track)
    t = track.t
    assert np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)
    seen = np.isfinite(track.x) & np.isfinite(track.y)
    assert int(seen.sum()) >= MIN_POSITIONS
    assert np.all(np.abs(track.x[seen]) <= MAX_POSITION)
    assert np.all(np.abs(track.y[seen]) <= MAX_POSITION)
    assert np.array_equal(np.isnan(track.x), np.isnan(track.y))


def _parse_case(text: str) -> None:
    _check_track_outcome(lambda: parse_track(text, "drawn.csv"), "drawn.csv")


def _bytes_case(folder: Path, raw: bytes) -> None:
    path = folder / "drawn.csv"
    path.write_bytes(raw)
    before = _files(folder)
    _check_track_outcome(lambda: read_track(path), str(path))
    assert _files(folder) == before


@st.composite
def valid_tracks(draw) -> Track:
    n = draw(st.integers(MIN_POSITIONS, 30))
    steps = draw(st.lists(st.floats(1e-4, 0.1), min_size=n, max_size=n))
    t = np.cumsum(steps) + draw(st.floats(-10.0, 10.0))
    coord = st.floats(-MAX_POSITION, MAX_POSITION)
    x = np.array(draw(st.lists(coord, min_size=n, max_size=n)))
    y = np.array(draw(st.lists(coord, min_size=n, max_size=n)))
    lost = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    lost[:MIN_POSITIONS] = False   # enough tracked frames to be a track
    x[lost] = y[lost] = np.nan
    extra = {}
    for name in draw(st.lists(st.sampled_from(["omega", "voltage", "theta"]), unique=True)):
        extra[name] = np.array(draw(st.lists(st.one_of(st.floats(-1e3, 1e3), st.just(math.nan)),
                                             min_size=n, max_size=n)))
    return Track(t=t, x=x, y=y, **extra)


def _roundtrip_case(folder: Path, track: Track, comment: str) -> None:
    path = folder / "out" / "release.csv"
    path.parent.mkdir(exist_ok=True)
    before = _files(folder)
    write_track(path, track, comments=[comment])
    assert _files(folder) == before | {"out/release.csv"}, "a write leaves only its file"
    back = read_track(path)
    for name in track.channels:
        assert np.array_equal(getattr(back, name), getattr(track, name), equal_nan=True), name
    path.unlink()


@_FAST
@given(text=track_texts())
def test_track_text_reads_or_is_a_named_error(text):
    _parse_case(text)


@_FAST
@given(raw=st.binary(max_size=300))
def test_track_bytes_read_or_are_a_named_error(tmp_path, raw):
    _bytes_case(tmp_path, raw)


@_FAST
@given(track=valid_tracks(), comment=st.text(max_size=20))
def test_a_written_track_reads_back_equal(tmp_path, track, comment):
    _roundtrip_case(tmp_path, track, comment)


@pytest.mark.slow
@_LONG
@given(text=track_texts())
def test_track_text_reads_or_is_a_named_error_long(text):
    _parse_case(text)


@pytest.mark.slow
@_LONG
@given(track=valid_tracks(), comment=st.text(max_size=20))
def test_a_written_track_reads_back_equal_long(tmp_path, track, comment):
    _roundtrip_case(tmp_path, track, comment)


# -- exported policy folders ----------------------------------------------------------------

@pytest.fixture(scope="module")
def honest_folder(tmp_path_factory):
    """A small PPO model exported as saddle-export exports it: the template of the drawn
    folders."""
    sb3 = pytest.importorskip("stable_baselines3")
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from agents.evaluation.export import export_policy
    from saddle_env.envs.sb3 import SaddleTrapSB3VecEnv

    root = tmp_path_factory.mktemp("honest")
    model = sb3.PPO("MlpPolicy", SaddleTrapSB3VecEnv(num_envs=2), n_steps=8, batch_size=16,
                    seed=0, policy_kwargs={"net_arch": [8, 8]}, device="cpu")
    model.save(root / "model.zip")
    (root / "model.json").write_text(json.dumps(
        {"algo": "ppo", "env_id": "SaddleTrap-v0", "env_kwargs": {}, "frame_stack": 1,
         "normalize": False}))
    return export_policy(root / "model.zip", root / "folder")


JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
              st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
              st.sampled_from(["policy.onnx", "../policy.onnx", "/etc/passwd", "clip", "unscale",
                               "ppo", "SaddleTrap-v0", "0" * 64])),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=8), inner,
                                                                 max_size=4),
    max_leaves=12)


def _paths(node, prefix=()) -> list[tuple]:
    """Every key path of a JSON object (dicts only)."""
    out = []
    if isinstance(node, dict):
        for k, v in node.items():
            out.append((*prefix, k))
            out += _paths(v, (*prefix, k))
    return out


@st.composite
def policy_json_edits(draw, template: dict) -> dict:
    """The honest policy.json with one to three keys replaced by any JSON value, or deleted."""
    data = json.loads(json.dumps(template))
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(data)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        node = data
        for key in path[:-1]:
            node = node[key]
        if draw(st.booleans()):
            node[path[-1]] = draw(JSON_VALUES)
        else:
            del node[path[-1]]
    return data


def _folder_case(honest: Path, scratch: Path, edit_json=None, graph: bytes | None = None) -> None:
    from saddle_env.deploy import Controller, PolicyFolderError

    folder = scratch / "drawn"
    shutil.rmtree(folder, ignore_errors=True)
    shutil.copytree(honest, folder)
    data = json.loads((folder / "policy.json").read_text())
    if graph is not None:   # the graph's digest follows it, so the graph itself is read
        (folder / "policy.onnx").write_bytes(graph)
        data["onnx"]["sha256"] = hashlib.sha256(graph).hexdigest()
    if edit_json is not None:
        data = edit_json
    (folder / "policy.json").write_text(json.dumps(data))
    before = _files(scratch)
    try:
        controller = Controller.from_dir(folder)
    except PolicyFolderError as exc:
        message = str(exc)
        assert str(folder) in message and "\n" not in message, message
    else:   # a folder that reads acts on an observation inside its box
        spec = controller.spec
        obs = np.clip(np.zeros(spec.observation_dim), spec.observation_low, spec.observation_high)
        action = controller.act(obs.astype(np.float32))
        assert action.shape == (spec.action_dim,) and np.all(np.isfinite(action))
    assert _files(scratch) == before, "reading a folder writes nothing"


def test_the_honest_folder_reads(honest_folder, tmp_path):
    from saddle_env.deploy import Controller

    _folder_case(honest_folder, tmp_path)
    assert Controller.from_dir(honest_folder) is not None


def _nan_weights(model) -> None:
    from onnx import numpy_helper

    weight = next(t for t in model.graph.initializer if len(t.dims) == 2)
    nan = np.full_like(numpy_helper.to_array(weight), np.nan)
    weight.CopyFrom(numpy_helper.from_array(nan, weight.name))


def _gather_out_of_bounds(model) -> None:
    # the index the batch size is read with (Gather of the input's shape) points past it
    from onnx import numpy_helper

    gather = next(n for n in model.graph.node if n.op_type == "Gather")
    const = next(n for n in model.graph.node if n.output[0] == gather.input[1])
    value = next(a for a in const.attribute if a.name == "value")
    value.t.CopyFrom(numpy_helper.from_array(np.array(2, dtype=np.int64), value.t.name))


@pytest.mark.parametrize("edit, words", [(_nan_weights, "non-finite action"),
                                         (_gather_out_of_bounds, "does not run")])
def test_a_graph_that_cannot_act_is_refused_when_read(honest_folder, tmp_path, edit, words):
    # Found by the long fuzz test: a damaged graph can pass every static check and fail only
    # when run, or act with NaN; the folder is refused by name when read, not at a first step
    import onnx

    from saddle_env.deploy import Controller, PolicyFolderError

    model = onnx.load_model_from_string((honest_folder / "policy.onnx").read_bytes())
    edit(model)
    raw = model.SerializeToString()
    folder = tmp_path / "edited"
    shutil.copytree(honest_folder, folder)
    (folder / "policy.onnx").write_bytes(raw)
    data = json.loads((folder / "policy.json").read_text())
    data["onnx"]["sha256"] = hashlib.sha256(raw).hexdigest()
    (folder / "policy.json").write_text(json.dumps(data))
    with pytest.raises(PolicyFolderError) as exc:
        Controller.from_dir(folder)
    message = str(exc.value)
    assert words in message and str(folder) in message and "\n" not in message


@settings(_FAST, max_examples=40)
@given(data=st.data())
def test_a_drawn_policy_json_reads_or_is_a_named_error(honest_folder, tmp_path, data):
    template = json.loads((honest_folder / "policy.json").read_text())
    _folder_case(honest_folder, tmp_path, edit_json=data.draw(policy_json_edits(template)))


def _damaged_graph_case(honest: Path, scratch: Path, data) -> None:
    raw = bytearray((honest / "policy.onnx").read_bytes())
    how = data.draw(st.sampled_from(["flip", "truncate", "append"]))
    if how == "flip":
        for i in data.draw(st.lists(st.integers(0, len(raw) - 1), min_size=1, max_size=8)):
            raw[i] ^= data.draw(st.integers(1, 255))
    elif how == "truncate":
        raw = raw[:data.draw(st.integers(0, len(raw) - 1))]
    else:
        raw += data.draw(st.binary(min_size=1, max_size=64))
    _folder_case(honest, scratch, graph=bytes(raw))


@settings(_FAST, max_examples=40)
@given(data=st.data())
def test_a_damaged_graph_reads_or_is_a_named_error(honest_folder, tmp_path, data):
    _damaged_graph_case(honest_folder, tmp_path, data)


@pytest.mark.slow
@settings(_LONG, max_examples=400)
@given(data=st.data())
def test_a_drawn_policy_json_reads_or_is_a_named_error_long(honest_folder, tmp_path, data):
    template = json.loads((honest_folder / "policy.json").read_text())
    _folder_case(honest_folder, tmp_path, edit_json=data.draw(policy_json_edits(template)))


@pytest.mark.slow
@settings(_LONG, max_examples=400)
@given(data=st.data())
def test_a_damaged_graph_reads_or_is_a_named_error_long(honest_folder, tmp_path, data):
    _damaged_graph_case(honest_folder, tmp_path, data)
