"""Executing a learned skill: the request, the controller settings, telemetry and the measured result, one module
each (``settings``, ``environment``, ``telemetry``, ``metrics``; the verdict: ``schemas.verdict``), all re-exported
here (``from schemas.execution import X``).

Conventions (docs/CONVENTIONS.md): SI units; quaternions scalar-last ``[x, y, z, w]``; 6-vectors
``[x, y, z, rx, ry, rz]``; wrenches are the wrench the TOOL APPLIES TO THE ENVIRONMENT at the
tool point, in the world frame unless a field says CF. The compliant frame (CF) z axis points
into the surface, so the desired normal force is a positive CF ``f_z``.
"""

from schemas.execution.environment import (
    MAX_FORCE_SCALE,
    MAX_OFFSET_M,
    MAX_SENSOR_BIAS_N,
    MAX_SENSOR_NOISE_N,
    MAX_TILT_DEG,
    NOMINAL_CONTACT_DAMPING_N_S_M,
    NOMINAL_CONTACT_STIFFNESS_N_M,
    Bias3,
    EnvironmentChange,
    Offset3,
    Placement,
    SensorChoice,
    Tilt2,
    WorkPieceSource,
)
from schemas.execution.metrics import ExecutionMetrics
from schemas.execution.settings import (
    DEFAULT_ENGINE,
    MAX_PAUSE_TIMEOUT_S,
    ControllerGains,
    ControllerKind,
    Engine,
    ExecutionRequest,
    ExecutionSettings,
    GainSchedule,
    NullSpaceProjection,
    Pace,
    RotStiffness3,
    Stiffness3,
    SurfaceWindowAction,
)
from schemas.execution.telemetry import (
    PHASE_CODES,
    PHASES_BY_CODE,
    STREAMED_TELEMETRY_COLUMNS,
    STREAMED_TELEMETRY_WIDTH,
    TELEMETRY_COLUMNS,
    TELEMETRY_WIDTH,
    ExecutionPhase,
    TelemetryBatch,
    TelemetryMode,
)

__all__ = [
    "DEFAULT_ENGINE",
    "MAX_FORCE_SCALE",
    "MAX_OFFSET_M",
    "MAX_PAUSE_TIMEOUT_S",
    "MAX_SENSOR_BIAS_N",
    "MAX_SENSOR_NOISE_N",
    "MAX_TILT_DEG",
    "NOMINAL_CONTACT_DAMPING_N_S_M",
    "NOMINAL_CONTACT_STIFFNESS_N_M",
    "PHASES_BY_CODE",
    "PHASE_CODES",
    "STREAMED_TELEMETRY_COLUMNS",
    "STREAMED_TELEMETRY_WIDTH",
    "TELEMETRY_COLUMNS",
    "TELEMETRY_WIDTH",
    "Bias3",
    "ControllerGains",
    "ControllerKind",
    "Engine",
    "EnvironmentChange",
    "ExecutionMetrics",
    "ExecutionPhase",
    "ExecutionRequest",
    "ExecutionSettings",
    "GainSchedule",
    "NullSpaceProjection",
    "Offset3",
    "Pace",
    "Placement",
    "RotStiffness3",
    "SensorChoice",
    "Stiffness3",
    "SurfaceWindowAction",
    "TelemetryBatch",
    "TelemetryMode",
    "Tilt2",
    "WorkPieceSource",
]
