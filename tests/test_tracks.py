"""The track format (saddle_env.calibrate.tracks): exact round trips, and every refusal names the
file, the line and the rule."""

import numpy as np
import pytest

from saddle_env.calibrate import Track, TrackError, read_track, read_tracks, write_track
from saddle_env.calibrate.tracks import MAX_BYTES, parse_track


def _track(n=50, seed=0, **optional):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(1 / 240, 1 / 60, n))          # a non-uniform frame clock
    return Track(t, 0.02 * np.sin(7 * t) + rng.normal(0, 1e-4, n),
                 0.015 * np.cos(5 * t) + rng.normal(0, 1e-4, n), **optional)


def test_a_written_track_reads_back_equal_bit_for_bit_with_lost_frames_and_every_channel(tmp_path):
    n = 40
    tr = _track(n, omega=np.full(n, 21.5), voltage=np.linspace(0, 24, n),
                theta=np.linspace(0, 30, n))
    x, y = tr.x.copy(), tr.y.copy()
    x[[3, 4, 20]] = y[[3, 4, 20]] = np.nan                    # tracking lost the ball
    volts = tr.voltage.copy()
    volts[7] = np.nan                                          # one missing reading
    tr = Track(tr.t, x, y, omega=tr.omega, voltage=volts, theta=tr.theta)
    back = read_track(write_track(tmp_path / "r.csv", tr, comments=["camera 120 fps"]))
    for name in ("t", "x", "y", "omega", "voltage", "theta"):
        assert np.array_equal(getattr(back, name), getattr(tr, name), equal_nan=True), name
    assert back.tracked.sum() == n - 3 and back.channels == tr.channels
    assert (tmp_path / "r.csv").read_text().startswith("# camera 120 fps\nt,x,y,omega,voltage,theta\n")


def test_optional_columns_may_be_absent_and_in_any_order():
    tr = parse_track("y,t,x,omega\n0.01,0,0.02,20\n0.011,0.01,0.019,20\n0.012,0.02,0.018,\n")
    assert tr.voltage is None and tr.theta is None
    assert list(tr.x) == [0.02, 0.019, 0.018] and np.isnan(tr.omega[2])


@pytest.mark.parametrize("text, message", [
    ("t,x\n0,0\n", "lacks ['y']"),
    ("t,x,y,speed\n0,0,0,1\n", "unknown column(s) ['speed']"),
    ("t,x,y,x\n0,0,0,0\n", "appear twice"),
    ("t,x,y\n0,0,0\n0.1,0\n", "line 3: 2 cells"),
    ("t,x,y\n0,0,0\n0.1,abc,0\n", "line 3: 'x' = 'abc' is not a number"),
    ("# a comment\nt,x,y\n0,0,0\n0.1,0,0\n0.05,0,0\n0.2,0,0\n", "line 5: 't' = 0.05 s does not"),
    ("t,x,y\n0,0,0\n0,0,0\n0.1,0,0\n", "line 3: 't' = 0.0 s does not"),
    ("t,x,y\n0,0,0\n,0,0\n0.1,0,0\n", "line 3: 't' must be a finite time"),
    ("t,x,y\n0,0,0\n0.1,0,inf\n0.2,0,0\n", "line 3: 'y' is infinite"),
    ("t,x,y\n0,0,0\n0.1,,0\n0.2,0,0\n0.3,0,0\n", "line 3: only one of 'x' and 'y'"),
    ("t,x,y\n0,0,0\n0.1,,\n0.2,,\n", "1 frames with a position"),
    ("t,x,y\n0,312,240\n0.1,313,240\n0.2,314,241\n", "line 2: 'x' = 312.0; positions are in metres"),
    ("# only a comment\n", "no header row"),
])
def test_a_bad_file_is_refused_naming_its_line_and_rule(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(TrackError) as err:
        read_track(path)
    assert message in str(err.value) and str(path) in str(err.value), str(err.value)


def test_files_that_are_not_tracks_are_refused_before_they_are_parsed(tmp_path):
    big = tmp_path / "big.csv"
    with big.open("wb") as f:
        f.truncate(MAX_BYTES + 1)
    with pytest.raises(TrackError, match="at most"):
        read_track(big)
    binary = tmp_path / "video.csv"
    binary.write_bytes(b"t,x,y\n\xff\xfe\x00")
    with pytest.raises(TrackError, match="not UTF-8"):
        read_track(binary)
    with pytest.raises(TrackError, match="cannot read"):
        read_track(tmp_path / "missing.csv")


def test_a_run_folder_reads_every_track_in_name_order(tmp_path):
    for i in (2, 0, 1):
        write_track(tmp_path / f"release_{i}.csv", _track(seed=i))
    (tmp_path / "notes.txt").write_text("not a track")
    tracks = read_tracks(tmp_path)
    assert [t.source.rsplit("/", 1)[-1] for t in tracks] == [f"release_{i}.csv" for i in range(3)]
    assert np.array_equal(tracks[1].x, _track(seed=1).x)
    (tmp_path / "empty").mkdir()
    with pytest.raises(TrackError, match="no \\*.csv"):
        read_tracks(tmp_path / "empty")


def test_a_track_built_from_arrays_keeps_the_same_rules():
    t = np.linspace(0, 1, 5)
    with pytest.raises(TrackError, match="'x' must be a 1-D array as long as 't'"):
        Track(t, np.zeros(4), np.zeros(5))
    with pytest.raises(TrackError, match="row 2: 't'"):
        Track(np.array([0, 0.1, 0.1, 0.2, 0.3]), np.zeros(5), np.zeros(5))
    tr = Track(t, np.zeros(5), np.zeros(5))
    with pytest.raises(ValueError):
        tr.x[0] = 1.0                                          # read-only: a track is a record
