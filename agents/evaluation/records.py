"""What an evaluation runs and what it records: episode specs, records, CSV, run keys.

One import for the evaluation's data: the episode specs and records with their columns,
keys and :data:`COLUMN_DOCS` (the unit and meaning of every column, from the record's
field definitions, for the docs' CSV glossary; :mod:`agents.evaluation.episodes`), the
results CSV (:mod:`agents.evaluation.record_csv`) and the run keys
(:mod:`agents.evaluation.run_keys`) are importable from here. The scenario list of the
paper is :data:`safe_nav_env.constants.PAPER_SCENARIOS`, the risk names
:data:`filters.wrapper.RISKS` and the scenario names :data:`safe_nav_env.SCENARIO_NAMES`.
"""

from __future__ import annotations

from agents.evaluation.episodes import (
    AUTO,
    COLUMN_DOCS,
    CYCLED_FIELDS,
    FILTER_STATUSES,
    KEY_FIELDS,
    PLANNERS,
    RECORD_FIELDS,
    REFERENCES,
    TIMING_FIELDS,
    EpisodeRecord,
    EpisodeSpec,
    episode_key,
    options_json,
)
from agents.evaluation.record_csv import RecordWriter, read_records, sort_records, write_records
from agents.evaluation.run_keys import (
    check_run_key,
    file_sha256,
    package_version,
    run_key,
    run_key_path,
)
from filters.wrapper import RISKS
from safe_nav_env.constants import PAPER_SCENARIOS
from safe_nav_env.scenarios import SCENARIO_NAMES

__all__ = [
    "AUTO",
    "COLUMN_DOCS",
    "CYCLED_FIELDS",
    "FILTER_STATUSES",
    "KEY_FIELDS",
    "PAPER_SCENARIOS",
    "PLANNERS",
    "RECORD_FIELDS",
    "REFERENCES",
    "RISKS",
    "SCENARIO_NAMES",
    "TIMING_FIELDS",
    "EpisodeRecord",
    "EpisodeSpec",
    "RecordWriter",
    "check_run_key",
    "episode_key",
    "file_sha256",
    "options_json",
    "package_version",
    "read_records",
    "run_key",
    "run_key_path",
    "sort_records",
    "write_records",
]
