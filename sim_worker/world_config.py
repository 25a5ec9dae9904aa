"""``WorldConfig``: everything that defines a simulated world, JSON-able (the taught world of a teacher recording,
an execution's world, a rebuilt work piece).

Frames and units: world frame, SI units (m, N, s), angles in degrees where a field name says ``_deg``;
see docs/CONVENTIONS.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

from schemas.execution import NOMINAL_CONTACT_DAMPING_N_S_M, NOMINAL_CONTACT_STIFFNESS_N_M
from skills.control import IIWA_TORQUE_LIMITS_NM


@dataclass
class WorldConfig:
    """Everything that defines a world; JSON-able via ``to_dict`` / ``from_dict``.

    The table top is a plane through ``(table_center_xy, table_height_m)``, tilted by ``table_tilt_deg``
    about the horizontal ``table_tilt_axis`` through that point. The ramp (the second plane) starts at a
    crease line on the table top, parallel to the table's y axis at table-x ``ramp_crease_x_m`` (relative to
    the table centre), and rises towards +x by ``ramp_tilt_deg`` relative to the table. The cylinder and the
    curved block lie on the table top at table-frame ``(x, y)`` positions, turned by a yaw about the table
    normal; their ``*_offset_m`` shifts them (world frame) away from lying on the table, e.g. to move a
    contour object for execution.

    ``work_pieces`` are further static convex solids, each ``{"name": str, "vertices": [[x, y, z], ...]}`` (the
    convex hull of the vertices, world frame, m): the work piece rebuilt from a skill (``sim_worker.work_piece``),
    usually with ``table_enabled`` false. An optional ``"layers": n`` says that each point of the part's top lies
    in ``n`` parts (a rebuilt strip's pieces overlap by half: 2); the world then makes each such contact ``n``
    times softer, so the surface keeps ``contact_stiffness`` and ``contact_damping`` where the parts overlap.
    """

    time_step_s: float = 1e-3
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    # Table: a box, top surface through (center, height).
    table_enabled: bool = True
    table_height_m: float = 0.10
    table_center_xy: tuple[float, float] = (0.60, 0.0)
    table_size_xy: tuple[float, float] = (0.60, 0.80)
    table_thickness_m: float = 0.04
    table_tilt_deg: float = 0.0
    table_tilt_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    # Ramp: the second plane ("two planes" scenario).
    ramp_enabled: bool = False
    ramp_tilt_deg: float = 20.0
    ramp_crease_x_m: float = 0.0
    ramp_length_m: float = 0.20
    ramp_thickness_m: float = 0.04
    # Cylinder lying on the table, axis along the table y axis turned by the yaw.
    cylinder_enabled: bool = False
    cylinder_radius_m: float = 0.08
    cylinder_length_m: float = 0.30
    cylinder_xy_m: tuple[float, float] = (0.0, 0.0)
    cylinder_yaw_deg: float = 0.0
    cylinder_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Curved block: a base slab of height block_base_height_m capped by a half-ellipse of semi-axes
    # (block_half_length_m along the block x, block_cap_height_m up), extruded over block_width_m.
    block_enabled: bool = False
    block_half_length_m: float = 0.15
    block_cap_height_m: float = 0.06
    block_base_height_m: float = 0.02
    block_width_m: float = 0.16
    block_xy_m: tuple[float, float] = (0.0, 0.0)
    block_yaw_deg: float = 0.0
    block_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    block_mesh_segments: int = 180
    # Work pieces: convex solids given by their vertices (rebuilt from a skill).
    work_pieces: tuple[dict[str, Any], ...] = ()
    # Contact model and tool.
    contact_stiffness: float = NOMINAL_CONTACT_STIFFNESS_N_M
    contact_damping: float = NOMINAL_CONTACT_DAMPING_N_S_M
    lateral_friction: float = 0.2
    tool_radius_m: float = 0.010
    tool_shaft_length_m: float = 0.070
    tool_shaft_radius_m: float = 0.008
    tool_mass_kg: float = 0.2
    # Robot.
    torque_limits_nm: tuple[float, ...] = IIWA_TORQUE_LIMITS_NM
    # Wrench sensor model (sim_worker.sensor): "ideal" reads the exact contact wrench; "wrist" a force/torque
    # sensor between flange and tool (tool weight compensated from the tool model, its inertia not). Noise, bias
    # drift, a constant untared force bias (world frame), delay and the driver's low-pass apply to either (all off
    # by default; executions turn on a realistic wrist sensor unless asked for the ideal one, see
    # ``sim_worker.sensor.WRIST_SENSOR``).
    sensor_model: str = "ideal"
    wrench_noise_force_std_n: float = 0.0
    wrench_noise_torque_std_nm: float = 0.0
    wrench_bias_drift_n_per_sqrt_s: float = 0.0
    wrench_delay_s: float = 0.0
    wrench_filter_cutoff_hz: float | None = None
    wrench_bias_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wrench_offset_tool_n: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the sensor's own offset, TOOL frame
    seed: int = 0
    # An unknown tilt of the work piece (the parts ``sim_worker.executor.shifted_world_config`` moves): rotated
    # about world x, then world y (deg), about the pivot (world, m; it moves with the work piece's offsets).
    work_piece_tilt_deg: tuple[float, float] = (0.0, 0.0)
    work_piece_tilt_pivot_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples become lists)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WorldConfig:
        """Inverse of ``to_dict``; unknown keys raise ``TypeError``."""
        kwargs = {}
        for f in fields(cls):
            if f.name in data:
                value = data[f.name]
                kwargs[f.name] = tuple(value) if isinstance(value, list) else value
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise TypeError(f"unknown WorldConfig fields: {sorted(unknown)}")
        return cls(**kwargs)

    def replace(self, **changes: Any) -> WorldConfig:
        """A copy with ``changes`` applied."""
        data = self.to_dict()
        data.update(changes)
        return WorldConfig.from_dict(data)
