"""The figure of a robustness sweep: for each varied parameter, the true normal-force RMS error of every trial and
the success rate along the parameter's range, one colour per controller (ours against the baselines).

matplotlib's object API with the Agg canvas (no pyplot state), as ``services.figures``.
"""

from __future__ import annotations

import os

import numpy as np

from schemas.sweep import SweepView, TrialResult
from skills.sweeps import equal_count_bins

_COLORS = {
    "hybrid_cf": "tab:blue",
    "impedance": "tab:red",
    "impedance_found_surface": "tab:orange",
    "hybrid_world_z": "tab:green",
}
BINS = 4
"""The success rate is shown over this many equal-count bins of each parameter."""


def _success_by_bin(values: np.ndarray, success: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bin centres (mean value per bin) and success rates over :data:`BINS` equal-count bins of ``values``."""
    groups = equal_count_bins(values, BINS)
    return np.array([values[g].mean() for g in groups]), np.array([success[g].mean() for g in groups])


PANEL_COLUMNS = 4
"""Parameters per row of the figure."""


def write_sweep_figure(view: SweepView, trials: list[TrialResult], path: str | os.PathLike[str]) -> None:
    """One panel pair per varied parameter (up to :data:`PANEL_COLUMNS` per row): above, each finished trial's TRUE
    normal-force RMS error (% of the reference force, log scale; an aborted trial is an x at the top edge) with the
    success threshold dashed; below, the success rate over quarters of the trials along the parameter."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator, NullFormatter

    names = list(view.request["vary"])
    threshold = float(view.request["success_rms_pct"])
    finished = [t for t in trials if t.success is not None]
    rms_values = [t.true_force_rms_error_pct for t in finished if t.true_force_rms_error_pct]
    low = min([threshold / 10.0, *rms_values]) * 0.8
    top = max([threshold * 3.0, *rms_values]) * 1.5
    columns = min(PANEL_COLUMNS, len(names))
    rows = -(-len(names) // columns)
    figure = Figure(figsize=(3.1 * columns, 3.3 * rows + 0.4), layout="constrained")
    FigureCanvasAgg(figure)
    panels = figure.subfigures(rows, columns, squeeze=False)
    axes = {}
    for j, name in enumerate(names):
        error_ax, success_ax = panels[j // columns, j % columns].subplots(
            2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]}
        )
        axes[name] = (error_ax, success_ax)
        error_ax.set_yscale("log")
        error_ax.set_ylim(low, top)
        error_ax.axhline(threshold, color="k", lw=0.8, ls="--")
        success_ax.set_ylim(-5, 105)
        success_ax.set_xlabel(name, fontsize=8)
        error_ax.set_ylabel("true RMS error, %", fontsize=7)
        success_ax.set_ylabel("success, %", fontsize=7)
        for ax in (error_ax, success_ax):
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
            if view.request["vary"][name].get("log"):
                ax.set_xscale("log")
                ax.xaxis.set_minor_formatter(NullFormatter())
            else:
                ax.xaxis.set_major_locator(MaxNLocator(4))
    for summary in view.controllers:
        controller = summary.controller.value
        mine = [t for t in finished if t.controller.value == controller]
        if not mine:
            continue
        color = _COLORS.get(controller, "tab:gray")
        rms = np.array([t.true_force_rms_error_pct or np.nan for t in mine])
        aborted = np.isnan(rms)
        success = np.array([bool(t.success) for t in mine], dtype=float)
        for j, name in enumerate(names):
            error_ax, success_ax = axes[name]
            values = np.array([t.parameters[name] for t in mine])
            label = controller if j == 0 else None
            error_ax.scatter(values[~aborted], rms[~aborted], s=7, color=color, alpha=0.55, label=label, lw=0)
            error_ax.scatter(values[aborted], np.full(aborted.sum(), top / 1.25), s=12, marker="x", color=color, lw=0.8)
            centres, rates = _success_by_bin(values, success)
            success_ax.plot(centres, 100 * rates, "o-", color=color, ms=3, lw=1.2)
    axes[names[0]][0].legend(fontsize=6, loc="lower left")
    counts = view.counts
    figure.suptitle(  # two lines: a figure of one or two parameters is narrower than the sentence
        f"sweep {view.id}: {view.request['trials']} trials, {counts.finished}/{counts.total} executions\n"
        f"x = aborted, dashed = success threshold {threshold:g} % (true normal force)",
        fontsize=9,
    )
    figure.savefig(os.fspath(path), dpi=100)
