"""``export_onnx``: MIPNet's eval forward as a standard ONNX model, written without torch.

The graph is built node by node with ``onnx.helper`` (:mod:`.network_graph`, :mod:`.correlation`,
:mod:`.graph`), checked with ``onnx.checker`` (full check, with strict shape inference) and written
atomically. See docs/deployment.md for running it with onnxruntime, OpenVINO and TensorRT.
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from ..errors import ArgumentError, DTypeError, ShapeError
from ..model.config import DIVISOR, MIN_SIZE
from ..model.network import MIPNet, gamma_draw
from ..utils.files import atomic_write
from .graph import FLOAT, GraphBuilder
from .network_graph import NetworkGraph

__all__ = ["export_onnx", "initial_disparity", "MIN_OPSET"]

#: The lowest opset written: GridSample (16) and the Reduce/Split/Pad signatures handled by GraphBuilder.
MIN_OPSET = 17


def initial_disparity(model: MIPNet, size: tuple[int, int], batch: int = 1, seed: int = 20) -> np.ndarray:
    """The initial disparity ``model(left, right, seed=seed)`` starts from at image size ``size``, as the
    ``disp_init`` input of a graph exported with one (a dynamic-size export).

    Parameters
    ----------
    model : MIPNet
        Its config gives the Gamma parameters (architecture.md §2.4).
    size : (int, int)
        Image height and width (before the padding to a multiple of 16).
    batch : int, default 1
        Pairs in the batch; each starts from the same draw, as in the eval forward.
    seed : int, default 20
        The seed of the eval forward (``MIPNet.forward``'s ``seed``).

    Returns
    -------
    numpy.ndarray
        (batch, 1, H16, W16) float32 in 1/16-level pixels, H16 and W16 the padded size over 16.
    """
    h16, w16 = _size16(*_check_size(size))
    cfg = model.config
    d0 = gamma_draw(np.random.default_rng(seed), (1, 1, h16, w16), cfg.gamma_shape, cfg.gamma_scale,
                    cfg.max_disp_init) / 16.0
    return np.repeat(d0.astype(np.float32), int(batch), axis=0)


def export_onnx(model: MIPNet, path: str | os.PathLike, *, size: Sequence[int] | None = None, dynamic: bool = False,
                iters: int | Sequence[int] = (6, 6), opset: int = MIN_OPSET, batch: int = 1, seed: int = 20,
                disp_init_input: bool | None = None):
    """Writes ``model``'s eval forward to ``path`` as an ONNX model (standard opset, no custom domain,
    iterations unrolled), built with the ``onnx`` package; torch is never imported.

    The graph takes ``left`` and ``right``, each (N, 3, H, W) float32 RGB in 0..255 (the batch
    ``MIPNet.forward`` takes), and returns ``disparity`` (N, 1, H, W) float32, the positive left-view
    disparity that ``model(left, right, iters=iters, seed=seed)`` returns (as (N, H, W) there). The
    replicate padding to a multiple of 16 and the crop back are in the graph, so any H, W >= 32 works.

    Parameters
    ----------
    model : MIPNet
        The network (float32). The graph is its eval-mode forward (BatchNorm running statistics)
        whatever mode it is in.
    path : str or os.PathLike
        The file to write, atomically: a failure leaves ``path`` as it was and no temporary file.
    size : (int, int), optional
        Fixed image size (H, W), both at least 32. Required unless ``dynamic``.
    dynamic : bool, default False
        Symbolic batch, height and width instead of a fixed size. The initial disparity is then the
        third input ``disp_init`` (see below), since the seeded Gamma draw depends on the size.
    iters : int or (int, int), default (6, 6)
        IPM iterations (n16, n4), unrolled into the graph; n16 >= 1, n4 >= 0.
    opset : int, default 17
        ONNX opset, from 17 to the newest the installed ``onnx`` knows.
    batch : int, default 1
        The fixed batch size N (fixed-size export only).
    seed : int, default 20
        The seed of the eval forward's Gamma draw, stored in the graph as the constant
        ``initial_disparity`` (fixed-size export without ``disp_init``).
    disp_init_input : bool, optional
        Take the initial disparity as a third input ``disp_init`` (N, 1, H16, W16) float32 in 1/16-level
        pixels (H16, W16: the padded size over 16), as ``MIPNet.forward``'s ``disp_init``;
        :func:`initial_disparity` gives the seeded draw. Default: only for ``dynamic``.

    Returns
    -------
    onnx.ModelProto
        The model written.

    Raises
    ------
    ArgumentError
        Not a MIPNet, bad ``iters``, ``opset``, ``batch`` or ``seed``, neither or both of ``size`` and
        ``dynamic``, ``dynamic`` without ``disp_init``, or the onnx package missing.
    ShapeError
        ``size`` not two integers of at least 32.
    DTypeError
        The model is not float32.
    FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError
        ``path`` cannot be written (checked before the graph is built).
    """
    try:
        import onnx
    except ImportError:
        raise ArgumentError("export_onnx needs the onnx package: pip install onnx (or mipnet[onnx])") from None
    if not isinstance(model, MIPNet):
        raise ArgumentError(f"export_onnx: model must be a mipnet.MIPNet, got {type(model).__name__}")
    if model.dtype != np.float32:
        raise DTypeError(f"export_onnx: the graph is float32, the model is {model.dtype} (call model.float())")
    n16, n4 = _check_iters(iters)
    newest = onnx.defs.onnx_opset_version()
    if not isinstance(opset, (int, np.integer)) or not MIN_OPSET <= opset <= newest:
        raise ArgumentError(f"export_onnx: opset must be an integer from {MIN_OPSET} to {newest} (the installed onnx "
                            f"{onnx.__version__}), got {opset!r}")
    if dynamic and size is not None:
        raise ArgumentError(f"export_onnx: give a fixed size or dynamic=True, not both (size={tuple(size)})")
    if not dynamic and size is None:
        raise ArgumentError("export_onnx: give the image size, size=(H, W), or dynamic=True")
    if not isinstance(batch, (int, np.integer)) or batch < 1:
        raise ArgumentError(f"export_onnx: batch must be a positive integer, got {batch!r}")
    with_init = dynamic if disp_init_input is None else bool(disp_init_input)
    if dynamic and not with_init:
        raise ArgumentError("export_onnx: a dynamic-size graph needs the disp_init input (the seeded initial "
                            "disparity depends on the size; mipnet.export.initial_disparity gives it)")
    if not with_init and not isinstance(seed, (int, np.integer)):
        raise ArgumentError(f"export_onnx: seed must be an integer (the eval forward's seeded draw), got {seed!r}")
    path = os.fspath(path)
    _check_writable(path)

    b = GraphBuilder(int(opset))
    if dynamic:
        n, h, w, h16, w16 = "batch", "height", "width", "height16", "width16"
    else:
        (h, w), n = _check_size(size), int(batch)
        h16, w16 = _size16(h, w)
    left, right = (b.input(name, FLOAT, [n, 3, h, w]) for name in ("left", "right"))
    if with_init:
        initial = b.input("disp_init", FLOAT, [n, 1, h16, w16])
    else:
        initial = b.initializer("initial_disparity", initial_disparity(model, (h, w), 1, int(seed)))
    disparity = NetworkGraph(b, model).forward(left, right, initial, (n16, n4))
    b.output(disparity, "disparity", FLOAT, [n, 1, h, w])
    size_text = "dynamic size" if dynamic else f"{n}x3x{h}x{w}"
    proto = b.model("mipnet", doc=f"MIPNet eval forward, {size_text}, iters ({n16}, {n4}), "
                                  + ("initial disparity from the disp_init input" if with_init else f"seed {seed}"))
    onnx.checker.check_model(proto, full_check=True)
    with atomic_write(path) as f:
        f.write(proto.SerializeToString())
    return proto


def _size16(h: int, w: int) -> tuple[int, int]:
    """The 1/16-level size: the padded size (the next multiples of 16, architecture.md §2.1) over 16."""
    # ceil(L / 16) = (L + 15) // 16
    return (h + DIVISOR - 1) // DIVISOR, (w + DIVISOR - 1) // DIVISOR


def _check_iters(iters) -> tuple[int, int]:
    n16, n4 = (iters, iters) if isinstance(iters, (int, np.integer)) else tuple(iters)
    if not all(isinstance(v, (int, np.integer)) for v in (n16, n4)) or n16 < 1 or n4 < 0:
        raise ArgumentError(f"export_onnx: iters=(n16, n4) needs integers n16 >= 1 and n4 >= 0, got {iters}")
    return int(n16), int(n4)


def _check_size(size) -> tuple[int, int]:
    try:
        h, w = size
    except (TypeError, ValueError):
        raise ShapeError(f"export_onnx: size must be (H, W), got {size!r}") from None
    if not all(isinstance(v, (int, np.integer)) for v in (h, w)) or min(h, w) < MIN_SIZE:
        raise ShapeError(f"export_onnx: size must be two integers of at least {MIN_SIZE} (H, W), got {tuple(size)}")
    return int(h), int(w)


def _check_writable(path: str) -> None:
    """Raises the OSError that writing ``path`` would meet, before any work: a missing folder, a folder
    at ``path``, or no permission to create files in its folder."""
    import errno

    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, "is a directory, not a file to write the ONNX model to", path)
    if not os.path.exists(folder):
        raise FileNotFoundError(errno.ENOENT, f"the folder {folder} does not exist", path)
    if not os.path.isdir(folder):
        raise NotADirectoryError(errno.ENOTDIR, f"{folder} is not a folder", path)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, f"no permission to write in {folder}", path)
