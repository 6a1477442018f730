"""The package flies without the repository: a wheel built from this tree, installed in a fresh
virtual environment with the runtime's dependencies only (no torch), lists its shipped models and
flies every one of them by name with `quad-sitl --model NAME`."""

import os
import re
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
MODELS = sorted(d.name for d in (ROOT / "models").iterdir() if (d / "policy.onnx").is_file())


def policy_file(name: str) -> str:
    """What quad-sitl flies for a shipped model: policy.tar for one of PX4 mc_raptor's contract."""
    return "policy.tar" if (ROOT / "models" / name / "policy.tar").is_file() else "policy.onnx"


def _run(cmd, cwd, timeout=900):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False)


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    # from a copy of the tree without build output: setuptools would reuse a stale build/ of the checkout
    skip = shutil.ignore_patterns(".git", ".venv", "venv", "build", "dist", "runs", "mutants", "*.egg-info", ".*cache")
    shutil.copytree(ROOT, tmp / "tree", symlinks=True, ignore=skip)
    built = _run([sys.executable, "-m", "pip", "wheel", "./tree", "--no-deps", "-q", "-w", str(tmp / "dist")], tmp)
    assert built.returncode == 0, built.stderr[-2000:]
    (wheel,) = (tmp / "dist").glob("quadpilot-*.whl")
    venv.create(tmp / "env", with_pip=True)
    py = tmp / "env" / "bin" / "python"
    got = _run([str(py), "-m", "pip", "install", "-q", str(wheel)], tmp)
    assert got.returncode == 0, got.stderr[-2000:]
    return tmp, tmp / "env" / "bin"


def test_the_installed_package_has_no_torch_and_no_repository(installed):
    tmp, bin_ = installed
    probe = _run(
        [
            str(bin_ / "python"),
            "-c",
            "import quadpilot, importlib.util as u; print(quadpilot.__file__); print(u.find_spec('torch') is None)",
        ],
        tmp,
    )
    where, no_torch = probe.stdout.split()
    assert "site-packages" in where and not where.startswith(str(ROOT)), where
    assert no_torch == "True"


def test_list_models_names_every_shipped_model_with_its_task(installed):
    tmp, bin_ = installed
    out = _run([str(bin_ / "quad-sitl"), "--list-models"], tmp)
    assert out.returncode == 0, out.stderr
    listed = {line.split()[0]: line for line in out.stdout.splitlines()[:-1]}
    assert sorted(listed) == MODELS
    assert re.search(r"\bhover on seed\b.*\(default\)", listed["hover"])
    assert "circle on" in listed["circle"] and "lstm" in listed["hover_lstm"]


@pytest.mark.parametrize("name", MODELS)
def test_the_installed_wheel_flies_the_shipped_model(installed, name):
    tmp, bin_ = installed
    out = _run([str(bin_ / "quad-sitl"), "--model", name, "--episodes", "1", "--gcs", "none", "--json", "s.json"], tmp)
    assert out.returncode == 0, out.stdout[-1500:] + out.stderr[-1500:]
    assert re.search(r"success rate\s+100%", out.stdout), out.stdout
    assert f"quadpilot/models/{name}/{policy_file(name)}" in out.stdout


def test_the_default_is_the_shipped_hover_model_and_a_wrong_name_is_one_line(installed):
    tmp, bin_ = installed
    flown = _run([str(bin_ / "quad-sitl"), "--episodes", "1", "--gcs", "none"], tmp)
    assert flown.returncode == 0 and "quadpilot/models/hover/policy.onnx" in flown.stdout, flown.stderr
    bad = _run([str(bin_ / "quad-sitl"), "--model", "nope"], tmp)
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.count("\n") == 1 and "expected one of circle, hover" in bad.stderr
