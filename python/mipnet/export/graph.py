"""A small ONNX graph builder over ``onnx.helper``: nodes with unique names, initializers, constants,
and the few operators whose signature changed between the opsets the exporter writes (17 and later).

Every helper takes and returns tensor *names* (str), as ONNX graphs connect nodes. Names are made
from a scope stack (``with builder.scope("encoder.stem"):``), so a node's name says which module of
the network made it, as the initializers carry the canonical parameter names (docs/architecture.md §2.10).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence

import numpy as np

from ..errors import ArgumentError

__all__ = ["GraphBuilder", "TO_END", "FLOAT", "INT64"]

#: ``onnx.TensorProto`` element types, without importing onnx when mipnet is imported.
FLOAT, INT64 = 1, 7
#: Slice end meaning "to the end of the axis" (ONNX clamps it to the axis length).
TO_END = np.iinfo(np.int64).max


class GraphBuilder:
    """Collects the nodes, initializers, inputs and outputs of one ONNX graph for ``opset`` (default domain only).

    Parameters
    ----------
    opset : int
        Version of the default ONNX operator set the graph is written for (17 or later).
    """

    def __init__(self, opset: int):
        import onnx

        self.onnx = onnx
        self.opset = int(opset)
        self.nodes: list = []
        self.initializers: dict[str, object] = {}
        self.inputs: list = []
        self.outputs: list = []
        self._scopes: list[str] = []
        self._count: dict[str, int] = {}
        self._constants: dict[tuple, str] = {}

    # ---- names ------------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def scope(self, name: str) -> Iterator[None]:
        """Prefixes the names of the nodes made inside the block with ``name`` (nested scopes join with '/')."""
        self._scopes.append(name)
        try:
            yield
        finally:
            self._scopes.pop()

    def _fresh(self, hint: str) -> str:
        base = "/".join(self._scopes + [hint])
        k = self._count.get(base, 0)
        self._count[base] = k + 1
        return base if k == 0 else f"{base}_{k}"

    # ---- graph inputs, outputs, data --------------------------------------------------------------------
    def input(self, name: str, elem_type: int, shape: Sequence[int | str]) -> str:
        """A graph input (``shape`` entries: ints, or strings for symbolic dimensions)."""
        self.inputs.append(self.onnx.helper.make_tensor_value_info(name, elem_type, list(shape)))
        return name

    def output(self, tensor: str, name: str, elem_type: int, shape: Sequence[int | str]) -> None:
        """Declares ``tensor`` a graph output under ``name`` (renamed through an Identity node)."""
        self.nodes.append(self.onnx.helper.make_node("Identity", [tensor], [name], name=name))
        self.outputs.append(self.onnx.helper.make_tensor_value_info(name, elem_type, list(shape)))

    def initializer(self, name: str, array: np.ndarray) -> str:
        """``array`` stored in the graph under ``name`` (once: later calls with the same name reuse it)."""
        if name not in self.initializers:
            self.initializers[name] = self.onnx.numpy_helper.from_array(np.array(array, order="C"), name)
        return name

    def const(self, value, dtype=np.int64) -> str:
        """A constant tensor (a scalar, or a list or array of values) as an initializer, shared by every
        use of the same dtype, shape and values."""
        array = np.asarray(value, dtype=dtype)
        key = (array.dtype.str, array.shape, array.tobytes())
        if key not in self._constants:
            self._constants[key] = self.initializer(f"const_{len(self._constants)}", array)
        return self._constants[key]

    # ---- nodes --------------------------------------------------------------------------------------------
    def op(self, op_type: str, inputs: Sequence[str], hint: str | None = None, outputs: int = 1, **attrs) -> str | tuple[str, ...]:
        """One node of ``op_type`` on ``inputs`` (names; "" for an omitted optional input); the name of its
        output, or a tuple of ``outputs`` names."""
        name = self._fresh(hint or op_type)
        outs = [name] if outputs == 1 else [f"{name}:{k}" for k in range(outputs)]
        self.nodes.append(self.onnx.helper.make_node(op_type, list(inputs), outs, name=name, **attrs))
        return outs[0] if outputs == 1 else tuple(outs)

    def reduce(self, op_type: str, x: str, axes: Sequence[int], keepdims: bool, hint: str | None = None) -> str:
        """ReduceMean / ReduceMax / ReduceSum over ``axes``: the axes are an attribute before opset 18 (13 for
        ReduceSum) and an input from then on."""
        input_axes = self.opset >= (13 if op_type == "ReduceSum" else 18)
        if input_axes:
            return self.op(op_type, [x, self.const(list(axes))], hint, keepdims=int(keepdims))
        return self.op(op_type, [x], hint, axes=list(axes), keepdims=int(keepdims))

    def split(self, x: str, parts: int, axis: int, hint: str | None = None) -> tuple[str, ...]:
        """``x`` cut into ``parts`` equal pieces along ``axis`` (opset 18 wants the count as an attribute)."""
        if self.opset >= 18:
            return self.op("Split", [x], hint, outputs=parts, axis=axis, num_outputs=parts)
        return self.op("Split", [x], hint, outputs=parts, axis=axis)

    def grid_sample(self, x: str, grid: str, hint: str | None = None) -> str:
        """Bilinear sampling with border padding and ``align_corners`` (opset 20 renamed "bilinear" "linear")."""
        mode = "linear" if self.opset >= 20 else "bilinear"
        return self.op("GridSample", [x, grid], hint, mode=mode, padding_mode="border", align_corners=1)

    def clamp(self, x: str, low: str, high: str, hint: str | None = None) -> str:
        """min(max(x, low), high) with Max and Min (Clip's bounds would have to be initializers for some
        runtimes, TensorRT's parser among them; here they are computed from shapes)."""
        return self.op("Min", [self.op("Max", [x, low]), high], hint)

    def window(self, padded: str, axes: Sequence[int], offsets: Sequence[int], radii: Sequence[int],
               hint: str | None = None) -> str:
        """The map shifted by ``offsets`` read from ``padded``, the map padded by ``radii`` on both sides of
        ``axes``: out[.., p, ..] = padded[.., p + radius + offset, ..] for every p of the unpadded length,
        without knowing that length (negative slice ends count from the end)."""
        starts, ends = [], []
        for offset, radius in zip(offsets, radii):
            if abs(offset) > radius:
                raise ArgumentError(f"GraphBuilder.window: offset {offset} beyond the padding {radius}")
            # [radius + offset, length + radius + offset) of the padded axis of length + 2 radius
            starts.append(radius + offset)
            ends.append(offset - radius if offset < radius else TO_END)
        return self.op("Slice", [padded, self.const(starts), self.const(ends), self.const(list(axes))], hint)

    def dim(self, x: str, axis: int, hint: str | None = None) -> str:
        """The length of ``x`` along ``axis`` as an int64 scalar computed in the graph."""
        shape = self.op("Shape", [x], start=axis, end=axis + 1)
        return self.op("Squeeze", [shape, self.const([0])], hint or f"dim{axis}")

    # ---- the model ----------------------------------------------------------------------------------------
    def model(self, name: str, doc: str = ""):
        """The finished ``onnx.ModelProto`` (the lowest IR version that holds the opset, for older runtimes)."""
        helper = self.onnx.helper
        graph = helper.make_graph(self.nodes, name, self.inputs, self.outputs, list(self.initializers.values()),
                                  doc_string=doc)
        opsets = [helper.make_opsetid("", self.opset)]
        return helper.make_model(graph, opset_imports=opsets, ir_version=helper.find_min_ir_version_for(opsets),
                                 producer_name="mipnet")
