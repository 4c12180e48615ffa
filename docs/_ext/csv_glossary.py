"""Sphinx extension: the CSV glossary, generated from ``agents.evaluation.records.COLUMN_DOCS``.

On ``builder-inited`` it writes ``docs/_generated/csv_columns.md`` (gitignored), which
``glossary.md`` includes; the column list therefore cannot drift from the record
definition (``tests/agents/evaluation/test_column_docs.py`` checks that every column is documented).
"""

from __future__ import annotations

from pathlib import Path


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def write_table(out_dir: Path) -> Path:
    from agents import EpisodeRecord
    from agents.evaluation.records import COLUMN_DOCS

    kinds = {name: field.type for name, field in EpisodeRecord.__dataclass_fields__.items()}
    lines = ["| # | column | type | unit | meaning |", "|---|---|---|---|---|"]
    for i, (name, (unit, meaning)) in enumerate(COLUMN_DOCS.items(), start=1):
        kind = str(kinds[name]).replace(" | ", " or ")
        lines.append(f"| {i} | `{name}` | {kind} | {_cell(unit) or '–'} | {_cell(meaning)} |")
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "csv_columns.md"
    text = "\n".join(lines) + "\n"
    if not path.exists() or path.read_text() != text:  # unchanged file: no rebuild
        path.write_text(text)
    return path


def _on_builder_inited(app) -> None:
    write_table(Path(app.srcdir) / "_generated")


def setup(app):
    app.connect("builder-inited", _on_builder_inited)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
