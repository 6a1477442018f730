"""Flight drawings: the trace container, the quadrotor's drawn geometry against known attitudes,
and the PNG and GIF written from synthetic flights (size, not blank, frames that move).

Frames: world ENU (z up), body FLU, R = Rz(yaw)·Ry(pitch)·Rx(roll) body → world. Motors in PX4
quad-X order: 0 front-right, 1 rear-left, 2 front-left, 3 rear-right, arms at ±45°.
"""

import ast
import itertools
import math
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from quadpilot.core.dynamics import IDX
from quadpilot.core.vehicle_file import CRAZYFLIE, SEED_VEHICLE
from quadpilot.viz import FlightTrace, VizUnavailable, body_points, display_arm, frame_indices
from quadpilot.viz.geometry import arm_length_of, rotor_discs

DT = 0.01
TARGET = np.array([0.0, 0.0, 2.0])
VIZ = pathlib.Path(__file__).parents[2] / "src" / "quadpilot" / "viz"


# --- synthetic flights -------------------------------------------------------------------------


def hover(seconds=3.0, start=(0.8, -0.5, 1.2), label="hover"):
    """A critically damped approach to TARGET with a decaying wobble: the shape of a good hover."""
    t = 1.0 + np.arange(round(seconds / DT)) * DT  # quad-sitl's clock starts at 1 s
    tau = (t - t[0])[:, None]
    pos = TARGET + (np.asarray(start) - TARGET) * np.exp(-tau / 0.5) * (1 + 2 * tau)
    s = np.zeros((len(t), 12))
    s[:, 0:3] = pos
    s[:, 3:6] = np.gradient(pos, DT, axis=0)
    s[:, IDX["roll"]] = np.radians(20) * np.exp(-tau[:, 0] / 0.4) * np.cos(6 * tau[:, 0])
    s[:, IDX["pitch"]] = np.radians(-15) * np.exp(-tau[:, 0] / 0.4) * np.sin(5 * tau[:, 0])
    s[:, IDX["yaw"]] = 0.8 * tau[:, 0]
    cmd = 0.68 + 0.1 * np.exp(-tau / 0.5) * np.sin(8 * tau + np.arange(4))
    return FlightTrace(t, s, cmd, TARGET, label=label)


def circle(seconds=3.0, radius=2.0):
    """Tracking a target moving on a horizontal circle, starting off it."""
    t = np.arange(round(seconds / DT)) * DT
    w = 2 * math.pi / 5
    target = np.stack([radius * np.cos(w * t), radius * np.sin(w * t), np.full_like(t, 2.0)], axis=1)
    pos = target + np.exp(-t / 0.5)[:, None] * np.array([-1.0, 0.5, -0.5])
    s = np.zeros((len(t), 12))
    s[:, 0:3] = pos
    s[:, 3:6] = np.gradient(pos, DT, axis=0)
    s[:, IDX["roll"]] = np.radians(15) * np.cos(w * t)
    s[:, IDX["yaw"]] = np.angle(np.exp(1j * (w * t + 3.0)))  # wraps at ±π
    cmd = 0.7 + 0.05 * np.sin(w * t[:, None] + np.arange(4) * math.pi / 2)
    return FlightTrace(t, s, cmd, target, label="circle")


def with_fallback_and_failsafe():
    """A hover where the fallback flew steps 80–139 and the failsafe latched at step 250."""
    h = hover()
    sources = ["policy"] * h.n
    sources[80:140] = ["fallback"] * 60
    sources[240:] = ["blind"] * (h.n - 240)
    return FlightTrace(h.t, h.states, h.commands, h.target, sources, "fallback", failsafe_t=float(h.t[250]))


@pytest.fixture
def pil():
    pytest.importorskip("matplotlib")
    return pytest.importorskip("PIL.Image")


def assert_not_blank(rgb: np.ndarray, where: str) -> None:
    """Real drawing, not an empty canvas: varied pixels and more than a handful of colours."""
    assert rgb.std() > 10, f"{where}: pixel std {rgb.std():.1f}, looks blank"
    colours = np.unique(rgb.reshape(-1, rgb.shape[-1]), axis=0)
    assert len(colours) > 8, f"{where}: only {len(colours)} distinct colours"


# --- FlightTrace -------------------------------------------------------------------------------


def test_trace_validates_and_derives():
    h = hover()
    assert h.n == 300 and h.states.dtype == np.float64
    assert h.time[0] == 0.0 and h.duration == pytest.approx(2.99)
    assert not h.moving_target and h.target_path.shape == (300, 3)
    assert h.error[0] == pytest.approx(np.linalg.norm(np.array([0.8, -0.5, 1.2]) - TARGET))
    assert circle().moving_target
    spans = with_fallback_and_failsafe().non_policy_spans()
    assert spans == [
        (pytest.approx(0.8), pytest.approx(1.4), "fallback"),
        (pytest.approx(2.4), pytest.approx(3.0), "blind"),
    ]
    assert with_fallback_and_failsafe().failsafe_time == pytest.approx(2.5)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(t=np.zeros((10, 1))), r"t must have shape \(N,\)"),
        (dict(t=np.zeros(0), states=np.zeros((0, 12)), commands=np.zeros((0, 4))), r"N ≥ 1"),
        (dict(t=np.arange(10.0)[::-1].copy()), r"non-decreasing"),
        (dict(t=np.full(10, np.nan)), r"t must be finite"),
        (dict(states=np.zeros((10, 13))), r"states must have shape \(10, 12\)"),
        (dict(states=np.zeros((9, 12))), r"states must have shape \(10, 12\)"),
        (dict(states=np.full((10, 12), np.nan)), r"no step with a finite position"),
        (dict(commands=np.zeros((10, 6))), r"commands must have shape \(10, 4\)"),
        (dict(commands=np.full((10, 4), np.nan)), r"commands has no finite value"),
        (dict(target=np.zeros(2)), r"target must have shape \(3,\) or \(10, 3\)"),
        (dict(target=np.zeros((9, 3))), r"target must have shape"),
        (dict(target=np.array([0.0, np.nan, 2.0])), r"target must be finite"),
        (dict(sources=["policy"] * 9), r"sources has 9 entries, t has 10"),
        (dict(sources="policy"), r"sources must be a list"),
        (dict(failsafe_t=math.inf), r"failsafe_t must be finite"),
        (dict(states="abc"), r"states must be numeric"),
    ],
)
def test_trace_rejects_bad_input(change, message):
    good = dict(t=np.arange(10) * DT, states=np.zeros((10, 12)), commands=np.zeros((10, 4)), target=TARGET)
    FlightTrace.from_arrays(**good)
    with pytest.raises(ValueError, match=message):
        FlightTrace.from_arrays(**{**good, **change})


@pytest.mark.parametrize("make", [hover, circle, with_fallback_and_failsafe])
def test_npz_round_trip(tmp_path, make):
    a = make()
    path = a.to_npz(tmp_path / "flight.trace")  # written exactly there, no ".npz" appended
    assert path == tmp_path / "flight.trace" and path.exists()
    with np.load(path, allow_pickle=False) as z:  # plain arrays only
        assert "states" in z.files
    b = FlightTrace.from_npz(path)
    for name in ("t", "states", "commands", "target"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (b.sources, b.label, b.failsafe_t) == (a.sources, a.label, a.failsafe_t)


def test_npz_rejects_other_files(tmp_path):
    other = tmp_path / "other.npz"
    np.savez(other, x=np.zeros(3))
    with pytest.raises(ValueError, match=r"not a FlightTrace file, missing arrays"):
        FlightTrace.from_npz(other)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"not a readable FlightTrace"):
        FlightTrace.from_npz(junk)


def test_from_episode_log_places_the_failsafe_at_the_last_step():
    class Log:  # the fields of autopilot.node.EpisodeLog that a trace reads
        t = [1.0, 1.01, 1.02]
        states = [np.zeros(12)] * 3
        commands = [np.full(4, 0.5)] * 3
        sources = ["policy", "fallback", "fallback"]
        failsafe = "state stream silent"

    tr = FlightTrace.from_episode_log(Log(), TARGET, label="ep 0")
    assert tr.failsafe_t == 1.02 and tr.sources == Log.sources and tr.n == 3
    Log.failsafe = None
    assert FlightTrace.from_episode_log(Log(), TARGET).failsafe_t is None


# --- the drawn quadrotor -----------------------------------------------------------------------


def state(roll=0.0, pitch=0.0, yaw=0.0, pos=(1.0, 2.0, 3.0)):
    s = np.zeros(12)
    s[0:3] = pos
    s[IDX["roll"]], s[IDX["pitch"]], s[IDX["yaw"]] = roll, pitch, yaw
    return s


def test_rotors_level():
    """Level, yaw 0: rotors at (±a/√2, ±a/√2) around the centre, all at its height; front-right is
    +x (forward) and −y (right, since FLU's y points left)."""
    a = 0.2
    d = a / math.sqrt(2)
    expected = np.array([[d, -d, 0], [-d, d, 0], [d, d, 0], [-d, -d, 0]]) + np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(body_points(state(), a), expected, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(body_points(state(), a) - [1, 2, 3], axis=1), a)


def test_rotors_yaw_90():
    """Yaw +90° (nose to world +y, counter-clockwise from above): front-right (+x, −y in the body)
    lands at world (+y, +x) → (d, d); front-left at (−d, d)."""
    d = 0.2 / math.sqrt(2)
    pts = body_points(state(yaw=math.pi / 2, pos=(0, 0, 0)), 0.2)
    np.testing.assert_allclose(pts[0], [d, d, 0], atol=1e-12)  # front-right
    np.testing.assert_allclose(pts[2], [-d, d, 0], atol=1e-12)  # front-left
    np.testing.assert_allclose(pts[1], [-d, -d, 0], atol=1e-12)  # rear-left
    np.testing.assert_allclose(pts[3], [d, -d, 0], atol=1e-12)  # rear-right


def test_rotors_roll_30():
    """Roll +30° about the forward axis lifts the left side (body +y) and drops the right:
    rotor heights are ±(a/√2)·sin 30° = ±a/(2√2)."""
    a = 0.2
    h = a / math.sqrt(2) * math.sin(math.radians(30))
    pts = body_points(state(roll=math.radians(30)), a)
    np.testing.assert_allclose(pts[:, 2] - 3.0, [-h, +h, +h, -h], atol=1e-12)  # FR, RL, FL, RR


def test_rotors_pitch_30_nose_down():
    """With FLU, positive pitch is nose down (dynamics docstring): front rotors drop."""
    h = 0.2 / math.sqrt(2) * math.sin(math.radians(30))
    pts = body_points(state(pitch=math.radians(30)), 0.2)
    np.testing.assert_allclose(pts[:, 2] - 3.0, [-h, +h, -h, +h], atol=1e-12)


def test_rotors_batched_and_discs_tilt_with_the_body():
    states = np.stack([state(), state(roll=0.3, yaw=1.0), state(pitch=-0.4)])
    batched = body_points(states, 0.1)
    assert batched.shape == (3, 4, 3)
    for k in range(3):
        np.testing.assert_allclose(batched[k], body_points(states[k], 0.1))
    discs = rotor_discs(state(roll=math.radians(30)), 0.1, 0.05, n=12)
    assert discs.shape == (4, 12, 3)
    np.testing.assert_allclose(discs.mean(axis=1), body_points(state(roll=math.radians(30)), 0.1), atol=1e-12)
    assert np.ptp(discs[0, :, 2]) == pytest.approx(2 * 0.05 * math.sin(math.radians(30)))
    with pytest.raises(ValueError, match=r"shape \(12,\) or \(N, 12\)"):
        body_points(np.zeros(9), 0.1)


def test_arm_length_sources_and_exaggeration():
    assert arm_length_of(None) == SEED_VEHICLE.arm
    assert arm_length_of("crazyflie") == CRAZYFLIE.arm
    with pytest.raises(ValueError, match="positive"):
        arm_length_of(-0.1)
    assert display_arm(0.105, 1.0) == (0.105, 1.0)  # a 1 m hover view: true size
    assert display_arm(0.105, 4.4) == (pytest.approx(0.315), 3.0)  # a 2 m circle: ×3


def test_frame_indices_subsample_to_fps():
    h = hover(seconds=1.0)  # 100 steps, 0.99 s
    idx = frame_indices(h, fps=10)
    assert len(idx) == 10 and idx[0] == 0 and np.all(np.diff(idx) == 10)
    assert len(frame_indices(h, fps=10, speed=2.0)) == 5
    assert len(frame_indices(hover(seconds=5.0), fps=25)) == 125


# --- files -------------------------------------------------------------------------------------


def test_plot_flight_writes_a_drawn_png(tmp_path, pil):
    from quadpilot.viz import plot_flight

    hovers = [hover(start=(0.3 * k, -0.4, 1.0 + 0.2 * k), label=f"ep {k}") for k in range(8)]
    mixed = [with_fallback_and_failsafe(), circle()]  # a fixed and a moving target in one figure
    for name, traces in [("hovers", hovers), ("mixed", mixed)]:
        out = plot_flight(traces, tmp_path / "sub" / f"{name}.png", title=name)
        assert out == tmp_path / "sub" / f"{name}.png"
        assert out.stat().st_size < 250_000, f"{name}: {out.stat().st_size} bytes"
        with pil.open(out) as im:
            assert im.size == (1200, 800)  # 12×8 in at 100 dpi
            rgb = np.asarray(im.convert("RGB"), dtype=float)
        assert_not_blank(rgb, name)
        assert_not_blank(rgb[100:500, 60:400], f"{name}, 3-D panel")
    shaded = np.asarray(pil.open(tmp_path / "sub" / "mixed.png").convert("RGB"), dtype=int)
    # tab:orange (255, 127, 14) at alpha 0.25 over white is about (255, 223, 195)
    orange = (shaded[..., 0] > 245) & (abs(shaded[..., 1] - 223) < 12) & (abs(shaded[..., 2] - 195) < 15)
    assert orange.sum() > 1000, "the fallback span is not shaded"
    assert not list(tmp_path.glob("sub/.*")), "a temporary file was left behind"


def test_plot_flight_rejects_bad_calls(tmp_path):
    pytest.importorskip("matplotlib")
    from quadpilot.viz import check_plot_output, plot_flight

    with pytest.raises(ValueError, match="no traces"):
        plot_flight([], tmp_path / "a.png")
    with pytest.raises(ValueError, match=r"must end in one of \.png"):
        plot_flight(hover(), tmp_path / "a.jpg")
    with pytest.raises(ValueError, match=r"must end in one of \.png"):
        check_plot_output(tmp_path / "a.jpg")
    with pytest.raises(ValueError, match="commands_of=3"):
        plot_flight([hover()], tmp_path / "a.png", commands_of=3)


def test_gif_has_the_frames_and_they_move(tmp_path, pil):
    from quadpilot.viz import render_flight_video

    fps, size = 10, (240, 180)
    for tr, speed in ((circle(seconds=1.0), 1.0), (with_fallback_and_failsafe(), 3.0)):  # ~1 s of video each
        out = render_flight_video(tr, tmp_path / f"{tr.label}.gif", fps=fps, size_px=size, dpi=50, speed=speed)
        frames = []
        with pil.open(out) as im:
            assert im.size == size
            for k in range(im.n_frames):
                im.seek(k)
                frames.append(np.asarray(im.convert("RGB"), dtype=float))
        assert abs(len(frames) - tr.duration / speed * fps) <= 1, (tr.label, len(frames))
        assert out.stat().st_size < 2_000_000
        for f in frames:
            assert_not_blank(f, f"{tr.label} frame")
        diffs = [np.abs(a - b).mean() for a, b in itertools.pairwise(frames)]
        assert min(diffs) > 0.05, f"{tr.label}: consecutive frames identical ({min(diffs):.3f})"


def test_mp4_without_ffmpeg_says_so(tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    from matplotlib import animation

    from quadpilot.viz import check_video_output, render_flight_video

    monkeypatch.setattr(animation.FFMpegWriter, "isAvailable", classmethod(lambda cls: False))
    with pytest.raises(VizUnavailable, match=r"ffmpeg.*\.gif"):
        render_flight_video(hover(seconds=0.2), tmp_path / "a.mp4")
    with pytest.raises(VizUnavailable, match=r"ffmpeg.*\.gif"):
        check_video_output(tmp_path / "a.mp4")  # what a CLI can ask before it flies
    check_video_output(tmp_path / "a.gif")
    assert not (tmp_path / "a.mp4").exists()
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        render_flight_video(hover(seconds=0.2), tmp_path / "a.avi")


# --- dependencies ------------------------------------------------------------------------------


def test_viz_imports_only_core_and_atomic_files_of_ours():
    for path in VIZ.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                assert top not in ("torch", "gymnasium", "stable_baselines3"), f"viz/{path.name} imports {name}"
                ours = name.startswith(("quadpilot.core", "quadpilot.atomic_files"))
                assert ours or top != "quadpilot", f"viz/{path.name} imports {name}"


def test_without_matplotlib_import_works_and_drawing_says_what_to_install(tmp_path):
    code = """
import sys
class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "matplotlib":
            raise ModuleNotFoundError("refused by the test: " + name)
        return None
sys.meta_path.insert(0, Refuse())
import numpy as np
import quadpilot.viz as viz
tr = viz.FlightTrace(np.arange(3) * 0.01, np.zeros((3, 12)), np.zeros((3, 4)), np.zeros(3))
for call, out in ((viz.plot_flight, "/a.png"), (viz.render_flight_video, "/a.gif")):
    try:
        call(tr, sys.argv[1] + out)
    except viz.VizUnavailable as e:
        assert isinstance(e, RuntimeError)
        print(e)
"""
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    expected = "plotting needs matplotlib: pip install 'quadpilot[train]' (or pip install matplotlib)"
    assert out.stdout.splitlines() == [expected, expected]


# --- montage -----------------------------------------------------------------------------------


def panels_of(rgb: np.ndarray, n: int) -> list[np.ndarray]:
    """The n side-by-side panels of a montage frame, the title strip included."""
    width = rgb.shape[1] // n
    return [rgb[:, k * width + 2 : (k + 1) * width - 2] for k in range(n)]


def test_montage_has_the_frames_and_panels_on_one_clock(tmp_path, pil):
    from quadpilot.viz import render_montage

    early = hover(seconds=1.2, start=(1.5, -1.0, 0.6), label="early")  # ends first, like a crash
    middle = hover(seconds=2.0, start=(1.0, 0.5, 1.5), label="middle")
    final = circle(seconds=2.0)
    fps, size, n = 10, (450, 200), 3
    out = render_montage(
        [early, middle, final], ["0 steps\ncrashed", "40k steps", "1M steps"], tmp_path / "m.gif", fps=fps, size_px=size
    )
    frames = []
    with pil.open(out) as im:
        assert im.size == size
        for k in range(im.n_frames):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB"), dtype=float))
    assert len(frames) == math.floor(final.duration * fps + 1e-9) + 1  # the longest flight sets the length
    assert out.stat().st_size < 500_000
    assert (frames[0][2, 2] == 255).all(), "the background is not pure white"
    for k, f in enumerate(frames):
        for i, panel in enumerate(panels_of(f, n)):
            assert_not_blank(panel, f"frame {k}, panel {i}")
    mid = panels_of(frames[len(frames) // 2], n)
    for (i, a), (j, b) in itertools.combinations(enumerate(mid), 2):
        assert np.abs(a - b).mean() > 1.0, f"panels {i} and {j} look the same"
    # after the early flight ended its panel holds still while the others move on
    last, before = panels_of(frames[-1], n), panels_of(frames[-2], n)
    assert np.abs(last[0] - before[0]).mean() < 0.05
    assert np.abs(last[1] - before[1]).mean() > 0.05 and np.abs(last[2] - before[2]).mean() > 0.05
    red = (frames[-1][..., 0] > 200) & (frames[-1][..., 1] < 60) & (frames[-1][..., 2] < 60)
    assert red[:, : size[0] // n].sum() > 20, "the ended panel does not say so"


def test_montage_rejects_bad_calls(tmp_path):
    pytest.importorskip("matplotlib")
    from quadpilot.viz import render_montage

    with pytest.raises(ValueError, match="non-empty list"):
        render_montage([], [], tmp_path / "m.gif")
    with pytest.raises(ValueError, match="non-empty list"):
        render_montage(hover(), None, tmp_path / "m.gif")
    with pytest.raises(ValueError, match="2 traces need 2 labels"):
        render_montage([hover(), hover()], ["one"], tmp_path / "m.gif")
    with pytest.raises(ValueError, match="every entry must be a FlightTrace"):
        render_montage([hover(), "x"], None, tmp_path / "m.gif")
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        render_montage([hover()], None, tmp_path / "m.png")
    assert not list(tmp_path.iterdir())
