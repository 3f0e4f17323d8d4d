"""`saddle-sim` command line."""

import csv
import io
import json
import subprocess
import sys

import numpy as np
import pytest

from saddle_env import Scene, initial_state, simulate
from saddle_env.cli import main

KEYS = ["t", "x", "y", "vx", "vy", "N_over_mg", "h", "event"]


def run_cli(args, capsys):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_json_matches_the_python_api(capsys):
    code, out, _ = run_cli(["--format", "json", "--t-end", "1", "--omega", "22",
                            "--x0", "0.004", "--y0", "0.002"], capsys)
    assert code == 0
    data = json.loads(out)
    assert list(data) == KEYS
    sc = Scene()
    tr = simulate(sc, initial_state(sc, 0.004, 0.002), 1.0, omega=22.0)
    assert data["t"] == tr.t.tolist() and data["x"] == tr.x.tolist()
    assert data["N_over_mg"] == tr.N_over_mg.tolist() and data["event"] is None
    assert len(data["t"]) == 101


def test_json_reports_the_event_and_stops_there(capsys):
    code, out, _ = run_cli(["--format", "json", "--R", "0.033", "--x0", "0.005", "--y0",
                            "0.005", "--omega", "30", "--t-end", "2"], capsys)
    data = json.loads(out)
    assert data["event"]["kind"] == "detach"
    assert data["t"][-1] <= data["event"]["t"] < data["t"][-1] + 0.01
    assert all(len(data[k]) == len(data["t"]) for k in KEYS[:-1])


def test_csv_output_to_file(tmp_path, capsys):
    path = tmp_path / "run.csv"
    code, out, _ = run_cli(["--contact", "point", "--start", "lab-rest", "--t-end", "0.5",
                            "--output", str(path)], capsys)
    assert code == 0 and out == ""
    rows = [r for r in csv.reader(io.StringIO(path.read_text())) if not r[0].startswith("#")]
    assert rows[0] == KEYS[:-1]
    body = np.array(rows[1:], dtype=float)
    assert body.shape == (51, 7)
    assert body[0, 3] == 0.0 and body[0, 4] != 0.0  # lab-rest overrides vx0/vy0


def test_time_varying_flags(capsys):
    code, out, _ = run_cli(["--format", "json", "--omega", "20", "--omega-rate", "2",
                            "--omega-amp", "1", "--omega-freq", "6", "--t-end", "1",
                            "--method", "rk4", "--dt", "0.001"], capsys)
    assert code == 0
    h = json.loads(out)["h"]
    assert max(h) - min(h) > 1e-6  # energy is pumped in by the changing speed


@pytest.mark.parametrize("args, message", [
    (["--R", "0.1"], "R must satisfy"),
    (["--a", "-1"], "a must be > 0"),
    (["--contact", "sliding"], "invalid choice"),
    (["--omega", "nan"], "omega must be finite"),
    (["--t-end", "0"], "t_end must be > 0"),
    (["--rtol", "5"], "rtol must satisfy"),
    (["--method", "rk4", "--rtol", "1e-6"], "no error estimate"),
    (["--rim", "nan"], "rim"),
    (["--x0", "abc"], "invalid float"),
    (["--format", "xml"], "invalid choice"),
    (["--output", "/nonexistent/dir/out.csv"], "cannot write"),
])
def test_bad_flags_exit_2_with_a_short_message(args, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert len(err.splitlines()) <= 3


def test_console_script_runs():
    proc = subprocess.run([sys.executable, "-m", "saddle_env.cli", "--t-end", "0.05",
                           "--R", "0.2"], capture_output=True, text=True)
    assert proc.returncode == 2 and "R must satisfy" in proc.stderr
    assert "Traceback" not in proc.stderr
