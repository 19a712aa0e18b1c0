"""Where the time goes: wall and CPU time per op family, forward and backward.

Usage::

    with mipnet.profiler.profile() as p:
        model(left, right)
    print(p.table())

or ``MIPNET_PROFILE=1 python script.py``, which profiles the whole process and prints the table to
stderr at exit. Like ``torch.profiler``'s ``key_averages().table()``, one row per op family
(``conv2d``, ``grid_sample``, ``gru_update``, ...) with its forward and backward time, call count and
share of the profiled wall time. ``CPU/wall`` is the process CPU time over the wall time of the op:
about the number of cores kept busy (2.0 = both cores of a 2-thread run).

Timing happens once, at the op-dispatch layer: ``Function.apply`` (forward) and the tape walk of
``autograd.backward`` (backward), which is where Python calls ``mipnet._core``. Work outside a
``Function`` (optimiser steps, gradient accumulation) is timed where it is marked with
:func:`record`. When no profile is active the cost is one module-attribute test per op.
"""

from __future__ import annotations

import atexit
import os
import sys
import time
from contextlib import contextmanager
from typing import Iterator

__all__ = ["Profile", "profile", "scope", "record"]

#: The active profile, or None. Read by the dispatch layer on every op.
ACTIVE: "Profile | None" = None


class _Stat:
    __slots__ = ("count", "wall", "cpu")

    def __init__(self) -> None:
        self.count, self.wall, self.cpu = 0, 0.0, 0.0


class Profile:
    """Accumulated op timings. Keys are (phase, scope, name): phase "forward" | "backward" | "other",
    scope the innermost :func:`scope` label active when the op was recorded (its forward's scope
    for a backward), name the op family."""

    def __init__(self) -> None:
        self.stats: dict[tuple[str, str, str], _Stat] = {}
        self.scopes: list[str] = []
        self.wall = 0.0
        self.cpu = 0.0
        self._t0 = self._c0 = 0.0

    # ---- recording -------------------------------------------------------------------------------
    def add(self, phase: str, scope: str, name: str, wall: float, cpu: float) -> None:
        s = self.stats.get((phase, scope, name))
        if s is None:
            s = self.stats[(phase, scope, name)] = _Stat()
        s.count += 1
        s.wall += wall
        s.cpu += cpu

    def scope(self) -> str:
        return self.scopes[-1] if self.scopes else ""

    def start(self) -> None:
        self._t0, self._c0 = time.perf_counter(), time.process_time()

    def stop(self) -> None:
        self.wall += time.perf_counter() - self._t0
        self.cpu += time.process_time() - self._c0

    # ---- reporting -------------------------------------------------------------------------------
    def totals(self, by_scope: bool = False) -> dict[str, dict[str, _Stat]]:
        """{row name: {phase: stat}}; rows are op families (``scope/op`` when ``by_scope``)."""
        rows: dict[str, dict[str, _Stat]] = {}
        for (phase, scope, name), s in self.stats.items():
            key = f"{scope}/{name}" if by_scope and scope else name
            t = rows.setdefault(key, {}).setdefault(phase, _Stat())
            t.count += s.count
            t.wall += s.wall
            t.cpu += s.cpu
        return rows

    def table(self, sort_by: str = "total", row_limit: int | None = None, by_scope: bool = False) -> str:
        """The table: one row per op family, sorted by total (or "forward"/"backward") wall time.

        Args:
            sort_by: "total", "forward", "backward" or "name".
            row_limit: print at most this many rows (the rest are summed into "(other ops)").
            by_scope: one row per (scope, op family), scopes being the labels of :func:`scope`
                (e.g. "level 1/16"), so the same op at two levels shows twice.
        """
        rows = self.totals(by_scope)
        empty = _Stat()

        def wall(r: dict[str, _Stat], phase: str | None = None) -> float:
            return sum(s.wall for p, s in r.items() if phase is None or p == phase)

        key = {"total": lambda kv: -wall(kv[1]), "forward": lambda kv: -wall(kv[1], "forward"),
               "backward": lambda kv: -wall(kv[1], "backward"), "name": lambda kv: kv[0]}[sort_by]
        items = sorted(rows.items(), key=key)
        if row_limit is not None and len(items) > row_limit:
            rest: dict[str, _Stat] = {}
            for _, r in items[row_limit:]:
                for p, s in r.items():
                    t = rest.setdefault(p, _Stat())
                    t.count, t.wall, t.cpu = t.count + s.count, t.wall + s.wall, t.cpu + s.cpu
            items = items[:row_limit] + [("(other ops)", rest)]
        recorded = sum(wall(r) for _, r in items)
        total = self.wall if self.wall > 0 else recorded
        width = max([len(k) for k, _ in items] + [24])
        head = (f"{'op':<{width}} {'fwd s':>8} {'fwd n':>7} {'bwd s':>8} {'bwd n':>7} {'total s':>8} "
                f"{'share':>6} {'CPU/wall':>8}")
        lines = [head, "-" * len(head)]
        for name, r in items:
            f, b = r.get("forward", empty), r.get("backward", empty)
            o = r.get("other", empty)
            tw = f.wall + b.wall + o.wall
            tc = f.cpu + b.cpu + o.cpu
            fs, fn = (f.wall + o.wall, f.count + o.count)
            lines.append(f"{name:<{width}} {fs:>8.3f} {fn:>7d} {b.wall:>8.3f} {b.count:>7d} {tw:>8.3f} "
                         f"{100 * tw / total:>5.1f}% {tc / tw if tw > 0 else 0:>8.2f}")
        lines.append("-" * len(head))
        untracked = total - recorded
        if self.wall > 0:
            lines.append(f"{'(outside ops: Python)':<{width}} {'':>8} {'':>7} {'':>8} {'':>7} {untracked:>8.3f} "
                         f"{100 * untracked / total:>5.1f}%")
        lines.append(f"{'total (wall)':<{width}} {'':>8} {'':>7} {'':>8} {'':>7} {total:>8.3f} {'100.0%':>6} "
                     f"{self.cpu / self.wall if self.wall > 0 else 0:>8.2f}")
        return "\n".join(lines)


    def scope_table(self) -> str:
        """One row per :func:`scope` label (ops outside any scope: "(none)"): op time, share of the
        profiled wall time and CPU/wall, e.g. to see whether both cores are busy at the 1/16 level."""
        rows: dict[str, _Stat] = {}
        for (phase, scope, _), s in self.stats.items():
            t = rows.setdefault(f"{scope or '(none)'} {phase}", _Stat())
            t.count, t.wall, t.cpu = t.count + s.count, t.wall + s.wall, t.cpu + s.cpu
        total = self.wall if self.wall > 0 else sum(s.wall for s in rows.values())
        head = f"{'scope, phase':<28} {'ops':>7} {'op time s':>10} {'share':>6} {'CPU/wall':>8}"
        lines = [head, "-" * len(head)]
        for name, s in sorted(rows.items(), key=lambda kv: -kv[1].wall):
            lines.append(f"{name:<28} {s.count:>7d} {s.wall:>10.3f} {100 * s.wall / total:>5.1f}% "
                         f"{s.cpu / s.wall if s.wall > 0 else 0:>8.2f}")
        return "\n".join(lines)


@contextmanager
def profile() -> Iterator[Profile]:
    """Profiles the ops run inside the block (forward and backward); yields the :class:`Profile`.
    Profiles do not nest: an inner ``profile()`` takes over until it ends."""
    global ACTIVE
    prev, p = ACTIVE, Profile()
    ACTIVE = p
    p.start()
    try:
        yield p
    finally:
        p.stop()
        ACTIVE = prev


@contextmanager
def scope(label: str) -> Iterator[None]:
    """Labels the ops run inside (``table(by_scope=True)`` groups by it); free when not profiling."""
    p = ACTIVE
    if p is None:
        yield
        return
    p.scopes.append(label)
    try:
        yield
    finally:
        p.scopes.pop()


@contextmanager
def record(name: str) -> Iterator[None]:
    """Times the block as one call of op ``name`` (for work outside a ``Function``: the optimiser
    step, gradient sums); free when not profiling."""
    p = ACTIVE
    if p is None:
        yield
        return
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        p.add("other", p.scope(), name, time.perf_counter() - t0, time.process_time() - c0)


def _profile_process() -> None:
    """MIPNET_PROFILE=1: profile the whole process, print the table to stderr at exit."""
    global ACTIVE
    p = ACTIVE = Profile()
    p.start()

    def report() -> None:
        p.stop()
        print(f"mipnet profile (MIPNET_PROFILE=1), pid {os.getpid()}:\n{p.table()}", file=sys.stderr)

    atexit.register(report)


if os.environ.get("MIPNET_PROFILE", "") not in ("", "0"):
    _profile_process()
