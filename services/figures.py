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
from skills.quaternions import matrix_from_quaternion, quaternions_sign_continuous, quaternions_slerp

_AXIS_COLORS = ("tab:red", "tab:green", "tab:blue")
_SEGMENT_COLORS = {SegmentKind.contact: "tab:orange", SegmentKind.free: "tab:gray"}


def segment_mask(t: NDArray[np.float64], segment: Segment) -> NDArray[np.bool_]:
    """Return the samples of demonstration times ``t`` (s) inside ``segment`` (its first to last sample time)."""
    return (t >= segment.t_start - 1e-9) & (t <= segment.t_end + 1e-9)


def compliant_frame_rotations(segment: Segment, t_since_start: NDArray[np.float64]) -> NDArray[np.float64]:
    """Return world-from-CF rotation matrices ``(M, 3, 3)`` of a contact segment at times since its start (s).

    One stored frame (slide) is constant; a series (contour) is slerped, clamped at its ends.
    """
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"segment {segment.index} ({segment.kind.value}) has no compliant frame")
    q = np.asarray(frames.orientations, dtype=float)
    if len(frames.t) == 1:
        return np.broadcast_to(matrix_from_quaternion(q[0]), (len(t_since_start), 3, 3)).copy()
    return matrix_from_quaternion(quaternions_slerp(t_since_start, frames.t, quaternions_sign_continuous(q)))


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


def compliant_frame_axes(demonstration: Demonstration, segment: Segment) -> CompliantFrameAxes:
    """Return the CF z axes of a contact ``segment`` in the world and in the tool frame (see the class)."""
    frames = segment.compliant_frames
    if frames is None:
        raise ValueError(f"segment {segment.index} ({segment.kind.value}) has no compliant frame")
    a = demonstration.arrays()
    t = segment.t_start + np.asarray(frames.t, dtype=float)
    z_world = matrix_from_quaternion(np.asarray(frames.orientations, dtype=float))[..., :, 2].reshape(-1, 3)
    R_tool = matrix_from_quaternion(quaternions_slerp(t, a.t, quaternions_sign_continuous(a.orientations)))
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

    Top: applied force in the world, x/y/z (N). Bottom: the same force in the compliant frame,
    x/y/z (N), with the learned CF-z force (constant or the force DMP's rollout) dashed black.
    Segments are background spans (contact orange, free grey) labelled with kind and index.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    a = demonstration.arrays()
    dt = float(np.median(np.diff(a.t)))
    f_cf = forces_in_compliant_frames(demonstration, skill)

    figure = Figure(figsize=(9, 6), layout="constrained")
    FigureCanvasAgg(figure)
    ax_world, ax_cf = figure.subplots(2, 1, sharex=True)
    for j, axis in enumerate("xyz"):
        ax_world.plot(a.t, a.wrenches[:, j], color=_AXIS_COLORS[j], lw=1.0, label=f"$f_{axis}$ world")
        ax_cf.plot(a.t, f_cf[:, j], color=_AXIS_COLORS[j], lw=1.0, label=f"$f_{axis}$ CF")
    learned_label = "learned $f_z$ (DMP)" if skill.skill_type.value == "contour" else "learned $f_z$ (constant)"
    for segment in skill.segments:
        curve = learned_force_curve(segment, dt)
        if curve is not None:
            ax_cf.plot(*curve, color="black", ls="--", lw=1.6, label=learned_label)
            learned_label = "_nolegend_"
        for ax in (ax_world, ax_cf):
            ax.axvspan(segment.t_start, segment.t_end, color=_SEGMENT_COLORS[segment.kind], alpha=0.12, lw=0)
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
    ax_cf.set_xlabel("time (s)")
    for ax in (ax_world, ax_cf):
        ax.grid(True, lw=0.3)
        ax.legend(loc="upper right", fontsize=8, ncols=2)
        ax.axhline(0.0, color="black", lw=0.5)
    figure.savefig(os.fspath(path), dpi=120)


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
