"""Compare DeepMimic humanoid3d clips converted by `mimickit.tools.deepmimic_convert` with the official
MimicKit humanoid clips of the same takes, by forward kinematics on the MimicKit humanoid.

    MIMICKIT_TEST_DATA=/work/shared/data python benchmarks/deepmimic_convert_report.py

For every DeepMimic clip with a MimicKit counterpart: frame counts, fps and loop mode of both, and for
pairs with equal frame counts the max body-position difference over all frames and bodies, the body
and frame where it occurs, how many frames differ by more than 1 mm, and the worst root (pelvis)
difference. A take whose converted frame count differs only because the converter resampled uneven
frame durations is compared again with `resample=False` (marked "no resample").
"""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import load_motion
from mimickit.tools.deepmimic_convert import convert_deepmimic, fk_body_distance


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.environ.get("MIMICKIT_TEST_DATA"), help="MimicKit data folder")
    args = ap.parse_args()
    if not args.data:
        ap.error("set MIMICKIT_TEST_DATA or pass --data")
    data = Path(args.data)
    char = load_char_model(data / "assets" / "humanoid" / "humanoid.xml")
    names = char.get_body_names()
    print(
        f"{'clip':16} {'DM T':>5} {'MK T':>5} {'fps DM/MK':>11} {'loop':>9}  {'max FK diff':>12}  "
        f"{'worst body @frame':24} {'>1mm':>7} {'root max':>9}  note"
    )
    for txt in sorted((data / "deepmimic_motions").glob("humanoid3d_*.txt")):
        take = txt.stem.removeprefix("humanoid3d_")
        pkl = data / "motions" / "humanoid" / f"humanoid_{take}.pkl"
        conv = convert_deepmimic(txt)
        head = f"{take:16} {conv.num_frames:5d}"
        if not pkl.is_file():
            fps = f"{conv.fps:g}/-"
            print(f"{head} {'-':>5} {fps:>11} {conv.loop_mode.value:>7}/-  no MimicKit clip")
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # humanoid_walk.pkl holds NaN columns
            ref = load_motion(pkl)
        rows = [(conv, "")]
        if conv.num_frames != ref.num_frames:
            raw = convert_deepmimic(txt, resample=False)
            if raw.num_frames == ref.num_frames:
                rows = [(conv, "resampled (uneven dt)"), (raw, "no resample")]
        for m, note in rows:
            loops = f"{m.loop_mode.value}/{ref.loop_mode.value}"
            fps = f"{m.fps:g}/{ref.fps:g}"
            line = f"{take:16} {m.num_frames:5d} {ref.num_frames:5d} {fps:>11} {loops:>9}  "
            if m.num_frames != ref.num_frames:
                print(line + f"{'-':>12}  {note or 'different take (frame counts differ)'}")
                continue
            d = fk_body_distance(char, m.frames, ref.frames)
            worst = int(d.argmax())
            f, b = divmod(worst, d.shape[1])
            over = int((d.max(dim=1).values > 1e-3).sum())
            root = d[:, 0].max().item()
            where = f"{names[b]} @{f}"
            print(
                line + f"{d.max().item() * 1000:9.4f} mm  {where:24} {over:3d}/{m.num_frames:<3d} "
                f"{root * 1000:6.3f}mm  {note}"
            )


if __name__ == "__main__":
    main()
