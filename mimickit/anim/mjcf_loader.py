"""Load an MJCF file with MuJoCo's own parser, tolerating missing visual meshes.

MuJoCo's compiler resolves defaults, classes, angle units, euler/axisangle frames and includes, so the
character model reads compiled values instead of re-implementing MJCF. Characters from MimicKit's data
archive sometimes lack their mesh files (Go2, PI+). Geoms of a missing mesh are dropped with a warning:
visual ones (contype = conaffinity = 0) are needed by neither kinematics nor simulation; colliding ones
(PI+'s links collide through their meshes) are needed by neither kinematics nor the bodies' masses when
the body gives its `<inertial>`, so they are dropped too. The warning names the bodies left with no
collision geometry (their contacts, e.g. a fallen torso on the floor, go unseen by the simulation) and those
whose mass came from a dropped geom (PI+'s fixed `head`: its mass is lost, the rest of the robot keeps its
`<inertial>` figures).
"""

from __future__ import annotations

from pathlib import Path

import mujoco

from mimickit.util.errors import MimicKitError
from mimickit.util.warn import warn


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
    dropped, colliding, massless = 0, 0, set()
    for geom in list(spec.geoms):
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.meshname in missing:
            if geom.contype != 0 or geom.conaffinity != 0:
                colliding += 1
                if not geom.parent.explicitinertial:
                    massless.add(geom.parent.name)
            spec.delete(geom)
            dropped += 1
    for mesh in list(spec.meshes):
        if mesh.name in missing:
            spec.delete(mesh)
    kind = f"({colliding} colliding)" if colliding else "visual-only"
    note = f"; dropped {dropped} {kind} geoms"
    bare = _bodies_without_collision(spec) if colliding else []
    if bare:
        note += f"; bodies with no collision geometry left: {', '.join(bare)}"
    if massless:
        note += f"; bodies whose mass came from dropped geoms: {', '.join(sorted(massless))}"
    warn(f"{path}: {len(missing)} mesh file(s) missing under {meshdir}{note}", stacklevel=3)


def _bodies_without_collision(spec: mujoco.MjSpec) -> list[str]:
    """Bodies (the world excepted) none of whose geoms can collide."""
    colliding = {g.parent.name for g in spec.geoms if g.contype != 0 or g.conaffinity != 0}
    return [b.name for b in spec.bodies[1:] if b.name not in colliding]


def _one_line(e: Exception) -> str:
    text = " ".join(str(e).split())
    return text[:300]
