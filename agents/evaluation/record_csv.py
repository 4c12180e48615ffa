"""The results CSV: one :class:`~agents.evaluation.episodes.EpisodeRecord` per row.

Columns :data:`~agents.evaluation.episodes.RECORD_FIELDS`, in order; written as episodes
finish (:class:`RecordWriter`, so an interrupted run can resume) or at once
(:func:`write_records`), read back by :func:`read_records` and put in a canonical order
by :func:`sort_records`.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from agents.errors import RecordsFileError
from agents.evaluation.episodes import _KINDS, AUTO, KEY_FIELDS, RECORD_FIELDS, EpisodeRecord
from filters.wrapper import RISKS

__all__ = ["RISK_ORDER", "RecordWriter", "read_records", "sort_records", "write_records"]

RISK_ORDER = {risk: i for i, risk in enumerate(RISKS)}
"""Order of the risk settings in the CSV and the tables (:data:`filters.wrapper.RISKS`)."""


def sort_records(records: Iterable[EpisodeRecord]) -> list[EpisodeRecord]:
    """Records in a canonical order (scenario, risk, seed, ...), independent of completion order."""
    epsilon = KEY_FIELDS.index("epsilon")

    def order(record: EpisodeRecord) -> tuple:
        key = list(record.key())
        value = key[epsilon]  # a fixed radius sorts before "auto" (str and float do not compare)
        key[epsilon] = (1, 0.0) if value == AUTO else (0, value)
        return (record.case, record.scenario, RISK_ORDER.get(record.risk, len(RISKS)), *key[2:])

    return sorted(records, key=order)


def _parse(name: str, raw: str, path: Path, line: int) -> Any:
    if name == "epsilon" and raw == AUTO:
        return raw
    kind = "float" if name == "epsilon" else _KINDS[name]
    try:
        if kind in ("int", int):
            return int(float(raw)) if raw else 0
        if kind in ("float", float):
            return float(raw) if raw else math.nan
        if kind in ("bool", bool):
            if raw not in ("True", "False", ""):
                raise ValueError(raw)
            return raw == "True"
    except ValueError:
        raise RecordsFileError(f"{path}, line {line}: column {name!r} must be {kind}, "
                               f"got {raw!r}") from None
    return raw


def _check_header(path: Path, header: Sequence[str]) -> None:
    """Raise :class:`RecordsFileError` unless ``header`` is :data:`RECORD_FIELDS`."""
    if tuple(header) != RECORD_FIELDS:
        missing = [c for c in RECORD_FIELDS if c not in header]
        extra = [c for c in header if c not in RECORD_FIELDS]
        raise RecordsFileError(
            f"{path} has other columns than this version of safe-nav writes (columns "
            f"missing: {missing or 'none'}, unknown: {extra or 'none'})")


def read_records(path: str | Path) -> list[EpisodeRecord]:
    """Records from a results CSV (written by :class:`RecordWriter`).

    Raises
    ------
    RecordsFileError
        If the header is not :data:`RECORD_FIELDS` (a CSV of another version) or a
        value does not parse.
    """
    path = Path(path)
    records = []
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        _check_header(path, reader.fieldnames or ())
        for row in reader:
            if None in row or any(row[name] is None for name in RECORD_FIELDS):
                raise RecordsFileError(f"{path}, line {reader.line_num}: wrong number of columns")
            records.append(EpisodeRecord(**{name: _parse(name, row[name], path, reader.line_num)
                                            for name in RECORD_FIELDS}))
    return records


class RecordWriter:
    """Appends records to a CSV as they finish, so an interrupted run can resume.

    Raises
    ------
    RecordsFileError
        If ``path`` exists with another header.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists() or self.path.stat().st_size == 0
        if not new:
            with open(self.path, newline="") as handle:
                _check_header(self.path, next(csv.reader(handle), ()))
        self._handle = open(self.path, "a", newline="")
        self._writer = csv.writer(self._handle)
        if new:
            self._writer.writerow(RECORD_FIELDS)
            self._handle.flush()

    def __call__(self, record: EpisodeRecord) -> None:
        # The fields are flat: dataclasses.asdict's row without its deep copy (the parent
        # writes one per episode while the workers run).
        self._writer.writerow([getattr(record, name) for name in RECORD_FIELDS])
        self._handle.flush()

    def close(self) -> None:
        self._handle.close()

    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_records(path: str | Path, records: Iterable[EpisodeRecord]) -> None:
    """Replace ``path`` by a CSV of ``records`` (atomically: a temporary file, then a rename)."""
    path = Path(path)
    temporary = path.with_name(path.name + ".tmp")
    temporary.unlink(missing_ok=True)  # a crashed rewrite's rows
    with RecordWriter(temporary) as writer:
        for record in records:
            writer(record)
    os.replace(temporary, path)
