"""Learning off the API's event loop: a pool of learner processes with a time and memory budget per job.

``POST /skills`` hands the demonstration (JSON text) and the `LearnOptions` to :meth:`LearnerPool.learn`, which waits
for a free process without blocking the event loop, sends the job, and polls for the reply. Each process
(``multiprocessing`` forkserver: forked from a clean server with the science preloaded, never from the API's threads)

- runs ONE BLAS/OpenMP thread (``threadpoolctl`` plus the ``*_NUM_THREADS`` variables), so N processes use N cores
  instead of oversubscribing them,
- has an address-space limit (``memory_mb``, ``RLIMIT_AS``): a job that needs more gets ``MemoryError``, answered
  as a 422 instead of taking the machine's memory,
- is killed and replaced when its job has used ``time_budget_s`` of CPU time (:class:`LearningTimedOut`) or when the
  client that asked for it goes away (:class:`LearningCancelled`): abandoned requests stop computing. The budget is
  the WORK a job may cost, not its wall time: learners run niced (:data:`LEARNER_NICENESS`), so on a busy machine a
  quick learn waits for CPU, and a wall-clock budget killed it for the machine's load (a 0.3 s learn took over 15 s
  at a load of 6). A job starved of CPU still ends: after :data:`WALL_BUDGETS` budgets of wall time (also where
  ``/proc`` cannot be read, the wall time alone is the budget).

At most ``max_waiting`` jobs wait for a process; more get :class:`LearnerPoolFull` (503).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import os
import pickle
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from enum import StrEnum
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

from services.local_processes import THREAD_LIMIT_ENV, cpu_seconds

if TYPE_CHECKING:
    from schemas.demonstration import Demonstration

log = logging.getLogger("contact_skills.learning")

LEARNER_POLL_S = 0.1
"""How often a running job checks its budget and its client, s."""
LEARNER_NICENESS = 10
"""Learner processes run this much nicer than the API: on a busy machine /health and the bus answer first."""
WALL_BUDGETS = 5
"""A job is stopped after this many CPU budgets of wall time even if it has not used its CPU budget (a learner
starved of CPU by the machine's load)."""


class LearningTimedOut(RuntimeError):  # noqa: N818 (the name is the interface)
    """The job ran past the pool's time budget; its process was killed."""


class LearningCancelled(RuntimeError):  # noqa: N818
    """The client went away; the job's process was killed (or the job never started)."""


class LearnerPoolFull(RuntimeError):  # noqa: N818
    """Too many jobs are waiting for a learner process."""


class LearnOutcomeKind(StrEnum):
    """What a learner process's answer is (:class:`LearnOutcome`), and which of its fields it fills."""

    ok = "ok"
    """A skill: ``skill_json``, ``skill_type``, ``seconds``, ``reasons`` (the skill's warnings), ``reference``."""
    checks = "checks"
    """Strict learning refused a skill: ``reasons``, one per failed check."""
    learning = "learning"
    """A `skills.parameterize.LearningError`: ``field``, ``reason``."""
    value = "value"
    """A ValueError of the science: ``reason``."""
    memory = "memory"
    """Over the memory budget (``reason`` when the process died)."""
    bug = "bug"
    """Anything else: ``reason``, the traceback, for the log."""


@dataclass(frozen=True)
class LearnOutcome:
    """What a learner process answered: its ``kind`` says which of the other fields it fills."""

    kind: LearnOutcomeKind
    skill_json: str = ""
    skill_type: str = ""
    seconds: float = 0.0
    field: str = ""
    reason: str = ""
    reasons: tuple[str, ...] = ()
    reference: str = ""
    """Several demonstrations learned together: the source of the reference, whose samples the skill's refer to."""


MAX_GRID_SAMPLES = 1_000_000
"""Most samples a demonstration may span on its uniform grid (duration / median step): 16.7 min at 1 kHz."""


def check_sampling(demonstration: Demonstration) -> None:
    """Raise `LearningError` on ``t`` for time stamps the pipeline cannot work on in bounded memory: a rate above
    ``skills.parameterize.MAX_RATE_HZ`` (filter windows are sized in samples per second) or a uniform grid (duration
    at the median step, what irregular stamps are resampled to) longer than :data:`MAX_GRID_SAMPLES`. Run in the
    learner process (numpy and the science are imported there, not in the API's)."""
    import numpy as np

    from skills.parameterize import MAX_RATE_HZ, LearningError

    t = np.asarray(demonstration.t)
    step = float(np.median(np.diff(t)))
    if 1.0 / step > MAX_RATE_HZ:
        raise LearningError(
            "t",
            f"median time step {step:.3g} s is a {1 / step:.3g} Hz rate, above {MAX_RATE_HZ:g} Hz: are the "
            "time stamps in seconds?",
        )
    grid = (t[-1] - t[0]) / step + 1
    if grid > MAX_GRID_SAMPLES:
        raise LearningError(
            "t",
            f"{t[-1] - t[0]:.6g} s at the median step of {step:.3g} s spans {grid:.3g} samples, more than "
            f"{MAX_GRID_SAMPLES} (a gap in the time stamps, or a very long recording)",
        )


def _limit_process(memory_mb: int) -> None:
    """In a learner process: a lower CPU priority (the API's event loop and the sim workers come first), one BLAS
    thread, and an address-space limit of ``memory_mb`` MiB (0: none)."""
    import resource

    from threadpoolctl import threadpool_limits

    os.nice(LEARNER_NICENESS)
    os.environ.update(THREAD_LIMIT_ENV)
    threadpool_limits(1)
    if memory_mb > 0:
        limit = memory_mb * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def _learn(payload: bytes) -> LearnOutcome:
    """One job in a learner process: validate the demonstrations, check their sampling, learn (one: as
    `learn_skill`; several: together, `skills.joint_learning.learn_joint_skill`, each named by its source)."""
    import traceback

    from pydantic import ValidationError

    from schemas.demonstration import Demonstration
    from schemas.skill import LearnOptions
    from skills.joint_learning import learn_joint_skill
    from skills.parameterize import LearningError, SkillCheckError

    demonstrations_json, sources, options_json = pickle.loads(payload)
    started = time.perf_counter()
    try:
        demonstrations = [Demonstration.model_validate_json(text) for text in demonstrations_json]
        for demonstration in demonstrations:
            check_sampling(demonstration)
        skill = learn_joint_skill(demonstrations, LearnOptions.model_validate_json(options_json), sources)
        seconds = time.perf_counter() - started
        warnings = tuple(skill.warnings())
        reference = next((use.source for use in skill.demonstrations or [] if use.reference), "")
        return LearnOutcome(
            LearnOutcomeKind.ok,
            skill.model_dump_json(),
            skill.skill_type.value,
            seconds,
            reasons=warnings,
            reference=reference,
        )
    except SkillCheckError as exc:
        return LearnOutcome(
            LearnOutcomeKind.checks, reasons=tuple(f"{check.name.value}: {check.message}" for check in exc.checks)
        )
    except LearningError as exc:
        return LearnOutcome(LearnOutcomeKind.learning, field=exc.field, reason=exc.reason)
    except MemoryError:
        return LearnOutcome(LearnOutcomeKind.memory)
    except ValidationError as exc:  # a stored demonstration that no longer validates (bounds added since)
        first = exc.errors()[0]
        return LearnOutcome(
            LearnOutcomeKind.learning, field=".".join(str(p) for p in first["loc"]), reason=first["msg"]
        )
    except ValueError as exc:
        return LearnOutcome(LearnOutcomeKind.value, reason=f"{type(exc).__name__}: {exc}")
    except Exception:
        return LearnOutcome(LearnOutcomeKind.bug, reason=traceback.format_exc())


def _serve(connection: Connection, memory_mb: int) -> None:
    """A learner process: answer jobs until the pipe closes."""
    _limit_process(memory_mb)
    while True:
        try:
            payload = connection.recv_bytes()
        except (EOFError, OSError):
            return
        connection.send_bytes(pickle.dumps(_learn(payload)))


@dataclass
class _Slot:
    process: Any
    connection: Connection


@dataclass
class PoolStats:
    """Counters of the pool since it started (in ``GET /health``)."""

    processes: int
    running: int = 0
    waiting: int = 0
    completed: int = 0
    timed_out: int = 0
    cancelled: int = 0
    restarted: int = 0
    rejected: int = 0


class LearnerPool:
    """``processes`` learner processes, started on first use (see the module docstring)."""

    def __init__(self, processes: int, time_budget_s: float, memory_mb: int = 0, max_waiting: int = 200) -> None:
        self.processes = max(1, processes)
        self.time_budget_s = time_budget_s
        self.memory_mb = memory_mb
        self.max_waiting = max_waiting
        self.stats = PoolStats(processes=self.processes)
        self._idle: list[_Slot] = []
        self._started = 0
        self._free: asyncio.Semaphore | None = None
        self._warming: asyncio.Task | None = None
        self._context = multiprocessing.get_context("forkserver")
        self._context.set_forkserver_preload(["services.learner_pool", "skills.parameterize"])
        for name, value in THREAD_LIMIT_ENV.items():  # the forkserver inherits them (it starts on first use)
            os.environ.setdefault(name, value)
        self._closed = False

    def _spawn(self) -> _Slot:
        parent, child = self._context.Pipe()
        process = self._context.Process(target=_serve, args=(child, self.memory_mb), name="learner", daemon=True)
        process.start()
        child.close()
        return _Slot(process, parent)

    @staticmethod
    def _kill(slot: _Slot) -> None:
        slot.process.kill()
        slot.process.join(5)
        slot.connection.close()

    def warm_up(self) -> None:
        """Start the learner processes in the background (call from the event loop, e.g. at startup), so the first
        requests do not wait for them."""
        if self._warming is None and not self._idle:
            self._warming = asyncio.get_running_loop().create_task(self._warm())

    async def _warm(self) -> None:
        for _ in range(self.processes):
            self._idle.append(await asyncio.to_thread(self._spawn))

    async def learn(
        self,
        demonstrations_json: list[str],
        sources: list[str],
        options_json: str,
        client_gone: Callable[[], Awaitable[bool]],
    ) -> LearnOutcome:
        """Learn from ``demonstrations_json`` (one, or several of one task given as ``sources``) in a free process;
        raises :class:`LearnerPoolFull`, :class:`LearningTimedOut`,
        :class:`LearningCancelled` (``client_gone()`` became true while waiting or learning)."""
        if self._closed:
            raise LearningCancelled("the learner pool is shut down")
        if self._warming is not None:
            await self._warming
        if self._free is None:
            self._free = asyncio.Semaphore(self.processes)
        if self.stats.waiting >= self.max_waiting:
            self.stats.rejected += 1
            raise LearnerPoolFull(f"{self.stats.waiting} learning requests are already waiting; try again later")
        self.stats.waiting += 1
        try:
            while True:
                try:
                    await asyncio.wait_for(self._free.acquire(), LEARNER_POLL_S * 5)
                    break
                except TimeoutError:
                    if await client_gone():
                        self.stats.cancelled += 1
                        raise LearningCancelled("the client went away while waiting") from None
        finally:
            self.stats.waiting -= 1
        slot: _Slot | None = None
        try:
            slot = self._idle.pop() if self._idle else await asyncio.to_thread(self._spawn)
            self.stats.running += 1
            outcome = await self._run(slot, pickle.dumps((demonstrations_json, sources, options_json)), client_gone)
            if slot.process.is_alive():
                self._idle.append(slot)
                slot = None
            return outcome
        finally:
            if slot is not None:  # its process died, ran past the budget or lost its client: replace it
                await asyncio.to_thread(self._kill, slot)
                self.stats.restarted += 1
            self.stats.running -= 1
            self._free.release()

    async def _run(self, slot: _Slot, payload: bytes, client_gone: Callable[[], Awaitable[bool]]) -> LearnOutcome:
        started = time.monotonic()
        cpu_before = cpu_seconds(slot.process.pid)  # the process's earlier jobs are not this one's
        walls = 1 if cpu_before is None else WALL_BUDGETS  # no CPU clock to read: the wall time is the budget
        await asyncio.to_thread(slot.connection.send_bytes, payload)
        while True:
            if await asyncio.to_thread(slot.connection.poll, LEARNER_POLL_S):
                try:
                    outcome = pickle.loads(await asyncio.to_thread(slot.connection.recv_bytes))
                except (EOFError, OSError):  # the process died (the OOM killer, a crash in native code)
                    return LearnOutcome(LearnOutcomeKind.memory, reason="the learner process died")
                self.stats.completed += 1
                return outcome
            cpu_now = cpu_seconds(slot.process.pid)
            used = None if cpu_before is None or cpu_now is None else cpu_now - cpu_before
            if (used is not None and used > self.time_budget_s) or (
                time.monotonic() - started > walls * self.time_budget_s
            ):
                self.stats.timed_out += 1
                spent = f"{used:.1f} s of CPU" if used is not None else "its wall time"
                raise LearningTimedOut(
                    f"learning took longer than the budget of {self.time_budget_s:g} s of CPU time ({spent} used in "
                    f"{time.monotonic() - started:.1f} s)"
                )
            if await client_gone():
                self.stats.cancelled += 1
                raise LearningCancelled("the client went away while learning")

    def pids(self) -> list[int]:
        """Process ids of the idle learner processes (for tests and logs)."""
        return [slot.process.pid for slot in self._idle]

    def close(self) -> None:
        """Stop every idle learner process (running jobs end with their requests)."""
        self._closed = True
        if self._warming is not None and not self._warming.done():
            self._warming.cancel()
        slots, self._idle = self._idle, []
        for slot in slots:
            with contextlib.suppress(OSError):
                slot.connection.close()
            slot.process.join(2)
            if slot.process.is_alive():
                self._kill(slot)
