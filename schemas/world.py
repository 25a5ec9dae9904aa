"""``WorldConfig``: everything that defines a simulated world (``sim_worker`` builds it), JSON-able (the taught
world of a teacher recording, an execution's world, a rebuilt work piece), as typed sub-configs: the table, the ramp,
the cylinder, the curved block, the work pieces and their unknown tilt, the contact model, the tool, the wrench
sensor. On the bus a start's ``world_overrides`` are checked against it (:data:`WorldOverrides`).

Frames and units: world frame, SI units (m, N, s), angles in degrees where a field name says ``_deg``;
see docs/CONVENTIONS.md.

Stored worlds (teacher recordings, world files, skills' taught worlds, bus payloads) written before the sub-configs
hold one FLAT dict (``table_height_m``, ``sensor_model``, ``work_pieces`` as dicts, ...): :data:`LEGACY_FIELDS` maps
each of those keys to its sub-config field, and every way into a ``WorldConfig`` (the constructor, ``from_dict``,
``replace``) accepts them, also mixed with the nested form (a flat key then wins over its nested field).
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from typing import Annotated, Any

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationError,
    model_serializer,
    model_validator,
)

from schemas.execution import (
    DEFAULT_ENGINE,
    NOMINAL_CONTACT_DAMPING_N_S_M,
    NOMINAL_CONTACT_STIFFNESS_N_M,
    Engine,
)
from schemas.text import JsonObject

IIWA_TORQUE_LIMITS_NM: tuple[float, ...] = (320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0)
"""The KUKA LBR iiwa 14 R820's joint torque limits, N·m (its data sheet), the simulated arm's."""

Vector2 = tuple[float, float]
Vector3 = tuple[float, float, float]


class _Part(BaseModel):
    """A frozen sub-config that refuses unknown fields (a typo is an error, not a silent default)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class TableConfig(_Part):
    """The table, a box whose top surface is a plane through ``(center_xy, height_m)``, tilted by ``tilt_deg`` about
    the horizontal ``tilt_axis`` (world) through that point; ``size_xy`` and ``thickness_m`` are the box's (m)."""

    enabled: bool = True
    height_m: float = 0.10
    center_xy: Vector2 = (0.60, 0.0)
    size_xy: Vector2 = (0.60, 0.80)
    thickness_m: float = 0.04
    tilt_deg: float = 0.0
    tilt_axis: Vector3 = (1.0, 0.0, 0.0)


class RampConfig(_Part):
    """The ramp, the second plane of the "two planes" scenario: it starts at a crease line on the table top, parallel
    to the table's y axis at table-x ``crease_x_m`` (relative to the table centre), and rises towards +x by
    ``tilt_deg`` relative to the table; ``length_m`` along its slope, ``thickness_m`` (m)."""

    enabled: bool = False
    tilt_deg: float = 20.0
    crease_x_m: float = 0.0
    length_m: float = 0.20
    thickness_m: float = 0.04


class CylinderConfig(_Part):
    """A cylinder lying on the table top at table-frame ``xy_m``, its axis along the table's y axis turned by
    ``yaw_deg`` about the table normal; ``offset_m`` (world, m) shifts it away from lying on the table (a contour
    object moved for an execution)."""

    enabled: bool = False
    radius_m: float = 0.08
    length_m: float = 0.30
    xy_m: Vector2 = (0.0, 0.0)
    yaw_deg: float = 0.0
    offset_m: Vector3 = (0.0, 0.0, 0.0)


class BlockConfig(_Part):
    """The curved block on the table top at table-frame ``xy_m``, turned by ``yaw_deg``, shifted by ``offset_m``
    (world, m): a base slab of height ``base_height_m`` capped by a half-ellipse of semi-axes (``half_length_m``
    along the block x, ``cap_height_m`` up), extruded over ``width_m``; its mesh has ``mesh_segments`` along the
    cap."""

    enabled: bool = False
    half_length_m: float = 0.15
    cap_height_m: float = 0.06
    base_height_m: float = 0.02
    width_m: float = 0.16
    xy_m: Vector2 = (0.0, 0.0)
    yaw_deg: float = 0.0
    offset_m: Vector3 = (0.0, 0.0, 0.0)
    mesh_segments: int = 180


class WorkPiece(_Part):
    """A static convex solid: the convex hull of ``vertices`` (world frame, m), e.g. a part of the work piece rebuilt
    from a skill (``sim_worker.work_piece``). ``layers`` says that each point of the part's top lies in that many
    parts (a rebuilt strip's pieces overlap by half: 2); the world then makes each such contact ``layers`` times
    softer, so the surface keeps the contact model's stiffness and damping where the parts overlap. Without a
    ``name`` the world calls it ``work_piece_<index>``."""

    name: str | None = None
    vertices: tuple[Vector3, ...]
    layers: int = Field(1, ge=1)


class WorkPieceTilt(_Part):
    """An unknown tilt of the work piece (the parts ``sim_worker.executor.shifted_world_config`` moves): rotated
    about world x, then world y, by ``deg`` (deg), about ``pivot_m`` (world, m; it moves with the work piece's
    offsets)."""

    deg: Vector2 = (0.0, 0.0)
    pivot_m: Vector3 = (0.0, 0.0, 0.0)


class ContactConfig(_Part):
    """The tool's contact model: the compliant pad (``stiffness_n_m`` N/m, ``damping_n_s_m`` N·s/m) and its Coulomb
    friction coefficient with every surface (``lateral_friction``; the environment bodies get 1, Bullet multiplies
    them)."""

    stiffness_n_m: float = NOMINAL_CONTACT_STIFFNESS_N_M
    damping_n_s_m: float = NOMINAL_CONTACT_DAMPING_N_S_M
    lateral_friction: float = 0.2


class ToolConfig(_Part):
    """The ball-tipped tool on the flange (``sim_worker.robot_model``): ball radius, shaft length and radius (m),
    mass (kg)."""

    radius_m: float = 0.010
    shaft_length_m: float = 0.070
    shaft_radius_m: float = 0.008
    mass_kg: float = 0.2


class SensorModel(StrEnum):
    """Where the controller's wrench reading comes from (``sim_worker.sensor``)."""

    ideal = "ideal"
    """The exact contact wrench (the sum over the simulator's contact points)."""
    wrist = "wrist"
    """A force/torque sensor between flange and tool (tool weight compensated from the tool model, its inertia not)."""


class SensorConfig(_Part):
    """The wrench sensor model (``sim_worker.sensor``). Noise (N, N·m), bias drift (N/sqrt(s)), a constant untared
    force bias fixed in the WORLD frame (N), delay (s) and the driver's low-pass (Hz) apply to either model (all off
    by default; executions turn on a realistic wrist sensor unless asked for the ideal one, see
    ``sim_worker.sensor.WRIST_SENSOR``); ``offset_tool_n`` is the sensor's own offset, TOOL frame (N); ``seed``
    seeds its noise."""

    model: SensorModel = SensorModel.ideal
    noise_force_std_n: float = 0.0
    noise_torque_std_nm: float = 0.0
    bias_drift_n_per_sqrt_s: float = 0.0
    delay_s: float = 0.0
    filter_cutoff_hz: float | None = None
    bias_n: Vector3 = (0.0, 0.0, 0.0)
    offset_tool_n: Vector3 = (0.0, 0.0, 0.0)
    seed: int = 0


LEGACY_FIELDS: dict[str, tuple[str, str]] = {
    **{f"table_{name}": ("table", name) for name in TableConfig.model_fields},
    **{f"ramp_{name}": ("ramp", name) for name in RampConfig.model_fields},
    **{f"cylinder_{name}": ("cylinder", name) for name in CylinderConfig.model_fields},
    **{f"block_{name}": ("block", name) for name in BlockConfig.model_fields},
    **{f"tool_{name}": ("tool", name) for name in ToolConfig.model_fields},
    "contact_stiffness": ("contact", "stiffness_n_m"),
    "contact_damping": ("contact", "damping_n_s_m"),
    "lateral_friction": ("contact", "lateral_friction"),
    "sensor_model": ("sensor", "model"),
    **{f"wrench_{name}": ("sensor", name) for name in SensorConfig.model_fields if name not in ("model", "seed")},
    "seed": ("sensor", "seed"),
    "work_piece_tilt_deg": ("work_piece_tilt", "deg"),
    "work_piece_tilt_pivot_m": ("work_piece_tilt", "pivot_m"),
}
"""The flat keys of a world stored before the sub-configs -> (sub-config, field)."""


def _nested(data: Mapping[str, object]) -> dict[str, object]:
    """``data`` with its legacy flat keys moved into their sub-configs (a flat key wins over its nested field)."""
    nested = {key: value for key, value in data.items() if key not in LEGACY_FIELDS}
    for key, value in data.items():
        if key in LEGACY_FIELDS:
            part, name = LEGACY_FIELDS[key]
            current = nested.get(part, {})
            section = current.model_dump() if isinstance(current, BaseModel) else dict(current)
            section[name] = value
            nested[part] = section
    return nested


class WorldConfig(BaseModel):
    """Everything that defines a world; JSON-able via ``to_dict`` / ``from_dict``. Frozen: ``replace`` makes a
    changed copy. ``engine``, when set, is the physics engine the world is simulated on unless the execution names
    one (:func:`engine_to_run`); a world that names none is written without the key, as before it existed."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    time_step_s: float = 1e-3
    gravity: Vector3 = (0.0, 0.0, -9.81)
    table: TableConfig = TableConfig()
    ramp: RampConfig = RampConfig()
    cylinder: CylinderConfig = CylinderConfig()
    block: BlockConfig = BlockConfig()
    work_pieces: tuple[WorkPiece, ...] = ()
    work_piece_tilt: WorkPieceTilt = WorkPieceTilt()
    contact: ContactConfig = ContactConfig()
    tool: ToolConfig = ToolConfig()
    torque_limits_nm: tuple[float, ...] = IIWA_TORQUE_LIMITS_NM
    """The robot's joint torque limits, N·m (:data:`IIWA_TORQUE_LIMITS_NM`)."""
    sensor: SensorConfig = SensorConfig()
    engine: Engine | None = Field(
        None,
        description="The physics engine that simulates this world when the execution names none (a world built for "
        "MuJoCo, a cell description kept with its engine); it wins over a worker's default engine, not over the "
        "execution's own `engine`. Absent (null): the execution's, else the worker's, else pybullet. "
        "docs/ENGINES.md.",
        examples=["mujoco"],
    )

    @model_validator(mode="before")
    @classmethod
    def _legacy_flat_keys(cls, data: Any) -> Any:
        """A world stored with the flat keys (:data:`LEGACY_FIELDS`) loads into the sub-configs."""
        return _nested(data) if isinstance(data, dict) and not LEGACY_FIELDS.keys().isdisjoint(data) else data

    @model_serializer(mode="wrap")
    def _without_absent_engine(self, handler: SerializerFunctionWrapHandler) -> Any:
        """The dump without ``engine`` when it is None: every world written before the field existed (a recording's
        world, a truth file, a skill's taught world) is written byte for byte as before."""
        data = handler(self)
        if self.engine is None and isinstance(data, dict):
            data.pop("engine", None)
        return data

    def to_dict(self) -> JsonObject:
        """JSON-able dict, nested as the sub-configs."""
        return self.model_dump(mode="json")

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> WorldConfig:
        """Inverse of ``to_dict``; also reads the legacy flat keys. Unknown keys or bad values raise ``ValueError``
        naming the field (``sensor.delay_s: ...``)."""
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            problems = "; ".join(
                f"{'.'.join(str(part) for part in error['loc']) or 'world'}: {error['msg']}" for error in exc.errors()
            )
            raise ValueError(f"WorldConfig: {problems}") from None

    def replace(self, **changes: Any) -> WorldConfig:
        """A copy with ``changes`` applied: whole sub-configs (``table=...``, as a model or a dict of its fields, the
        rest of it kept) or legacy flat keys (``table_height_m=0.12``)."""
        data = self.to_dict()
        for key, value in _nested(changes).items():
            if isinstance(value, dict) and isinstance(data.get(key), dict):
                data[key] = {**data[key], **value}
            else:
                data[key] = value.model_dump() if isinstance(value, BaseModel) else value
        return WorldConfig.from_dict(data)

    def with_only_work_pieces(self, pieces: list[WorkPiece]) -> WorldConfig:
        """A copy without the table, ramp, cylinder and block, holding ``pieces`` (a rebuilt, measured or CAD work
        piece, world frame)."""
        return self.model_copy(
            update={
                "table": self.table.model_copy(update={"enabled": False}),
                "ramp": self.ramp.model_copy(update={"enabled": False}),
                "cylinder": self.cylinder.model_copy(update={"enabled": False}),
                "block": self.block.model_copy(update={"enabled": False}),
                "work_pieces": tuple(pieces),
            }
        )


def engine_to_run(requested: Engine | None, world: Engine | None, default: Engine = DEFAULT_ENGINE) -> Engine:
    """The engine an execution runs on: the one it names (``requested``, ``ExecutionSettings.engine``), else the one
    its world names (``world``, :attr:`WorldConfig.engine`), else ``default`` (a worker's default engine;
    :data:`schemas.execution.DEFAULT_ENGINE` for a local run or a sweep). The execution's own choice wins so that one
    world can be run on both engines and compared (issue 44); the metrics say which ran (docs/ENGINES.md)."""
    return requested or world or default


def world_engine(world: Mapping[str, object] | None) -> Engine | None:
    """The engine a world dict (a ``WorldConfig`` dict: a skill's taught world) names in its ``engine``; None when it
    names none or there is no world. Raises ValueError naming the engines for any other value (the rest of the world
    is not checked here)."""
    value = None if world is None else world.get("engine")
    if value is None:
        return None
    try:
        return Engine(value)
    except ValueError:
        known = ", ".join(engine.value for engine in Engine)
        raise ValueError(f"{value!r} is not an engine (give one of {known}, or leave it out)") from None


def checked_world_overrides(overrides: JsonObject) -> JsonObject:
    """``overrides`` as they are, when they change a world as :meth:`WorldConfig.replace` does (whole sub-configs or
    some of their fields, or legacy flat keys); else ``ValueError`` naming the field and why
    (``WorldConfig: cylinder.radius_mm: Extra inputs are not permitted``)."""
    WorldConfig().replace(**overrides)
    return overrides


WorldOverrides = Annotated[JsonObject, AfterValidator(checked_world_overrides)]
"""Changes to a world (the scenario's or the skill's taught one), as JSON: checked against :class:`WorldConfig`
wherever a model holding them is validated (both ends of the bus), carried unchanged."""
