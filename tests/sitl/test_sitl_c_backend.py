"""quad-sitl flies the compiled C kernel (`--backend c`) over MAVLink like the other backends, and
says in one line why it cannot where there is no C compiler."""

import pytest

from quadpilot.runtime.cbackend import find_compiler
from quadpilot.sitl import main

pytestmark = pytest.mark.sitl


@pytest.mark.skipif(find_compiler() is None, reason="the c backend needs a C compiler")
def test_a_short_lockstep_flight_on_the_c_backend(capsys):
    flags = ["--episodes", "2", "--duration", "3", "--gcs", "none", "--min-success", "1"]
    assert main(["--backend", "c", *flags]) == 0  # both episodes reach the hover bar
    out = capsys.readouterr().out
    assert "success rate            100%" in out and "fallback steps 0" in out


def test_without_a_compiler_quad_sitl_fails_in_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, gcc or clang
    monkeypatch.setenv("QUADPILOT_CACHE_DIR", str(tmp_path / "cache"))
    assert main(["--backend", "c", "--episodes", "1", "--duration", "1", "--gcs", "none"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("quad-sitl: error:") and "needs a C compiler" in err and "Traceback" not in err
