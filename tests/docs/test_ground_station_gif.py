"""docs/ground_station_gif.py draws a commanded flight's trace (benchmarks/commanded_flight.py's CSV and
JSON) as a GIF: here on a tiny synthetic flight in tmp_path, a few seconds."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("docs_ground_station_gif", ROOT / "docs" / "ground_station_gif.py")
gif = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = gif
_spec.loader.exec_module(gif)

GOALS = {"takeoff": [0.0, 0.0, 2.5], "goto": [3.0, 0.0, 2.5], "mission": [[3.0, 2.0, 2.5], [1.0, 2.0, 3.0]]}
COLUMNS = ("t_s", "east_m", "north_m", "up_m", "yaw_rad", "armed", "mode", "phase")


def synthetic_flight(tmp_path: Path, seconds: float = 3.0) -> Path:
    """A JSON with goals and its trace beside it: `seconds` of flight at 10 Hz from t = 1 s, through
    every phase the benchmark writes."""
    out = tmp_path / "flight.json"
    out.write_text(json.dumps({"goals_enu_m": GOALS}))
    t = 1.0 + np.arange(round(seconds * 10) + 1) / 10
    phases = ["disarmed", "take-off", "hold", "goto", "mission item 1", "mission item 2", "hold", "land", "disarmed"]
    with open(tmp_path / "flight_trace.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for k, tk in enumerate(t):
            s = k / (len(t) - 1)
            phase = phases[min(int(s * len(phases)), len(phases) - 1)]
            w.writerow([f"{tk:.2f}", 3 * s, 2 * s, 2.5 * np.sin(np.pi * s), 0.0, 1, "Hold", phase])
    return out


def test_the_gif_has_one_frame_per_speed_over_fps_seconds_its_size_and_is_deterministic(tmp_path):
    image = pytest.importorskip("PIL.Image")
    flight = synthetic_flight(tmp_path, seconds=3.0)
    out, again = tmp_path / "img" / "flight.gif", tmp_path / "again.gif"
    assert gif.main(["--json", str(flight), "--out", str(out)]) == 0
    expected = 3 * gif.FPS / gif.SPEED + 1  # frames at 0, SPEED/FPS, ... 3 s of flight
    with image.open(out) as im:
        assert im.size == gif.SIZE_PX
        assert im.n_frames == expected
        im.seek(im.n_frames - 1)
        rgb = np.asarray(im.convert("RGB"), dtype=float)
        assert rgb.std() > 10 and len(np.unique(rgb.reshape(-1, 3), axis=0)) > 8, "the last frame looks blank"
    assert out.stat().st_size < 1_500_000
    assert gif.main(["--json", str(flight), "--csv", str(tmp_path / "flight_trace.csv"), "--out", str(again)]) == 0
    assert again.read_bytes() == out.read_bytes()  # same data, same file


def test_a_trace_without_positions_is_one_line_and_exit_1(tmp_path, capsys):
    flight = synthetic_flight(tmp_path)
    (tmp_path / "flight_trace.csv").write_text("t_s,phase\n1.0,disarmed\n")
    assert gif.main(["--json", str(flight), "--out", str(tmp_path / "x.gif")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "flight_trace.csv" in err and "east_m" in err, err
    assert not (tmp_path / "x.gif").exists()
