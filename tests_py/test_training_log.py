"""The training loop reports through ``logging`` (mipnet.training.fit, mipnet.training.checkpoint), and
``mipnet train`` shows those records on stderr as it always printed them."""

from __future__ import annotations

import logging
import os

import pytest

import mipnet.cli
from mipnet.cli.common import show_training_log
from mipnet.errors import FormatError
from mipnet.training.checkpoint import checkpoint_dir, load_latest_checkpoint

TINY = ["--crop", "64", "96", "--batch-size", "2", "--iters", "1", "1", "--workers", "0",
        "--data", "scenes:0.5", "synthetic:0.5", "--quiet"]


def test_a_skipped_checkpoint_is_a_warning_record(tmp_path, caplog):
    run = str(tmp_path / "run")
    os.makedirs(checkpoint_dir(run))
    with open(os.path.join(checkpoint_dir(run), "ckpt-00000002.safetensors"), "wb") as f:
        f.write(b"\x00" * 5)
    with caplog.at_level(logging.WARNING, logger="mipnet"), pytest.raises(FormatError, match="every checkpoint"):
        load_latest_checkpoint(run)
    [record] = [r for r in caplog.records if r.name == "mipnet.training.checkpoint"]
    assert record.levelno == logging.WARNING
    assert "skipping" in record.getMessage() and "ckpt-00000002.safetensors" in record.getMessage()


def test_the_train_command_shows_info_records_on_stderr_only_while_it_runs(capsys):
    logger = logging.getLogger("mipnet")
    level, handlers = logger.level, list(logger.handlers)
    with show_training_log():
        logging.getLogger("mipnet.training.fit").info("validation at step 7:\n  air epe 1.000")
        logging.getLogger("mipnet.training.fit").debug("not shown")
    logging.getLogger("mipnet.training.fit").info("after the command: not on stderr")
    err = capsys.readouterr().err
    assert err == "validation at step 7:\n  air epe 1.000\n"
    assert logger.level == level and logger.handlers == handlers


def test_mipnet_train_prints_the_validation_table(tmp_path, capsys):
    run = str(tmp_path / "run")
    args = ["train", "--preset", "cpu", "--steps", "1", "--out", run, "--val-every", "1", "--val-pairs", "1",
            "--val-size", "64", "96"] + TINY
    assert mipnet.cli.main(args) == 0
    err = capsys.readouterr().err
    assert "validation at step 1:" in err and "epe" in err
