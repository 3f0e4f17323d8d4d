"""The environment throughput measurement (``python -m saddle_env.envs.throughput``) writes its
figures and rejects bad arguments."""

from __future__ import annotations

import csv
import json

import pytest

from saddle_env.envs import throughput


def test_throughput_writes_json_csv_and_figure(tmp_path, capsys):
    out = tmp_path / "env"
    rc = throughput.main(["--seconds", "0.05", "--sizes", "4,8", "--num-envs", "8",
                         "--skip-cold", "--out", str(out)])
    assert rc == 0
    data = json.loads((out / "throughput.json").read_text())
    for key in ("saddle_steps_per_s", "cartpole_steps_per_s", "single_ratio",
                "saddle_vector_steps_per_s", "saddle_vector_scalar_steps_per_s",
                "cartpole_vector_steps_per_s", "first_step_warm_s"):
        assert data[key] > 0, key
    assert data["vector_num_envs"] == 8 and "first_step_cold_s" not in data
    assert data["vector_ratio"] == pytest.approx(data["saddle_vector_steps_per_s"]
                                                 / data["cartpole_vector_steps_per_s"])
    assert data["single_ratio"] == pytest.approx(data["saddle_steps_per_s"]
                                                 / data["cartpole_steps_per_s"])
    # as users make them: gym.make's wrappers, gym.make_vec's default (the native vector env)
    assert data["single_made_as"] == "<TimeLimit<SaddleTrapEnv<SaddleTrap-v0>>>"
    assert data["vector_made_as"].startswith("SaddleTrapVectorEnv(SaddleTrap-v0, num_envs=8")
    assert len(data["date"]) == 10 and data["machine"]["gymnasium"]
    rows = list(csv.DictReader(open(out / "batch_sizes.csv")))
    assert [int(r["num_envs"]) for r in rows] == [4, 8]
    assert all(float(r["saddle_steps_per_s"]) > 0 for r in rows)
    assert (out / "throughput.png").stat().st_size > 1000
    assert "vector env, 8 balls" in capsys.readouterr().out


@pytest.mark.parametrize("args", [["--seconds", "0"], ["--seconds", "nan"], ["--num-envs", "0"],
                                  ["--sizes", "16,x"], ["--sizes", "0,4"], ["--bogus"]])
def test_throughput_rejects_bad_arguments(args, capsys):
    with pytest.raises(SystemExit) as e:
        throughput.main(args)
    assert e.value.code == 2
    assert "error" in capsys.readouterr().err
