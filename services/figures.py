"""The learning figure (like the paper's Fig. 3c) and the compliant-frame numbers it and the CLI report.

Everything here reads a demonstration (world frame, wrench applied by the tool) and the skill
learned from it; segments are matched to the demonstration by TIME (``t_start``..``t_end``),
so the figure is right whether or not the learner resampled. Plots use matplotlib's
object API with the Agg canvas (no pyplot state, safe in a server thread).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from schemas import Demonstration, Segment, SegmentKind, Skill
from schemas.demonstration import DemonstrationArrays
from schemas.execution import ExecutionPhase
from schemas.skill import SkillType
from skills.compliant_frames import compliant_frame_rotations
from skills.quaternions import matrix_from_quaternion, quaternions_sign_continuous, quaternions_slerp

_AXIS_COLORS = ("tab:red", "tab:green", "tab:blue")
_SEGMENT_COLORS = {SegmentKind.contact: "tab:orange", SegmentKind.free: "tab:gray"}


_MOVING_PHASES = frozenset(
    {ExecutionPhase.free, ExecutionPhase.approach, ExecutionPhase.contact, ExecutionPhase.retreat}
)
"""The phases in which the tool follows the skill's path (drawn as the executed path)."""


def segment_mask(t: NDArray[np.float64], segment: Segment) -> NDArray[np.bool_]:
    """Return the samples of demonstration times ``t`` (s) inside ``segment`` (its first to last sample time)."""
    return (t >= segment.t_start - 1e-9) & (t <= segment.t_end + 1e-9)


def forces_in_compliant_frames(demonstration: Demonstration, skill: Skill) -> NDArray[np.float64]:
    """Return the demonstrated applied force in each sample's CF, ``(N, 3)`` N; NaN outside contact segments.

    ``f_CF = R_CF^T f_world`` with ``R_CF`` the segment's world-from-CF rotation at that time.
    """
    a = demonstration.arrays()
    out = np.full((a.t.size, 3), np.nan)
    for segment in skill.segments:
        if segment.kind != SegmentKind.contact or segment.compliant_frames is None:
            continue
        rows = segment_mask(a.t, segment)
        R = compliant_frame_rotations(segment, a.t[rows] - segment.t_start)
        out[rows] = np.einsum("nji,nj->ni", R, a.wrenches[rows, :3])
    return out


@dataclass(frozen=True)
class CompliantFrameAxes:
    """The CF z axes of one contact segment at its stored frame times: in the world and in the TOOL frame."""

    t: NDArray[np.float64]
    """Demonstration time of each frame, s."""
    z_world: NDArray[np.float64]
    """(K, 3) unit CF z axes in the world."""
    z_tool: NDArray[np.float64]
    """(K, 3) the same axes in the tool frame (``R_tool^T z_world``, tool orientation slerped at ``t``)."""

    @staticmethod
    def _mean(z: NDArray[np.float64]) -> NDArray[np.float64]:
        m = z.mean(axis=0)
        return m / np.linalg.norm(m)

    @property
    def mean_world(self) -> NDArray[np.float64]:
        """Normalized mean of ``z_world``."""
        return self._mean(self.z_world)

    @property
    def mean_tool(self) -> NDArray[np.float64]:
        """Normalized mean of ``z_tool``."""
        return self._mean(self.z_tool)

    @property
    def tool_spread_deg(self) -> float:
        """RMS angle of ``z_tool`` about its mean, deg: how constant the CF z is in the tool frame."""
        cos = np.clip(self.z_tool @ self.mean_tool, -1.0, 1.0)
        return float(np.degrees(np.sqrt(np.mean(np.arccos(cos) ** 2))))


def compliant_frame_axes(demonstration: Demonstration | DemonstrationArrays, segment: Segment) -> CompliantFrameAxes:
    """Return the CF z axes of a contact ``segment`` in the world and in the tool frame (see the class).

    Reads only the segment's own samples: a caller going over every segment of a long recording passes its
    ``arrays()`` once (converting them costs as much as the rest)."""
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"segment {segment.index} ({segment.kind.value}) has no compliant frame")
    a = demonstration.arrays() if isinstance(demonstration, Demonstration) else demonstration
    t = segment.t_start + np.asarray(frames.t, dtype=float)
    z_world = matrix_from_quaternion(np.asarray(frames.orientations, dtype=float))[..., :, 2].reshape(-1, 3)
    first, last = np.searchsorted(a.t, [t[0], t[-1]])  # the samples around the segment's frames
    end = min(max(last + 1, 2), a.t.size)
    window = slice(max(min(first - 1, end - 2), 0), end)  # at least two: a slide's one frame at the first sample
    orientations = quaternions_sign_continuous(a.orientations[window])
    R_tool = matrix_from_quaternion(quaternions_slerp(t, a.t[window], orientations))
    z_tool = np.einsum("nji,nj->ni", R_tool.reshape(-1, 3, 3), np.broadcast_to(z_world, (t.size, 3)))
    return CompliantFrameAxes(t=t, z_world=np.broadcast_to(z_world, (t.size, 3)).copy(), z_tool=z_tool)


def learned_force_curve(segment: Segment, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Return (demonstration time s, learned CF-z force N) of a contact segment, or None for a free one.

    Slide: the constant over the segment. Contour: the force DMP rolled out at step ``dt`` (s).
    """
    if segment.force_dmp is not None:
        from skills.dmp import DMP

        rollout = DMP.from_parameters(segment.force_dmp).rollout(dt)
        return segment.t_start + rollout.t, rollout.y[:, 0]
    if segment.force_constant_n is not None:
        return np.array([segment.t_start, segment.t_end]), np.full(2, segment.force_constant_n)
    return None


def write_learning_figure(demonstration: Demonstration, skill: Skill, path: str | os.PathLike[str]) -> None:
    """Write a PNG (or any matplotlib format, by suffix) of the demonstrated force and the learned one.

    Top: applied force in the world, x/y/z (N). Middle: the same force in the compliant frame,
    x/y/z (N), with the learned CF-z force (constant or the force DMP's rollout) dashed black.
    Bottom: the tool's height above the touched surface (mm, along the mean CF z of the contact
    segments) and its speed (m/s): contact is pressing ON the surface, which is what tells a
    stroke from a hand's push in the air. Segments are background spans (contact orange, free
    grey) labelled with kind and index; each boundary is a dotted line labelled with what decided
    it (force, surface, crease).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    a = demonstration.arrays()
    dt = float(np.median(np.diff(a.t)))
    f_cf = forces_in_compliant_frames(demonstration, skill)

    figure = Figure(figsize=(9, 8.5), layout="constrained")
    FigureCanvasAgg(figure)
    ax_world, ax_cf, ax_height = figure.subplots(3, 1, sharex=True, height_ratios=(1.0, 1.0, 0.8))
    for j, axis in enumerate("xyz"):
        ax_world.plot(a.t, a.wrenches[:, j], color=_AXIS_COLORS[j], lw=1.0, label=f"$f_{axis}$ world")
        ax_cf.plot(a.t, f_cf[:, j], color=_AXIS_COLORS[j], lw=1.0, label=f"$f_{axis}$ CF")
    _plot_height_and_speed(ax_height, a.t, a.positions, skill)
    learned_label = "learned $f_z$ (DMP)" if skill.skill_type is SkillType.contour else "learned $f_z$ (constant)"
    previous = None
    for segment in skill.segments:
        curve = learned_force_curve(segment, dt)
        if curve is not None:
            ax_cf.plot(*curve, color="black", ls="--", lw=1.6, label=learned_label)
            learned_label = "_nolegend_"
        for ax in (ax_world, ax_cf, ax_height):
            ax.axvspan(segment.t_start, segment.t_end, color=_SEGMENT_COLORS[segment.kind], alpha=0.12, lw=0)
        if previous is not None:  # what decided the boundary: the contact's own reason, on either side
            reason = segment.start_reason if segment.kind is SegmentKind.contact else previous.end_reason
            ax_height.axvline(segment.t_start, color="black", ls=":", lw=0.8)
            ax_height.text(
                segment.t_start, 0.98, f" {reason or ''}", transform=ax_height.get_xaxis_transform(),
                rotation=90, ha="right", va="top", fontsize=7,
            )  # fmt: skip
        previous = segment
        ax_world.text(
            (segment.t_start + segment.t_end) / 2, 1.0, f"{segment.kind.value} {segment.index}",
            transform=ax_world.get_xaxis_transform(), ha="center", va="bottom", fontsize=8,
        )  # fmt: skip
    title = demonstration.metadata.name or "demonstration"
    if skill.auto_selection is not None:
        chosen = f"{skill.skill_type.value} (auto, confidence {skill.auto_selection.confidence:.2f})"
    else:
        chosen = skill.skill_type.value
    ax_world.set_title(f"{title}: {chosen} skill, {len(skill.segments)} segment(s)", pad=14)
    ax_world.set_ylabel("applied force, world (N)")
    ax_cf.set_ylabel("applied force, compliant frame (N)")
    ax_height.set_xlabel("time (s)")
    for ax in (ax_world, ax_cf):
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=8, ncols=2)
        ax.axhline(0.0, color="black", lw=0.5)
    figure.savefig(os.fspath(path), dpi=120)


def _plot_height_and_speed(ax, t: np.ndarray, positions: np.ndarray, skill: Skill) -> None:
    """Plot the tool's height (mm) above the touched surface along the contact segments' mean CF z, and its speed."""
    axes = [
        matrix_from_quaternion(np.asarray(s.compliant_frames.orientations))[:, :, 2].mean(axis=0)
        for s in skill.segments
        if s.compliant_frames is not None
    ]
    down = np.mean(axes, axis=0) if axes else np.array([0.0, 0.0, -1.0])
    down /= np.linalg.norm(down)
    depth = positions @ down
    contact = np.zeros(t.size, dtype=bool)
    for s in skill.segments:
        if s.compliant_frames is not None:
            contact |= (t >= s.t_start) & (t <= s.t_end)
    surface = np.median(depth[contact]) if contact.any() else depth.max()
    ax.plot(t, 1000.0 * (surface - depth), color="tab:blue", lw=1.0, label="height above the surface (mm)")
    ax.set_ylabel("tool height (mm)")
    speed = np.linalg.norm(np.gradient(positions, t, axis=0), axis=1)
    twin = ax.twinx()
    twin.plot(t, speed, color="tab:gray", lw=0.7, alpha=0.7, label="speed (m/s)")
    twin.set_ylabel("speed (m/s)")
    ax.legend(loc="upper left", fontsize=8)
    twin.legend(loc="upper right", fontsize=8)


def write_execution_figure(result, path: str | os.PathLike[str]) -> None:
    """Write the force-tracking figure of an execution (like the paper's Fig. 3d / 4d) as PNG (or by suffix).

    ``result`` is a ``sim_worker.executor.ExecutionResult`` (only its ``telemetry`` arrays and
    ``metrics`` are read, so this module does not import the simulator). Top: the measured force
    in the compliant frame, x/y/z (N), and the desired CF-z force dashed black; phases are
    background spans (approach/contact orange, free/settle/retreat grey). Bottom: the CF-z force
    error (measured - desired, N) over the contact phase, with the metrics in the title.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    tel = result.telemetry
    metrics = result.metrics
    t = tel.t
    phases = [p.value for p in tel.phases]
    figure = Figure(figsize=(9, 6), layout="constrained")
    FigureCanvasAgg(figure)
    ax_force, ax_error = figure.subplots(2, 1, sharex=True)
    for j, axis in enumerate("xyz"):
        ax_force.plot(t, tel.wrench_cf[:, j], color=_AXIS_COLORS[j], lw=1.0, label=f"$f_{axis}$ CF measured")
    ax_force.plot(t, tel.desired_force, color="black", ls="--", lw=1.4, label="desired $f_z$")
    contact = np.array([p == "contact" for p in phases])
    error = np.where(contact, tel.wrench_cf[:, 2] - tel.desired_force, np.nan)
    ax_error.plot(t, error, color="tab:blue", lw=1.0, label="$f_z$ measured - desired (contact)")
    # phase spans
    start = 0
    for k in range(1, len(phases) + 1):
        if k == len(phases) or phases[k] != phases[start]:
            kind = phases[start]
            color = "tab:orange" if kind in ("approach", "contact") else "tab:gray"
            for ax in (ax_force, ax_error):
                ax.axvspan(t[start], t[k - 1], color=color, alpha=0.12 if kind == "contact" else 0.06, lw=0)
            if t[k - 1] - t[start] > 0.05 * max(t[-1] - t[0], 1e-9):
                ax_force.text(
                    (t[start] + t[k - 1]) / 2, 1.0, kind, transform=ax_force.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=8,
                )  # fmt: skip
            start = k
    parts = [f"{metrics.controller.value}: {metrics.phase.value}"]
    if metrics.force_rms_error_n is not None:
        parts.append(f"f_z RMS error {metrics.force_rms_error_n:.2f} N ({metrics.force_rms_error_pct:.1f} %)")
    if metrics.contact_ratio is not None:
        parts.append(f"contact {100 * metrics.contact_ratio:.1f} %")
    if metrics.path_rms_m is not None:
        parts.append(f"path RMS {1e3 * metrics.path_rms_m:.2f} mm")
    if metrics.abort_reason:
        parts.append(metrics.abort_reason)
    ax_force.set_title("; ".join(parts), pad=14, fontsize=10)
    ax_force.set_ylabel("applied force, compliant frame (N)")
    ax_error.set_ylabel("CF-z force error (N)")
    ax_error.set_xlabel("time (s)")
    for ax in (ax_force, ax_error):
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=8, ncols=2)
        ax.axhline(0.0, color="black", lw=0.5)
    figure.savefig(os.fspath(path), dpi=120)


# --------------------------------------------------------------------------- demo figures (paper Fig. 3/4 a-b, d)

_TRIAL_COLORS = ("tab:orange", "tab:purple", "tab:cyan", "tab:brown", "tab:pink", "tab:olive", "goldenrod", "slategray")
"""Reproduction colours: none of them red, green or blue, the colours of the CF axes drawn on the paths."""
_CONTROLLER_STYLE = {
    "hybrid_cf": ("tab:blue", 1.3, "ours (hybrid_cf)"),
    "impedance": ("tab:orange", 0.9, "impedance"),
    "impedance_found_surface": ("tab:brown", 0.9, "impedance (found surface)"),
    "hybrid_world_z": ("tab:purple", 0.9, "hybrid_world_z"),
}


@dataclass(frozen=True)
class Trace:
    """One execution's recorded stream, as the figures need it (e.g. from ``GET /executions/{id}/telemetry``).

    ``t`` (N,) s since the execution started; ``phases`` the phase names; ``segment_index`` (N,);
    ``position`` (N, 3) the measured tool point in the world, m; ``wrench_cf`` (N, 6) the applied wrench in the
    CF; ``desired`` (N,) the desired CF-z force, N.
    """

    label: str
    t: NDArray[np.float64]
    phases: list[str]
    segment_index: NDArray[np.int_]
    position: NDArray[np.float64]
    wrench_cf: NDArray[np.float64]
    desired: NDArray[np.float64]

    @classmethod
    def from_columns(cls, label: str, columns: dict) -> Trace:
        """From the columns of a ``TelemetryBatch``/``TelemetryView`` JSON (phases as names)."""
        return cls(
            label=label,
            t=np.asarray(columns["t"], dtype=float),
            phases=[str(p) for p in columns["phase"]],
            segment_index=np.asarray(columns["segment_index"], dtype=int),
            position=np.asarray(columns["tool_position"], dtype=float).reshape(-1, 3),
            wrench_cf=np.asarray(columns["wrench_cf"], dtype=float).reshape(-1, 6),
            desired=np.asarray(columns["desired_force_cf_z_n"], dtype=float),
        )

    def mask(self, *phases: str) -> NDArray[np.bool_]:
        """The samples in any of ``phases``."""
        return np.array([p in phases for p in self.phases], dtype=bool)

    @property
    def contact_start(self) -> float | None:
        """Time of the first contact-phase sample, s (None if the execution never reached contact)."""
        rows = np.flatnonzero(self.mask("contact"))
        return float(self.t[rows[0]]) if rows.size else None


def _frames_along(
    positions: NDArray[np.float64], times: NDArray[np.float64], segment: Segment, count: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(origins (K, 3), rotations (K, 3, 3)) of ``count`` CFs of ``segment`` along a path sampled at ``times``
    (s, from 0 at the segment's start to its end): origins on the path, rotations the learned CF at the same
    time FRACTION of the segment (a slide's single frame: at the middle)."""
    if positions.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    single = segment.compliant_frames is not None and len(segment.compliant_frames.t) == 1
    fractions = np.array([0.5]) if single else np.linspace(0.0, 1.0, max(count, 2))
    span = max(float(times[-1] - times[0]), 1e-9)
    rows = np.clip(np.searchsorted((times - times[0]) / span, fractions), 0, positions.shape[0] - 1)
    R = compliant_frame_rotations(segment, fractions * (segment.t_end - segment.t_start))
    return positions[rows], R


def _draw_frames(ax, origins: NDArray[np.float64], rotations: NDArray[np.float64], length: float) -> None:
    for j in range(3):
        d = rotations[:, :, j]
        ax.quiver(origins[:, 0], origins[:, 1], origins[:, 2], d[:, 0], d[:, 1], d[:, 2], length=length,
                  color=_AXIS_COLORS[j], lw=1.1, arrow_length_ratio=0.25)  # fmt: skip


def write_paths_figure(
    demonstration: Demonstration,
    skill: Skill,
    trials: list[tuple[str, Trace]],
    path: str | os.PathLike[str],
    title: str = "",
    contour_frames: int = 7,
    view: tuple[float, float] = (22.0, -58.0),
) -> None:
    """Write the 3-D paths of the demonstration and of reproductions with their compliant frames (paper Fig. 3b/4b).

    The demonstration: its contact segments bold black, free motion dotted grey. Each trial (a :class:`Trace`):
    its contact phase bold in its own colour, the rest thin. Compliant frames (x red, y green, z blue: into the
    surface) are drawn ON each path: a slide segment's one frame at its middle, a contour's frames at
    ``contour_frames`` evenly spaced times — the learned CF at the same time fraction of the segment. Axes are
    to scale (equal metres on x, y, z); ``view`` is the camera (elevation, azimuth), deg.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    a = demonstration.arrays()
    contact_segments = [s for s in skill.segments if s.kind == SegmentKind.contact and s.compliant_frames is not None]
    figure = Figure(figsize=(10, 7.5), layout="constrained")
    FigureCanvasAgg(figure)
    ax = figure.add_subplot(projection="3d")
    points = [a.positions]
    in_contact = np.zeros(a.t.size, dtype=bool)
    for segment in contact_segments:
        in_contact |= segment_mask(a.t, segment)
    free = np.where(in_contact[:, None], np.nan, a.positions)
    ax.plot(*free.T, color="0.55", lw=0.8, ls=":")
    ax.plot(*np.where(in_contact[:, None], a.positions, np.nan).T, color="black", lw=2.2)
    handles = [Line2D([], [], color="black", lw=2.2, label="demonstration (contact)"),
               Line2D([], [], color="0.55", lw=0.8, ls=":", label="demonstration (free)")]  # fmt: skip
    frame_sets = []
    for segment in contact_segments:
        rows = segment_mask(a.t, segment)
        frame_sets.append(_frames_along(a.positions[rows], a.t[rows], segment, contour_frames))
    for k, (label, trace) in enumerate(trials):
        color = _TRIAL_COLORS[k % len(_TRIAL_COLORS)]
        contact = trace.mask("contact")
        moving = trace.mask("free", "approach", "contact", "retreat")
        ax.plot(*np.where(moving[:, None] & ~contact[:, None], trace.position, np.nan).T, color=color, lw=0.6,
                alpha=0.6)  # fmt: skip
        ax.plot(*np.where(contact[:, None], trace.position, np.nan).T, color=color, lw=1.6)
        handles.append(Line2D([], [], color=color, lw=1.6, label=label))
        points.append(trace.position[moving])
        for segment in contact_segments:
            rows = contact & (trace.segment_index == segment.index)
            frame_sets.append(_frames_along(trace.position[rows], trace.t[rows], segment, contour_frames))
    everything = np.concatenate([p for p in points if p.size])
    low, high = everything.min(axis=0), everything.max(axis=0)
    extent = float(max(np.max(high - low), 1e-3))
    for origins, rotations in frame_sets:  # a slide's single frame drawn larger than a contour's series
        if origins.shape[0]:
            _draw_frames(ax, origins, rotations, 0.07 * extent if origins.shape[0] == 1 else min(0.08 * extent, 0.015))
    margin = 0.06 * extent
    low, high = low - margin, high + margin
    ranges = np.maximum(high - low, 0.25 * extent)
    centre = 0.5 * (low + high)
    ax.set_xlim(centre[0] - ranges[0] / 2, centre[0] + ranges[0] / 2)
    ax.set_ylim(centre[1] - ranges[1] / 2, centre[1] + ranges[1] / 2)
    ax.set_zlim(centre[2] - ranges[2] / 2, centre[2] + ranges[2] / 2)
    ax.set_box_aspect(tuple(ranges))
    from matplotlib.ticker import MaxNLocator

    for axis, name in ((ax.xaxis, "x"), (ax.yaxis, "y"), (ax.zaxis, "z")):
        axis.set_major_locator(MaxNLocator(nbins=max(2, round(4 * ranges["xyz".index(name)] / ranges.max()) + 1)))
        axis.set_label_text(f"{name} (m)")
    ax.view_init(elev=view[0], azim=view[1])
    handles += [Line2D([], [], color=c, lw=1.5, label=f"CF {n}") for c, n in zip(_AXIS_COLORS, "xyz", strict=True)]
    ax.legend(handles=handles, loc="upper left", fontsize=8, ncols=1)
    ax.set_title(title or f"{demonstration.metadata.name}: demonstration and reproductions", fontsize=11)
    figure.savefig(os.fspath(path), dpi=110)


def write_trials_force_figure(
    trials: list[tuple[str, dict[str, Trace]]],
    path: str | os.PathLike[str],
    ours: str = "hybrid_cf",
    title: str = "",
) -> None:
    """Write the reproduction force in the CF per trial (paper Fig. 3d/4d): one subplot per trial.

    ``trials``: (label, {controller: Trace}). In each subplot, time is measured from that execution's first
    contact-phase sample; ours (``ours``) shows the measured CF x, y (thin) and z force and the desired CF-z force
    (dashed black); each baseline its measured CF-z force.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = max(len(trials), 1)
    figure = Figure(figsize=(9.5, 1.85 * n + 1.0), layout="constrained")
    FigureCanvasAgg(figure)
    axes = np.atleast_1d(figure.subplots(n, 1, sharex=True, squeeze=False)[:, 0])
    for ax, (label, traces) in zip(axes, trials, strict=False):
        for controller, trace in sorted(traces.items(), key=lambda kv: kv[0] != ours):
            t0 = trace.contact_start
            if t0 is None:
                continue
            window = trace.mask("approach", "contact", "retreat") & (trace.t >= t0 - 0.3)
            t = np.where(window, trace.t - t0, np.nan)
            color, lw, name = _CONTROLLER_STYLE.get(controller, ("tab:gray", 0.9, controller))
            if controller == ours:
                for j in (0, 1):
                    ax.plot(t, trace.wrench_cf[:, j], color=_AXIS_COLORS[j], lw=0.6, alpha=0.6,
                            label=f"$f_{'xy'[j]}$ CF, ours")  # fmt: skip
                ax.plot(t, trace.desired, color="black", ls="--", lw=1.3, label="desired $f_z$", zorder=5)
            ax.plot(t, trace.wrench_cf[:, 2], color=color, lw=lw, label=f"$f_z$ CF, {name}",
                    zorder=4 if controller == ours else 3)  # fmt: skip
        ax.set_title(label, fontsize=9, loc="left")
        ax.axhline(0.0, color="black", lw=0.5)
        ax.grid(True, lw=0.3)
        ax.set_ylabel("CF force (N)")
    axes[-1].set_xlabel("time since contact (s)")
    if title:
        figure.suptitle(title, fontsize=11)
    handles: dict[str, object] = {}
    for ax in axes:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    figure.legend(list(handles.values()), list(handles), loc="outside lower center", ncols=6, fontsize=8)
    figure.savefig(os.fspath(path), dpi=110)


def write_scene_figure(
    skill: Skill,
    telemetry,
    work_pieces: list,
    path: str | os.PathLike[str],
    title: str = "",
    view: tuple[float, float] = (28.0, -60.0),
) -> None:
    """Write the 3-D scene of an execution: the work piece, the learned and the executed paths, the CFs.

    ``telemetry`` is a ``execution.telemetry.Telemetry`` (its ``tool_position`` and phases are read);
    ``work_pieces`` the vertex arrays (K, 3) of the rebuilt work piece's convex parts (world frame, m; empty for a
    taught world). The learned path is each contact segment's DMP rolled out from its demonstrated start (black);
    the executed contact phase in blue. Compliant frames (x red, y green, z blue: into the surface) are drawn on the
    learned path, a slide's frame once at its middle, a contour's at 7 times, with arrows sized to the scene.
    Axes are to scale (equal metres on x, y, z).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from scipy.spatial import ConvexHull

    from skills.placement import segment_positions

    figure = Figure(figsize=(10, 7.5), layout="constrained")
    FigureCanvasAgg(figure)
    ax = figure.add_subplot(projection="3d")
    points = []
    for vertices in work_pieces:
        v = np.asarray(vertices, dtype=float)
        hull = ConvexHull(v)
        ax.add_collection3d(Poly3DCollection(v[hull.simplices], facecolor=(0.85, 0.65, 0.35, 0.25),
                                             edgecolor=(0.6, 0.4, 0.2, 0.15), lw=0.2))  # fmt: skip
        points.append(v)
    learned = []
    for segment in skill.segments:
        if segment.kind == SegmentKind.contact and segment.compliant_frames is not None:
            p = segment_positions(segment, 0.01)
            learned.append((segment, p))
            ax.plot(*p.T, color="black", lw=2.0)
            points.append(p)
    contact = np.array([ph is ExecutionPhase.contact for ph in telemetry.phases], dtype=bool)
    executed = telemetry.tool_position
    moving = np.array([ph in _MOVING_PHASES for ph in telemetry.phases])
    ax.plot(*np.where((moving & ~contact)[:, None], executed, np.nan).T, color="tab:blue", lw=0.6, alpha=0.6)
    ax.plot(*np.where(contact[:, None], executed, np.nan).T, color="tab:blue", lw=1.4)
    points.append(executed[moving])
    everything = np.concatenate([p for p in points if p.size])
    low, high = everything.min(axis=0), everything.max(axis=0)
    extent = float(max(np.max(high - low), 1e-3))
    for segment, p in learned:
        times = np.linspace(0.0, 1.0, p.shape[0])
        origins, rotations = _frames_along(p, times, segment, 7)
        _draw_frames(ax, origins, rotations, 0.12 * extent if origins.shape[0] == 1 else 0.06 * extent)
    centre = 0.5 * (low + high)
    half = 0.55 * extent
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1.0, 1.0, 1.0))
    for axis, name in ((ax.xaxis, "x"), (ax.yaxis, "y"), (ax.zaxis, "z")):
        axis.set_label_text(f"{name} (m)")
    ax.view_init(elev=view[0], azim=view[1])
    handles = [Line2D([], [], color="black", lw=2.0, label="learned contact path"),
               Line2D([], [], color="tab:blue", lw=1.4, label="executed (contact)")]  # fmt: skip
    if work_pieces:
        handles.append(Line2D([], [], color=(0.85, 0.65, 0.35), lw=6, alpha=0.5, label="rebuilt work piece"))
    handles += [Line2D([], [], color=c, lw=1.5, label=f"CF {n}") for c, n in zip(_AXIS_COLORS, "xyz", strict=True)]
    ax.legend(handles=handles, loc="upper left", fontsize=8)
    ax.set_title(title, fontsize=9, wrap=True)
    figure.savefig(os.fspath(path), dpi=110)
