"""``RUN/log.jsonl``: one JSON object per line — one per training step (``step``, ``loss``, ``lr``,
``epe``, ``seconds``, ...) and one per validation (``step``, ``val``: set -> metrics)."""

from __future__ import annotations

import json
import math
import os

from ..utils.files import atomic_write


def _finite_or_none(value):
    """JSON has no NaN/inf: write them as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    return value


class TrainLog:
    """Appends records to ``path``; ``truncate_after(step)`` drops what a resumed run will redo."""

    def __init__(self, path: str):
        self.path = path

    def append(self, record: dict) -> None:
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(json.dumps(_finite_or_none(record), sort_keys=True) + "\n")
            f.flush()

    def records(self) -> list[dict]:
        """Every complete record (a torn last line, from a process killed mid-write, is ignored)."""
        if not os.path.exists(self.path):
            return []
        out = []
        with open(self.path, encoding="utf-8") as f:
            for line in f:
                try:
                    out.append(json.loads(line))
                except json.JSONDecodeError:
                    continue
        return out

    def truncate_after(self, step: int) -> None:
        """Keeps only records of steps <= ``step`` (rewritten atomically)."""
        kept = [r for r in self.records() if r.get("step", 0) <= step]
        with atomic_write(self.path, "w") as f:
            for r in kept:
                f.write(json.dumps(r, sort_keys=True) + "\n")
