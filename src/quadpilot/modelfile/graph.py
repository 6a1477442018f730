"""The graph of a policy file is exactly the architecture its metadata declares (`check_graph`).

`model.read_model` calls `check_graph` once the metadata is read and checked: the operators in the
order `export.onnx_export` writes them (`expected_graph` builds that sequence from the
architecture), their attributes, the initializers the metadata names with the shapes that chain the
layers, and scalar constants equal to the metadata's clips and u_hover; no other node, initializer,
operator set or local function. So ONNX Runtime, which runs the graph, and the NumPy and C backends,
which compute the architecture from the same initializers (`network`), compute the same function.
The first difference is reported in one line, as a `ModelContractError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .contract import NUM_MOTORS, ModelContractError, ModelInfo, fail, quote

OPSETS = range(18, 24)
"""Standard operator set versions whose export of our networks is the graph `check_graph` expects
(checked for 18 to 23; the ops used did not change meaning between them). 18 is quad-export's
default; below 18, Split has no num_outputs attribute."""

_ATTRIBUTE_DEFAULTS = {
    # ONNX operator specs (onnx/docs/Operators.md): the attributes each op we use may carry, and
    # their defaults; any other attribute is refused
    "Gemm": {"alpha": 1.0, "beta": 1.0, "transA": 0, "transB": 0},
    "Split": {"axis": 0, "num_outputs": None},
    "Elu": {"alpha": 1.0},
}
_GEMM = {"alpha": 1.0, "beta": 1.0, "transA": 0, "transB": 1}  # y = x·Wᵀ + b, torch's nn.Linear


@dataclass(frozen=True)
class _Ref:
    """What one node input must be: a graph input, an earlier node's output, an initializer the
    architecture names (with its shape), a scalar float32 constant, or absent (an optional input)."""

    kind: str
    name: str = ""
    node: int = -1
    output: int = 0
    shape: tuple = ()
    value: float = 0.0

    def describe(self, ops: list[str]) -> str:
        if self.kind == "input":
            return f"graph input {self.name!r}"
        if self.kind == "node":
            return f"output {self.output} of node {self.node} ({ops[self.node]})"
        if self.kind == "weight":
            return f"initializer {quote(self.name, 40)} {list(self.shape)}"
        if self.kind == "const":
            return f"the constant {self.value:.9g}"
        return "no input"


@dataclass(frozen=True)
class _Node:
    op: str
    inputs: tuple[_Ref, ...]
    outputs: tuple[str | None, ...]
    """Graph output names this node must produce (None: an intermediate value)."""
    attributes: dict


class _Template:
    """The node sequence `export.onnx_export` writes for an architecture (see `expected_graph`)."""

    def __init__(self) -> None:
        self.nodes: list[_Node] = []

    def add(self, op: str, *inputs: _Ref, outputs=(None,), **attributes) -> list[_Ref]:
        self.nodes.append(_Node(op, inputs, tuple(outputs), attributes))
        k = len(self.nodes) - 1
        return [_Ref("node", node=k, output=j) for j in range(len(outputs))]

    def describe(self, k: int) -> str:
        node = self.nodes[k]
        ops = [n.op for n in self.nodes]
        return f"{node.op}({', '.join(r.describe(ops) for r in node.inputs)})"


def _const(value: float) -> _Ref:
    return _Ref("const", value=float(np.float32(value)))


def expected_graph(path, info: ModelInfo, arrays: dict[str, np.ndarray]) -> _Template:
    """The graph the architecture metadata declares, built from what `export.onnx_export` writes:
    `_Deployable._normalized` (Sub, Mul, Clip), the LSTM cell of `DeployableRecurrentPolicy.forward`
    (two Gemm, Add, Split into i, f, g, o, then the gate arithmetic in torch's order), each
    nn.Linear as Gemm(x, W, b) with transB = 1 (no bias input when the exporter dropped an all-zero
    bias) and its activation, then `_Deployable._command` (Clip, Add 1, Sqrt, Mul u_hover, Clip) or,
    for a tanh head, `DeployablePolicy.forward`'s 2u²·p/(p + q) form. The widths come from the
    initializers' shapes, which must chain from obs_dim to 4."""
    arch = info.architecture
    t = _Template()

    def weight(name: str, shape: tuple[int, ...], what: str) -> _Ref:
        if name not in arrays:
            raise fail(path, f"architecture names {what} {quote(name)}, which is not an initializer of the graph")
        if arrays[name].shape != shape:
            raise fail(
                path,
                f"initializer {quote(name)} ({what}) has shape {list(arrays[name].shape)}, "
                f"the declared architecture needs {list(shape)}",
            )
        return _Ref("weight", name=name, shape=shape)

    def gemm(x: _Ref, w: str, b: str | None, rows: int, cols: int, what: str, outputs=(None,)) -> _Ref:
        refs = [x, weight(w, (rows, cols), f"{what} weight")]
        if b is not None:
            refs.append(weight(b, (rows,), f"{what} bias"))
        return t.add("Gemm", *refs, outputs=outputs, **_GEMM)[0]

    d = info.obs_dim
    x = _Ref("input", name="obs")
    norm = arch["normalize"]
    if norm is not None:
        x = t.add("Sub", x, weight(norm["mean"], (d,), "normalize mean"))[0]
        x = t.add("Mul", x, weight(norm["inv_std"], (d,), "normalize inv_std"))[0]
        x = t.add("Clip", x, _const(-norm["clip"]), _const(norm["clip"]))[0]
    if info.recurrent:
        spec, hsz = arch["lstm"], arch["hidden"]
        a = gemm(x, spec["weight_ih"], spec["bias_ih"], 4 * hsz, d, "lstm input")
        b = gemm(_Ref("input", name="h_in"), spec["weight_hh"], spec["bias_hh"], 4 * hsz, hsz, "lstm recurrent")
        gates = t.add("Add", a, b)[0]
        i, f, g, o = t.add("Split", gates, outputs=(None,) * 4, axis=1, num_outputs=4)
        forget = t.add("Mul", t.add("Sigmoid", f)[0], _Ref("input", name="c_in"))[0]
        update = t.add("Mul", t.add("Sigmoid", i)[0], t.add("Tanh", g)[0])[0]
        c = t.add("Add", forget, update, outputs=("c_out",))[0]
        out_gate = t.add("Sigmoid", o)[0]
        x = t.add("Mul", out_gate, t.add("Tanh", c)[0], outputs=("h_out",))[0]
        d = hsz
    layers = arch["layers"]
    for k, layer in enumerate(layers):
        w = layer["weight"]
        if w not in arrays:
            raise fail(
                path, f"architecture names layer {k} weight {quote(w)}, which is not an initializer of the graph"
            )
        shape = arrays[w].shape
        rows = shape[0] if len(shape) == 2 else -1
        last = k == len(layers) - 1
        if rows < 1 or (last and rows != NUM_MOTORS):
            want = f"[{NUM_MOTORS}, {d}]" if last else f"[width, {d}]"
            raise fail(path, f"initializer {quote(w)} (layer {k} weight) has shape {list(shape)}, expected {want}")
        x = gemm(x, w, layer["bias"], rows, d, f"layer {k}")
        act = layer["activation"]
        if act == "tanh" and not last:
            x = t.add("Tanh", x)[0]
        elif act == "relu":
            x = t.add("Relu", x)[0]
        elif act == "elu":
            x = t.add("Elu", x, alpha=1.0)[0]
        d = rows
    u, (c_lo, c_hi) = arch["u_hover"], arch["command_clip"]
    if layers[-1]["activation"] == "tanh":  # u²·(1 + tanh z) = 2u²·p/(p + q), p = e^(2·min(z, 0)), q = e^(−2·max(z, 0))
        z = x
        p = t.add("Exp", t.add("Mul", t.add("Clip", z, _Ref("absent"), _const(0.0))[0], _const(2.0))[0])[0]
        q = t.add("Exp", t.add("Mul", t.add("Clip", z, _const(0.0))[0], _const(-2.0))[0])[0]
        two_p = t.add("Mul", p, _const(2.0))[0]
        y = t.add("Div", two_p, t.add("Add", p, q)[0])[0]
    else:
        lo, hi = arch["action_clip"]
        y = t.add("Add", t.add("Clip", x, _const(lo), _const(hi))[0], _const(1.0))[0]
    y = t.add("Mul", t.add("Sqrt", y)[0], _const(u))[0]
    t.add("Clip", y, _const(c_lo), _const(c_hi), outputs=("action",))
    return t


def check_graph(path, model, info: ModelInfo, arrays: dict[str, np.ndarray]) -> None:
    """Refuse any graph that is not exactly the declared architecture; one line names the first
    difference (see `expected_graph` for what is expected)."""
    import onnx

    opsets = {o.domain: o.version for o in model.opset_import}
    version = opsets.pop("", opsets.pop("ai.onnx", None))
    if opsets:
        raise fail(
            path, f"imports operator sets {quote(sorted(opsets))}; a quadpilot policy uses the standard one only"
        )
    if version not in OPSETS:
        raise fail(path, f"standard operator set {version}: expected {OPSETS.start} to {OPSETS.stop - 1}")
    if len(model.functions) or len(model.training_info):
        raise fail(path, "defines model-local functions or training graphs; a quadpilot policy has neither")
    graph = model.graph
    if len(graph.sparse_initializer):
        raise fail(path, "holds sparse initializers; a quadpilot policy's weights are dense float32")
    inputs = {v.name for v in graph.input}
    shadowed = sorted(inputs & set(arrays))
    if shadowed:
        raise fail(path, f"graph input {quote(shadowed[0])} is also an initializer")
    want = expected_graph(path, info, arrays)
    kind = info.architecture["kind"]
    ops = [n.op for n in want.nodes]
    produced: dict[str, tuple[int, int]] = {}
    used: set[str] = set()

    def found(name: str) -> str:
        if name == "":
            return "no input"
        if name in produced:
            k, j = produced[name]
            return f"output {j} of node {k} ({graph.node[k].op_type})"
        if name in inputs:
            return f"graph input {quote(name, 40)}"
        if name in arrays:
            a = arrays[name]
            return f"initializer {quote(name, 40)} {list(a.shape)}" + (f" = {float(a):.9g}" if a.shape == () else "")
        return f"the undefined value {quote(name, 40)}"

    def matches(name: str, ref: _Ref) -> bool:
        if ref.kind == "input":
            return name == ref.name
        if ref.kind == "node":
            return produced.get(name) == (ref.node, ref.output)
        if ref.kind == "weight":
            return name == ref.name
        if ref.kind == "const":
            a = arrays.get(name)
            return a is not None and a.shape == () and float(a) == ref.value
        return name == ""

    def differ(k: int, what: str) -> ModelContractError:
        return fail(path, f"the graph is not the declared {kind} architecture: node {k} {what}")

    for k, expected in enumerate(want.nodes):
        if k >= len(graph.node):
            raise differ(k, f"is missing (expected {want.describe(k)}; the graph ends after {len(graph.node)} nodes)")
        node = graph.node[k]
        got = f"{quote(node.op_type, 30)[1:-1]}({', '.join(found(n) for n in node.input)})"
        if node.domain not in ("", "ai.onnx") or node.op_type != expected.op or len(node.input) != len(expected.inputs):
            raise differ(k, f"is {got}, expected {want.describe(k)}")
        for j, (name, ref) in enumerate(zip(node.input, expected.inputs, strict=True)):
            if not matches(name, ref):
                raise differ(k, f"({expected.op}) input {j} is {found(name)}, expected {ref.describe(ops)}")
            if ref.kind in ("weight", "const"):
                used.add(name)
        attributes = dict(_ATTRIBUTE_DEFAULTS.get(expected.op, {}))
        for a in node.attribute:
            default = attributes.get(a.name, KeyError)
            value = onnx.helper.get_attribute_value(a) if not a.ref_attr_name else KeyError
            kind_ok = a.type == (onnx.AttributeProto.FLOAT if isinstance(default, float) else onnx.AttributeProto.INT)
            if default is KeyError or value is KeyError or not kind_ok:
                raise differ(
                    k, f"({expected.op}) has the attribute {quote(a.name, 30)}, which the architecture does not"
                )
            attributes[a.name] = value
        wanted = dict(_ATTRIBUTE_DEFAULTS.get(expected.op, {})) | expected.attributes
        if attributes != wanted:
            diff = {n: v for n, v in attributes.items() if wanted.get(n) != v}
            raise differ(k, f"({expected.op}) has attributes {diff}, expected { ({n: wanted[n] for n in diff}) }")
        if len(node.output) != len(expected.outputs):
            raise differ(k, f"({expected.op}) has {len(node.output)} outputs, expected {len(expected.outputs)}")
        for j, (name, graph_output) in enumerate(zip(node.output, expected.outputs, strict=True)):
            if graph_output is not None and name != graph_output:
                raise differ(
                    k, f"({expected.op}) output {j} is {quote(name, 40)}, expected the graph output {graph_output!r}"
                )
            if not name or name in produced or name in inputs or name in arrays:
                raise differ(k, f"({expected.op}) output {j} {quote(name, 40)} is empty or already defined")
            produced[name] = (k, j)
    if len(graph.node) > len(want.nodes):
        k = len(want.nodes)
        extra = graph.node[k]
        raise differ(k, f"({quote(extra.op_type, 30)[1:-1]}) is one more than the architecture's {k} nodes")
    unused = [name for name in arrays if name not in used]
    if unused:
        raise fail(path, f"initializer {quote(unused[0])} is not used by the declared {kind} architecture")
