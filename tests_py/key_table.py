"""The canonical state-dict keys and shapes of the default MIPNet (docs/architecture.md §2.10), read from
reference/state_dict_keys.txt; imports neither mipnet nor torch, so both engines' tests can use it."""

import re
from pathlib import Path

KEY_TABLE = Path(__file__).resolve().parent / "reference" / "state_dict_keys.txt"


def canonical_key_table() -> list[tuple[str, tuple[int, ...]]]:
    """(key, shape) rows of the table, in order."""
    rows = []
    for line in KEY_TABLE.read_text(encoding="utf-8").splitlines():
        match = re.fullmatch(r"\s*(\S+)\s+\[([0-9, ]*)\]\s*", line)
        if match:
            rows.append((match.group(1), tuple(int(d) for d in match.group(2).replace(" ", "").split(",") if d)))
    return rows
