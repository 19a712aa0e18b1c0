"""``python -m mipnet.bench precision``: where float32 loses accuracy in a training-mode forward.

The same network (the torch reference's seeded initialisation, copied into mipnet) runs in training mode
in float32 and in float64, in mipnet and in torch, on the same generated pairs. Each row is one layer group
(the encoder's stages, then predictions of the 24-step sequence, then the sequence loss) and gives each
engine's float32 error against its own float64 result, so the first row where mipnet's error exceeds
torch's shows where precision is lost. Encoder rows: mean |f32 - f64| / mean |f64| of the stage's output
(each engine feeding its own float32 output on, as in the network); prediction rows: mean |f32 - f64| in
pixels; the loss row: |f32 - f64| / |f64|; "updates alone": the predictions of the iterations run on the
float64 encoder output (cast to float32 for the float32 run), which isolates the update blocks. Forward passes only (``no_grad``): the batch statistics of the
training-mode BatchNorms are what differs from eval.
"""

from __future__ import annotations

import sys
from typing import Callable

import numpy as np

import mipnet
from mipnet.autograd import no_grad
from mipnet.data.registry import open_dataset
from mipnet.data.synthetic import EVAL_SEED_START
from mipnet.model.losses import sequence_loss
from mipnet.tensor import Tensor

from .machine import machine_header
from .model import REFERENCE_HINT, reference_dir

#: The encoder's stages, in order, as attribute names shared by mipnet's and the reference's Encoder.
ENCODER_STAGES = ("stem", "layer1", "layer2", "layer3", "out")


def batch(n: int, h: int, w: int, inputs: str = "scenes") -> tuple[np.ndarray, ...]:
    """``n`` pairs (N,3,H,W float64 0..255), their ground truth and validity (N,1,H,W), and a seeded 1/16
    initial disparity (N,1,H/16,W/16). ``inputs``: "scenes", held-out generated scene pairs; "noise", the
    pairs of ``python -m mipnet.bench model`` (uniform noise, the right view the left shifted by 4 pixels),
    whose nearly equal global statistics make the iAFF BatchNorms amplify rounding the most."""
    if inputs == "noise":
        rng = np.random.default_rng(0)
        left = rng.uniform(0, 255, (n, 3, h, w))
        right = np.roll(left, -4, axis=3)
        gt, valid = np.full((n, 1, h, w), 4.0), np.ones((n, 1, h, w), bool)
    else:
        data = open_dataset("scenes", size=(h, w), seed=EVAL_SEED_START + 500, count=n)
        samples = [data[i] for i in range(n)]
        left, right = (np.stack([s[k].transpose(2, 0, 1) for s in samples]).astype(np.float64) for k in ("left", "right"))
        gt = np.stack([s["disparity"][None] for s in samples]).astype(np.float64)
        valid = np.stack([s["valid"][None] for s in samples])
    d0 = np.random.default_rng(1).uniform(0.5, 3.0, (n, 1, h // 16, w // 16))
    return left, right, gt, valid, d0


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    """mean |a - b| / mean |b|."""
    return float(np.mean(np.abs(a - b)) / np.mean(np.abs(b)))


def _mipnet_model(state: dict, dtype) -> mipnet.MIPNet:
    """mipnet's network with ``state`` in ``dtype``, in training mode."""
    model = mipnet.MIPNet()
    model.load_state_dict(state)
    if dtype == np.float64:
        model.double()
    return model.train()


def _torch_model(torch, ref_cls, state: dict, dtype):
    """The torch reference with ``state`` in ``dtype``, in training mode."""
    ref = ref_cls()
    ref.load_state_dict({k: torch.from_numpy(np.array(v)) for k, v in state.items()})
    return ref.to(torch.float64 if dtype == np.float64 else torch.float32).train()


def _encoder_stages(run_stage: Callable[[str, object], object], images: object, to_numpy) -> list[np.ndarray]:
    """The output of every encoder stage, each stage fed the previous one's output."""
    outs, x = [], images
    for name in ENCODER_STAGES:
        x = run_stage(name, x)
        outs.append(to_numpy(x))
    return outs


def mipnet_run(state: dict, dtype, data, iters: tuple[int, int], features: np.ndarray | None) -> dict:
    """mipnet's stage outputs, predictions and loss in ``dtype`` (training mode, no gradients), and the
    predictions of the update iterations alone, run on ``features`` (the float64 encoder output) cast to ``dtype``."""
    left, right, gt, valid, d0 = data
    model = _mipnet_model(state, dtype)
    images = Tensor((2 * (np.concatenate([left, right]) / 255) - 1).astype(dtype))
    forward = lambda: model(left.astype(dtype), right.astype(dtype), iters=iters, disp_init=d0)  # noqa: E731
    with no_grad():
        stages = _encoder_stages(lambda name, x: getattr(model.encoder, name)(x), images, lambda t: t.numpy())
        preds = forward()
        loss = float(sequence_loss(preds, gt.astype(dtype), valid).numpy())
        object.__setattr__(model.encoder, "forward", lambda x: Tensor((stages[-1] if features is None else features).astype(dtype)))
        updates = forward()
    return {"stages": stages, "preds": [p.numpy()[:, 0] for p in preds], "loss": loss,
            "updates": [p.numpy()[:, 0] for p in updates]}


def torch_run(torch, ref_cls, state: dict, dtype, data, iters: tuple[int, int], loss_fn,
              features: np.ndarray | None) -> dict:
    """The reference's outputs as :func:`mipnet_run` gives mipnet's."""
    left, right, gt, valid, d0 = data
    tdt = torch.float64 if dtype == np.float64 else torch.float32
    ref = _torch_model(torch, ref_cls, state, dtype)
    t = lambda a: torch.tensor(a, dtype=tdt)  # noqa: E731
    images = t(2 * (np.concatenate([left, right]) / 255) - 1)
    forward = lambda: ref(t(left), t(right), iters=iters, disp_init=t(d0))  # noqa: E731
    with torch.no_grad():
        stages = _encoder_stages(lambda name, x: getattr(ref.encoder, name)(x), images, lambda x: x.numpy())
        preds = forward()
        loss = float(loss_fn(preds, t(gt), torch.tensor(valid)))
        ref.encoder.forward = lambda x: t(stages[-1] if features is None else features)
        updates = forward()
    return {"stages": stages, "preds": [p.numpy()[:, 0] for p in preds], "loss": loss,
            "updates": [p.numpy()[:, 0] for p in updates]}


def errors(f32: dict, f64: dict) -> list[tuple[str, float]]:
    """(row name, float32 error against float64) for every layer group."""
    mean_px = lambda a, b: float(np.mean(np.abs(a - b)))  # noqa: E731
    rows = [(f"encoder.{name} (rel)", _relative(a, b)) for name, a, b in zip(ENCODER_STAGES, f32["stages"], f64["stages"])]
    rows += [(f"prediction {i} (px)", mean_px(f32["preds"][i], f64["preds"][i])) for i in _shown(len(f64["preds"]))]
    rows.append(("sequence loss (rel)", abs(f32["loss"] - f64["loss"]) / abs(f64["loss"])))
    rows += [(f"updates alone: prediction {i} (px)", mean_px(f32["updates"][i], f64["updates"][i]))
             for i in _shown(len(f64["updates"]))]
    return rows


def _shown(n: int) -> list[int]:
    """The predictions a table shows: the first and last of each level and the last one."""
    return sorted({0, 1, n // 2 - 1, n // 2, n - 1})


def block_ops(torch) -> list[tuple[str, Callable, Callable, str, str]]:
    """The ops of one encoder residual block with iAFF in order: (name, mipnet op, torch op, input, output),
    each op taking (block, input) and the names naming the activations between them ("x": the block's input;
    "block": the whole block on "x")."""
    F = torch.nn.functional
    norm = lambda x: F.instance_norm(x, eps=1e-5)  # noqa: E731
    glob = lambda att: getattr(att, "global")  # noqa: E731
    return [
        ("conv1 3x3", lambda b, x: b.conv1(x), lambda b, x: b.conv1(x), "x", "c1"),
        ("norm1 (instance)", lambda b, x: b.norm1(x), lambda b, x: norm(x), "c1", "n1"),
        ("conv2 3x3", lambda b, x: b.conv2(mipnet.ops.relu(x)), lambda b, x: b.conv2(F.relu(x)), "n1", "c2"),
        ("proj 1x1", lambda b, x: b.proj(x), lambda b, x: b.proj(x), "x", "p"),
        ("fuse.att1.local.conv1 1x1", lambda b, x: b.fuse.att1.local.conv1(x), lambda b, x: b.fuse.att1.local.conv1(x),
         "c2", "l1"),
        ("fuse.att1.local.bn1 (batch)", lambda b, x: b.fuse.att1.local.bn1(x), lambda b, x: b.fuse.att1.local.bn1(x),
         "l1", "l2"),
        ("spatial mean (GAP)", lambda b, x: mipnet.ops.mean(x, (2, 3), keepdim=True),
         lambda b, x: x.mean(dim=(2, 3), keepdim=True), "c2", "g"),
        ("fuse.att1.global branch", lambda b, x: glob(b.fuse.att1)(x), lambda b, x: glob(b.fuse.att1)(x), "g", "G"),
        ("the whole block", lambda b, x: b(x), lambda b, x: b(x), "x", "block"),
    ]


def op_errors(torch, ref, state: dict, images: np.ndarray) -> list[tuple[str, float, float]]:
    """(op, mipnet's and torch's float32 error against their float64 results) for every op of the encoder's
    first residual block in training mode, each op fed the exact float64 input (mipnet's float64 chain, which equals
    torch's to ~1e-15) cast to the type: the mean |f32 - f64| / mean |f64| of its output."""
    models = {dtype: _mipnet_model(state, dtype) for dtype in (np.float32, np.float64)}
    blocks = {dtype: next(iter(model.encoder.layer1.children())) for dtype, model in models.items()}
    torch_blocks = {dtype: _torch_model(torch, ref, state, dtype).encoder.layer1[0] for dtype in (np.float32, np.float64)}
    rows = []
    with no_grad(), torch.no_grad():
        acts = {"x": models[np.float64].encoder.stem(Tensor(images)).numpy()}
        for name, ours, theirs, src, dst in block_ops(torch):
            exact = ours(blocks[np.float64], Tensor(acts[src])).numpy()
            acts[dst] = exact
            mine = ours(blocks[np.float32], Tensor(acts[src].astype(np.float32))).numpy()
            t32 = theirs(torch_blocks[np.float32], torch.tensor(acts[src], dtype=torch.float32)).numpy()
            t64 = theirs(torch_blocks[np.float64], torch.tensor(acts[src])).numpy()
            rows.append((name, _relative(mine, exact), _relative(t32, t64)))
    return rows


def table(ours: list[tuple[str, float]], theirs: list[tuple[str, float]]) -> str:
    lines = ["| layer group | mipnet f32 vs f64 | torch f32 vs f64 | mipnet / torch |", "|---|---|---|---|"]
    for (name, a), (_, b) in zip(ours, theirs):
        lines.append(f"| {name} | {a:.3e} | {b:.3e} | {a / b if b > 0 else float('inf'):.2f} |")
    return "\n".join(lines)


def run(size: tuple[int, int], n: int, iters: tuple[int, int], threads: int, inputs: str = "scenes",
        ops: bool = False) -> int:
    ref_dir = reference_dir()
    if ref_dir is None:
        print(f"mipnet.bench precision: no torch reference found: {REFERENCE_HINT}", file=sys.stderr)
        return 1
    try:
        import torch
    except ImportError:
        print("mipnet.bench precision: torch is needed for the comparison; install it (pip install torch)", file=sys.stderr)
        return 1
    sys.path.insert(0, str(ref_dir))
    from reference import MIPNetTorch, sequence_loss_torch

    torch.set_num_threads(threads)
    mipnet.set_num_threads(threads)
    torch.manual_seed(0)
    state = {k: v.numpy().copy() for k, v in MIPNetTorch().state_dict().items()}
    data = batch(n, *size, inputs=inputs)
    print(machine_header(threads)[0])
    print(f"training-mode forward, {size[0]}x{size[1]} batch {n}, iterations {iters}, the reference's seed-0 "
          f"initialisation, inputs: {inputs}\n")
    if ops:
        images = 2 * (np.concatenate(data[:2]) / 255) - 1
        rows = op_errors(torch, MIPNetTorch, state, images)
        print("the encoder's first residual block, training mode, each op fed the exact float64 input\n")
        print(table([(name, a) for name, a, _ in rows], [(name, b) for name, _, b in rows]).replace("layer group", "op"))
        return 0
    f64 = {"mipnet": mipnet_run(state, np.float64, data, iters, None)}
    features = f64["mipnet"]["stages"][-1]
    f64["torch"] = torch_run(torch, MIPNetTorch, state, np.float64, data, iters, sequence_loss_torch, features)
    ours = errors(mipnet_run(state, np.float32, data, iters, features), f64["mipnet"])
    theirs = errors(torch_run(torch, MIPNetTorch, state, np.float32, data, iters, sequence_loss_torch, features),
                    f64["torch"])
    print(table(ours, theirs))
    return 0


def parse_args(parser) -> None:
    parser.add_argument("--size", default="384x512", help="input size HxW, multiples of 16 (default 384x512)")
    parser.add_argument("--batch", type=int, default=2, help="pairs in the batch (default 2)")
    parser.add_argument("--iters", default="6,6", help="iterations N16,N4 (default 6,6)")
    parser.add_argument("--threads", type=int, default=2, help="threads for mipnet and torch (default 2)")
    parser.add_argument("--inputs", choices=("scenes", "noise"), default="scenes",
                        help="held-out generated scene pairs (default) or the uniform-noise pairs of the model bench")
    parser.add_argument("--ops", action="store_true",
                        help="instead of the network: each op of the encoder's first residual block, fed the exact "
                             "float64 input (relative error of its output)")


def main(args) -> int:
    size = tuple(int(v) for v in args.size.lower().split("x"))
    iters = tuple(int(v) for v in args.iters.split(","))
    return run(size, args.batch, iters, args.threads, args.inputs, args.ops)
