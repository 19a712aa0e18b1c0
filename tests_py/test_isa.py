"""``MIPNET_ISA``: a wrong value is an ``ArgumentError`` (a ``RuntimeError``) from every kernel call, and
one line ``mipnet <command>: error: ...`` from the command line, naming the variable and the values it
accepts; a valid value is taken. Each case runs in a subprocess, since the choice is made once per process."""

import os
import subprocess
import sys

ACCEPTED = ("avx512", "avx2", "generic")


def run_python(args, isa, tmp_path):
    """``python args`` with ``MIPNET_ISA=isa``, in ``tmp_path``."""
    env = {**os.environ, "MIPNET_ISA": isa}
    return subprocess.run([sys.executable, *args], env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)


def test_wrong_value_is_one_clear_line_from_the_command_line(tmp_path):
    res = run_python(["-m", "mipnet", "infer", "-o", str(tmp_path / "out")], "bogus", tmp_path)
    assert res.returncode != 0
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, res.stderr
    line = lines[0]
    assert line.startswith("mipnet infer: error: ") and "MIPNET_ISA" in line and "bogus" in line, line
    assert all(name in line for name in ACCEPTED), line
    assert not (tmp_path / "out").exists(), "the command stops before any work"


_KERNEL_CALL = r"""
import numpy as np
import mipnet
from mipnet.errors import ArgumentError
try:
    mipnet._core.unary_fwd(np.ones(3, np.float32), "relu")
except ArgumentError as error:
    assert isinstance(error, RuntimeError)
    print(error)
else:
    raise SystemExit("no error")
"""


def test_wrong_value_is_an_argument_error_from_a_kernel_call(tmp_path):
    res = run_python(["-c", _KERNEL_CALL], "avx3", tmp_path)
    assert res.returncode == 0, res.stderr
    assert "MIPNET_ISA" in res.stdout and "avx3" in res.stdout and all(n in res.stdout for n in ACCEPTED)


def test_valid_value_is_taken(tmp_path):
    script = "import mipnet; mipnet.MIPNet(); print(mipnet._core.simd_isa(), mipnet._core.cpu_info()['isa'])"
    res = run_python(["-c", script], "Generic", tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["generic", "generic"]
