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

from agents.evaluation import episodes, record_csv, run_keys
from agents.evaluation.episodes import *  # noqa: F403 (the façade: every name of __all__)
from agents.evaluation.record_csv import *  # noqa: F403
from agents.evaluation.run_keys import *  # noqa: F403
from filters.wrapper import RISKS
from safe_nav_env.constants import PAPER_SCENARIOS
from safe_nav_env.scenarios import SCENARIO_NAMES

__all__ = ["PAPER_SCENARIOS", "RISKS", "SCENARIO_NAMES"]
__all__ += episodes.__all__ + record_csv.__all__ + run_keys.__all__
