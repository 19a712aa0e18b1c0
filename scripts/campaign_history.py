"""The training campaign's history from the shipped weights themselves: every version of the packaged weights
file in this checkout's git history carries its step count and validation table in its metadata
(`scripts/ship_weights.py`); this plots validation EPE against steps, per set, with SGBM's and the targets.

    python scripts/campaign_history.py docs/campaign_history.png [--table]

Points of one validation setup (pairs, size) are joined; the setup changed twice (256x320 then 384x512, 8 then
32 pairs), so only points of the same marker compare. `--table` also prints the points.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys

WEIGHTS = "python/mipnet/assets/mipnet_pretrained.safetensors"
# the sets of the validation table, with the EPE target where it sets one
SETS = {"air": 1.0, "turbid": 2.5, "low_light": 2.5, "scenes": None, "motorcycle": None, "cones": None}


def metadata_at(rev: str, root: str) -> dict[str, str]:
    """The safetensors metadata of the weights file at commit `rev` (an 8-byte header length, then the header)."""
    raw = subprocess.run(["git", "show", f"{rev}:{WEIGHTS}"], cwd=root, capture_output=True, check=True).stdout
    (n,) = struct.unpack("<Q", raw[:8])
    return json.loads(raw[8:8 + n]).get("__metadata__", {})


def history(root: str) -> list[dict]:
    """One record per committed version of the weights, oldest first: commit, date, steps, setup, EPE per set."""
    log = subprocess.run(["git", "log", "--format=%h %cs", "--", WEIGHTS], cwd=root, capture_output=True, text=True,
                         check=True).stdout.split()
    points = []
    for rev, date in reversed(list(zip(log[::2], log[1::2]))):
        meta = metadata_at(rev, root)
        if "validation" not in meta:
            continue
        setup = json.loads(meta.get("validation_setup", "{}"))
        table = json.loads(meta["validation"])
        sgbm = json.loads(meta.get("validation_sgbm", "{}"))
        points.append({"rev": rev, "date": date, "step": int(meta["step"]),
                       "setup": f"{setup.get('pairs')} pairs, {'x'.join(map(str, setup.get('size', [])))}",
                       "epe": {k: v["epe"] for k, v in table.items()},
                       "sgbm": {k: v["epe"] for k, v in sgbm.items()}})
    return points


def plot(points: list[dict], out: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    setups = list(dict.fromkeys(p["setup"] for p in points))
    markers = dict(zip(setups, "s^o"))
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), sharex=True)
    for ax, (name, target) in zip(axes.flat, SETS.items()):
        for setup in setups:
            pts = [p for p in points if p["setup"] == setup and name in p["epe"]]
            ax.plot([p["step"] for p in pts], [p["epe"][name] for p in pts], marker=markers[setup], label=setup)
        # SGBM on the newest setup's pairs (each file carries the SGBM row of its own validation)
        last = [p for p in points if p["setup"] == setups[-1] and name in p["sgbm"]]
        if last:
            ax.axhline(last[-1]["sgbm"][name], color="grey", ls=":", label=f"SGBM ({setups[-1]})")
        if target is not None:
            ax.axhline(target, color="red", ls="--", label="issue target (50 test pairs)")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(ticker.FormatStrFormatter("%g"))
        ax.set_title(name.replace("_", " "))
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("training steps of the shipped weights")
    for ax in axes[:, 0]:
        ax.set_ylabel("validation EPE, px")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("mipnet's CPU training campaign: validation EPE of every shipped version ((6, 6) iterations)")
    fig.tight_layout()
    fig.savefig(out + ".tmp.png", dpi=90)
    os.replace(out + ".tmp.png", out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="PNG to write")
    ap.add_argument("--table", action="store_true", help="also print the points")
    a = ap.parse_args()
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    points = history(root)
    if not points:
        print("no committed weights with a validation table in this checkout's history", file=sys.stderr)
        return 1
    plot(points, a.out)
    if a.table:
        names = list(SETS)
        print("| commit | date | steps | validation | " + " | ".join(names) + " |")
        print("|---" * (4 + len(names)) + "|")
        for p in points:
            row = " | ".join(f"{p['epe'][n]:.3f}" if n in p["epe"] else "" for n in names)
            print(f"| {p['rev']} | {p['date']} | {p['step']:,} | {p['setup']} | {row} |")
    print(f"wrote {a.out} ({len(points)} versions)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
