"""What one job of a sim worker (an execution or a recording) may cost, and what its settings imply.

Settings each within their own bounds can still imply hours of simulation (a guarded approach at 10 µm/s over
15 cm) or millions of control steps (a 10 µs time step); the worker keeps a row of every step in memory and allocates
each phase's references before the phase runs. So every job is estimated from ALL its settings before it runs
(:class:`JobEstimate`: simulated time, control steps, worker memory, telemetry) and held to a :class:`JobBudget`:
the API refuses a job over it with a 422 naming the settings that make it long, a worker refuses one that reaches it
over the bus, and a worker aborts a job whose steps reach the budget all the same (a pause's held steps, a surface
found farther than where it was taught: what an estimate made before the run cannot know).

Both read the budget from the same environment variables (:data:`ENV_JOB_MAX_SIMULATED_S`,
:data:`ENV_JOB_MAX_STEPS`), which ``contact-skills up`` hands to its API and its workers.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.demonstration import MAX_DEMONSTRATION_SAMPLES, MAX_DURATION_S
from schemas.execution import STREAMED_TELEMETRY_WIDTH, TELEMETRY_WIDTH
from schemas.numbers import Real

ENV_JOB_MAX_SIMULATED_S = "CONTACT_SKILLS_JOB_MAX_SIMULATED_S"
ENV_JOB_MAX_STEPS = "CONTACT_SKILLS_JOB_MAX_STEPS"
DEFAULT_JOB_MAX_SIMULATED_S = 1800.0
"""Longest simulated time of one job, s (30 min: a 20-minute execution fits; the longest taught skill runs ~30 s)."""
DEFAULT_JOB_MAX_STEPS = 2_000_000
"""Most control steps of one job (33 min at 1 kHz; about 2 GB of worker memory at the peak, 0.5 GB of telemetry)."""

WORKER_BYTES_PER_STEP = 3 * TELEMETRY_WIDTH * 8
"""Worker memory per control step run, bytes: the row of every step (float64) in an array that doubles as it fills,
and a copy kept for replays while the telemetry streams (measured: 687 MB for a 607 000-step run whose estimate,
references included, is 991 MB)."""
PLAN_BYTES_PER_STEP = 26 * 8
"""Memory per control step of a phase's references, allocated before the phase runs, bytes (float64: position, twist
and force, their packed copy with the orientation, a guarded approach's speed and travel)."""
TELEMETRY_BYTES_PER_STEP = STREAMED_TELEMETRY_WIDTH * 8
"""Stored telemetry per control step, bytes (float64, before compression; ~550 bytes as JSON)."""
NOMINAL_TIME_STEP_S = 1e-3
"""The control step of a simulated world that sets none (``schemas.world.WorldConfig``), s: a job whose
steps would fit at it is refused for its time step."""
RECORDING_BYTES_PER_STEP = 2200
"""Worker memory per step of a teacher's recording horizon, bytes (its log, the demonstration built from it, the
reply's JSON; measured: 309 MB for a 10 kHz recording's 143 000 steps)."""


class JobBudget(BaseModel):
    """The most one job may imply; the API and every worker hold each job to it (see the module docstring)."""

    model_config = ConfigDict(frozen=True)

    max_simulated_s: Real = Field(
        DEFAULT_JOB_MAX_SIMULATED_S,
        gt=0,
        description=f"Longest simulated time of one job, s ({ENV_JOB_MAX_SIMULATED_S}).",
    )
    max_steps: int = Field(
        DEFAULT_JOB_MAX_STEPS, ge=1, description=f"Most control steps of one job ({ENV_JOB_MAX_STEPS})."
    )

    @classmethod
    def from_env(cls, env: Mapping[str, str]) -> JobBudget:
        """The budget the environment ``env`` sets (the caller passes its process's ``os.environ``: the contract reads
        no environment itself); the defaults where it sets none."""
        values: dict[str, float | int] = {}
        for name, var, kind in (
            ("max_simulated_s", ENV_JOB_MAX_SIMULATED_S, float),
            ("max_steps", ENV_JOB_MAX_STEPS, int),
        ):
            if (raw := env.get(var, "").strip()) != "":
                try:
                    values[name] = kind(raw)
                except ValueError:
                    raise ValueError(f"{var}={raw!r}: not a valid {kind.__name__}") from None
        return cls(**values)

    def step_limit(self, time_step_s: float) -> int:
        """The most control steps of ``time_step_s`` (s) a job may run: the step budget, or fewer where the
        simulated time runs out first."""
        return min(self.max_steps, int(self.max_simulated_s / time_step_s))

    def describe(self) -> str:
        """The budget in words, with the variables that set it."""
        return (
            f"the job budget of {self.max_simulated_s:g} s and {self.max_steps:,} control steps "
            f"({ENV_JOB_MAX_SIMULATED_S}, {ENV_JOB_MAX_STEPS})"
        )


class JobPart(BaseModel):
    """One stretch of a job's simulated time and the setting that sets its length."""

    what: str = Field(description="The stretch, in words (with the values that set its length).")
    field: str = Field(
        description="The request field that makes it as long as it is, a dotted path from the request's top "
        "(``touchdown_speed_m_s``, ``overrides.move_duration_s``; ``skill`` for the skill's own segments)."
    )
    simulated_s: Real = Field(ge=0, description="Its simulated time, s.")


class JobEstimate(BaseModel):
    """What a job implies, from all its settings, before it runs (``skills.job_estimate``, ``sim_worker.teacher``)."""

    kind: Literal["execution", "recording"]
    time_step_s: Real = Field(gt=0, description="The simulation's control step, s.")
    time_step_field: str = Field(description="The request field that sets the time step (dotted path).")
    parts: list[JobPart] = Field(description="Its stretches of simulated time, in order.")
    longest_phase: JobPart = Field(
        description="The longest phase whose references are allocated at once before it runs (a guarded approach "
        "over its whole approach_max_distance_m, a recording's horizon): what must fit before the run can be cut."
    )

    @property
    def simulated_s(self) -> float:
        """Simulated time of the whole job, s."""
        return sum(part.simulated_s for part in self.parts)

    @property
    def steps(self) -> int:
        """Control steps of the whole job."""
        return _steps(self.simulated_s, self.time_step_s)

    @property
    def worker_memory_bytes(self) -> int:
        """Peak worker memory the job adds, bytes (its rows or log, and the longest phase's references)."""
        if self.kind == "recording":
            return _steps(self.longest_phase.simulated_s, self.time_step_s) * RECORDING_BYTES_PER_STEP
        longest = _steps(self.longest_phase.simulated_s, self.time_step_s) * PLAN_BYTES_PER_STEP
        return self.steps * WORKER_BYTES_PER_STEP + longest

    @property
    def telemetry_bytes(self) -> int:
        """Telemetry an execution streams and the API stores (0 for a recording), bytes."""
        return self.steps * TELEMETRY_BYTES_PER_STEP if self.kind == "execution" else 0

    def describe(self) -> str:
        """The job's size in words."""
        if self.simulated_s >= sys.maxsize:
            return f"the {self.kind} would never end"
        size = (
            f"{self.simulated_s:,.0f} s of simulated time ({self.steps:,} control steps of {self.time_step_s:g} s; "
            f"about {_bytes(self.worker_memory_bytes)} of worker memory"
        )
        telemetry = f", {_bytes(self.telemetry_bytes)} of telemetry" if self.kind == "execution" else ""
        return f"the {self.kind} implies {size}{telemetry})"

    def problems(self, budget: JobBudget) -> list[tuple[str, str]]:
        """``(field, message)`` for each setting that takes the job past ``budget`` (none when it fits): the longest
        parts of a job too long; for too many control steps (or a longest phase over the step budget), a time step
        below the nominal one, and the longest parts (or that phase) still too many at the nominal step. A recording
        is also held to what a demonstration may hold (``MAX_DEMONSTRATION_SAMPLES`` samples over
        ``MAX_DURATION_S``): it records a sample every step."""
        max_s, max_steps, limit = budget.max_simulated_s, budget.max_steps, budget.describe()
        if self.kind == "recording":
            max_s, max_steps = min(max_s, MAX_DURATION_S), min(max_steps, MAX_DEMONSTRATION_SAMPLES)
            limit += f" and the {MAX_DEMONSTRATION_SAMPLES:,} samples a demonstration holds (one per step)"
        over = f"{self.describe()}, over {limit}"
        phase = self.longest_phase
        phase_steps = _steps(phase.simulated_s, self.time_step_s)
        at = max(self.time_step_s, NOMINAL_TIME_STEP_S)  # where a finer time step is taken back to
        found: dict[str, str] = {}
        if self.simulated_s > max_s:
            _name_longest(found, self.parts, self.simulated_s - max_s, over)
        if (self.steps > max_steps or phase_steps > max_steps) and self.time_step_s < NOMINAL_TIME_STEP_S:
            found.setdefault(self.time_step_field, f"a time step of {self.time_step_s:g} s: {over}")
        _name_longest(found, self.parts, self.simulated_s - max_steps * at, over)
        if _steps(phase.simulated_s, at) > max_steps:
            found.setdefault(
                phase.field,
                f"{phase.what} allocates its {phase_steps:,} control steps of references before it runs "
                f"({_seconds(phase.simulated_s)}), more than {limit}",
            )
        return list(found.items())


def _steps(simulated_s: float, time_step_s: float) -> int:
    """Control steps of ``simulated_s`` (s) at ``time_step_s`` (s), saturating at ``sys.maxsize``: a speed of 5e-324 m/s
    makes a phase last forever, and its job is refused naming it, never an overflow."""
    steps = simulated_s / time_step_s
    return round(steps) if steps < sys.maxsize else sys.maxsize


def _name_longest(found: dict[str, str], parts: list[JobPart], excess_s: float, over: str) -> None:
    """Add to ``found`` the fields of the longest ``parts`` that together make up ``excess_s`` (s), each with its
    part and ``over`` (a field already named keeps its message)."""
    for part in sorted(parts, key=lambda p: p.simulated_s, reverse=True):
        if excess_s <= 0:
            return
        found.setdefault(part.field, f"{part.what} takes {_seconds(part.simulated_s)}: {over}")
        excess_s -= part.simulated_s


def _seconds(simulated_s: float) -> str:
    """A simulated time in words: ``8,000 s``, or ``forever`` (a speed so small that the phase never ends)."""
    return f"{simulated_s:,.0f} s" if simulated_s < sys.maxsize else "forever"


def _bytes(n: int) -> str:
    """``n`` bytes in MB or GB."""
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"
