"""quad-compare: the sweep it plans, the pool that runs it (never more processes than --workers),
a clear refusal of --engine ray without Ray, and a report that rewrites only its own section."""

import importlib.util
import json
import threading
import time

import numpy as np
import pytest

from quadpilot.studies import compare, compare_report
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.runs.runlog import MetricsLog, write_json


@pytest.mark.skipif(importlib.util.find_spec("ray") is not None, reason="Ray is installed here")
def test_engine_ray_without_ray_is_a_one_line_error_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert compare.main(["run", "--engine", "ray", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("quad-compare: error: --engine ray needs Ray"), err
    assert "pip install 'quadpilot[cluster]'" in err and "Traceback" not in err
    assert not out.exists()


def test_plan_interleaves_algorithms_with_the_same_options(tmp_path):
    args = compare.build_parser().parse_args(["run", "--seeds", "3,4", "--out", str(tmp_path), "--total-steps", "9"])
    specs = compare.plan(args)
    assert [(s.algo, s.seed) for s in specs] == [("ppo", 3), ("sb3", 3), ("ppo", 4), ("sb3", 4)]
    for s in specs:
        argv = list(s.argv)
        assert argv[argv.index("--algo") + 1] == s.algo and argv[argv.index("--threads") + 1] == "1"
        assert argv[argv.index("--preset") + 1] == "fast" and argv[argv.index("--total-steps") + 1] == "9"
        assert argv[argv.index("--out") + 1] == s.out == str(tmp_path / f"{s.algo}-seed{s.seed}")
    assert args.workers == 2 and args.engine == "process"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--out", "x", "--algos", "ppo,dqn"], "unknown ['dqn']"),
        (["run", "--out", "x", "--workers", "0"], "--workers must be ≥ 1"),
        (["run", "--out", "x", "--seeds", "0,0"], "repeated"),
        (["report"], "required: DIR"),
    ],
)
def test_bad_requests_exit_2(args, message, capsys):
    assert compare.main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err


def test_the_pool_runs_every_pair_at_most_workers_at_a_time_and_keeps_finished_runs(tmp_path, monkeypatch):
    running, peak, lock = [0], [0], threading.Lock()

    def fake_run_one(spec):
        with lock:
            running[0] += 1
            peak[0] = max(peak[0], running[0])
        time.sleep(0.05)
        (tmp_path / "s" / f"{spec.algo}-seed{spec.seed}").mkdir(parents=True)
        (tmp_path / "s" / f"{spec.algo}-seed{spec.seed}" / "eval.json").write_text("{}")
        with lock:
            running[0] -= 1
        return {"algo": spec.algo, "seed": spec.seed, "dir": spec.out, "returncode": 0, "wall_s": 0.05}

    monkeypatch.setattr(compare, "run_one", fake_run_one)
    assert compare.main(["run", "--seeds", "0,1,2", "--out", str(tmp_path / "s")]) == 0
    assert peak[0] == 2
    sweep = json.loads((tmp_path / "s" / compare.SWEEP).read_text())
    assert len(sweep["runs"]) == 6 and sweep["threads"] == 1 and sweep["workers"] == 2
    assert compare.main(["run", "--seeds", "0,1,2,3", "--out", str(tmp_path / "s")]) == 0  # only seed 3 is new
    sweep = json.loads((tmp_path / "s" / compare.SWEEP).read_text())
    assert sorted((r["algo"], r["seed"]) for r in sweep["runs"]) == sorted(
        (a, s) for a in ("ppo", "sb3") for s in range(4)
    )


def fake_run(directory, algo, seed, reach_at):
    """A finished run directory as quad-train writes it: 10 updates of 1,000 steps."""
    directory.mkdir(parents=True)
    cfg = PPOConfig(seed=seed, total_steps=10_000)
    write_json(
        directory / "config.json", {"algo": algo, "ppo": cfg.to_json()} if algo == "sb3" else {"ppo": cfg.to_json()}
    )
    with MetricsLog(directory / "metrics.csv") as log:
        for k in range(1, 11):
            log.write(
                {
                    "global_step": 1000 * k,
                    "update": k,
                    "time_s": 0.5 * k,
                    "ep_return": float(k) if k % 2 else float("nan"),
                    "eval_success_rate": (1.0 if k >= reach_at else 0.1 * k) if k % 2 == 0 else None,
                }
            )
    first = {"global_step": 1000 * reach_at, "train_time_s": 0.5 * reach_at, "success_rate": 1.0}
    write_json(
        directory / "eval.json",
        {
            "global_step": 10_000,
            "train_time_s": 5.0,
            "first_success": first if reach_at <= 10 else None,
            "success_rate": 1.0 if reach_at <= 10 else 0.5,
            "mean_return": 300.0,
            "mean_error_last_window_m": 0.01,
            "time_breakdown_s": {"fractions": {"env_s": 0.1, "inference_s": 0.1, "update_s": 0.8}},
        },
    )


def fake_sweep(sweep_dir):
    for seed, (p, s) in enumerate([(4, 6), (4, 8), (6, 99)]):
        fake_run(sweep_dir / f"ppo-seed{seed}", "ppo", seed, p)
        fake_run(sweep_dir / f"sb3-seed{seed}", "sb3", seed, s)
    write_json(
        sweep_dir / compare.SWEEP,
        {
            "task": "hover",
            "preset": "fast",
            "seeds": [0, 1, 2],
            "eval_every": 2,
            "threads": 1,
            "workers": 2,
            "engine": "process",
            "nice": 10,
            "command": "quad-compare run --out sweep",
            "machine": {"cpu": "a CPU", "cores": 2},
            "started": "2026-01-01T00:00:00+00:00",
        },
    )


def test_report_writes_figures_and_only_its_own_section(tmp_path):
    sweep_dir = tmp_path / "sweep"
    fake_sweep(sweep_dir)
    doc = tmp_path / "docs" / "comparison.md"
    doc.parent.mkdir()
    begin, end = compare_report.BEGIN, compare_report.END
    doc.write_text(f"# Title\n\nmy analysis\n\n{begin}\nold tables\n{end}\n\nmore prose\n")
    figures = tmp_path / "docs" / "comparison"
    assert compare.main(["report", str(sweep_dir), "--doc", str(doc), "--figures", str(figures)]) == 0
    text = doc.read_text()
    assert text.startswith("# Title\n\nmy analysis\n\n" + compare_report.BEGIN) and text.endswith(
        compare_report.END + "\n\nmore prose\n"
    )
    assert "old tables" not in text and text.count(compare_report.BEGIN) == 1
    png = figures / "hover-fast.png"
    assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size < 200_000
    assert "](comparison/hover-fast.png)" in text
    assert "not reached within 0.01 M steps" not in text  # every SB3 seed but one reached it
    assert "4,667 (4,000–6,000), 2 of 3 seeds" not in text
    assert "| ours (PPO from scratch) | 3 |" in text and "4,667 (4,000–6,000)" in text
    assert "7,000 (6,000–8,000), 2 of 3 seeds" in text  # SB3: seed 2 never reached the bar
    assert "`vf_coef = 0.5` | `vf_coef = 0.25`" in text  # the matched-settings table
    assert "quad-compare run --out sweep" in text
    # a second report replaces its section, nothing else
    assert compare.main(["report", str(sweep_dir), "--doc", str(doc), "--figures", str(figures)]) == 0
    assert doc.read_text().count(compare_report.BEGIN) == 1 and "more prose" in doc.read_text()


def test_report_by_default_writes_beside_the_sweeps_not_the_repository_page(tmp_path, monkeypatch, capsys):
    """Without --doc and --figures the report goes beside the first sweep: the tracked
    docs/comparison.md (and docs/comparison/) is rewritten only when named."""
    from pathlib import Path

    repo = Path(__file__).parents[2]
    page, figures = repo / "docs" / "comparison.md", repo / "docs" / "comparison"
    before = (page.read_bytes(), sorted((p.name, p.stat().st_mtime_ns) for p in figures.iterdir()))
    sweeps = tmp_path / "runs" / "compare"
    fake_sweep(sweeps / "hover-fast")
    monkeypatch.chdir(repo)  # as the documented command runs it, from the repository root
    assert compare.main(["report", str(sweeps / "hover-fast")]) == 0
    assert (page.read_bytes(), sorted((p.name, p.stat().st_mtime_ns) for p in figures.iterdir())) == before
    written = (sweeps / "comparison.md").read_text()
    assert compare_report.BEGIN in written and "](comparison/hover-fast.png)" in written
    assert (sweeps / "comparison" / "hover-fast.png").is_file()
    assert f"wrote {sweeps / 'comparison.md'}" in capsys.readouterr().out


def test_forward_fill_and_band():
    y = compare_report._ffill(np.array([np.nan, 1.0, np.nan, 3.0, np.nan]))
    assert np.isnan(y[0]) and list(y[1:]) == [1.0, 1.0, 3.0, 3.0]
    grid = np.array([0.0, 1.0, 2.0])
    mean, lo, hi = compare_report._band(
        [(np.array([0.0, 2.0]), np.array([0.0, 2.0])), (grid, np.array([2.0, 2.0, 2.0]))], grid
    )
    assert list(mean) == [1.0, 1.5, 2.0] and list(lo) == [0.0, 1.0, 2.0] and list(hi) == [2.0, 2.0, 2.0]


def test_a_real_sweep_of_one_seed_runs_both_algorithms(tmp_path):
    """Two real quad-train processes side by side, one update of 8,192 steps each (~5 s)."""
    out = tmp_path / "s"
    assert compare.main(["run", "--seeds", "0", "--total-steps", "8192", "--out", str(out)]) == 0
    for algo in ("ppo", "sb3"):
        ev = json.loads((out / f"{algo}-seed0" / "eval.json").read_text())
        assert ev["global_step"] == 8192 and ev["episodes"] == 100


def test_the_matched_settings_tables_of_docs_comparison_md_are_the_code_presets():
    """docs/comparison.md's matched-settings tables are those of the runs its commands train, as
    quad-train reads the preset now (`compare.planned_config`): a preset or a field that changes
    shows here, not only in a report made after a new sweep."""
    import shlex
    from pathlib import Path

    doc = (Path(__file__).parents[2] / "docs" / "comparison.md").read_text(encoding="utf-8")
    lines = [line for line in doc.splitlines() if line.startswith("nice -n 10 .venv/bin/quad-compare run ")]
    runs = [shlex.split(line.split("quad-compare run ", 1)[1]) for line in lines]
    assert len(runs) == 3
    for argv in runs:
        preset = argv[argv.index("--preset") + 1]
        table = "\n".join(compare_report.settings_section(compare.planned_config(argv), preset)).strip("\n")
        assert table in doc, f"docs/comparison.md: the matched settings of preset {preset} are not the code's"
    assert ".venv/bin/quad-compare report" in doc and "--doc docs/comparison.md --figures docs/comparison" in doc
