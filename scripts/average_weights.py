"""Average several weights files of one network into one (`mipnet.serialization.average_safetensors`: a "model soup";
SWA over the ends of the campaign's one-cycle runs), to validate the mean before `scripts/ship_weights.py --average`
ships it.

    python scripts/average_weights.py A.safetensors B.safetensors [C ...] --out soup.safetensors [--weights 0.5 0.5]

The output's metadata is the first file's, with ``averaged_from`` (the files and their weights) added, so
`scripts/validate_weights.py` takes it like a run's ``model.safetensors``.
"""

from __future__ import annotations

import argparse
import json
import os

from mipnet.serialization import average_safetensors, load_safetensors, save_safetensors


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="+")
    p.add_argument("--out", required=True)
    p.add_argument("--weights", type=float, nargs="+", help="one per file (default: equal)")
    args = p.parse_args()
    weights = args.weights or [1.0] * len(args.files)
    _, metadata = load_safetensors(args.files[0])
    metadata["averaged_from"] = json.dumps([{"file": os.path.abspath(f), "weight": w}
                                            for f, w in zip(args.files, weights)])
    save_safetensors(args.out, average_safetensors(args.files, weights), metadata)
    print(f"wrote {args.out}: the mean of {len(args.files)} files, weights {weights}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
