"""The vocabulary every generated C file shares: the names of the files and of the functions they
define, and how numbers and text are written into them. Used by the generator (`ccode.generate`) and by
the timing program (`ccode.bench`).

The generated text is compiled and loaded, and the model file it comes from is untrusted (docs/architecture.md,
"Trust boundaries"): a number goes in only as `c_float` writes it (the shortest decimal that reads
back to the same binary32 value), a comment's text only through `ascii_text` (ASCII, no comment
delimiters).
"""

from __future__ import annotations

import math
import textwrap
import unicodedata

import numpy as np

GENERATOR = "quadpilot.ccode.generate/1"
"""Identifies the generated code's conventions; part of the runtime's compile-cache key."""
HEADER_NAME, SOURCE_NAME = "policy.h", "policy.c"
ENTRY, STEP, RESET = "quadpilot_policy", "quadpilot_policy_step", "quadpilot_policy_reset"
VALUES_PER_LINE = 6

_ASCII = {
    "ᵀ": "^T",
    "·": "*",
    "−": "-",
    "→": "->",
    "←": "<-",
    "≤": "<=",
    "≥": ">=",
    "±": "+/-",
    "×": "x",
    "…": "...",
    "°": " deg",
    "²": "^2",
    "³": "^3",
    "√": "sqrt",
    "ω": "omega",
    "π": "pi",
    "σ": "sigma",
    "–": "-",
    "—": "-",
    "’": "'",
}


def ascii_text(text: str) -> str:
    """`text` in ASCII for a C comment: known symbols spelled out, accents dropped, `*/` broken."""
    out = []
    for ch in text:
        if ord(ch) < 128:
            out.append(ch)
        elif ch in _ASCII:
            out.append(_ASCII[ch])
        else:
            plain = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode()
            out.append(plain or "?")
    return "".join(out).replace("*/", "* /").replace("/*", "/ *")


def c_float(value) -> str:
    """A float32 value as a C float constant that reads back to the same bits."""
    v = np.float32(value)
    if not math.isfinite(v):
        raise ValueError(f"{v} has no C float constant")
    s = np.format_float_scientific(v, unique=True, trim="-") if v and not 1e-4 <= abs(v) < 1e7 else str(v)
    if not any(c in s for c in ".e"):
        s += ".0"
    return s + "f"


def c_array(name: str, a: np.ndarray, comment: str) -> str:
    a = np.asarray(a, np.float32)
    dims = "".join(f"[{n}]" for n in a.shape)
    lines = [f"/* {ascii_text(comment)} */", f"static const float {name}{dims} = {{"]
    rows = a.reshape(-1, a.shape[-1]) if a.ndim == 2 else a.reshape(1, -1)
    for r, row in enumerate(rows):
        values = [c_float(v) for v in row]
        chunks = [", ".join(values[k : k + VALUES_PER_LINE]) for k in range(0, len(values), VALUES_PER_LINE)]
        if a.ndim == 2:
            body = ",\n      ".join(chunks)
            lines.append(f"    {{ {body} }}{',' if r < len(rows) - 1 else ''}")
        else:
            lines.extend(f"    {c}{',' if k < len(chunks) - 1 else ''}" for k, c in enumerate(chunks))
    lines.append("};")
    return "\n".join(lines)


def wrap(text: str, width: int = 100) -> str:
    """A paragraph for a ` * ` comment block (the first line's ` * ` is the caller's)."""
    return "\n * ".join(textwrap.wrap(text, width - 3, break_on_hyphens=False, break_long_words=False))


def clamp(var: str, lo: str, hi: str) -> str:
    """`var` clamped to [lo, hi] as comparisons, so that a NaN passes through (as in the graph)."""
    return f"{var} < {lo} ? {lo} : ({var} > {hi} ? {hi} : {var})"
