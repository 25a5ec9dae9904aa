"""The force/torque sensor model: what the controller reads instead of the exact contact wrench.

Every reading is the wrench the tool applies to the environment at the tool point, world frame (N, N·m;
docs/CONVENTIONS.md). Its source (``SensorConfig.model``, a :class:`~sim_worker.world_config.SensorModel`):

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

from sim_worker.world_config import SensorConfig, SensorModel

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


class WrenchSensor:
    """Drift, noise, delay and low-pass on a wrench source; ``measure_into`` is called once per control step.

    The state lives in small arrays and one compiled function updates it (:func:`_measure_into`): at 1 kHz the
    dozen numpy calls of a plain-Python version cost ~10 µs per step, the compiled one ~1.5 µs with the same
    floating-point operations in the same order (the same readings to the last bit).
    """

    def __init__(self, config: SensorConfig, time_step_s: float) -> None:
        """``config`` the sensor; ``time_step_s`` the control step (s), at which it samples."""
        self.config = config
        dt = time_step_s
        std = np.array([config.noise_force_std_n] * 3 + [config.noise_torque_std_nm] * 3)
        drift_step = config.bias_drift_n_per_sqrt_s * math.sqrt(dt)
        self._random_each_step = bool(np.any(std > 0.0)) or drift_step > 0.0
        self._fixed_bias = np.concatenate([np.asarray(config.bias_n, dtype=float), np.zeros(3)])
        self._biased = bool(np.any(self._fixed_bias != 0.0))
        self.tool_offset = np.concatenate([np.asarray(config.offset_tool_n, dtype=float), np.zeros(3)])
        """The sensor's own offset (6,), TOOL frame: the world adds it turned with the tool (``SimWorld``)."""
        delay_steps = round(config.delay_s / dt)
        cutoff_hz = config.filter_cutoff_hz
        self._alpha = 1.0 if cutoff_hz is None else dt / (dt + 1.0 / (2.0 * math.pi * cutoff_hz))
        self.ideal = (
            config.model is SensorModel.ideal
            and not self._random_each_step
            and not self._biased
            and not np.any(self.tool_offset)
            and delay_steps == 0
            and cutoff_hz is None
        )
        """True when the reading is the exact contact wrench (ideal source, nothing added): read every step."""
        self._rng = np.random.default_rng(config.seed)
        self._scale = np.concatenate([std, np.full(3, drift_step)])
        self._block = np.zeros((BLOCK, 9))
        """The noise (6) and bias increments (3) of the next steps, one row per step, refilled in place."""
        self._drawn = np.array([BLOCK])
        """The next row of ``_block`` (all drawn: the first reading fills it); not reset with a run."""
        self._line = np.zeros((delay_steps + 1, 6))
        """The delay line: the last ``delay_steps + 1`` raw readings, a ring."""
        self._bias = np.zeros(6)
        self._filtered = np.zeros(6)
        self._counters = np.zeros(3, dtype=np.int64)
        """Readings in the delay line, its next slot, whether the filter has started."""
        self.state = (
            self._block, self._drawn, self._random_each_step, self._bias, self._fixed_bias, self._biased, self._line,
            self._counters, self._filtered, self._alpha,
        )  # fmt: skip
        """The arguments of :func:`measure_drawn` after the source and the reading: arrays updated in place (one
        tuple for a compiled caller, no packing per step; call :meth:`draw` before each reading)."""
        self.reset()

    def reset(self) -> None:
        """Start afresh (a new run, ``SimWorld.reset``): zero drift, empty delay line, the filter restarts from the
        next reading."""
        self._bias[:] = 0.0
        self._counters[:] = 0

    def draw(self) -> None:
        """Make this step's noise and bias increment ready: the next block of them is drawn (one generator call per
        ``BLOCK`` steps) when the last is used up."""
        if self._random_each_step and self._drawn[0] >= BLOCK:
            self._block[:] = self._rng.normal(0.0, 1.0, (BLOCK, 9)) * self._scale
            self._drawn[0] = 0

    def measure_into(self, source: NDArray[np.float64], out: NDArray[np.float64]) -> None:
        """Write the reading (6,) for this step's source wrench (6,) into ``out`` (float64, may not be ``source``)."""
        self.draw()
        measure_drawn(source, out, *self.state)

    def measure(self, source: NDArray[np.float64]) -> NDArray[np.float64]:
        """The reading (6,) for this step's source wrench (6,), a new array."""
        out = np.empty(6)
        self.measure_into(np.asarray(source, dtype=float), out)
        return out


@numba.njit(cache=True)
def measure_drawn(
    source, out, block, drawn, add_random, bias, fixed_bias, biased, line, counters, filtered, alpha
):  # pragma: no cover - compiled
    """:func:`_measure_into` with this step's row of ``block`` (``drawn``: its index, advanced) when the sensor adds
    noise or drift (:attr:`WrenchSensor.state` after :meth:`WrenchSensor.draw`)."""
    random = block[0]  # not read without noise and drift
    if add_random:
        random = block[drawn[0]]
        drawn[0] += 1
    _measure_into(source, out, random, add_random, bias, fixed_bias, biased, line, counters, filtered, alpha)


@numba.njit(cache=True)
def _measure_into(
    source, out, random, add_random, bias, fixed_bias, biased, line, counters, filtered, alpha
):  # pragma: no cover - compiled
    """One reading: ``raw = source + (noise + bias)`` (the bias first drifts by its increment), ``+ fixed_bias``;
    into the delay line; the oldest reading in the line through the low-pass ``f += alpha (delayed - f)``, into
    ``out``. ``counters``: readings in the line, its next slot, whether the filter has started."""
    size = line.shape[0]
    slot = counters[1]
    for i in range(6):
        raw = source[i]
        if add_random:
            if i < 3:
                bias[i] += random[6 + i]
            raw = raw + (random[i] + bias[i])
        if biased:
            raw = raw + fixed_bias[i]
        line[slot, i] = raw
    counters[1] = (slot + 1) % size
    if counters[0] < size:
        counters[0] += 1
    oldest = 0 if counters[0] < size else counters[1]
    if counters[2] == 0:
        counters[2] = 1
        for i in range(6):
            filtered[i] = line[oldest, i]
    else:
        for i in range(6):
            filtered[i] = filtered[i] + alpha * (line[oldest, i] - filtered[i])
    for i in range(6):
        out[i] = filtered[i]
