"""An execution's verdict: what it must achieve (:class:`ExecutionTolerances`), each check of what it achieved
against that (:class:`VerdictCheck`), where on the part it pressed against where it was taught
(:class:`SurfacePressed`), and the verdict (:class:`ExecutionVerdict`). Angles in degrees, normals into the surface
(docs/CONVENTIONS.md)."""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field

from schemas.numbers import Real


class Verdict(StrEnum):
    """Whether an execution did what its skill asked, within the tolerances (:class:`ExecutionTolerances`)."""

    passed = "pass"
    failed = "fail"


class VerdictCheckName(StrEnum):
    """The checks of a verdict (:class:`VerdictCheck`)."""

    finished = "finished"
    """The execution ran every segment (not aborted, not failed)."""
    true_force_rms = "true_force_rms"
    true_force_max = "true_force_max"
    contact_ratio = "contact_ratio"
    touchdown = "touchdown"
    surface_found = "surface_found"
    """Every guarded approach found the surface within the expected window of where it was taught (outside it: a
    warning, or an abort with ``surface_outside_window: abort``)."""
    not_relocated = "not_relocated"
    """No contour was relocated where its touch-down found the part (``follow_surface_normal``; relocated: a warning
    naming the part's move, which the run believed)."""
    surface_pressed = "surface_pressed"
    """Every contact segment pressed on the surface it was taught on: its touch-down and final normals within the
    friction cone of the taught ones (``normal_cone_deg``), and across a switch between two contact segments the normal
    turned the taught crease's way by at least half its angle (:class:`SurfacePressed`)."""
    next_surface = "next_surface"
    """Following the surface, every switch between two contact segments met the next surface (the tracked normal
    turned towards it) before the segment's extension past its taught end ran out; met only later in the next
    segment: a warning; never: a failure ("next surface not found")."""
    region_covered = "region_covered"
    """Every contour pressed on at least ``region_coverage`` of the region it was taught on (the share of its taught
    normals' turn that the pressed normals span)."""
    exit_collision = "exit_collision"
    """No free segment after a contact hit the part on the way out (a hit there is not a touch-down)."""
    judged_on = "judged_on"
    """What the verdict was judged on: a work piece measured from the skill's own recording (or rebuilt from the
    skill) can confirm that recording only, not that the skill does the job on the real part: a warning."""
    force_in_band = "force_in_band"
    """A skill learned from several demonstrations: the share of the contact whose TRUE normal force lies within the
    band the demonstrations pressed (``Segment.force_band``), aligned to it by where the tool is; below
    ``force_in_band`` a failure, below `schemas.skill.IN_BAND_SHARE` without it a warning."""
    skill_checks = "skill_checks"
    """The skill passes its own checks against its demonstration (``Skill.checks``). A failed one is a warning; it
    fails the verdict where the work piece carries the mistake, so that the run cannot show it wrong: one rebuilt from
    what the skill learned, or one measured from its demonstration when a check of the recording itself failed (its
    wrench's sign, its sensor offset)."""


class ExecutionTolerances(BaseModel):
    """What an execution must achieve to pass its verdict (errors of the TRUE normal force, over the steady contact
    including crease passages and segment switches)."""

    model_config = ConfigDict(extra="forbid")

    true_force_rms_pct: Real = Field(
        10.0, gt=0, le=1000, description="Largest RMS error of the true normal force, % of the reference force."
    )
    true_force_max_pct: Real = Field(
        50.0, gt=0, le=1000, description="Largest error of the true normal force at a steady step, % of the reference."
    )
    contact_ratio: Real = Field(
        0.97, ge=0, le=1, description="Smallest share of the contact phase spent touching the surface."
    )
    touchdown_ratio: Real = Field(
        1.5, gt=0, le=100, description="Largest touch-down peak over the first desired force (1 = no overshoot)."
    )
    normal_cone_deg: Real = Field(
        42.0,
        gt=0,
        le=90,
        description="Largest angle between a normal pressed (at a touch-down, at a contact's end) and the taught one, "
        "deg; default: the widest friction cone (μ 0.9): beyond it the tool pressed on another surface, or another "
        "place of the part.",
    )
    region_coverage: Real = Field(
        0.85,
        ge=0,
        le=1,
        description="Smallest share of a contour's taught region (the turn of its taught normals) the normals it "
        "pressed on must span.",
    )
    force_in_band: Real | None = Field(
        None,
        ge=0,
        le=1,
        description="Skills learned from several demonstrations: the least share of the contact whose true normal "
        "force lies within the demonstrated force band (the verdict fails below it); None: judged as a warning below "
        "0.9.",
    )
    surface_window_m: Real | None = Field(
        None,
        gt=0,
        le=0.5,
        description="How far from where it was taught a guarded approach may find the surface, m (along CF z, "
        "either way); default: the approach's slow zone, approach_slow_distance_m (at least 5 mm): beyond it the "
        "tool met the surface faster than the touch-down speed, or met another surface.",
    )


class VerdictCheck(BaseModel):
    """One check of a verdict: the measured value against its limit."""

    model_config = ConfigDict(extra="forbid")

    name: VerdictCheckName
    passed: bool
    warning_only: bool = Field(False, description="A failure is a warning and does not fail the verdict.")
    value: Real | None = Field(None, description="The measured value (unit of the limit; None: not measured).")
    limit: Real | None = Field(None, description="The tolerance it is held to.")
    message: str = Field(description="What was measured against what, in words.")


class ExecutionVerdict(BaseModel):
    """Pass or fail, and why: every check of the execution against its tolerances."""

    model_config = ConfigDict(extra="forbid")

    verdict: Verdict
    reasons: list[str] = Field(default_factory=list, description="The failed checks' messages (empty on pass).")
    warnings: list[str] = Field(
        default_factory=list, description="What held the execution to less than it expected, without failing it."
    )
    checks: list[VerdictCheck] = Field(default_factory=list)

    def lines(self) -> list[str]:
        """The verdict in words: ``verdict: pass (5 checks)`` or ``verdict: FAIL``, then one line per reason and
        warning."""
        head = f"verdict: pass ({len(self.checks)} checks)" if self.verdict is Verdict.passed else "verdict: FAIL"
        return [head, *(f"  - {reason}" for reason in self.reasons), *(f"  WARNING: {w}" for w in self.warnings)]


class SurfacePressed(BaseModel):
    """Where one contact segment pressed against where it was taught, told by the surface normals (unit, into the
    surface, world; ``skills.pressed_normals``): the TRUE contact normals the tool pressed on in the segment's contact
    phase, against the taught CF z (its frame, or its frame series at the same share of the segment)."""

    model_config = ConfigDict(extra="forbid")

    segment: int = Field(description="The contact segment's index.")
    normal_error_deg: Real = Field(
        description="Median angle between the normal pressed and the one taught at the same share of the segment, deg."
    )
    normal_error_max_deg: Real = Field(description="Its 95th percentile, deg.")
    touchdown_normal_error_deg: Real = Field(
        description="Angle between the normal pressed over the first 0.1 s and the taught first normal, deg."
    )
    final_normal_error_deg: Real = Field(
        description="Angle between the normal pressed over the last 0.1 s and the taught last normal, deg."
    )
    taught_region_deg: tuple[float, float] | None = Field(
        None,
        description="A contour's taught normals as angles about the axis they turn about (smallest, largest), deg; "
        "None where they turn less than 10°.",
    )
    pressed_region_deg: tuple[float, float] | None = Field(
        None, description="The span of the normals pressed about the same axis (2nd to 98th percentile), deg."
    )
    region_coverage: Real | None = Field(
        None, ge=0, le=1, description="The share of the taught region the pressed one spans."
    )
    crease_deg: Real | None = Field(
        None,
        description="Entered from another contact segment: the angle of the taught crease between them (the taught "
        "normals on either side), deg.",
    )
    crease_turn_deg: Real | None = Field(
        None,
        description="How far the normal pressed turned across the switch (from the previous segment's to this one's), "
        "about the axis of the taught crease, deg, positive the taught way (a part tilted as a whole turns as taught, "
        "a steeper surface more, a missing surface not at all).",
    )
    next_surface_found: bool | None = Field(
        None,
        description="Following the surface into this segment across a crease: whether the tracked normal turned "
        "towards it (the next surface met) before the previous segment's extension ran out; None otherwise.",
    )
