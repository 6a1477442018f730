"""Smoke test of benchmarks/airframes.py (the whole table is `benchmarks/airframes.py run`): one
airframe, one episode per flight, both controllers; the table's shape, and the two flights whose
outcome is known (RAPTOR and our SIH policy hover PX4's SIH quad-X, docs/px4.md)."""

import airframes


def test_one_airframe_gives_every_flight_for_both_controllers(tmp_path):
    data = airframes.run(tmp_path / "a.json", ["px4_sih_quadx"], episodes=1)
    rows = data["airframes"]["px4_sih_quadx"]
    for controller in ("raptor", "ours"):
        assert set(rows[controller]) == set(airframes.FLIGHTS)
        assert all("refused" not in r for r in rows[controller].values()), rows[controller]
        hover = rows[controller]["hover"]
        assert hover["success_rate"] == 1.0 and hover["mean_error_last_2s_m"] <= 0.05, hover
    assert (tmp_path / "a.json").is_file()
