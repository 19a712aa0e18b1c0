"""mipnet on Ray (``mipnet.distributed``, docs/distributed.md) on a local cluster of 2 CPUs: ``mipnet infer --ray``
writes the single-process command's outputs bitwise, records a broken pair and resumes without model work;
``mipnet train --ray`` gives the one-process run's losses and weights (tolerances below), resumes exactly, and
stops with a resumable checkpoint when a worker is lost or on SIGTERM; without Ray, ``--ray`` is one line.

Every test runs under a deadline (SIGALRM): a hung Ray pipeline fails the test instead of hanging CI.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import mipnet
from mipnet.cli import main
from mipnet.data.synthetic import make_pair
from mipnet.distributed import RayGradients, infer_dataset
from mipnet.inference.outputs import OutputOptions, OutputWriter
from mipnet.stereo import io
from mipnet.training import resolve_config
from mipnet.training.checkpoint import load_latest_checkpoint
from mipnet.training.fit import _new_model, _transform, backward_pass, build_dataset
from mipnet.training.log import TrainLog
from mipnet.utils.data.dataloader import DataLoader

from helpers import require

#: seconds any one test (or the cluster's start) may take before it fails
DEADLINE = 300
PAIRS, BROKEN = 12, 5
ITERS = ["--iters", "2", "2"]
TRAIN = ["--preset", "cpu", "--crop", "64", "96", "--batch-size", "2", "--iters", "1", "1", "--val-every", "0",
         "--workers", "0", "--checkpoint-every", "100", "--data", "scenes:0.5", "synthetic-underwater:0.5",
         "--freeze-bn", "--quiet"]
ON_RAY = ["--ray", "--workers", "2"]
#: one process vs 2 workers: the loss of a step from the same weights within this relative error (measured
#: 3e-8) ...
LOSS_RTOL = 1e-6
#: ... the losses of steps 2 and 3, which follow the weights after AdamW updates (see WEIGHTS_RTOL), within this
#: (measured 1e-8 to 1.5e-6, depending on which near-zero gradient entries the rounding flips) ...
LATER_LOSS_RTOL = 1e-5
#: ... a step's summed gradient within this share of its largest entry (measured 9e-8) ...
GRAD_TOL = 1e-6
#: ... and the weights after 3 AdamW steps within this relative L2 distance over the model (measured 1.2e-5), not
#: 1e-6 each: AdamW divides each gradient entry by its own RMS, so small gradients (attention BatchNorm biases in
#: the warm-up) and gradients that are rounding noise (conv biases before an InstanceNorm, exactly 0 in exact
#: arithmetic) turn 1e-7 differences into per-cent differences of near-zero weights (docs/distributed.md).
WEIGHTS_RTOL = 1e-4


@contextlib.contextmanager
def deadline(seconds: int):
    """TimeoutError in this (the main) thread after ``seconds``."""
    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s: a hung Ray pipeline?")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(autouse=True)
def _deadline():
    with deadline(DEADLINE):
        yield


@pytest.fixture(scope="module")
def ray_cluster():
    """One local Ray cluster of 2 CPUs for the module (mipnet's Ray code uses a session it finds as it is)."""
    ray = require("ray")
    require("ray.data")
    with deadline(DEADLINE):
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


# ---- mipnet infer --ray -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """12 generated 64x96 pairs in L/ and R/, pair 5's right image 48 rows high; a calib.txt."""
    root = tmp_path_factory.mktemp("pairs")
    for side in "LR":
        (root / side).mkdir()
    for i in range(PAIRS):
        pair = make_pair(64, 96, seed=i)
        io.write_image(root / "L" / f"p{i:02d}.png", pair["left"])
        io.write_image(root / "R" / f"p{i:02d}.png", pair["right"][:48] if i == BROKEN else pair["right"])
    (root / "calib.txt").write_text("cam0=[120 0 48; 0 120 32; 0 0 1]\ncam1=[120 0 50; 0 120 32; 0 0 1]\n"
                                    "baseline=100\nwidth=96\nheight=64\n")
    return root


def _files(folder) -> dict[str, bytes]:
    return {name: (folder / name).read_bytes() for name in sorted(os.listdir(folder))}


def test_infer_on_ray_writes_the_single_process_outputs_records_the_broken_pair_and_resumes(
        ray_cluster, pairs, tmp_path, capsys):
    command = ["infer", "-l", str(pairs / "L" / "*.png"), "-r", str(pairs / "R" / "*.png"), *ITERS, "--confidence",
               "--calib", str(pairs / "calib.txt")]
    single, on_ray = tmp_path / "single", tmp_path / "on_ray"
    assert main(command + ["-o", str(single), "--batch-size", "1"]) == 1
    single_err = capsys.readouterr().err
    assert main(command + ["-o", str(on_ray), "--ray", "--workers", "2"]) == 1
    ray_out, ray_err = capsys.readouterr()
    assert f"wrote {PAIRS - 1} disparity map(s)" in ray_out
    assert f"1 of {PAIRS} pairs failed" in ray_err

    expected = _files(single)
    names = [f"p{i:02d}" for i in range(PAIRS) if i != BROKEN]
    writer = OutputWriter(OutputOptions(confidence=True), on_ray, io.read_calib(pairs / "calib.txt"))
    assert sorted(expected) == sorted(path.name for name in names for path in writer.outputs(name))
    written = _files(on_ray)
    assert sorted(written) == sorted([*expected, "failures.jsonl"])
    for name in expected:  # 11 pairs x disparity, confidence, depth, point cloud: bitwise
        assert written[name] == expected[name], name

    broken = f"p{BROKEN:02d}"
    failures = [json.loads(line) for line in written["failures.jsonl"].decode().splitlines()]
    assert [(f["name"], f["left"], f["right"]) for f in failures] == [
        (broken, str(pairs / "L" / f"{broken}.png"), str(pairs / "R" / f"{broken}.png"))]
    assert "48x96" in failures[0]["reason"] and f"  {failures[0]['reason']}" in single_err.splitlines()

    # a rerun: pair 0 lost one file (an interrupted run), the 10 others are complete
    (on_ray / "p00_disp.png").unlink()
    stamps = {name: os.stat(on_ray / name).st_mtime_ns for name in expected if not name.startswith("p00_")}
    report = infer_dataset(str(pairs / "L" / "*.png"), str(pairs / "R" / "*.png"), on_ray, workers=2,
                           iters=(2, 2), options=OutputOptions(confidence=True), calib=str(pairs / "calib.txt"),
                           progress=False)
    assert report.run == ["p00"] and sorted(report.skipped) == names[1:]
    assert [f["name"] for f in report.failed] == [broken]
    assert len(report.threads) == 2  # what reached an actor: p00 and the broken pair, no other
    assert report.threads == [1, 1]  # 2 actors on 2 CPUs: one kernel thread each
    assert {name: os.stat(on_ray / name).st_mtime_ns for name in stamps} == stamps
    assert _files(on_ray) == written


def test_infer_on_ray_of_a_single_broken_pair_is_the_command_error(ray_cluster, pairs, tmp_path, capsys):
    broken = f"p{BROKEN:02d}.png"
    assert main(["infer", "-l", str(pairs / "L" / broken), "-r", str(pairs / "R" / broken), "-o", str(tmp_path),
                 *ITERS, "--ray"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("mipnet infer: error:")]
    assert len(err) == 1 and "48x96" in err[0]
    assert main(["infer", "-l", str(pairs / "L" / broken), "-r", str(pairs / "R" / broken), "-o", str(tmp_path),
                 "--ray", "--batch-size", "2"]) == 2
    assert "--batch-size does not apply with --ray" in capsys.readouterr().err


# ---- mipnet train --ray -----------------------------------------------------------------------------


def _losses(run) -> list[float]:
    return [r["loss"] for r in TrainLog(os.path.join(run, "log.jsonl")).records() if "loss" in r]


def _weights(run) -> dict[str, np.ndarray]:
    return mipnet.load(os.path.join(run, "model.safetensors")).state_dict()


def _config():
    """The TrainConfig of the command line ``TRAIN``."""
    return resolve_config("cpu", overrides=dict(crop=(64, 96), batch_size=2, iters=(1, 1), val_every=0, workers=0,
                                                data=["scenes:0.5", "synthetic-underwater:0.5"], freeze_bn=True))


@pytest.fixture(scope="module")
def runs(ray_cluster, tmp_path_factory):
    """3 steps of one process and of 2 Ray workers, one global batch of 2, BatchNorm frozen."""
    base = tmp_path_factory.mktemp("runs")
    one, two = str(base / "one"), str(base / "two")
    with deadline(DEADLINE):
        assert main(["train", *TRAIN, "--steps", "3", "--out", one]) == 0
        assert main(["train", *TRAIN, "--steps", "3", "--out", two, *ON_RAY]) == 0
    return one, two


def test_train_on_ray_gives_the_losses_and_weights_of_one_process(runs):
    one, two = runs
    a, b = _losses(one), _losses(two)
    assert len(a) == len(b) == 3
    assert b[0] == pytest.approx(a[0], rel=LOSS_RTOL)
    np.testing.assert_allclose(b[1:], a[1:], rtol=LATER_LOSS_RTOL)
    wa, wb = _weights(one), _weights(two)
    assert list(wa) == list(wb)
    flat_a, flat_b = (np.concatenate([w[key].ravel() for key in wa]) for w in (wa, wb))
    assert np.linalg.norm(flat_b - flat_a) <= WEIGHTS_RTOL * np.linalg.norm(flat_a)
    initial = _new_model(_config()).state_dict()
    flat_initial = np.concatenate([initial[key].ravel() for key in wa])
    # the two runs are far closer to each other than to where they started
    assert np.linalg.norm(flat_b - flat_a) < 1e-2 * np.linalg.norm(flat_a - flat_initial)


def test_a_step_on_two_workers_sums_to_the_one_process_gradient(ray_cluster):
    config = _config()
    dataset, augmentors = build_dataset(config)
    sample = next(iter(DataLoader(dataset, batch_size=2, shuffle=True, seed=config.seed,
                                  transform=_transform(augmentors))))
    model = _new_model(config).train().freeze_bn()
    generator = mipnet.random.default_generator()
    before = generator.bit_generator.state
    loss, final = backward_pass(model, sample, config)
    expected = [p.grad.data.copy() for p in model.parameters()]
    after = generator.bit_generator.state
    generator.bit_generator.state = before
    model.zero_grad()
    gradients = RayGradients(ray_cluster, 2, timeout=DEADLINE)
    try:
        ray_loss, ray_final = gradients(model, sample, config)
    finally:
        gradients.close()
    assert generator.bit_generator.state == after  # the driver drew what the one-process forward draws
    assert ray_loss == pytest.approx(loss, rel=LOSS_RTOL)
    scale = max(np.abs(g).max() for g in expected)
    for p, g in zip(model.parameters(), expected):
        np.testing.assert_allclose(p.grad.data, g, rtol=0, atol=GRAD_TOL * scale)
    np.testing.assert_allclose(ray_final, final, rtol=0, atol=1e-4)
    assert gradients.threads == [1, 1] and len(gradients.timings) == 1


def _interrupt_on_call(monkeypatch, call: int, interrupt) -> None:
    """``interrupt(gradients)`` just before RayGradients' ``call``-th step."""
    original, calls = RayGradients.__call__, []

    def step(self, model, sample, config):
        calls.append(1)
        if len(calls) == call:
            interrupt(self)
        return original(self, model, sample, config)

    monkeypatch.setattr(RayGradients, "__call__", step)


def _assert_resumes_to_the_uninterrupted_run(run: str, uninterrupted: str) -> None:
    assert load_latest_checkpoint(run).step == 2
    assert main(["train", "--resume", run, "--steps", "3", "--quiet", *ON_RAY]) == 0
    assert _losses(run) == _losses(uninterrupted)
    a, b = _weights(run), _weights(uninterrupted)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_a_lost_worker_stops_the_run_with_a_resumable_checkpoint(runs, ray_cluster, tmp_path, monkeypatch, capsys):
    run = str(tmp_path / "run")
    _interrupt_on_call(monkeypatch, 3, lambda gradients: ray_cluster.kill(gradients.actors[1]))
    assert main(["train", *TRAIN, "--steps", "3", "--out", run, *ON_RAY]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("mipnet train: error:")]
    assert len(err) == 1, err
    assert "step 3 failed: Ray worker 2 of 2 was lost" in err[0] and "saved at step 2" in err[0], err[0]
    monkeypatch.undo()
    _assert_resumes_to_the_uninterrupted_run(run, runs[1])


def test_sigterm_stops_a_run_on_ray_after_the_step_with_a_checkpoint(runs, tmp_path, monkeypatch):
    run = str(tmp_path / "run")
    _interrupt_on_call(monkeypatch, 2, lambda gradients: os.kill(os.getpid(), signal.SIGTERM))
    assert main(["train", *TRAIN, "--steps", "3", "--out", run, *ON_RAY]) == 0
    assert len(_losses(run)) == 2
    monkeypatch.undo()
    _assert_resumes_to_the_uninterrupted_run(run, runs[1])


# ---- without Ray ------------------------------------------------------------------------------------

WITHOUT_RAY = textwrap.dedent("""
    import sys
    sys.modules["ray"] = None  # `import ray` raises ImportError, as when it is not installed
    import mipnet, mipnet.distributed
    from mipnet.cli import main
    pair = mipnet.data.synthetic.make_pair(64, 96, seed=0)
    assert mipnet.MIPNet.pretrained()(pair["left"], pair["right"], iters=(1, 1)).shape == (64, 96)
    print("infer", main(["infer", "--ray"]), file=sys.stderr)
    print("train", main(["train", "--out", sys.argv[1], "--ray"]), file=sys.stderr)
    print("api", end=" ", file=sys.stderr)
    try:
        mipnet.distributed.infer_dataset(None, None, sys.argv[1])
    except mipnet.errors.ArgumentError as error:
        print(error, file=sys.stderr)
""")


def test_without_ray_the_package_works_and_ray_is_one_line(tmp_path):
    done = subprocess.run([sys.executable, "-c", WITHOUT_RAY, str(tmp_path / "run")], capture_output=True, text=True,
                          timeout=DEADLINE)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.splitlines()
    hint = "pip install 'mipnet[ray]'"
    for command in ("infer", "train"):
        error = [i for i, line in enumerate(lines) if line.startswith(f"mipnet {command}: error:")]
        assert len(error) == 1 and hint in lines[error[0]], lines
        assert lines[error[0] + 1] == f"{command} 2"
    assert any(line.startswith("api ") and hint in line for line in lines), lines
