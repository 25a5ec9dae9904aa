"""What the executor knows of an execution beyond its telemetry rows (``ExecutionLog``), for its metrics and verdict."""

from __future__ import annotations

from dataclasses import dataclass, field

from execution.contact_detection import ContactGuard


@dataclass
class ExecutionLog:
    """What the executor knows beyond the telemetry rows: where each guarded approach found the surface, the
    control frames it took and the contact guard of its last approach."""

    contact_offsets_m: list[float] = field(default_factory=list)
    """Per guarded approach: the surface found along +CF z from where it was taught, m."""
    frame_log: list[tuple[int, float, float, float]] = field(default_factory=list)
    """(first telemetry row, CF z) of every control frame the controller took."""
    contact_guard: ContactGuard | None = None
    relocations_m: list[list[float]] = field(default_factory=list)
    """Per contour relocated where its touch-down found the part, the part's move (m, world)."""
    unconfirmed_relocations_m: list[list[float]] = field(default_factory=list)
    """Per move of the part a touch-down suggested and a second touch did not confirm (m, world): not relocated."""
    surface_window_m: float = 0.02
    """How far from where it was taught a surface may be found, m."""
    work_piece: str | None = None
    """Where the world's work piece came from, when it was resolved for the skill (``ExecutionWorld.source``)."""
    next_surface_found: dict[int, bool] = field(default_factory=dict)
    """Following the surface: per contact segment entered across a crease, whether the next surface was met."""
