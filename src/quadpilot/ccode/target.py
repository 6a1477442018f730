"""The generated C kernel cross-built for a Cortex-M and booted in QEMU: the embedded runtime on
the cores it is written for, emulated.

    image = build_image(code, info, "hover_m4/", "cortex-m4f")    # policy.c, harness.c -> policy.elf
    run = run_image(image, encode_inputs(obs))                    # qemu-system-arm -M mps2-an386
    run.motors, run.ticks, run.trailer                            # what the image computed and counted
    footprint(image)                                              # flash and RAM by part, from the map

Targets (`TARGETS`): cortex-m4f (-mcpu=cortex-m4 -mfpu=fpv4-sp-d16) booted on QEMU's mps2-an386,
cortex-m7 (-mcpu=cortex-m7 -mfpu=fpv5-d16) on mps2-an500; hard float, Thumb-2, C99 at -O2 with
-Wall -Wextra -Werror, linked against newlib-nano's libm (Debian's gcc-arm-none-eabi and
libnewlib-arm-none-eabi). The image is `ccode.harness`'s: it checks the model's golden vectors at boot
and exits through semihosting with status 0 only if they match.

Counting: QEMU runs the image with `-icount shift=0`, so its virtual clock advances 1 ns per guest
instruction, deterministically; SysTick counts that clock at the MPS2 boards' 25 MHz
(`SYSCLK_FRQ` in QEMU's hw/arm/mps2.c), one tick per 40 instructions. The image times a known
assembly loop at boot (`ccode.harness.CALIBRATION_INSTRUCTIONS`) and `RunResult.instructions_per_tick`
is derived from it, not assumed. These are instructions executed, not cycles: QEMU models no
pipeline, no flash wait states, no cache (and no DWT cycle counter).

A missing tool raises `CrossToolError`, one line naming the apt-get install.
"""

from __future__ import annotations

import re
import shutil
import struct
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quadpilot.core import dynamics
from quadpilot.core.observation import build_observation
from quadpilot.core.params import ParamBatch
from quadpilot.core.start import sample_start_states
from quadpilot.core.state import POS, ROLL_PITCH
from quadpilot.modelfile.contract import NUM_MOTORS, ModelInfo

from . import generate as cgen
from . import harness as charness

APT_INSTALL = "apt-get install -y gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm"
CC, QEMU = "arm-none-eabi-gcc", "qemu-system-arm"
CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-ffunction-sections", "-fdata-sections")
"""C99 as the kernel was written for (ISO C: no contraction of a*b + c into a fused multiply-add,
so the sums round as on the host); sections per function for --gc-sections. With OPT."""
OPT = "-O2"
"""The optimisation level of the kernel and the harness: the host runtime's (cbackend.COMPILE_FLAGS)."""
LDFLAGS = ("-nostartfiles", "--specs=nano.specs", "-Wl,--gc-sections")
BUILD_TIMEOUT_S = 300.0
RUN_TIMEOUT_S = 120.0
"""Every boot is bounded: a hung image is killed and reported."""
ELF_NAME, MAP_NAME = "policy.elf", "policy.map"


@dataclass(frozen=True)
class Target:
    name: str
    flags: tuple[str, ...]
    machine: str
    """The QEMU machine that boots it."""
    core: str


TARGETS = {
    "cortex-m4f": Target(
        "cortex-m4f",
        ("-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-mthumb"),
        "mps2-an386",
        "Cortex-M4F",
    ),
    "cortex-m7": Target(
        "cortex-m7", ("-mcpu=cortex-m7", "-mfpu=fpv5-d16", "-mfloat-abi=hard", "-mthumb"), "mps2-an500", "Cortex-M7"
    ),
}


class CrossToolError(RuntimeError):
    """The cross compiler or QEMU is missing, or a build failed (the message says which, in one line)."""


def find_tool(name: str) -> str | None:
    return shutil.which(name)


def missing_tools() -> list[str]:
    """The tools a build and a boot need (compiler, QEMU, binutils' size) that are not on PATH."""
    return [t for t in (CC, QEMU, "arm-none-eabi-size") if find_tool(t) is None]


def require_tool(name: str) -> str:
    """The path of `name` on PATH, or CrossToolError naming the Debian install."""
    path = find_tool(name)
    if path is None:
        raise CrossToolError(f"{name} not found on PATH; install it with: {APT_INSTALL}")
    return path


def toolchain_versions() -> dict[str, str]:
    """The versions an instruction count holds for: the compiler's and QEMU's first --version line,
    and newlib's (`_NEWLIB_VERSION`, whose libm `expf` takes most of a tanh and a sigmoid)."""
    cc = require_tool(CC)

    def first_line(argv: list[str], stdin: str | None = None) -> str:
        done = subprocess.run(argv, input=stdin, capture_output=True, text=True, check=True, timeout=BUILD_TIMEOUT_S)
        return done.stdout.strip().splitlines()[-1 if stdin else 0].strip()

    newlib = first_line([cc, "-E", "-P", "-x", "c", "-"], "#include <_newlib_version.h>\n_NEWLIB_VERSION\n")
    return {
        "gcc": first_line([cc, "--version"]),
        "newlib": newlib.strip('"'),
        "qemu": first_line([require_tool(QEMU), "--version"]),
    }


@dataclass(frozen=True)
class Image:
    elf: Path
    map: Path
    target: Target
    stages: tuple[str, ...]
    """The stages each record's ticks time after the whole call (`cgen.stages`), () for a plain image."""
    hidden: int
    """Recurrent state size (0: none)."""


def _run(argv: list[str], cwd: Path, what: str) -> None:
    try:
        done = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise CrossToolError(f"{what}: {' '.join(argv[:1])} could not run: {e}") from None
    if done.returncode != 0:
        lines = (done.stderr or done.stdout).strip().splitlines()
        raise CrossToolError(f"{what} failed (exit {done.returncode}): " + " | ".join(lines[:6]))


def build_image(
    code: cgen.CCode, info: ModelInfo, out_dir, target: str | Target, profile: bool = False, opt: str = OPT
) -> Image:
    """Write policy.c/.h, harness.c and the linker script into `out_dir` and cross-compile them into
    policy.elf (with policy.map). `profile`: also time each stage of the step (the kernel's QP_PROBE
    hooks record SysTick; costs a load and a store per stage); `opt` the optimisation flag (-O2,
    -Os, ...). Raises CrossToolError."""
    t = TARGETS[target] if isinstance(target, str) else target
    cc = require_tool(CC)
    out = Path(out_dir)
    code.write(out)
    stages = tuple(cgen.stages(code.network)) if profile else ()
    (out / charness.HARNESS_NAME).write_text(charness.harness_source(info, code.network, len(stages)), "ascii")
    (out / charness.LINKER_NAME).write_text(charness.LINKER_SCRIPT, "ascii")
    policy_flags = []
    if profile:
        (out / charness.PROBE_HEADER).write_text(charness.probe_header(), "ascii")
        policy_flags = ["-include", charness.PROBE_HEADER]
    if not re.fullmatch(r"-O[0-3sz]", opt):
        raise ValueError(f"opt must be one of -O0..-O3, -Os, -Oz; got {opt!r}")
    base = [cc, *CFLAGS, opt, *t.flags]
    _run([*base, *policy_flags, "-c", cgen.SOURCE_NAME, "-o", "policy.o"], out, f"compiling {cgen.SOURCE_NAME}")
    _run([*base, "-c", charness.HARNESS_NAME, "-o", "harness.o"], out, f"compiling {charness.HARNESS_NAME}")
    link = [cc, *t.flags, *LDFLAGS, "-T", charness.LINKER_NAME, f"-Wl,-Map={MAP_NAME}", "-o", ELF_NAME]
    _run([*link, "harness.o", "policy.o", "-lm"], out, "linking the image")
    return Image(out / ELF_NAME, out / MAP_NAME, t, stages, code.network.hidden if code.network.recurrent else 0)


# --- inputs, outputs, a run ---------------------------------------------------------------------


def encode_inputs(obs: np.ndarray, resets: np.ndarray | None = None) -> bytes:
    """qp_in.bin for observations (N, obs_dim): per record uint32 flags (bit 0: zero the state
    first), then the observation as float32, little-endian. `resets` (N,) bool; None: only before
    the first record."""
    obs = np.ascontiguousarray(obs, "<f4")
    n, d = obs.shape
    flags = np.zeros(n, "<u4")
    if resets is None:
        flags[0] = 1
    else:
        flags[np.asarray(resets, bool)] = 1
    rec = np.empty((n, 1 + d), "<u4")
    rec[:, 0] = flags
    rec[:, 1:] = obs.view("<u4")
    return rec.tobytes()


@dataclass(frozen=True)
class RunResult:
    status: int
    """QEMU's exit status: the image's (charness: 0 ok, 1 golden vectors, 2 output, 3 input)."""
    console: str
    """What the image said through semihosting (and QEMU on its stderr)."""
    motors: np.ndarray
    """(N, 4) float32, one row per input record."""
    ticks: np.ndarray
    """(N, 1 + stages) SysTick ticks: the whole call, then each stage (profile builds)."""
    trailer: dict
    """records, kernel_stack_bytes, stack_high_water_bytes, calibration_ticks, calibration_instructions."""

    @property
    def instructions_per_tick(self) -> float:
        return self.trailer["calibration_instructions"] / self.trailer["calibration_ticks"]

    @property
    def instructions(self) -> np.ndarray:
        """ticks as instructions (each record's: within one tick, averaging to better over many)."""
        return self.ticks * self.instructions_per_tick


def qemu_argv(image: Image) -> list[str]:
    """How the image is booted: deterministic instruction counting, semihosting to the host's files."""
    return [
        require_tool(QEMU),
        "-M",
        image.target.machine,
        "-nographic",
        "-monitor",
        "none",
        "-semihosting-config",
        "enable=on,target=native",
        "-icount",
        "shift=0",
        "-kernel",
        str(image.elf.resolve()),
    ]


def run_image(image: Image, inputs: bytes | None = None, timeout: float = RUN_TIMEOUT_S) -> RunResult:
    """Boot `image` in QEMU (in a fresh working directory holding qp_in.bin when `inputs` is given)
    and read back what it wrote. Raises CrossToolError if QEMU is missing or the boot outlives
    `timeout` (the process is killed)."""
    argv = qemu_argv(image)
    with tempfile.TemporaryDirectory(prefix="quadpilot-qemu-") as tmp:
        tmp = Path(tmp)
        if inputs is not None:
            (tmp / charness.INPUT_NAME).write_bytes(inputs)
        try:
            done = subprocess.run(argv, cwd=tmp, capture_output=True, timeout=timeout, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            raise CrossToolError(
                f"{image.elf}: QEMU ({image.target.machine}) did not exit within {timeout:g} s"
            ) from None
        console = (done.stdout + done.stderr).decode("ascii", "replace")
        out_path = tmp / charness.OUTPUT_NAME
        data = out_path.read_bytes() if out_path.is_file() else b""
    motors, ticks, trailer = _decode(data, len(image.stages), done.returncode)
    return RunResult(done.returncode, console, motors, ticks, trailer)


def _decode(data: bytes, stages: int, status: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """qp_out.bin's records and trailer. An image that stopped early (status != 0) leaves no
    trailer: its complete records are returned with an empty trailer."""
    width = NUM_MOTORS + 1 + stages
    tail = 4 * charness.TRAILER_WORDS
    values = struct.unpack(f"<{charness.TRAILER_WORDS}I", data[-tail:]) if len(data) >= tail else ()
    if values and values[0] == charness.TRAILER_MAGIC and len(data) - tail == 4 * width * values[1]:
        body, trailer = data[:-tail], dict(zip(_TRAILER_KEYS, values[1:], strict=True))
    elif status != 0 or not data:
        body, trailer = data[: len(data) // (4 * width) * 4 * width], {}
    else:
        raise CrossToolError(f"{charness.OUTPUT_NAME}: not the image's format ({len(data)} bytes)")
    rows = np.frombuffer(body, "<u4").reshape(-1, width)
    return rows[:, :NUM_MOTORS].copy().view("<f4").astype(np.float32), rows[:, NUM_MOTORS:].astype(np.int64), trailer


_TRAILER_KEYS = (
    "records",
    "kernel_stack_bytes",
    "stack_high_water_bytes",
    "calibration_ticks",
    "calibration_instructions",
)


# --- footprint ----------------------------------------------------------------------------------

_OUTPUT_SECTIONS = (".text", ".rodata", ".ARM.exidx", ".data", ".bss")
_INPUT_RE = re.compile(r"^ (?P<name>[.*]\S*)?\s+0x(?P<addr>[0-9a-f]+)\s+0x(?P<size>[0-9a-f]+)(?:\s+(?P<file>\S.*))?$")


def _part(file: str | None) -> str:
    """Which part of the image an input file of the link map belongs to."""
    if file is None:
        return "padding"
    name = Path(file.split("(")[0]).name
    if name == "policy.o":
        return "policy"
    if name == "harness.o":
        return "harness"
    if name.startswith("libm"):
        return "libm"
    if name.startswith("libgcc"):
        return "libgcc"
    if name.startswith(("libc", "libg")):  # newlib-nano's libc_nano.a, libg_nano.a
        return "libc"
    return "other"


def footprint(image: Image) -> dict:
    """Bytes per output section and part: {section: {part: bytes}}, the parts policy (policy.o),
    harness (harness.o), libm, libc, libgcc, from the link map, and padding (alignment: what the
    ELF's section holds beyond its input sections, arm-none-eabi-size -A)."""
    sizes: dict[str, dict[str, int]] = {s: {} for s in _OUTPUT_SECTIONS}
    current = None
    pending = None
    for line in image.map.read_text(errors="replace").splitlines():
        head = line.split()[0] if line and not line[0].isspace() else None
        if head is not None:
            current = head if head in sizes else None
            pending = None
            continue
        if current is None:
            continue
        m = _INPUT_RE.match(line)
        if m is None:
            name = line.strip()
            pending = name if line.startswith(" .") and " " not in name else None
            continue
        named = m.group("name") is not None or pending is not None  # not a symbol's address line
        size = int(m.group("size"), 16)
        pending = None
        if named and size:
            part = "padding" if m.group("name") == "*fill*" else _part(m.group("file"))
            sizes[current][part] = sizes[current].get(part, 0) + size
    elf = elf_sections(image)
    for section, parts in sizes.items():
        padding = elf.get(section, 0) - sum(v for k, v in parts.items() if k != "padding")
        if padding < 0:
            raise CrossToolError(f"{image.map}: {section} parts exceed the ELF's section ({padding} B)")
        parts["padding"] = padding
    return {s: dict(sorted(p.items())) for s, p in sizes.items()}


def elf_sections(image: Image) -> dict[str, int]:
    """Section sizes of the ELF as binutils reads them (arm-none-eabi-size -A), for cross-checking
    the map."""
    size = require_tool("arm-none-eabi-size")
    done = subprocess.run([size, "-A", str(image.elf)], capture_output=True, text=True, check=True)
    out = {}
    for line in done.stdout.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith(".") and parts[1].isdigit():
            out[parts[0]] = int(parts[1])
    return out


# --- observations to feed an image ----------------------------------------------------------------


def _observations(info: ModelInfo, state: np.ndarray) -> np.ndarray:
    target_vel = np.zeros(3) if info.layout.tracks else None
    return build_observation(state, np.zeros(3), target_vel)


def envelope_observations(info: ModelInfo, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, obs_dim) float32 from states inside the file's envelope, target at the origin: position
    uniform in the ball of max_distance_m, roll and pitch each uniform in ±max_tilt_deg, any yaw,
    velocity ±2 m/s and body rates ±3 rad/s per axis."""
    env = info.envelope
    state = sample_start_states(rng, np.zeros((n, 3)), env["max_distance_m"], 2.0, env["max_tilt_deg"], 3.0)
    return _observations(info, state)


def flight_observations(policy, info: ModelInfo, steps: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A recorded closed-loop flight: `policy` (a runtime Policy) flies the file's vehicle on
    core.dynamics from a random start near the target (1 m, 0.5 m/s, 15°), one control period a
    step; an episode that leaves the envelope ends and the next starts. Returns the observations
    (steps, obs_dim) float32 and the episode starts (steps,) bool, for replaying the sequence with
    its recurrent state carried across steps."""
    params = ParamBatch.from_preset(info.vehicle, 1)
    obs = np.empty((steps, info.obs_dim), np.float32)
    starts = np.zeros(steps, bool)
    state = rotor = None
    for t in range(steps):
        if state is None:
            state = sample_start_states(rng, np.zeros((1, 3)), 1.0, 0.5, 15.0, 0.5)
            rotor = np.full((1, NUM_MOTORS), float(dynamics.hover_command(params)[0]))
            policy.reset()
            starts[t] = True
        obs[t] = _observations(info, state)[0]
        command = policy.act(obs[t])[None, :].astype(np.float64)
        state, rotor = dynamics.step(state, rotor, command, params, info.control_period_s)
        tilt = np.degrees(np.abs(state[0, ROLL_PITCH])).max()
        if np.linalg.norm(state[0, POS]) > info.envelope["max_distance_m"] or tilt > info.envelope["max_tilt_deg"]:
            state = None
    policy.reset()
    return obs, starts


def check_inputs(policy, random: int = 1_000, flight: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """What the tests and benchmarks/embedded.py feed an image: the file's golden vectors (from zero
    state), `random` envelope observations (one sequence), a recorded `flight` of that many steps
    (its own episode starts). Returns observations (N, obs_dim) float32 and resets (N,) bool."""
    info = policy.info
    rng = np.random.default_rng(seed)
    obs_random = envelope_observations(info, random, rng)
    obs_flight, starts = flight_observations(policy, info, flight, rng)
    obs = np.concatenate([info.golden_obs, obs_random, obs_flight]).astype(np.float32)
    resets = np.zeros(len(obs), bool)
    resets[0] = resets[len(info.golden_obs)] = True
    resets[len(info.golden_obs) + random :] = starts
    return obs, resets


def replay(policy, obs: np.ndarray, resets: np.ndarray) -> np.ndarray:
    """`policy`'s commands (N, 4) over a sequence, its state zeroed where `resets` says (and after)."""
    out = np.empty((len(obs), NUM_MOTORS), np.float32)
    for k, (o, r) in enumerate(zip(obs, resets, strict=True)):
        if r:
            policy.reset()
        out[k] = policy.act(o)
    policy.reset()
    return out
