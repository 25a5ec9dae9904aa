"""Generated sections of the Markdown docs: a script owns the text between ``<!-- NAME:start -->`` and
``<!-- NAME:end -->`` and replaces only that (docs/BENCHMARKS.md, the sweeps of docs/RESULTS.md)."""

from __future__ import annotations

from pathlib import Path


def _marks(name: str) -> tuple[str, str]:
    return f"<!-- {name}:start -->", f"<!-- {name}:end -->"


def section_of(text: str, name: str) -> str | None:
    """The section ``name`` of ``text``, its markers included, or None when it has none."""
    start_mark, end_mark = _marks(name)
    start, end = text.find(start_mark), text.find(end_mark)
    return text[start : end + len(end_mark)] if start != -1 and end > start else None


def write_section(path: Path, name: str, body: str, title: str = "") -> None:
    """Replace (or append) the section ``name`` of the file at ``path`` with ``body``; keep everything else (a new
    file starts with ``title``)."""
    start_mark, end_mark = _marks(name)
    section = f"{start_mark}\n{body.rstrip()}\n{end_mark}"
    text = path.read_text() if path.exists() else title
    old = section_of(text, name)
    text = text.replace(old, section) if old is not None else text.rstrip("\n") + "\n\n" + section + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
