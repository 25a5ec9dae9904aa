"""The object of the KU Leuven contour recordings, from its CAD (``data/kuleuven_contour``: ``contour.STL``,
``contour_edge.mat``, MIT), and the ground truth it gives each recording: where the object was, and the normal cone
of the crease the tool rode on at every sample.

The files are in millimetres; everything returned is in metres. The CAD frame is the model's own; world is the
recording's (z up). No object pose was recorded and the object moved between sessions, so each recording places it
by registering the object's crease to the recorded contact path (`skills.registration`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import scipy.io
from numpy.typing import ArrayLike, NDArray

from schemas import Demonstration, Skill
from schemas.import_options import CsvImportOptions
from schemas.skill import SegmentKind
from services.csv_import import demonstration_from_csv
from services.datasets import KULEUVEN_EDGE_MAT, KULEUVEN_IMPORT, KULEUVEN_OBJECT_STL, kuleuven_file
from skills.registration import (
    Crease,
    NormalCone,
    Registration,
    TriangleMesh,
    angle_outside_cone,
    bisector_angles_of_placements,
    crease_along_edge,
    edge_registrations,
    normal_cones_at,
    registration_pressed_into,
    welded_mesh,
)

M_PER_MM = 1e-3
"""The CAD files are in millimetres."""
EDGE_VARIABLE = "contour_edge"
"""The variable of ``contour_edge.mat`` holding the edge (K, 3), mm."""

_STL_HEADER_BYTES = 80
_STL_TRIANGLE = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def stl_triangles(path: Path) -> NDArray[np.float64]:
    """The triangles (T, 3, 3) of a binary STL file, in the file's units and frame, corners in the file's order.

    Raises ``ValueError`` when the file is not a binary STL (an ASCII STL, or a size that does not match its
    triangle count).
    """
    data = Path(path).read_bytes()
    if len(data) < _STL_HEADER_BYTES + 4:
        raise ValueError(f"{path}: {len(data)} bytes, too short for a binary STL")
    count = int(np.frombuffer(data, "<u4", count=1, offset=_STL_HEADER_BYTES)[0])
    expected = _STL_HEADER_BYTES + 4 + count * _STL_TRIANGLE.itemsize
    if len(data) != expected:
        raise ValueError(
            f"{path}: {len(data)} bytes, but a binary STL of {count} triangles has {expected} (an ASCII STL?)"
        )
    records = np.frombuffer(data, _STL_TRIANGLE, count=count, offset=_STL_HEADER_BYTES + 4)
    return records["corners"].astype(float)


def mat_polyline(path: Path, variable: str) -> NDArray[np.float64]:
    """The polyline (K, 3) stored as ``variable`` in a MATLAB (v5) file, in the file's units and frame."""
    values = scipy.io.loadmat(path)
    if variable not in values:
        raise ValueError(f"{path}: no variable {variable!r} (has {sorted(k for k in values if not k.startswith('_'))})")
    polyline = np.asarray(values[variable], dtype=float)
    if polyline.ndim != 2 or polyline.shape[1] != 3 or len(polyline) < 2:
        raise ValueError(f"{path}: {variable!r} has shape {polyline.shape}, not (K >= 2, 3)")
    return polyline


@dataclass(frozen=True, eq=False)
class KuleuvenObject:
    """The contour object, CAD frame, m: its ``mesh``, the authors' ``edge`` (101, 3) the tool followed, and the
    mesh's convex ``crease`` along it (the chain of mesh edges the tool rode on, with the two faces at each)."""

    mesh: TriangleMesh
    edge: NDArray[np.float64]
    crease: Crease


@lru_cache(maxsize=4)
def _object_from(stl: Path, edge_mat: Path) -> KuleuvenObject:
    mesh = welded_mesh(stl_triangles(stl) * M_PER_MM)
    edge = mat_polyline(edge_mat, EDGE_VARIABLE) * M_PER_MM
    return KuleuvenObject(mesh=mesh, edge=edge, crease=crease_along_edge(mesh, edge))


def kuleuven_object() -> KuleuvenObject:
    """The contour object from ``contour.STL`` and ``contour_edge.mat`` in the data directory
    (`services.datasets.kuleuven_file`), in metres, CAD frame (read once per process and place)."""
    return _object_from(kuleuven_file(KULEUVEN_OBJECT_STL), kuleuven_file(KULEUVEN_EDGE_MAT))


@dataclass(frozen=True, eq=False)
class KuleuvenGroundTruth:
    """Where the object was during one KU Leuven recording, and its normal cone at every sample.

    - ``demonstration``: the recording as imported (`services.csv_import.demonstration_from_csv` with
      ``KULEUVEN_IMPORT``: resampled uniformly, applied wrench, world frame);
    - ``candidates``: every placement of the object's crease on the contact path the registration found, best fit
      first (`skills.registration.edge_registrations`); ``candidate_bisector_angles_rad`` (C,): for each, the median
      angle between the applied force and the bisector of the cone it puts there;
    - ``registration``: the placement the force presses into (`skills.registration.registration_pressed_into`),
      world-from-CAD, with the distances of the path to the crease (m);
    - ``cone``: the normal cone (inward normals of the two faces, their bisector and opening) at every sample of
      ``demonstration``, world frame; :meth:`cones_at` gives it at any other positions.
    """

    demonstration: Demonstration
    kuleuven_object: KuleuvenObject
    candidates: tuple[Registration, ...]
    candidate_bisector_angles_rad: NDArray[np.float64]
    registration: Registration
    cone: NormalCone

    def cones_at(self, positions: ArrayLike) -> NormalCone:
        """The normal cone of the crease nearest each of ``positions`` (M, 3) m, world frame (e.g. a learner's own
        samples of the path)."""
        return normal_cones_at(positions, self.kuleuven_object.crease, self.registration)

    def placed_registration(self, rotation: ArrayLike, translation: ArrayLike) -> Registration:
        """The object where a placement ``x_robot = R x_world + t`` (``rotation`` (3, 3), ``translation`` (3,) m: the
        placement that puts the recording's skill in the robot's reach, docs/CONVENTIONS.md) puts it: robot's world
        from CAD, ``(R R_reg, R t_reg + t)``; the path distances stay the registration's."""
        R = np.asarray(rotation, dtype=float)
        reg = self.registration
        return Registration(
            rotation=R @ reg.rotation,
            translation_m=R @ reg.translation_m + np.asarray(translation, dtype=float),
            rms_distance_m=reg.rms_distance_m,
            max_distance_m=reg.max_distance_m,
        )


def kuleuven_ground_truth(recording: Path) -> KuleuvenGroundTruth:
    """The ground truth of one KU Leuven recording (a ``contour_*.csv``): import it as the README says, register the
    object's crease to its contact path, choose the placement the applied force presses into, and evaluate the
    normal cone at every sample."""
    demonstration = demonstration_from_csv(recording, CsvImportOptions(**KULEUVEN_IMPORT))
    arrays = demonstration.arrays()
    contour = kuleuven_object()
    positions, forces = arrays.positions, arrays.wrenches[:, :3]
    candidates = edge_registrations(positions, contour.crease.points)
    registration = registration_pressed_into(candidates, contour.crease, positions, forces)
    return KuleuvenGroundTruth(
        demonstration=demonstration,
        kuleuven_object=contour,
        candidates=tuple(candidates),
        candidate_bisector_angles_rad=bisector_angles_of_placements(candidates, contour.crease, positions, forces),
        registration=registration,
        cone=normal_cones_at(positions, contour.crease, registration),
    )


@dataclass(frozen=True)
class SkillAgainstObject:
    """A skill learned from a KU Leuven recording, judged against the object's CAD at every sample of its contact
    segments (angles in rad): ``outside_cone`` the CF z's angle outside the normal cone of the crease (0 inside);
    ``from_bisector`` its angle to the cone's bisector; ``from_friction_free`` its angle to the friction-free force
    the learner sees (`skills.friction.blended_friction_free` about the CF z, smoothed as
    `skills.skill_checks.reference_directions`); ``since_touch_down_s`` (s) each sample's time since its segment's
    start.
    """

    outside_cone: NDArray[np.float64]
    from_bisector: NDArray[np.float64]
    from_friction_free: NDArray[np.float64]
    since_touch_down_s: NDArray[np.float64]


def skill_against_object(skill: Skill, truth: KuleuvenGroundTruth) -> SkillAgainstObject:
    """Judge the compliant frames of ``skill`` (learned from ``truth.demonstration``) against the object's normal
    cones, sample by sample of its contact segments (the skill's own resampled grid)."""
    from skills.compliant_frames import compliant_frame_rotations, tool_velocities
    from skills.friction import blended_friction_free, friction_coefficient
    from skills.parameterize import uniform_arrays
    from skills.skill_checks import reference_directions

    t, positions, _, wrenches = uniform_arrays(truth.demonstration)
    velocities = tool_velocities(positions, skill.sample_rate_hz)
    parts: list[list[NDArray[np.float64]]] = [[], [], [], []]
    for segment in (s for s in skill.segments if s.kind is SegmentKind.contact):
        rows = slice(segment.start_index, segment.end_index)
        since = t[rows] - t[segment.start_index]
        z = compliant_frame_rotations(segment, since)[:, :, 2]
        cone = truth.cones_at(positions[rows])
        forces, v = wrenches[rows, :3], velocities[rows]
        free = blended_friction_free(forces, v, friction_coefficient(forces, v), normals=z)
        smoothed = reference_directions(free, skill.sample_rate_hz)
        parts[0].append(angle_outside_cone(z, cone.inward_a, cone.inward_b))
        parts[1].append(np.arccos(np.clip(np.sum(z * cone.bisectors, axis=1), -1.0, 1.0)))
        parts[2].append(np.arccos(np.clip(np.sum(z * smoothed, axis=1), -1.0, 1.0)))
        parts[3].append(since)
    return SkillAgainstObject(*(np.concatenate(p) for p in parts))
