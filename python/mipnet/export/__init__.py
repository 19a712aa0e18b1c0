"""MIPNet as a standard ONNX model, for onnxruntime, OpenVINO, TensorRT and other runtimes (docs/deployment.md).

``export_onnx(model, "model.onnx", size=(384, 512))`` writes the eval forward of ``model`` — inputs
``left``, ``right`` (N, 3, H, W) float32 RGB in 0..255, output ``disparity`` (N, 1, H, W) — with the
``onnx`` package alone (``pip install mipnet[onnx]``); torch is not involved.

Design. The graph is not traced: a small builder (:mod:`.graph`, names, initializers, the operators whose
signature changed between opsets) and an emitter that walks the network's modules in the order of
``MIPNet.forward`` (:mod:`.network_graph`: encoder, pyramid, initial field, update blocks, upsampling,
iteration schedule; :mod:`.correlation`: the IP and RLS correlations and their warps) write each layer as
standard ONNX operators. The emitter reads the modules and the config, so every architecture option
(``use_aff``, ``use_ip``, ``use_rls``, ``rx``, ``ry``, ``vertical_constraint``) exports, every parameter is
an initializer under its canonical name (docs/architecture.md §2.10), and a change to the network shows as
a mismatch in ``tests_py/test_export_onnx.py``, which runs the graph in onnxruntime and OpenVINO against
``MIPNet.forward``. The fused kernels of mipnet's engine become plain operators: the warps are ``Gather``
along rows (the vertical constraint, the default) or ``GridSample`` (without it), the convex upsampling a
softmax, nine shifted products and ``DepthToSpace``; every size is computed from the inputs' shapes, so
one graph serves a fixed and a dynamic size. The seeded Gamma draw of the initial disparity becomes the
constant ``initial_disparity`` in a fixed-size graph and the input ``disp_init`` in a dynamic one
(:func:`initial_disparity` computes it).
"""

from .onnx_export import MIN_OPSET, export_onnx, initial_disparity

__all__ = ["export_onnx", "initial_disparity", "MIN_OPSET"]
