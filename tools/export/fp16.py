"""Mixed-precision DA3 graphs: the ViT backbone in float16, everything else in float32.

Upstream DA3 runs its backbone under fp16/bf16 autocast and its depth head and camera encoder and
decoder in fp32 (notes/da3.md: the heads' `Exp` overflows fp16 above about 11). `to_mixed_fp16` does
the same to an exported fp32 graph: the nodes the dynamo exporter recorded inside `net.backbone` (its
`pkg.torch.onnx.name_scopes` metadata) compute in fp16 with fp16 weights, all others stay fp32, and
Casts join the two. The graph's inputs and outputs keep their contract types (float32), so an fp16
graph is a drop-in replacement for the fp32 one on the same contract. (ONNX Runtime's own converter,
`onnxruntime.transformers.float16`, rounds the tensors *between* two fp32 nodes to fp16 too, which would
put the heads' `Exp` output through fp16: hence this small rewrite.)
"""

from __future__ import annotations

import ast
from collections import Counter

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from models.da3.contract import PRECISION_KEY
from runtime.errors import ModelError

F32, F16 = TensorProto.FLOAT, TensorProto.FLOAT16

#: metadata key under which torch's dynamo exporter records a node's module path (a repr'd list)
SCOPE_KEY = "pkg.torch.onnx.name_scopes"
#: the module (in the export wrapper `SingleGraph`) whose nodes run in fp16
FP16_SCOPE = "net.backbone"
#: ops computed in fp32 wherever they sit (trigonometry and powers lose digits in fp16). Their outputs are
#: cast back to fp16 for region nodes that read them: what keeps the heads' `exp` (which overflows fp16
#: above ~11) in fp32 is that the heads lie outside the region, not this list.
KEEP_FP32_OPS = ("Exp", "Log", "Pow", "Sin", "Cos", "Tan", "Atan", "Acos", "Asin", "Reciprocal", "Range",
                 "CumSum", "RandomNormal", "RandomUniform", "RandomNormalLike", "RandomUniformLike")
#: inputs (by index) that ONNX types as float32 whatever the data's type (Resize's roi and scales)
FLOAT32_INPUTS = {"Resize": (1, 2), "Upsample": (1,)}


def node_scopes(node) -> list[str] | None:
    """The module paths the exporter recorded for `node` (root first), or None if it recorded none."""
    for prop in node.metadata_props:
        if prop.key == SCOPE_KEY:
            try:
                scopes = ast.literal_eval(prop.value)
            except (SyntaxError, ValueError):
                return None
            return [str(s) for s in scopes] if isinstance(scopes, (list, tuple)) else None
    return None


def in_scope(node, scope: str) -> bool:
    """Whether the exporter placed `node` inside module `scope` (or a submodule of it)."""
    scopes = node_scopes(node) or []
    return any(s == scope or s.startswith(scope + ".") for s in scopes)


def _elem_types(model) -> dict[str, int]:
    """ONNX element type of every tensor the graph declares or onnx's shape inference can tell."""
    g = model.graph
    types: dict[str, int] = {t.name: t.data_type for t in g.initializer}
    for vi in list(g.input) + list(g.output) + list(g.value_info):
        if vi.type.HasField("tensor_type"):
            types[vi.name] = vi.type.tensor_type.elem_type
    produced = [o for n in g.node for o in n.output if o]
    if any(o not in types for o in produced):
        inferred = onnx.shape_inference.infer_shapes(model)
        for vi in inferred.graph.value_info:
            if vi.type.HasField("tensor_type") and vi.name not in types:
                types[vi.name] = vi.type.tensor_type.elem_type
    return types


def _attrs_to_fp16(node) -> None:
    """Rewrite the attributes of an fp16 node that would make it emit float32."""
    for a in list(node.attribute):
        if a.name == "to" and node.op_type == "Cast" and a.i == F32:
            a.i = F16
        elif a.name == "dtype" and a.type == onnx.AttributeProto.INT and a.i == F32:
            a.i = F16
        elif a.type == onnx.AttributeProto.TENSOR and a.t.data_type == F32:
            a.t.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(a.t).astype(np.float16), a.t.name))
        elif node.op_type == "Constant" and a.name in ("value_float", "value_floats"):
            value = np.array(a.f if a.name == "value_float" else list(a.floats), np.float16)
            node.attribute.remove(a)
            node.attribute.append(helper.make_attribute("value", numpy_helper.from_array(value)))
    if node.op_type == "ConstantOfShape" and not any(a.name == "value" for a in node.attribute):
        zero = numpy_helper.from_array(np.zeros(1, np.float16))
        node.attribute.append(helper.make_attribute("value", zero))


def to_mixed_fp16(model, scope: str = FP16_SCOPE, where: str = "graph"):
    """Rewrite `model` (an fp32 onnx.ModelProto, changed in place) so that the nodes inside `scope`
    compute in float16; returns (model, summary).

    Float32 tensors entering the fp16 region are cast (initializers converted once), float32 tensors
    leaving it are cast back under their own names, so every node outside keeps its exact inputs.
    summary: {"fp16_nodes", "fp32_nodes", "unscoped_nodes", "fp16_ops": {op: count}, "casts"}; unscoped
    nodes (no exporter metadata, e.g. made by the optimiser) stay fp32.

    Nodes stay fp32, too, when a float input or output has no type ONNX can tell, and when their float
    outputs feed only inputs ONNX types as float32 (e.g. Resize's scales), so such values are not rounded.

    Raises:
        ModelError: no node carries the exporter's scope metadata, none lies inside `scope`, or the graph
            holds subgraphs (If, Loop, Scan: not rewritten).
    """
    g = model.graph
    nodes = list(g.node)
    graphs = (onnx.AttributeProto.GRAPH, onnx.AttributeProto.GRAPHS)
    if any(a.type in graphs for n in nodes for a in n.attribute):
        raise ModelError(f"{where}: the graph holds subgraphs (If/Loop/Scan); the fp16 rewrite does not "
                         "handle them: use the fp32 graph")
    scoped = [n for n in nodes if node_scopes(n) is not None]
    if not scoped:
        raise ModelError(
            f"{where}: no node carries the exporter's module scopes ({SCOPE_KEY}); "
            "fp16 conversion needs a graph from `davio export-da3` (torch's dynamo exporter)"
        )
    types = _elem_types(model)

    def eligible(n) -> bool:
        if n.domain not in ("", "ai.onnx") or not in_scope(n, scope) or n.op_type in KEEP_FP32_OPS:
            return False
        return all(name in types for name in list(n.input) + list(n.output) if name)

    half_ids = {id(n) for n in nodes if eligible(n)}
    # nodes whose float outputs go only into float32-only inputs, directly or through other such nodes of
    # any kind (a Reciprocal outside the region's ops, too), stay fp32
    readers: dict[str, list[tuple[object, int]]] = {}
    for n in nodes:
        for i, name in enumerate(n.input):
            readers.setdefault(name, []).append((n, i))
    outputs = {o.name for o in g.output}
    keep_f32: set[int] = set()
    changed = True
    while changed:
        changed = False
        for n in reversed(nodes):      # readers first (the exporter's order is topological): one pass
            if id(n) in keep_f32:
                continue
            floats = [o for o in n.output if o and types.get(o) == F32]
            if floats and not any(o in outputs for o in floats) and all(
                readers.get(o) and all(id(r) in keep_f32 or i in FLOAT32_INPUTS.get(r.op_type, ())
                                       for r, i in readers[o])
                for o in floats
            ):
                keep_f32.add(id(n))
                changed = True
    half_ids -= keep_f32
    if not half_ids:
        raise ModelError(f"{where}: no node lies inside module {scope!r}; nothing to run in fp16")
    taken = {name for n in nodes for name in list(n.input) + list(n.output)}
    taken |= {t.name for t in g.initializer} | {i.name for i in g.input} | outputs
    taken |= {n.name for n in nodes if n.name}    # the Casts' node names are fresh, too

    def fresh(base: str) -> str:
        name, k = base, 1
        while name in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name)
        return name

    is_half = {o: id(n) in half_ids for n in nodes for o in n.output if o}
    renamed = {o: fresh(f"{o}__fp16") for n in nodes if id(n) in half_ids for o in n.output
               if types.get(o) == F32}
    needs_f32 = {o.name for o in g.output}
    for n in nodes:
        for i, name in enumerate(n.input):
            if id(n) not in half_ids or i in FLOAT32_INPUTS.get(n.op_type, ()):
                needs_f32.add(name)
    graph_inputs = {i.name for i in g.input}   # an initializer that is also an input is fed at run time
    inits = {t.name: t for t in g.initializer if t.name not in graph_inputs}
    to_half: dict[str, str] = {}  # fp32 tensor from outside the region -> its fp16 twin
    new_inits, out_nodes, casts = [], [], 0
    for n in nodes:
        if id(n) in half_ids:
            for i, name in enumerate(n.input):
                if not name or i in FLOAT32_INPUTS.get(n.op_type, ()):
                    continue
                if name in renamed:
                    n.input[i] = renamed[name]
                elif types.get(name) == F32 and not is_half.get(name, False):
                    if name not in to_half:
                        to_half[name] = fresh(f"{name}__to_fp16")
                        if name in inits:
                            arr = numpy_helper.to_array(inits[name]).astype(np.float16)
                            new_inits.append(numpy_helper.from_array(arr, to_half[name]))
                        else:
                            out_nodes.append(helper.make_node("Cast", [name], [to_half[name]], to=F16,
                                                              name=fresh(f"{to_half[name]}_cast")))
                            casts += 1
                    n.input[i] = to_half[name]
            _attrs_to_fp16(n)
            out_nodes.append(n)
            for i, name in enumerate(n.output):
                if name in renamed:
                    n.output[i] = renamed[name]
                    if name in needs_f32:
                        out_nodes.append(helper.make_node("Cast", [renamed[name]], [name], to=F32,
                                                          name=fresh(f"{name}__to_fp32_cast")))
                        casts += 1
        else:
            out_nodes.append(n)
    del g.node[:]
    g.node.extend(out_nodes)
    g.initializer.extend(new_inits)
    used = {name for n in g.node for name in n.input} | {o.name for o in g.output}
    kept = [t for t in g.initializer if t.name in used]
    del g.initializer[:]
    g.initializer.extend(kept)
    del g.value_info[:]  # stale types; ONNX Runtime infers them again
    set_precision(model, "fp16")
    half_nodes = [n for n in nodes if id(n) in half_ids]
    summary = {
        "fp16_nodes": len(half_nodes),
        "fp32_nodes": len(nodes) - len(half_nodes),
        "unscoped_nodes": len(nodes) - len(scoped),
        "casts": casts,
        "fp16_ops": dict(sorted(Counter(n.op_type for n in half_nodes).items())),
    }
    return model, summary


def set_precision(model, precision: str) -> None:
    """Record `precision` in `model`'s metadata (PRECISION_KEY)."""
    for prop in model.metadata_props:
        if prop.key == PRECISION_KEY:
            prop.value = precision
            return
    model.metadata_props.add(key=PRECISION_KEY, value=precision)


def graph_precision(model) -> str:
    """The precision a DAVIO export recorded in `model`'s metadata ("fp32" when it recorded none)."""
    for prop in model.metadata_props:
        if prop.key == PRECISION_KEY:
            return prop.value
    return "fp32"
