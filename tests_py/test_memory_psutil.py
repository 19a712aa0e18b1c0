"""mipnet.model.memory reads the process's resident memory and the system's available memory with psutil."""

import os
import re

import psutil
import pytest

from mipnet.model import memory


def test_resident_bytes_is_the_processes_rss():
    ours = memory._resident_bytes()
    assert abs(ours - psutil.Process().memory_info().rss) < 64 * 2**20
    if os.path.exists("/proc/self/status"):
        vmrss = int(re.search(r"^VmRSS:\s+(\d+) kB", open("/proc/self/status").read(), re.M).group(1)) * 1024
        assert abs(ours - vmrss) < 64 * 2**20


def test_available_memory_is_bounded_by_the_systems_and_the_cap(monkeypatch):
    monkeypatch.delenv("MIPNET_MEMORY_LIMIT", raising=False)
    room, source = memory.available_memory()
    system = psutil.virtual_memory().available
    assert 0 < room <= system * 1.1 + 2**26
    if memory._cgroup_room() is None:
        assert source == "available system memory" and abs(room - system) < max(0.1 * system, 2**28)
    monkeypatch.setenv("MIPNET_MEMORY_LIMIT", "100T")  # far above the system: the system's bound stays
    assert memory.available_memory()[1] != "MIPNET_MEMORY_LIMIT=100T"
    cap = memory._resident_bytes() + 2**20
    monkeypatch.setenv("MIPNET_MEMORY_LIMIT", str(cap))
    capped, source = memory.available_memory()
    assert source == f"MIPNET_MEMORY_LIMIT={cap}" and capped == pytest.approx(2**20, abs=32 * 2**20)
