"""Print the lowest foot point of every humanoid clip played on the project humanoid (FK only).

MIMICKIT_TEST_DATA=../shared/data python benchmarks/clip_ground_report.py [--top 20]
"""

import argparse
import os
import warnings
from pathlib import Path

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import load_motion
from mimickit.tools.clip_ground import lowest_foot_z
from mimickit.util.paths import PROJECT_DATA_DIR


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--top", type=int, default=20)
    ap.add_argument("--threshold", type=float, default=-0.03)
    args = ap.parse_args()
    root = Path(os.environ["MIMICKIT_TEST_DATA"]) / "motions" / "humanoid"
    char = load_char_model(PROJECT_DATA_DIR / "assets/humanoid/humanoid.xml")
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for p in sorted(root.rglob("*.pkl")):
            z = lowest_foot_z(char, load_motion(p), ["right_foot", "left_foot"])
            below = (z < args.threshold).float().mean().item()
            rows.append((z.min().item(), below, str(p.relative_to(root))))
    rows.sort()
    print(f"{len(rows)} humanoid clips; {sum(r[0] < args.threshold for r in rows)} go below {args.threshold} m")
    print(f"{'lowest foot z (m)':>18}  {'frames below':>12}  clip")
    for z, below, name in rows[: args.top]:
        print(f"{z:18.4f}  {below:12.1%}  {name}")


if __name__ == "__main__":
    main()
