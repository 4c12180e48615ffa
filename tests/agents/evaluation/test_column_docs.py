"""COLUMN_DOCS documents every CSV column, and nothing else (the docs' glossary)."""

from agents.evaluation.records import COLUMN_DOCS, RECORD_FIELDS


def test_column_docs_cover_exactly_the_record_fields():
    assert tuple(COLUMN_DOCS) == RECORD_FIELDS


def test_every_column_has_a_meaning_and_a_unit_string():
    for name, (unit, meaning) in COLUMN_DOCS.items():
        assert isinstance(unit, str), name
        assert meaning.strip(), f"column {name!r} has no meaning"
