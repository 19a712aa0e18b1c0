"""The machine lines printed beside every speed figure (``mipnet.bench.machine``): the CPU, the FMA peak and the drift
check after a run."""

from mipnet import _core
from mipnet.bench.machine import PEAK_DRIFT, cpu_name, machine_header, peak_drift_line


def test_header_names_the_cpu_and_the_peak_it_is_given():
    text, peak = machine_header(2, 123.4)
    lines = text.splitlines()
    assert peak == 123.4
    assert lines[0].startswith(f"CPU: {cpu_name()}")
    assert _core.cpu_info()["model"] in lines[0]
    assert _core.cpu_info()["isa"] in lines[1]
    assert lines[2].startswith("FMA peak measured: ") and lines[2].endswith("shares of the peak use 123.4")


def test_header_measures_the_peak_when_none_is_given():
    text, peak = machine_header(1)
    assert peak > 0
    assert f"FMA peak measured: {peak:.0f} GFLOP/s on 1 core" in text


def test_drift_is_flagged_only_beyond_the_threshold():
    steady = peak_drift_line(230.0, 230.0 * (1 - PEAK_DRIFT / 2))
    assert steady.startswith("FMA peak at the start 230, at the end")
    assert "changed" not in steady
    slow_start = peak_drift_line(117.0, 230.0)
    assert "changed by more than 15%" in slow_start
    assert "117" in slow_start and "230" in slow_start
