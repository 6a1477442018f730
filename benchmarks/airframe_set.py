"""The airframe set (benchmarks/airframes/*.toml) as a Markdown table, read from the vehicle files
themselves (docs/raptor.md prints it with `python docs/figures.py update`):

    .venv/bin/python benchmarks/airframe_set.py benchmarks/airframes
"""

from __future__ import annotations

import sys
from pathlib import Path

from quadpilot.core.vehicle_file import load_vehicle_file


def first_comment(path: Path) -> str:
    """The file's first comment line: where the airframe comes from."""
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").split(", written by")[0].strip()
    return ""


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not Path(argv[0]).is_dir():
        print("usage: airframe_set.py DIR (a folder of vehicle files)", file=sys.stderr)
        return 2
    print("| vehicle file | mass | thrust / weight | hover command | motor lag | drag, rotor aerodynamics | from |")
    print("|---|---:|---:|---:|---:|---|---|")
    for path in sorted(Path(argv[0]).glob("*.toml")):
        v = load_vehicle_file(path)
        hover = sorted({round(float(c), 2) for c in v.hover_commands})
        hover_text = " / ".join(f"{c:.2f}" for c in hover)
        terms = [
            name
            for name, on in (
                ("linear", v.drag > 0),
                ("quadratic", v.c_dx or v.c_dy or v.c_dz),
                ("rotor drag", v.k_d or v.k_z),
                ("lift", v.k_h),
                ("flapping", v.k_flap),
            )
            if on
        ]
        mass = f"{v.mass * 1000:.0f} g" if v.mass < 1 else f"{v.mass:.1f} kg"
        print(
            f"| `{path.name}` | {mass} | {v.thrust_to_weight:.2f} | {hover_text} | {v.motor_tau * 1000:.1f} ms "
            f"| {', '.join(terms) or 'none'} | {first_comment(path)} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
