"""The results tables of a demo run: one row per execution (``TABLE_HEADER``), for the console and for RESULTS.md,
and read back from a RESULTS.md (``parse_markdown_table``). Forces in N and % of the reference force, the TRUE normal
force beside the CF-z one."""

from __future__ import annotations

from experiments.cases import (
    Outcome,
    fmt,
)

TABLE_HEADER = (
    "case",
    "controller",
    "true RMS (N)",
    "true RMS (%)",
    "true max (%)",
    "CF-z RMS (N)",
    "CF-z RMS (%)",
    "CF-z max (%)",
    "touch-down (N)",
    "touch-down (x target)",
    "contact (%)",
    "path RMS (mm)",
    "RTF",
    "final",
    "verdict",
    "target",
)
"""Columns of the results tables (``docs/RESULTS.md`` and the console)."""


def table_rows(outcomes: list[Outcome], compact: bool = False) -> list[tuple[str, ...]]:
    """One row of strings per execution, columns :data:`TABLE_HEADER` (``compact``: shorter case and final texts,
    for the console)."""
    rows = []
    for o in outcomes:
        final, verdict = o.final, o.execution_verdict
        if compact:  # the console: the first 40 characters
            final = final if len(final) <= 40 else final[:39] + "…)"
            verdict = verdict if len(verdict) <= 40 else verdict[:39] + "…"
        rows.append(
            (
                f"{o.case.skill}: {o.case.label}" if compact else f"{o.case.spec.title}: {o.case.label}",
                o.controller,
                fmt(o.metric("true_force_rms_error_n"), digits=3),
                fmt(o.metric("true_force_rms_error_pct")),
                fmt(o.metric("true_force_max_error_pct")),
                fmt(o.metric("force_rms_error_n"), digits=3),
                fmt(o.metric("force_rms_error_pct")),
                fmt(o.metric("force_max_error_pct")),
                fmt(o.metric("touchdown_peak_n")),
                fmt(o.metric("touchdown_peak_ratio")),
                fmt(o.metric("contact_ratio"), 100),
                fmt(o.metric("path_rms_m"), 1e3),
                fmt(o.metric("real_time_factor"), digits=1),
                final,
                verdict,
                o.target_text,
            )
        )
    return rows


def markdown_table(outcomes: list[Outcome]) -> str:
    lines = ["| " + " | ".join(TABLE_HEADER) + " |", "|" + "|".join(" --- " for _ in TABLE_HEADER) + "|"]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in table_rows(outcomes)]
    return "\n".join(lines)


def text_table(outcomes: list[Outcome]) -> str:
    """The results table for the console: aligned columns."""
    rows = [TABLE_HEADER, *table_rows(outcomes, compact=True)]
    widths = [max(len(r[j]) for r in rows) for j in range(len(TABLE_HEADER) - 1)]
    out = []
    for k, row in enumerate(rows):
        out.append("  ".join(c.ljust(w) for c, w in zip(row[:-1], widths, strict=True)) + "  " + row[-1])
        if k == 0:
            out.append("  ".join("-" * w for w in widths) + "  " + "-" * 6)
    return "\n".join(out)


def parse_markdown_table(text: str) -> list[dict[str, str]]:
    """The rows of every results table in a RESULTS.md (header :data:`TABLE_HEADER`), in page order, as dicts of
    cell strings."""
    header = "| " + " | ".join(TABLE_HEADER) + " |"
    lines = [line.strip() for line in text.splitlines()]
    rows = []
    for start in [k for k, line in enumerate(lines) if line == header]:
        for line in lines[start + 2 :]:
            cells = [c.strip() for c in line.strip("|").split(" | ")] if line.startswith("|") else []
            if len(cells) != len(TABLE_HEADER):
                break
            rows.append(dict(zip(TABLE_HEADER, cells, strict=True)))
    return rows
