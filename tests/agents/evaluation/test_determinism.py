"""Determinism: the same seeds and code give the same CSV, timing columns aside, on 1 or 2
workers and on a re-run (the equivalence rule of the docs' design page)."""

from __future__ import annotations

import csv
from pathlib import Path

from agents.cli import main
from agents.evaluation.records import TIMING_FIELDS


def _rows(folder: Path) -> list[dict[str, str]]:
    with open(folder / "episodes.csv", newline="") as handle:
        rows = [{k: v for k, v in row.items() if k not in TIMING_FIELDS}
                for row in csv.DictReader(handle)]
    return sorted(rows, key=lambda row: (row["scenario"], row["risk"], int(row["seed"])))


def _evaluate(folder: Path, workers: int) -> list[dict[str, str]]:
    code = main(["evaluate", "--scenarios", "Intersection", "RandomCrossing", "--risks", "none",
                 "mean", "dr_cvar", "--episodes", "6", "--workers", str(workers),
                 "--no-plots", "--no-progress", "--output", str(folder)])
    assert code == 0
    return _rows(folder)


def test_one_worker_two_workers_and_a_rerun_write_the_same_rows(tmp_path):
    one = _evaluate(tmp_path / "one", 1)
    assert len(one) == 2 * 3 * 6
    assert any(row["collision"] == "True" for row in one)  # rows that say something
    assert _evaluate(tmp_path / "two", 2) == one
    assert _evaluate(tmp_path / "again", 1) == one
