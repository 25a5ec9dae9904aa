"""The force/torque sensor model: what the controller reads instead of the exact contact wrench.

Every reading is the wrench the tool applies to the environment at the tool point, world frame (N, N·m;
docs/CONVENTIONS.md). Its source (``SensorConfig.model``, a :class:`~schemas.world.SensorModel`):

- ``ideal``: the exact contact wrench (the sum over the simulator's contact points);
- ``wrist``: a force/torque sensor between the flange and the tool, as mounted on a real arm. It reads the force
  the flange exerts on the tool (PyBullet's reaction of the fixed tool joint, whose origin is the tool point) and
  the tool's weight is compensated from the tool model (mass, centre of mass) as a real integration does; the
  tool's inertia is not, so accelerating the tool shows up (0.2 kg x a).

Then, once per control step and in this order: a bias that drifts as a random walk
(``bias_drift_n_per_sqrt_s``, zero at the start), white noise (``noise_*``), a constant force offset
fixed in the world (``bias_n``, as a misestimated tool weight), a delay
(``delay_s``, whole steps) and the driver's first-order low-pass (``filter_cutoff_hz``). With none
of them and the ideal source the controller reads the exact wrench. The sensor's own offset
(``offset_tool_n``, its strain gauges' zero, fixed in the TOOL frame) is added by the world, turned with the
tool. A tare (``SimWorld.tare_sensor``, which the executor takes in free space before contact) removes an offset in
the tool frame from the readings after it: the sensor's own entirely, a world-fixed one in the tare's pose only.

:data:`WRIST_SENSOR` is what a real cell has (values of a small six-axis sensor at 1 kHz, e.g. the
ATI Mini45 class: 0.06 N / 0.002 N·m noise, 2 ms of transport and driver delay, a 200 Hz driver filter, a
0.02 N/sqrt(s) bias drift); executions use it unless asked for the ideal sensor.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from schemas.world import SensorConfig, SensorModel

WRIST_SENSOR = SensorConfig(
    model=SensorModel.wrist,
    noise_force_std_n=0.06,
    noise_torque_std_nm=0.002,
    bias_drift_n_per_sqrt_s=0.02,
    delay_s=0.002,
    filter_cutoff_hz=200.0,
)
"""The realistic wrist sensor (no bias, no own offset, noise seed 0)."""
BLOCK = 1024
"""Steps of noise drawn at once (a generator call costs as much as a control law step's arithmetic)."""


# Layout of :attr:`WrenchSensor.buffer`: the sensor's whole state in one float array, so that a compiled caller passes
# one argument (each array argument costs ~40 ns of dispatch per step). Counters are whole numbers stored as floats.
_DRIFT_BIAS = 0  # (6,) the drifting bias (its force part drifts)
_FIXED_BIAS = 6  # (6,) the constant bias, world frame
_FILTERED = 12  # (6,) the low-pass output
_ALPHA = 18  # the low-pass coefficient (1: no filter)
_ADD_RANDOM = 19  # 1: noise or drift are drawn per step
_BIASED = 20  # 1: the constant bias is added
_DRAWN = 21  # the next row of the noise block
_READINGS = 22  # readings in the delay line
_DELAY_SLOT = 23  # the delay line's next slot
_STARTED = 24  # 1: the filter has started
_LINE_ROWS = 25  # rows of the delay line
_HEAD = 26  # then the delay line ((rows, 6) by rows), then the noise block ((BLOCK, 9) by rows)


class WrenchSensor:
    """Drift, noise, delay and low-pass on a wrench source; ``measure_into`` is called once per control step.

    The state lives in one array (:attr:`buffer`) and one compiled function updates it (:func:`_measure_into`): at
    1 kHz the dozen numpy calls of a plain-Python version cost ~10 µs per step, the compiled one ~1.5 µs with the same
    floating-point operations in the same order (the same readings to the last bit).
    """

    def __init__(self, config: SensorConfig, time_step_s: float) -> None:
        """``config`` the sensor; ``time_step_s`` the control step (s), at which it samples."""
        self.config = config
        dt = time_step_s
        std = np.array([config.noise_force_std_n] * 3 + [config.noise_torque_std_nm] * 3)
        drift_step = config.bias_drift_n_per_sqrt_s * math.sqrt(dt)
        self._random_each_step = bool(np.any(std > 0.0)) or drift_step > 0.0
        fixed_bias = np.concatenate([np.asarray(config.bias_n, dtype=float), np.zeros(3)])
        biased = bool(np.any(fixed_bias != 0.0))
        self.tool_offset = np.concatenate([np.asarray(config.offset_tool_n, dtype=float), np.zeros(3)])
        """The sensor's own offset (6,), TOOL frame: the world adds it turned with the tool (``SimWorld``)."""
        delay_steps = round(config.delay_s / dt)
        cutoff_hz = config.filter_cutoff_hz
        self.ideal = (
            config.model is SensorModel.ideal
            and not self._random_each_step
            and not biased
            and not np.any(self.tool_offset)
            and delay_steps == 0
            and cutoff_hz is None
        )
        """True when the reading is the exact contact wrench (ideal source, nothing added): read every step."""
        self._rng = np.random.default_rng(config.seed)
        self._scale = np.concatenate([std, np.full(3, drift_step)])
        line_rows = delay_steps + 1
        block_start = _HEAD + 6 * line_rows
        self.buffer = np.zeros(block_start + BLOCK * 9)
        """The sensor's state, updated in place (layout ``_DRIFT_BIAS`` ...): the delay line holds the last
        ``delay_steps + 1`` raw readings, a ring; the noise block the noise (6) and bias increments (3) of the next
        steps, one row per step, refilled by :meth:`draw` (all drawn at first: the first reading fills it; not reset
        with a run). A compiled caller passes it to :func:`measure_drawn` after :meth:`draw`."""
        buffer = self.buffer
        buffer[_FIXED_BIAS : _FIXED_BIAS + 6] = fixed_bias
        buffer[_ALPHA] = 1.0 if cutoff_hz is None else dt / (dt + 1.0 / (2.0 * math.pi * cutoff_hz))
        buffer[_ADD_RANDOM] = float(self._random_each_step)
        buffer[_BIASED] = float(biased)
        buffer[_DRAWN] = BLOCK
        buffer[_LINE_ROWS] = line_rows
        self._block = buffer[block_start:].reshape(BLOCK, 9)
        self.reset()

    def reset(self) -> None:
        """Start afresh (a new run, ``SimWorld.reset``): zero drift, empty delay line, the filter restarts from the
        next reading."""
        buffer = self.buffer
        buffer[_DRIFT_BIAS : _DRIFT_BIAS + 6] = 0.0
        buffer[_READINGS] = buffer[_DELAY_SLOT] = buffer[_STARTED] = 0.0

    def draw(self) -> None:
        """Make this step's noise and bias increment ready: the next block of them is drawn (one generator call per
        ``BLOCK`` steps) when the last is used up."""
        if self._random_each_step and self.buffer[_DRAWN] >= BLOCK:
            self._block[:] = self._rng.normal(0.0, 1.0, (BLOCK, 9)) * self._scale
            self.buffer[_DRAWN] = 0.0

    def measure_into(self, source: NDArray[np.float64], out: NDArray[np.float64]) -> None:
        """Write the reading (6,) for this step's source wrench (6,) into ``out`` (float64, may not be ``source``)."""
        self.draw()
        measure_drawn(source, out, self.buffer)

    def measure(self, source: NDArray[np.float64]) -> NDArray[np.float64]:
        """The reading (6,) for this step's source wrench (6,), a new array."""
        out = np.empty(6)
        self.measure_into(np.asarray(source, dtype=float), out)
        return out


@numba.njit(cache=True)
def measure_drawn(source, out, sensor):  # pragma: no cover - compiled
    """:func:`_measure_into` on the sensor state ``sensor`` (a :attr:`WrenchSensor.buffer` after
    :meth:`WrenchSensor.draw`) with this step's row of its noise block (its index advanced) when the sensor adds noise
    or drift."""
    rows = int(sensor[_LINE_ROWS])
    block = _HEAD + 6 * rows
    line = sensor[_HEAD:block].reshape((rows, 6))
    random = sensor[block : block + 9]  # not read without noise and drift
    if sensor[_ADD_RANDOM] != 0.0:
        drawn = int(sensor[_DRAWN])
        random = sensor[block + 9 * drawn : block + 9 * drawn + 9]
        sensor[_DRAWN] = drawn + 1
    _measure_into(source, out, random, sensor, line)


@numba.njit(cache=True)
def _measure_into(source, out, random, sensor, line):  # pragma: no cover - compiled
    """One reading: ``raw = source + (noise + bias)`` (the bias first drifts by its increment), ``+ fixed_bias``;
    into the delay ``line``; the oldest reading in the line through the low-pass ``f += alpha (delayed - f)``, into
    ``out``. ``sensor``: the state (:attr:`WrenchSensor.buffer`), ``random`` this step's noise and increments."""
    size = line.shape[0]
    slot = int(sensor[_DELAY_SLOT])
    add_random, biased = sensor[_ADD_RANDOM] != 0.0, sensor[_BIASED] != 0.0
    for i in range(6):
        raw = source[i]
        if add_random:
            if i < 3:
                sensor[_DRIFT_BIAS + i] += random[6 + i]
            raw = raw + (random[i] + sensor[_DRIFT_BIAS + i])
        if biased:
            raw = raw + sensor[_FIXED_BIAS + i]
        line[slot, i] = raw
    following = (slot + 1) % size
    sensor[_DELAY_SLOT] = following
    readings = int(sensor[_READINGS])
    if readings < size:
        readings += 1
        sensor[_READINGS] = readings
    oldest = 0 if readings < size else following
    alpha = sensor[_ALPHA]
    if sensor[_STARTED] == 0.0:
        sensor[_STARTED] = 1.0
        for i in range(6):
            sensor[_FILTERED + i] = line[oldest, i]
    else:
        for i in range(6):
            sensor[_FILTERED + i] = sensor[_FILTERED + i] + alpha * (line[oldest, i] - sensor[_FILTERED + i])
    for i in range(6):
        out[i] = sensor[_FILTERED + i]
