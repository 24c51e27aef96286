"""e3D of the missing-data cases on held-out seeds, for comparing two checkouts of moju_core.

    git archive dfc2c41 moju_core | tar -x -C /tmp/before
    PYTHONPATH=/tmp/before python benchmarks/rule_removal_cost.py /tmp/before.json
    python benchmarks/rule_removal_cost.py /tmp/after.json

Writes {"case|seed": e3D} for the closing occlusion on faces, sheets and markers (the cases the
removed completion and group-fill rules concern), seeds 301-306, known rotations (and the
paper with its own), with the solves of :mod:`rule_ablation`.
"""

from __future__ import annotations

import json
import sys

import rule_ablation as r

C = r.CLOSING
CASES = (
    r.Case("face1", 10, 300, occlusion=C),
    r.Case("face3", 99, 300, occlusion=C),
    r.Case("face3", 99, 300, noise=0.01, occlusion=C),
    r.Case("paper", 60, 300, occlusion=C),
    r.Case("bumps-osc", 60, 300, occlusion=C),
    r.Case("face4", 350, 41, occlusion=C),
    r.Case("face4", 350, 41, noise=0.01, occlusion=C),
    r.Case("body-osc", 350, 41, occlusion=C),
    r.Case("paper", 60, 300, occlusion=C, known=False),
)


def main() -> None:
    out = {}
    for case in CASES:
        for seed in r.HELD_OUT_SEEDS:
            out[f"{case.label}|{seed}"] = r.run_case(case, seed)["e3d"]
            print(case.label, seed, f"{out[f'{case.label}|{seed}']:.5f}", flush=True)
    with open(sys.argv[1], "w") as file:
        json.dump(out, file, indent=1)


if __name__ == "__main__":
    main()
