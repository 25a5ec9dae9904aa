"""The live execution in Foxglove: a Foxglove WebSocket server (Foxglove's WebSocket protocol, the ``foxglove-sdk``
package, under either of its names: :data:`SDK_SUBPROTOCOL` and :data:`WEBSOCKET_SUBPROTOCOL`) in the API process,
on the API's own bind address (loopback by default; in docker-compose the container's interfaces, published on the
host's loopback), streaming the execution that runs.

What it streams is what the exported MCAP holds (``services.telemetry_export.ExecutionMessages``: the same topics,
ROS 2 message types, CDR, built by the same code), so a recorded run looks in Foxglove as the live one did: poses,
wrenches (world, CF), desired force, phase, segment, ``/tf`` (one tree that agrees with the URDF: the arm's links,
flange and tool link; tool, reference, ``cf`` under ``world``),
``/joint_states``, ``/robot_description`` (the URDF; its meshes served by the asset handler, ``package://`` URIs) and
``/markers`` (paths, CF triads, the touched work piece); and what the simulator knows of the contact,
``/force/true`` (the true normal force, N) and ``/contact`` (``services.dashboard.ros_scene.truth_messages``).
``/execution`` (``std_msgs/msg/String``) names the execution shown.

Where the telemetry comes from: the store, as the API's bus callbacks write it (``services.bus_events``), polled
every :data:`ROWS_POLL_S` from a cursor: every sample received (a repaired gap too) is shown once, in order. One
execution at a time: the newest one running; when it ends the view keeps it until another starts. Poses, wrenches
and ``/tf`` at :data:`LIVE_HZ` (every n-th control step; a whole run at 1 kHz is in the export), joint states and
markers at the scene's own rates.

Configuration: ``CONTACT_SKILLS_FOXGLOVE_PORT`` (``services.settings.ServiceSettings.foxglove_port``: default 8765;
``0`` any free port; ``off`` no server). A port already taken falls back to a free one (``/health`` gives the URL,
``foxglove_url``). The handshake is held to the REST API's browser rule (``services.origin_gate``: a foreign
``Origin`` is refused unless in ``CONTACT_SKILLS_CORS_ORIGINS``; a ``Host`` not the service's), and the same gate
answers a client that offers only ``foxglove.websocket.v1`` in that name. The protocol has no
authentication: when the API's reads need its token
(``CONTACT_SKILLS_TOKEN_READS``) the server is off unless the variable is set.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any

import numpy as np

from schemas.api import ExecutionState
from services.dashboard.stream import decimated, stored_rows
from services.http_rules import LOOPBACK_NAMES
from services.local_processes import LOOPBACK
from services.origin_gate import OriginGate
from services.settings import DEFAULT_FOXGLOVE_PORT, ServiceSettings
from services.store import TERMINAL, Store

if TYPE_CHECKING:
    import foxglove

log = logging.getLogger("contact_skills.foxglove")

LOOPBACK_OF_ALL = {"0.0.0.0": LOOPBACK, "": LOOPBACK, "::": "::1"}
"""The loopback address a client on this machine connects to when the server listens on all interfaces."""
ROWS_POLL_S = 0.05
"""How often the store is read for new samples, s (20 Hz; each read sends everything new)."""
LIVE_HZ = 100.0
"""Poses, wrenches and ``/tf`` per second of execution time (1 kHz control steps; the last of each read always)."""
EXECUTION_TOPIC = "/execution"
SDK_SUBPROTOCOL = "foxglove.sdk.v1"
"""The WebSocket subprotocol the SDK's server accepts (and it alone)."""
WEBSOCKET_SUBPROTOCOL = "foxglove.websocket.v1"
"""The same protocol's original name, the only one older Foxglove Studio releases and some forks offer: the origin
gate answers it in that name (``services.origin_gate``)."""
MESSAGE_BACKLOG = 8192
"""Messages the server holds per client before it drops the oldest (the SDK's default is 1024): about 7 s of the
live stream (eleven topics at :data:`LIVE_HZ`; joint states and markers slower), so an API that stalls a few
seconds (a loaded machine, a learn) still sends every step once it reads the store again. A message is a few
hundred bytes (markers a few kB)."""


def client_url(host: str, port: int) -> str:
    """``ws://HOST:PORT`` of a server listening on ``host``: on all interfaces, the loopback address (a local client's;
    a container's port published on the host's loopback maps to it as well)."""
    host = LOOPBACK_OF_ALL.get(host, host)
    return f"ws://{f'[{host}]' if ':' in host else host}:{port}"


def live_view(store: Store, settings: ServiceSettings) -> FoxgloveLive | None:
    """The live view ``settings`` ask for (``foxglove_server_port``), or None, saying why in the log when the token
    turned it off (an operator who set ``CONTACT_SKILLS_TOKEN_READS`` may wonder where it went)."""
    port = settings.foxglove_server_port
    if port is None and settings.foxglove_port is None:
        log.info("Foxglove live view off: reads need the token and CONTACT_SKILLS_FOXGLOVE_PORT is not set")
    if port is None:
        return None
    return FoxgloveLive(store, port, settings.host, settings.cors_origins, settings.host_names)


class FoxgloveLive:
    """The Foxglove WebSocket server of one API process, following ``store``'s running executions (see the module
    docstring). :meth:`start` it, :meth:`close` it; :attr:`url` is where Foxglove connects. ``host``: the address
    to listen on, the API's (``ServiceSettings.host``); ``allowed_origins``, ``host_names``: the browser rule of the
    REST API (``ServiceSettings.cors_origins``, ``.host_names``), which the handshake is held to
    (``services.origin_gate``)."""

    def __init__(
        self,
        store: Store,
        port: int = DEFAULT_FOXGLOVE_PORT,
        host: str = LOOPBACK,
        allowed_origins: list[str] | None = None,
        host_names: frozenset[str] = LOOPBACK_NAMES,
    ) -> None:
        self.store = store
        self.port = port
        self.host = host
        self.allowed_origins = list(allowed_origins or [])
        self.host_names = host_names
        self.server: Any = None
        self.gate: OriginGate | None = None
        self._context: Any = None
        self._channels: dict[str, foxglove.Channel] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._solver: Any = None  # the IK, made on the first execution (a PyBullet client)
        self._following: str | None = None
        self._created = 0.0
        self._cursor = 0
        self._resends: set[str] = set()
        self._lock = threading.Lock()
        self._done = False
        self._messages: Any = None
        self._description: bytes | None = None
        self._markers: bytes | None = None

    @property
    def url(self) -> str | None:
        """Where a client connects while serving (:func:`client_url`), else None."""
        return None if self.gate is None else client_url(self.host, self.gate.port)

    def start(self) -> None:
        """Serve on :attr:`host` (falling back to a free port when :attr:`port` is taken) through the origin gate,
        the SDK's server behind it on a loopback port of its own, and start following."""
        import foxglove

        from services.dashboard.ros_scene import message_definition
        from services.dashboard.scene import robot_asset, robot_description
        from services.telemetry_export import execution_topics

        context = self._context = foxglove.Context()  # kept: the channels and the server live in it
        topics = {**execution_topics(), EXECUTION_TOPIC: "std_msgs/msg/String"}
        for topic, msgtype in topics.items():
            schema = foxglove.Schema(name=msgtype, encoding="ros2msg", data=message_definition(msgtype).encode())
            self._channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=context)
        options = dict(name="contact-skills", host=LOOPBACK, port=0, context=context, asset_handler=robot_asset,
                       server_listener=_Listener(self), message_backlog_size=MESSAGE_BACKLOG)  # fmt: skip
        try:
            self.server = foxglove.start_server(**options)
        except RuntimeError:  # the API serves on without the live view (/health: foxglove_url null)
            log.exception("Foxglove server could not start")
            return
        for port in (self.port, 0):
            aliases = {WEBSOCKET_SUBPROTOCOL: SDK_SUBPROTOCOL}
            gate = OriginGate(self.host, port, self.server.port, self.allowed_origins, self.host_names, aliases)
            try:
                gate.start()
            except OSError as exc:
                log.warning("Foxglove server: port %d not available (%s): serving on a free port", port, exc)
                continue
            self.gate = gate
            break
        self._description = self._string(robot_description())
        log.info("Foxglove live view on %s", self.url)
        self._thread = threading.Thread(target=self._run, name="foxglove-live", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        if self.gate is not None:
            self.gate.close()
            self.gate = None
        if self.server is not None:
            self.server.stop()
            self.server = None
        if self._solver is not None:
            self._solver.close()

    # ------------------------------------------------------------------------------------------ following

    def _run(self) -> None:
        while not self._stop.wait(ROWS_POLL_S):
            try:
                self._step()
            except Exception:  # a bad row must not end the live view
                log.exception("Foxglove live view: following %s failed", self._following)
                self._done = True

    def _step(self) -> None:
        with self._lock:
            resends, self._resends = self._resends, set()
        for topic in resends:
            self._resend(topic)
        running = [row for row in self.store.executions.active() if row.status is not ExecutionState.queued
                   and row.streams_telemetry]  # fmt: skip
        newest = max(running, key=lambda row: row.created, default=None)
        if newest is not None and newest.id != self._following and (self._done or self._following is None
                                                                    or newest.created >= self._created):  # fmt: skip
            self._follow(newest.id, newest.created)
        if self._following is None or self._done:
            return
        row = self.store.executions.get(self._following)
        finished = row is None or row.status in TERMINAL
        rows = stored_rows(self.store, self._following, self._cursor)
        if rows.shape[0]:
            self._cursor += rows.shape[0]
            self._publish(rows, final=finished)
        if finished:
            self._done = True

    def _follow(self, execution_id: str, created: float) -> None:
        from services.dashboard.scene import JointSolver
        from services.telemetry_export import ExecutionMessages

        if self._solver is None:
            self._solver = JointSolver()
        self._following, self._created, self._cursor, self._done = execution_id, created, 0, False
        self._messages = ExecutionMessages(int(created * 1e9), self._solver)
        self._log(EXECUTION_TOPIC, self._string(execution_id), int(created * 1e9))
        log.info("Foxglove live view follows %s", execution_id)

    def _publish(self, rows: np.ndarray, final: bool) -> None:
        from services.dashboard.ros_scene import MARKERS, ROBOT_DESCRIPTION

        shown = rows[decimated(rows[:, 0], LIVE_HZ)]
        messages = self._messages.messages(shown, final)
        # In time order, not topic by topic: a client that lags loses the OLDEST messages of its backlog (the
        # server's policy), so a read larger than the backlog then drops whole early steps, never a whole topic of
        # the read (a step's /tf, wrenches and truth arrive together or not at all).
        sent = [(topic, stamp, payload) for topic, (stamps, payloads) in messages.items()
                for stamp, payload in zip(stamps.tolist(), payloads, strict=True)]  # fmt: skip
        for topic, stamp, payload in sorted(sent, key=lambda message: message[1]):  # stable: topics keep their order
            self._log(topic, payload, stamp)
        if ROBOT_DESCRIPTION in messages:
            self._description = messages[ROBOT_DESCRIPTION][1][-1]
        if MARKERS in messages:
            self._markers = messages[MARKERS][1][-1]

    def _log(self, topic: str, payload: bytes, stamp_ns: int) -> None:
        self._channels[topic].log(payload, log_time=int(stamp_ns))

    @staticmethod
    def _string(text: str) -> bytes:
        """A ``std_msgs/msg/String``, CDR."""
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS2_HUMBLE)
        return bytes(store.serialize_cdr(store.types["std_msgs/msg/String"](data=text), "std_msgs/msg/String"))

    def subscribed(self, topic: str) -> None:
        """A client subscribed to ``topic``: what is sent only once goes again at the next poll (not from the
        server's callback, which runs before the subscription is in place)."""
        with self._lock:
            self._resends.add(topic)

    def _resend(self, topic: str) -> None:
        import time

        from services.dashboard.ros_scene import MARKERS, ROBOT_DESCRIPTION

        latched = {ROBOT_DESCRIPTION: self._description, MARKERS: self._markers,
                   EXECUTION_TOPIC: self._string(self._following) if self._following else None}  # fmt: skip
        if latched.get(topic) is not None:
            self._log(topic, latched[topic], time.time_ns())


class _Listener:
    """The server's callbacks: a new subscriber gets what is sent only once (Foxglove's protocol keeps nothing)."""

    def __init__(self, live: FoxgloveLive) -> None:
        self.live = live

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.live.subscribed(channel.topic)
