"""The machine lines of ``python -m mipnet.bench model``: the header's FMA peak and the drift check after the table."""

from mipnet.bench_model import PEAK_DRIFT, machine_header, peak_drift_line


def test_header_prints_the_peak_it_is_given():
    line = machine_header(2, 123.4)
    assert "FMA peak at 2 threads: 123 GFLOP/s" in line
    assert line.startswith("CPU: ")


def test_drift_is_flagged_only_beyond_the_threshold():
    steady = peak_drift_line(230.0, 230.0 * (1 - PEAK_DRIFT / 2))
    assert steady.startswith("FMA peak at the start 230, at the end")
    assert "changed" not in steady
    slow_start = peak_drift_line(117.0, 230.0)
    assert "changed by more than 15%" in slow_start
    assert "117" in slow_start and "230" in slow_start


def test_drift_without_a_measurement_says_so():
    assert peak_drift_line(None, 230.0) == "FMA peak at the end: not measured"
