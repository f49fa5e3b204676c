"""The arm in 3-D, for a plant read from a URDF: its links (the URDF's visual meshes and
shapes, loaded by Rerun's own URDF loader) moving with the trace, one transform per moving
joint per drawn row, and a skeleton joining the joints that shows even where a mesh is
missing. Runs in the writer process. SI units, radians (metres for a prismatic joint).

Layout under ``/<run>/arm3d``:

    <robot>/visual_geometries/<link>/...    the loader's geometry, each in its link's frame
    joints/<joint>                          the joint's transform parent link -> child link:
                                            moving joints at the trace's q, others static
    skeleton/<link>                         lines from the link's origin to its child joints'
    desired/{base, joints/…, skeleton/…}    the pose the reference asks for (q_d), as a
                                            grey skeleton on the same base

Frames are the URDF's link names under ``<run>/`` (one arm per run, moved by its own q), and
under ``<run>/desired/`` for the desired pose. A joint's or link's name is one part of an
entity path, escaped (:func:`part`): a link 'a/b' is not the child 'b' of a link 'a'.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from plant_fmu.urdf import check_meshes, package_dirs

from .layout import REFERENCE_COLOR, UrdfArm

SKELETON_COLOR = (230, 150, 40)  # the arm's skeleton: orange, seen through grey meshes


def part(name: str) -> str:
    """A URDF name as one part of an entity path (its '/', spaces and the like escaped, as
    Rerun's own URDF loader escapes the names of its entities)."""
    import rerun as rr

    return rr.escape_entity_path_part(name)


def frame(run: str, link: str) -> str:
    """The frame of one run's link."""
    return f"{run}/{link}"


def package_paths(urdf: Path) -> list[str]:
    """The ROS_PACKAGE_PATH entries that let Rerun's loader find the file's
    ``package://NAME/…`` meshes where the URDF reader finds them
    (:func:`plant_fmu.urdf.package_dirs`): each found package folder's parent."""
    names = set(re.findall(r"package://([^/\"']+)/", urdf.read_text(encoding="utf-8")))
    return list(dict.fromkeys(str(folder.parent) for name in sorted(names)
                              for folder in package_dirs(name, near=urdf.parent)))


def load_tree(run: str, arm: UrdfArm):
    """Rerun's URDF tree of ``arm``, its frames under ``<run>/``, package meshes resolved."""
    import rerun as rr

    extra = package_paths(Path(arm.path))
    if extra:
        known = os.environ.get("ROS_PACKAGE_PATH", "")
        os.environ["ROS_PACKAGE_PATH"] = os.pathsep.join([*extra, *filter(None, [known])])
    return rr.urdf.UrdfTree.from_file_path(arm.path, frame_prefix=f"{run}/")


def log_model(rec, run: str, arm: UrdfArm) -> tuple:
    """The static part of one run's arm and of the pose its reference asks for (a second
    set of frames, ``<run>/desired/<link>``, on the same base): the geometry, the joints
    that do not move, the skeletons. Returns both trees (for :func:`log_pose`)."""
    import rerun as rr

    # Rerun's loader copies every mesh file it is given into the recording, whatever it is:
    # the URDF's meshes are checked here, beside the loader (plant_fmu.meshes says why).
    check_meshes(Path(arm.path))
    tree, desired = load_tree(run, arm), load_tree(f"{run}/desired", arm)
    unknown = [name for name in arm.joints if tree.get_joint_by_name(name) is None]
    if unknown:
        raise ValueError(f"{arm.path} has no joint {', '.join(unknown)} (the plant's joints: "
                         f"{', '.join(arm.joints)})")
    root = f"/{run}/arm3d"
    # Visual geometry only: the collision meshes would double the file for nothing seen.
    rec.send_chunks([chunk.with_entity_path(f"{root}{chunk.entity_path}")
                     for chunk in tree.stream(include_joint_transforms=False).to_chunks()
                     if "/collision_geometries" not in str(chunk.entity_path)])
    base = tree.root_link().name
    rec.log(f"{root}/desired/base", rr.Transform3D(
        translation=[0.0, 0.0, 0.0], quaternion=rr.Quaternion(xyzw=[0.0, 0.0, 0.0, 1.0]),
        parent_frame=frame(run, base), child_frame=frame(f"{run}/desired", base)), static=True)
    for prefix, frames, color, which in ((root, run, SKELETON_COLOR, tree),
                                         (f"{root}/desired", f"{run}/desired",
                                          REFERENCE_COLOR, desired)):
        _log_still_joints(rec, f"{prefix}/joints", which, arm)
        _log_skeleton(rec, f"{prefix}/skeleton", frames, which, color)
    return tree, desired


def _log_still_joints(rec, entity: str, tree, arm: UrdfArm) -> None:
    """The joints that do not move (fixed, or held at a value by the plant), static."""
    for joint in tree.joints():
        if joint.name not in arm.joints:
            value = arm.held.get(joint.name, 0.0)
            rec.log(f"{entity}/{part(joint.name)}", joint.compute_transform(value, clamp=False),
                    static=True)


def _log_skeleton(rec, entity: str, frames: str, tree, color) -> None:
    """A line from each link's origin to each of its child joints, in that link's frame."""
    import rerun as rr

    children: dict[str, list[tuple[float, float, float]]] = {}
    for joint in tree.joints():
        children.setdefault(joint.parent_link, []).append(joint.origin_xyz)
    reach = max((float(np.linalg.norm(xyz)) for ends in children.values() for xyz in ends),
                default=0.1)
    for link, ends in children.items():
        rec.log(f"{entity}/{part(link)}", rr.LineStrips3D([[(0.0, 0.0, 0.0), end] for end in ends],
                                                    colors=[color], radii=[0.03 * reach]),
                rr.CoordinateFrame(frame(frames, link)), static=True)


def log_pose(rec, run: str, arm: UrdfArm, trees: tuple, times: np.ndarray, q: np.ndarray,
             q_d: np.ndarray) -> None:
    """The moving joints' transforms at ``times`` (s), of the arm from ``q`` and of the
    desired pose from ``q_d`` (rows, n): column j is joint ``arm.joints[j]``."""
    import rerun as rr

    index = [rr.TimeColumn("sim_time", duration=times)]
    for prefix, tree, values in ((f"/{run}/arm3d", trees[0], q),
                                 (f"/{run}/arm3d/desired", trees[1], q_d)):
        for j, name in enumerate(arm.joints):
            joint = tree.get_joint_by_name(name)
            rec.send_columns(f"{prefix}/joints/{part(name)}", indexes=index,
                             columns=joint.compute_transform_columns(values[:, j].tolist(),
                                                                     clamp=False))
