"""The mixer of a rotor layout, compiled: rotor thrusts → (thrust, τx, τy, τz).

`core.dynamics` steps every batch through these functions: `wrench_function` (one expression per
row, allocating) and `wrench_into_function` (the same expressions written into buffers, for the
in-place `Stepper`). A layout is compiled once per process (`wrench_maker`); the source holds
only rotor indices, signs and names made here, never text from a vehicle file.
"""

from __future__ import annotations

import numpy as np


def wrench_function(layout: tuple, scales: tuple, cast):
    """f ↦ (thrust, τx, τy, τz) for a batch's layout (`ParamBatch.layout`: x/arm, y/arm, spin in
    FLU per rotor), with τx = arm·Σ y_i·F_i, τy = −arm·Σ x_i·F_i, τz = −k_m·Σ spin_i·F_i (module
    docstring); `scales` the per-drone (arm, arm, k_m)."""
    make, factors, coefs, terms = wrench_maker(layout)
    consts = [cast(scale / (1.0 / g)) for scale, g in zip(scales, factors, strict=True) if g]
    ks = [cast(k)[()] for k in coefs]
    fn = make(*consts, *ks)
    fn.source = make.source
    # the same rows with the same constants, for `wrench_into_function` (the in-place step)
    bound = iter(consts)
    fn.rows = tuple(
        None if row is None else (next(bound), tuple((neg, None if j is None else ks[j], i) for neg, j, i in row))
        for row in terms
    )
    return fn


_WRENCH_MAKERS: dict = {}
_MAX_WRENCH_MAKERS = 64  # layouts compiled per process; a batch has one, a run a handful


def wrench_maker(layout: tuple):
    """(make, row factors g, other coefficients, row terms) for a layout, compiled once per layout.

    The mixer is written out as one expression per row and compiled, so that stepping costs what a
    hand-written mixer costs: each row's largest |coefficient| g goes into a per-drone factor, so
    the rows of a symmetric frame (every |coefficient| equal or 0: quad-X, "+") are sums and
    differences of the rotor thrusts times one factor, exactly the quad-X rows the ENPM 667 project writes out;
    any other coefficient is one more multiplication. `make(a0, a1, a2, k...)` binds the per-drone
    factors (arm·g, k_m·g) and coefficients of a batch without compiling again (domain randomisation
    makes a new batch at every reset). The source holds only rotor indices, signs and names made
    here, never text from a vehicle file. The row terms, (negative, coefficient index or None,
    rotor index) in the source's order, let `wrench_into_function` write the same expressions in place."""
    hit = _WRENCH_MAKERS.get(layout)
    if hit is not None:
        return hit
    lay = np.asarray(layout, dtype=np.float64)
    factors, coefs, params, rows = [], [], [], []
    terms = []  # per row: None (no torque) or its terms (negative, coefficient index or None, rotor)
    for r, coef in enumerate((lay[:, 1], -lay[:, 0], -lay[:, 2])):
        g = float(np.abs(coef).max())
        factors.append(g)
        if g == 0.0:
            rows.append("0.0")  # no rotor makes this torque (VehicleParams refuses such layouts)
            terms.append(None)
            continue
        params.append(f"a{r}")
        expr = ""
        row_terms = []
        for i, ci in enumerate(coef):
            k = float(ci / g)
            if k == 0.0:
                continue
            if k in (1.0, -1.0):
                term = f"f[{i}]"
                row_terms.append((k < 0, None, i))
            else:
                coefs.append(abs(k))
                term = f"k{len(coefs) - 1} * f[{i}]"
                row_terms.append((k < 0, len(coefs) - 1, i))
            expr += (" - " if k < 0 else " + ") + term if expr else ("-" if k < 0 else "") + term
        rows.append(f"a{r} * ({expr})")
        terms.append(tuple(row_terms))
    params += [f"k{j}" for j in range(len(coefs))]
    thrust = " + ".join(f"f[{i}]" for i in range(len(lay)))
    src = (
        f"def make({', '.join(params)}):\n"
        f"    def wrench(f):\n        return {thrust}, {rows[0]}, {rows[1]}, {rows[2]}\n"
        "    return wrench\n"
    )
    namespace: dict = {}
    exec(compile(src, "<core.dynamics wrench>", "exec"), namespace)  # the source is built above, from numbers
    make = namespace["make"]
    make.source = src  # what was compiled, for a reader (and the tests)
    if len(_WRENCH_MAKERS) >= _MAX_WRENCH_MAKERS:
        _WRENCH_MAKERS.clear()
    _WRENCH_MAKERS[layout] = hit = (make, tuple(factors), tuple(coefs), tuple(terms))
    return hit


def wrench_into_function(rows, m: int):
    """wrench_into(f_rows, out_rows, tmp): the wrench function's expressions (`wrench_maker`) for
    rotor thrust rows f_rows (M of (N,)), evaluated into out_rows (thrust, τx, τy, τz) with the same
    operations in the same order, tmp an (N,) scratch row. `rows` is the wrench function's `rows`
    (per torque row: None, or the per-drone factor and the terms). Written out as straight-line
    code like the allocating mixer, so stepping pays no loop over terms; the source holds only
    indices and names made here."""
    consts: list = []

    def const(value) -> str:
        consts.append(value)
        return f"c{len(consts) - 1}"

    body = [f"    f{i} = f[{i}]" for i in range(m)] + ["    o0, o1, o2, o3 = out"]
    body.append("    copyto(o0, f0)" if m == 1 else "    add(f0, f1, o0)")
    body += [f"    add(o0, f{i}, o0)" for i in range(2, m)]
    for r, row in enumerate(rows, start=1):
        o = f"o{r}"
        if row is None:  # "0.0"
            body.append(f"    {o}.fill(0.0)")
            continue
        factor, terms = row
        for j, (neg, k, i) in enumerate(terms):
            if j == 0:  # "-k * f[i]" is (−k)·f[i]; "-f[i]" is −f[i]
                if k is None:
                    body.append(f"    negative(f{i}, {o})" if neg else f"    copyto({o}, f{i})")
                else:
                    body.append(f"    multiply({const(-k if neg else k)}, f{i}, {o})")
            elif k is None:
                body.append(f"    {'subtract' if neg else 'add'}({o}, f{i}, {o})")
            else:
                body.append(f"    multiply({const(k)}, f{i}, tmp)")
                body.append(f"    {'subtract' if neg else 'add'}({o}, tmp, {o})")
        body.append(f"    multiply({const(factor)}, {o}, {o})")  # a_r·(...)
    src = "def wrench_into(f, out, tmp):\n" + "\n".join(body) + "\n"
    namespace = {
        "add": np.add,
        "subtract": np.subtract,
        "multiply": np.multiply,
        "negative": np.negative,
        "copyto": np.copyto,
        **{f"c{i}": c for i, c in enumerate(consts)},
    }
    exec(compile(src, "<core.dynamics wrench_into>", "exec"), namespace)  # built above from indices and names
    fn = namespace["wrench_into"]
    fn.source = src
    return fn
