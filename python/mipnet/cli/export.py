"""``mipnet export``: the network as a standard ONNX model for onnxruntime, OpenVINO, TensorRT (docs/deployment.md).

    mipnet export --onnx model.onnx                          # the shipped weights, 384x512, 6+6 iterations
    mipnet export --onnx model.onnx --weights w.safetensors --size 480 640 --iters 4 4
    mipnet export --onnx model.onnx --dynamic                # any size; the initial disparity is an input
"""

from __future__ import annotations

import argparse
import os

from .common import ImageSize, add_iters, load_model, positive_int, require_module

#: the fixed size written when neither --size nor --dynamic is given (the size of the README's figures)
DEFAULT_SIZE = (384, 512)


def add_parser(sub) -> argparse.ArgumentParser:
    """Registers ``export`` on the ``mipnet`` sub-command parsers."""
    from ..export import MIN_OPSET

    p = sub.add_parser("export", help="write the network as an ONNX model (onnxruntime, OpenVINO, TensorRT)",
                       description="Write the eval forward as a standard-opset ONNX model (iterations unrolled, "
                                   "no custom operators): inputs left, right (N,3,H,W) float32 RGB 0..255, "
                                   "output disparity (N,1,H,W). Needs the onnx package, not torch.")
    p.add_argument("--onnx", required=True, metavar="FILE", help="the ONNX file to write")
    p.add_argument("--weights", metavar="FILE", help="weights to export (default: the shipped weights)")
    shape = p.add_mutually_exclusive_group()
    shape.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), action=ImageSize,
                       help=f"fixed image size (default {DEFAULT_SIZE[0]} {DEFAULT_SIZE[1]}); any H, W >= 32")
    shape.add_argument("--dynamic", action="store_true",
                       help="symbolic batch, height and width; the initial disparity becomes a third input, "
                            "disp_init (docs/deployment.md)")
    p.add_argument("--batch", type=positive_int, default=1, help="fixed batch size N (default 1; not with --dynamic)")
    p.add_argument("--opset", type=int, default=MIN_OPSET, help=f"ONNX opset (default {MIN_OPSET})")
    add_iters(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..errors import ArgumentError
    from ..export import export_onnx

    require_module("onnx", "onnx", "mipnet export --onnx")
    if args.dynamic and args.batch != 1:
        raise ArgumentError("--batch fixes the batch size; with --dynamic the batch is symbolic already")
    model = load_model(args.weights)
    size = None if args.dynamic else (args.size or DEFAULT_SIZE)
    proto = export_onnx(model, args.onnx, size=size, dynamic=args.dynamic, iters=args.iters, opset=args.opset,
                        batch=args.batch)
    shapes = {v.name: "x".join(str(d.dim_value or d.dim_param) for d in v.type.tensor_type.shape.dim)
              for v in list(proto.graph.input) + list(proto.graph.output)}
    inputs = ", ".join(f"{name} {dims}" for name, dims in shapes.items() if name != "disparity")
    print(f"mipnet export: wrote {args.onnx} ({os.path.getsize(args.onnx) / 2**20:.1f} MiB, opset {args.opset}, "
          f"{len(proto.graph.node)} nodes, iterations {args.iters[0]}+{args.iters[1]}); inputs {inputs}; "
          f"output disparity {shapes['disparity']}")
    return 0
