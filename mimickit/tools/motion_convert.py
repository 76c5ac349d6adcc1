"""`mimickit motion convert`: one entry point for the clip converters.

Formats: `deepmimic` (DeepMimic humanoid3d `.txt`), `amass` (AMASS/SMPL `.npz` → the SMPL humanoid),
`gmr` (GMR robot retargets, `.pkl`/`.npz` → G1, Go2, ...). `auto` picks by extension (`.txt`, `.pkl`)
and, for `.npz`, by its keys (`poses` → amass, `dof_pos` → gmr). Then, in this order: the frame
range (`start_frame`, `end_frame`, in input frames), the loop mode, and resampling to `fps` (see
`mimickit.anim.motion_resample`).
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import LoopMode, Motion
from mimickit.anim.motion_resample import ROOT_ROT_COL, char_expmap_columns, resample_motion
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths

FORMATS = ("auto", "deepmimic", "amass", "gmr")
SMPL_CHAR = "data/assets/smpl/smpl.xml"
_LOOP = {"wrap": LoopMode.WRAP, "clamp": LoopMode.CLAMP}


@dataclass
class ConvertOptions:
    fmt: str = "auto"
    char: str | None = None  # MJCF; amass: default SMPL_CHAR; gmr: checks the DoF count
    fps: float | None = None  # resample to this rate
    loop: str | None = None  # wrap|clamp; default: the file's (DeepMimic) or wrap
    start_frame: int = 0
    end_frame: int = -1  # exclusive; -1: to the end
    z_correction: str = "calibrate"  # amass
    up: str = "z"  # amass: the input world's up axis
    input_fps: float | None = None  # amass: when the file has no frame rate
    root_rot_order: str = "xyzw"  # gmr
    data_paths: DataPaths = PROJECT_DATA  # where `data/...` names (the SMPL character) are found


@dataclass
class ConvertResult:
    motion: Motion
    fmt: str
    input_frames: int
    input_fps: float


def detect_format(path: str | Path) -> str:
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".txt":
        return "deepmimic"
    if suffix == ".pkl":
        return "gmr"
    if suffix == ".npz":
        try:
            with np.load(p, allow_pickle=False) as data:
                keys = set(data.files)
        except (OSError, ValueError, zipfile.BadZipFile) as e:
            raise MimicKitError(f"{p}: not a readable .npz file ({e})") from None
        if "poses" in keys:
            return "amass"
        if "dof_pos" in keys:
            return "gmr"
        raise MimicKitError(f"{p}: neither AMASS (key 'poses') nor GMR (key 'dof_pos'); keys: {sorted(keys)}")
    raise MimicKitError(f"{p}: cannot tell the format from '{suffix}'; give --format deepmimic|amass|gmr")


def convert_motion(path: str | Path, opts: ConvertOptions) -> ConvertResult:
    """Convert one file; every user mistake is a MimicKitError naming the file (and the key)."""
    if opts.fmt not in FORMATS:
        raise MimicKitError(f"unknown format '{opts.fmt}'; one of {', '.join(FORMATS)}")
    if opts.loop is not None and opts.loop not in _LOOP:
        raise MimicKitError(f"--loop must be wrap or clamp, got {opts.loop!r}")
    if opts.fps is not None and not opts.fps > 0:
        raise MimicKitError(f"--fps must be positive, got {opts.fps}")
    fmt = detect_format(path) if opts.fmt == "auto" else opts.fmt
    motion, expmap_cols = _convert(Path(path), fmt, opts)
    input_frames, input_fps = motion.num_frames, motion.fps
    motion = _frame_range(motion, opts.start_frame, opts.end_frame, path)
    if opts.loop is not None:
        motion.loop_mode = _LOOP[opts.loop]
    if opts.fps is not None:
        motion = resample_motion(motion, opts.fps, expmap_cols)
    return ConvertResult(motion, fmt, input_frames, input_fps)


def _convert(path: Path, fmt: str, opts: ConvertOptions) -> tuple[Motion, list[int]]:
    """(Motion at the input rate, first columns of its exponential maps)."""
    if fmt == "deepmimic":
        from mimickit.tools.deepmimic_convert import MK_EXPMAP_COLUMNS, convert_deepmimic

        return convert_deepmimic(path), MK_EXPMAP_COLUMNS
    if fmt == "amass":
        from mimickit.tools.smpl_convert import convert_smpl, load_amass_npz

        char = _smpl_char(opts.char, opts.data_paths)
        poses = load_amass_npz(path, input_fps=opts.input_fps)
        motion = convert_smpl(poses, char, up=opts.up, z_correction=opts.z_correction)
        return motion, char_expmap_columns(char)
    if fmt == "gmr":
        from mimickit.tools.gmr_convert import gmr_to_motion, load_gmr

        char = load_char_model(opts.char) if opts.char else None
        motion = gmr_to_motion(load_gmr(path), source=str(path), char=char, root_rot_order=opts.root_rot_order)
        # Robot joints are hinges (lerped); a character with 3-DoF joints names its exp maps.
        return motion, char_expmap_columns(char) if char else [ROOT_ROT_COL]
    raise MimicKitError(f"unknown format '{fmt}'; one of {', '.join(FORMATS)}")


def _smpl_char(char: str | None, data_paths: DataPaths) -> KinCharModel:
    path = data_paths.resolve(char or SMPL_CHAR)
    if not path.is_file():
        if char:
            raise MimicKitError(f"character file not found: {char}")
        raise MimicKitError(
            f"AMASS conversion needs MimicKit's SMPL character ({SMPL_CHAR}): "
            "give --char PATH/smpl.xml or --data_dir with MimicKit's data folder"
        )
    return load_char_model(path)


def _frame_range(motion: Motion, start: int, end: int, path: str | Path) -> Motion:
    n = motion.num_frames
    stop = n if end == -1 else end
    if not 0 <= start < stop <= n or stop - start < 2:
        raise MimicKitError(f"{path}: frame range [{start}, {end}) does not fit {n} frames (at least 2 needed)")
    if (start, stop) == (0, n):
        return motion
    return Motion(motion.loop_mode, motion.fps, motion.frames[start:stop].copy())
