"""Floods without a login and read bursts (issue 41, items 2 and 4): `/health` and new bus sessions through the
floods, the API's peak memory through the read bursts.

Run: ``.venv/bin/python benchmarks/bench_floods.py`` (``--smoke``: small floods, 3 s each, a 20 000-sample
demonstration, nothing written); writes the ``bench_floods`` section of docs/BENCHMARKS.md (``--no-write``: only
print).

``contact-skills up --workers 1`` (temp SQLite) on free loopback ports, every client in this process:

1. ``GET /health`` on a fresh connection every 0.2 s for ``--seconds``: p50, p99, max latency and the probes not
   answered 200 (an error or a timeout counts, at the time it took), (a) quiet, (b) while ``--slow-bodies`` slow
   ``POST /demonstrations`` bodies are held (the head with a 100 000-byte ``Content-Length``, then 1 byte every 2 s;
   each reopened as soon as the server closes it), (c) while ``--idle`` idle TCP connections to the Zenoh router's
   port are held (no login; reopened likewise). Probing starts after the flood has been held ``--settle`` s. In (a)
   and (c), how long a new Zenoh session with the observer login ``/health`` hands out (``zenoh_login``) takes to
   open, 3 times in a row.
2. The API process's peak resident set (``VmHWM`` from ``/proc``, reset through ``clear_refs`` before each burst)
   during 12 concurrent paged reads of one ``--samples``-sample demonstration (``GET /demonstrations/{id}`` with
   ``cursor`` and the largest ``limit``, following ``X-Next-Cursor``), and during 3 concurrent
   ``GET /demonstrations`` of 6 demonstrations whose names have the most characters a name may have.
"""

from __future__ import annotations

import os
import socket
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the floods of tests/floods.py

from benchmarks.bench_service import child_commands, demonstration_body, running
from benchmarks.bench_worker_memory import resident_mb
from benchmarks.report import machine_line, pin_blas_threads, report_main

pin_blas_threads()

import httpx  # noqa: E402
import numpy as np  # noqa: E402
from floods import IdleFlood, closed, port_of, slow_body  # noqa: E402

from schemas.api import NEXT_OFFSET_HEADER  # noqa: E402
from schemas.text import MAX_NAME_CHARS  # noqa: E402
from services.api.deps import NEXT_CURSOR_HEADER  # noqa: E402
from services.local_processes import free_port  # noqa: E402

SECTION = "bench_floods"
PROBE_EVERY_S = 0.2
"""How often ``/health`` is asked, s (as the issue's probe did)."""
PROBE_TIMEOUT_S = 10.0
"""A probe not answered within this long counts as not 200, at this time, s."""
BYTE_EVERY_S = 2.0
"""How often each slow body sends its next byte, s."""
SESSION_OPENS = 3
SESSION_WAIT_S = 60.0
"""How long a new bus session may retry before it counts as refused, s."""
READERS = 12
LISTERS = 3
LISTED = 6
LISTED_SAMPLES_S = 1.0
"""Each listed demonstration's length, s at 1 kHz: a list shows summaries, not samples."""
HEALTH_TARGET_P99_S = 1.0
MEMORY_BOUND_MB = 1000.0
"""Issue 41's "done when": /health p99 under 1 s through the floods, the API's memory under a read burst ≤ 1 GB."""
FULL = {"slow_bodies": 300, "idle": 110, "seconds": 20.0, "settle": 3.0, "samples": 163_503}
SMOKE = {"slow_bodies": 20, "idle": 20, "seconds": 3.0, "settle": 0.5, "samples": 20_000}


class SlowBodyFlood(IdleFlood):
    """``n`` slow ``POST /demonstrations`` bodies to the API at ``url`` (``tests/floods.py``'s ``slow_body``: the
    head with a 100 000-byte ``Content-Length`` and its first byte), each sending one more byte every
    :data:`BYTE_EVERY_S` s; one the server closed is reopened when it comes to send its next byte (as the issue's
    probe did: a client that dribbles a body learns of the close when it writes)."""

    def __init__(self, url: str, n: int) -> None:
        super().__init__(port_of(url), n)
        self.url = url
        self._next_byte_s = 0.0
        self._dead: set[socket.socket] = set()

    def _open(self) -> socket.socket:
        return slow_body(self.url, SESSION_WAIT_S)

    def _gone(self, sock: socket.socket) -> bool:
        return sock in self._dead

    def _tend(self, held: list[socket.socket]) -> None:
        if time.monotonic() < self._next_byte_s:
            return
        self._next_byte_s = time.monotonic() + BYTE_EVERY_S
        self._dead.clear()  # those reopened already
        for sock in held:
            try:
                if closed(sock):
                    raise ConnectionResetError
                sock.send(b" ")
            except OSError:
                self._dead.add(sock)


def probe_health(url: str, seconds: float) -> dict:
    """``GET /health`` on a fresh connection every :data:`PROBE_EVERY_S` s for ``seconds``: the latencies (s), how
    many were not answered 200 and what they got instead (a status, or the client's error)."""
    latencies, not_ok, failures = [], 0, Counter()
    end = time.monotonic() + seconds
    fresh = httpx.Limits(max_keepalive_connections=0)  # a new connection each time: it must get through the flood
    with httpx.Client(base_url=url, timeout=PROBE_TIMEOUT_S, limits=fresh) as http:
        while (start := time.monotonic()) < end:
            try:
                got: int | str = http.get("/health").status_code
            except httpx.HTTPError as exc:
                got = type(exc).__name__
            latencies.append(time.monotonic() - start)
            not_ok += got != 200
            failures[got] += got != 200
            time.sleep(max(0.0, start + PROBE_EVERY_S - time.monotonic()))
    return {"probes": len(latencies), "not_ok": not_ok, "failures": +failures,
            "p50": float(np.percentile(latencies, 50)), "p99": float(np.percentile(latencies, 99)),
            "max": max(latencies)}  # fmt: skip


def session_opens(url: str) -> list[float | None]:
    """How long each of :data:`SESSION_OPENS` new Zenoh sessions with the observer login ``/health`` hands out took
    to open, s (None: refused for :data:`SESSION_WAIT_S` s)."""
    from schemas.bus_security import BusSecurity
    from services.bus import open_session

    health = httpx.get(f"{url}/health", timeout=PROBE_TIMEOUT_S).json()
    login = BusSecurity(user=health["zenoh_login"]["user"], password=health["zenoh_login"]["password"])
    times: list[float | None] = []
    for _ in range(SESSION_OPENS):
        start = time.monotonic()
        try:
            session = open_session("client", connect=health["zenoh_endpoints"], wait_s=SESSION_WAIT_S, security=login)
        except ConnectionError:
            times.append(None)
            continue
        times.append(time.monotonic() - start)
        session.close()
    return times


def api_pid(up_pid: int) -> int:
    """The pid of the API process among ``contact-skills up``'s children."""
    (pid,) = [pid for pid, argv in child_commands(up_pid).items() if "api" in argv]
    return pid


def peak_during(pid: int, burst) -> tuple[float, float, list]:
    """Run ``burst()`` (returns a list); ``pid``'s resident set before it and its peak during it (``VmHWM``, reset
    first: the upload before it peaked higher), MB, and what ``burst`` returned."""
    Path(f"/proc/{pid}/clear_refs").write_text("5")  # 5: reset VmHWM to VmRSS (proc(5))
    before = resident_mb(pid)[0]
    results = burst()
    return before, resident_mb(pid)[1], results


def paged_read(url: str, demo_id: str, samples: int) -> dict:
    """Read demonstration ``demo_id`` page by page (the largest ``limit``: ``samples``): samples, pages, largest
    reply (bytes)."""
    got, pages, largest, cursor = 0, 0, 0, "0"
    with httpx.Client(base_url=url, timeout=600) as http:
        while cursor is not None:
            reply = http.get(f"/demonstrations/{demo_id}", params={"cursor": cursor, "limit": samples})
            reply.raise_for_status()
            got += len(reply.json()["demonstration"]["t"])
            pages, largest = pages + 1, max(largest, len(reply.content))
            cursor = reply.headers.get(NEXT_CURSOR_HEADER)
    return {"samples": got, "pages": pages, "largest": largest}


def listed(url: str) -> dict:
    """``GET /demonstrations`` (every page): items, pages, largest reply (bytes)."""
    items, pages, largest, offset = 0, 0, 0, "0"
    with httpx.Client(base_url=url, timeout=600) as http:
        while offset is not None:
            reply = http.get("/demonstrations", params={"offset": offset})
            reply.raise_for_status()
            items, pages, largest = items + len(reply.json()), pages + 1, max(largest, len(reply.content))
            offset = reply.headers.get(NEXT_OFFSET_HEADER)
    return {"items": items, "pages": pages, "largest": largest}


def measure(slow_bodies: int, idle: int, seconds: float, settle: float, samples: int, work_dir: Path) -> dict:
    """Run the benchmark once; returns its figures."""
    port, zenoh_port = free_port(), free_port()
    url = f"http://127.0.0.1:{port}"
    argv = ["up", "--workers", "1", "--port", str(port), "--zenoh-port", str(zenoh_port),
            "--db", str(work_dir / "floods.db"), "--log-level", "warning"]  # fmt: skip
    big = demonstration_body(samples / 1000.0, name="read burst")
    assert len(big["t"]) == samples, len(big["t"])
    floods = {}
    with running(argv, url, workers=1) as up, httpx.Client(base_url=url, timeout=600) as http:
        floods["quiet"] = {**probe_health(url, seconds), "sessions": session_opens(url)}
        with SlowBodyFlood(url, slow_bodies) as flood:
            time.sleep(settle)
            floods["slow"] = {**probe_health(url, seconds), "opened": flood.opened}
        with IdleFlood(zenoh_port, idle) as flood:
            time.sleep(settle)
            floods["idle"] = {**probe_health(url, seconds), "sessions": session_opens(url), "opened": flood.opened}

        pid = api_pid(up.pid)
        demo_id = http.post("/demonstrations", json=big).raise_for_status().json()["id"]
        del big
        with ThreadPoolExecutor(READERS) as pool:
            reads = peak_during(pid, lambda: list(pool.map(lambda _: paged_read(url, demo_id, samples),
                                                           range(READERS))))  # fmt: skip
        http.delete(f"/demonstrations/{demo_id}").raise_for_status()  # the lists hold the named ones only
        for k in range(LISTED):
            named = demonstration_body(LISTED_SAMPLES_S, name=f"{k}" * MAX_NAME_CHARS)
            http.post("/demonstrations", json=named).raise_for_status()
        with ThreadPoolExecutor(LISTERS) as pool:
            lists = peak_during(pid, lambda: list(pool.map(lambda _: listed(url), range(LISTERS))))
    return {"slow_bodies": slow_bodies, "idle": idle, "seconds": seconds, "settle": settle, "samples": samples,
            "floods": floods, "reads": reads, "lists": lists}  # fmt: skip


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:.0f}" if seconds >= 0.1 else f"{seconds * 1000:.1f}"


def _failures(probes: dict) -> str:
    """How many probes were not answered 200, and what they got instead (``"38 (503 × 30, ReadTimeout × 8)"``)."""
    kinds = ", ".join(f"{kind} × {count}" for kind, count in sorted(probes["failures"].items(), key=str))
    return f"{probes['not_ok']} ({kinds})" if kinds else str(probes["not_ok"])


def _sessions(times: list[float | None]) -> str:
    opened = [t for t in times if t is not None]
    refused = len(times) - len(opened)
    shown = f"{_ms(float(np.median(opened)))} / {_ms(max(opened))}" if opened else "—"
    return shown + (f" ({refused} of {len(times)} refused)" if refused else "")


def report(figures: dict, load_at_start: float) -> str:
    f, floods = figures, figures["floods"]
    quiet, slow, idle = floods["quiet"], floods["slow"], floods["idle"]
    (reads_before, reads_peak, reads), (lists_before, lists_peak, lists) = f["reads"], f["lists"]
    worst_p99 = max(slow["p99"], idle["p99"])
    worst_peak = max(reads_peak, lists_peak)
    largest_page = max(r["largest"] for r in reads) / 1e6
    pages = reads[0]["pages"]
    flood_rows = (
        ("quiet", "—", quiet, quiet["sessions"]),
        ("slow `POST` bodies to the API", f"{f['slow_bodies']} ({slow['opened']} opened)", slow, None),
        ("idle TCP connections to the Zenoh port", f"{f['idle']} ({idle['opened']} opened)", idle, idle["sessions"]),
    )
    lines = [
        "## Floods without a login and read bursts (`benchmarks/bench_floods.py`)",
        "",
        f"{machine_line('', load_at_start)} `contact-skills up --workers 1` (temp SQLite) on 127.0.0.1; every flood "
        f"and probe runs in the benchmark's own process on the same machine (loopback: no network between them, so "
        f"the figures are the service's, not a network's). `/health` asked on a fresh connection every "
        f"{PROBE_EVERY_S:g} s for {f['seconds']:g} s (a probe not answered within {PROBE_TIMEOUT_S:g} s counts as "
        f"not 200), after the flood was held {f['settle']:g} s; a slow body sends its head (`Content-Length` "
        f"100 000) and 1 byte every {BYTE_EVERY_S:g} s, and is reopened when its next byte finds it closed; an idle "
        f"router connection is reopened as soon as the router closes it. A new bus session: the observer login "
        f"`/health` hands out, {SESSION_OPENS} opened in a row. `.venv/bin/python benchmarks/bench_floods.py`.",
        "",
        "| flood | held | probes | not 200 | /health p50 ms | p99 ms | max ms | new bus session, ms (median / max) |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |",
        *(
            f"| {name} | {held} | {p['probes']} | {_failures(p)} | {_ms(p['p50'])} | {_ms(p['p99'])} | "
            f"{_ms(p['max'])} | {_sessions(sessions) if sessions is not None else '—'} |"
            for name, held, p, sessions in flood_rows
        ),
        "",
        "| read burst | answered | largest reply, MB | API resident before, MB | API peak during, MB |",
        "| --- | --- | ---: | ---: | ---: |",
        f"| {READERS} concurrent paged reads of one {f['samples']:,}-sample demonstration | "
        f"{sum(r['samples'] == f['samples'] for r in reads)} of {READERS} whole, in {pages} "
        f"page{'s' * (pages > 1)} each | "
        f"{largest_page:.1f} | {reads_before:.0f} | {reads_peak:.0f} |",
        f"| {LISTERS} concurrent `GET /demonstrations` of {LISTED} with {MAX_NAME_CHARS}-character names | "
        f"{sum(r['items'] == LISTED for r in lists)} of {LISTERS} with all {LISTED} | "
        f"{max(r['largest'] for r in lists) / 1e6:.3f} | {lists_before:.0f} | {lists_peak:.0f} |",
        "",
        f"- p99 of `/health` during the slow-body flood: {_ms(slow['p99'])} ms ({slow['not_ok']} of "
        f"{slow['probes']} probes not 200); during the idle-connection flood: {_ms(idle['p99'])} ms "
        f"({idle['not_ok']} of {idle['probes']} not 200); quiet: {_ms(quiet['p99'])} ms. Issue 41's bound, every "
        f"probe 200 and p99 under {HEALTH_TARGET_P99_S:g} s through the floods: "
        f"{'met' if worst_p99 < HEALTH_TARGET_P99_S and not slow['not_ok'] + idle['not_ok'] else 'NOT met'}.",
        f"- A new bus session opened in {_sessions(idle['sessions'])} ms (median / max of {SESSION_OPENS}) while "
        f"{f['idle']} idle connections were held to the router's port, against {_sessions(quiet['sessions'])} ms "
        "quiet.",
        f"- The API's peak resident set (`VmHWM`, MB = 10^6 bytes, reset before each burst) was {reads_peak:.0f} MB "
        f"during the paged reads (pages of at most {largest_page:.1f} MB) and {lists_peak:.0f} MB during the lists: "
        f"{'within' if worst_peak <= MEMORY_BOUND_MB else 'OVER'} issue 41's bound of {MEMORY_BOUND_MB:.0f} MB.",
        "- Limits: one run on a shared 2-core machine (the floods' own threads compete with the API for the cores, "
        "the load average beside); loopback only; one attacker address; the floods are those of issue 41, not the "
        "largest the service holds.",
    ]
    return "\n".join(lines) + "\n"


def build(slow_bodies: int, idle: int, seconds: float, settle: float, samples: int) -> str:
    """Run the benchmark once on a temporary database; its report."""
    load_at_start = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        figures = measure(slow_bodies, idle, seconds, settle, samples, Path(tmp))
    return report(figures, load_at_start)


def main(argv: list[str] | None = None) -> int:
    options = [
        ("--slow-bodies", {"type": int, "default": FULL["slow_bodies"], "help": "slow POST bodies held"}),
        ("--idle", {"type": int, "default": FULL["idle"], "help": "idle connections held to the router"}),
        ("--seconds", {"type": float, "default": FULL["seconds"], "help": "/health probed this long, s"}),
        ("--settle", {"type": float, "default": FULL["settle"], "help": "flood held before probing, s"}),
        ("--samples", {"type": int, "default": FULL["samples"], "help": "samples of the demonstration read"}),
    ]
    return report_main(__doc__.split("\n\n")[0], SECTION, build, argv, options=options, smoke=SMOKE)


if __name__ == "__main__":
    sys.exit(main())
