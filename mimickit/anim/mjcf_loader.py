"""Load an MJCF file with MuJoCo's own parser, tolerating missing visual meshes.

MuJoCo's compiler resolves defaults, classes, angle units, euler/axisangle frames and includes, so the
character model reads compiled values instead of re-implementing MJCF. Characters from MimicKit's data
archive sometimes lack their mesh files (Go2); when every geom using a missing mesh is visual only
(contype = conaffinity = 0) those geoms are dropped with a warning, since neither kinematics nor
simulation need them.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco

from mimickit.util.errors import MimicKitError


def load_mjcf_spec(path: str | Path) -> mujoco.MjSpec:
    """Parse `path` into an MjSpec with geoms of missing meshes removed (warned)."""
    p = Path(path)
    if not p.is_file():
        raise MimicKitError(f"character file not found: {p}")
    try:
        spec = mujoco.MjSpec.from_file(str(p))
    except Exception as e:  # MuJoCo raises ValueError with the parser's message
        raise MimicKitError(f"{p}: not a valid MJCF file ({_one_line(e)})") from None
    _drop_missing_meshes(spec, p)
    return spec


def compile_spec(spec: mujoco.MjSpec, source: str | Path) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as e:
        raise MimicKitError(f"{source}: MuJoCo could not compile the model ({_one_line(e)})") from None


def load_mjcf_model(path: str | Path) -> mujoco.MjModel:
    return compile_spec(load_mjcf_spec(path), path)


def _drop_missing_meshes(spec: mujoco.MjSpec, path: Path) -> None:
    meshdir = Path(spec.meshdir) if spec.meshdir else Path()
    if not meshdir.is_absolute():
        meshdir = path.parent / meshdir
    missing = {m.name for m in spec.meshes if m.file and not (meshdir / m.file).is_file()}
    if not missing:
        return
    dropped = 0
    for geom in list(spec.geoms):
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.meshname in missing:
            if geom.contype != 0 or geom.conaffinity != 0:
                raise MimicKitError(
                    f"{path}: mesh '{geom.meshname}' is missing and geom '{geom.name or geom.meshname}' "
                    "collides, so the model cannot be simulated without it"
                )
            spec.delete(geom)
            dropped += 1
    for mesh in list(spec.meshes):
        if mesh.name in missing:
            spec.delete(mesh)
    warnings.warn(
        f"{path}: {len(missing)} mesh file(s) missing under {meshdir}; dropped {dropped} visual-only geoms",
        stacklevel=3,
    )


def _one_line(e: Exception) -> str:
    text = " ".join(str(e).split())
    return text[:300]
