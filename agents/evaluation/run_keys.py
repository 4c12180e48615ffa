"""Run keys: every setting the rows of one results CSV share.

The record keys (:data:`~agents.evaluation.episodes.KEY_FIELDS`) say which episode a row
answers; the *run key* (:func:`run_key`, stored next to the CSV: :func:`run_key_path`)
covers every setting shared by the rows of a run -- planner, policy file (by the
SHA-256 of its content, :func:`file_sha256`), filter and environment settings, noise
and the package version (:func:`package_version`) -- so that a resumed run never
reuses the rows of another (:func:`check_run_key`).
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agents.errors import RunMismatchError
from agents.evaluation.episodes import CYCLED_FIELDS, KEY_FIELDS
from filters.errors import InvalidParameterError
from filters.wrapper import calibration_settings

if TYPE_CHECKING:
    from agents.evaluation.episodes import EpisodeSpec

__all__ = ["check_run_key", "file_sha256", "package_version", "run_key", "run_key_path"]


@functools.cache  # the metadata is read once per process
def package_version() -> str:
    """Version of the installed safe-nav package (``"unknown"`` if it is not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("safe-nav")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "unknown"


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's content (read at once: policy files are a few hundred kB)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run_key(specs: Sequence[EpisodeSpec], *, vary: Sequence[str] = ()) -> dict[str, Any]:
    """Every setting the episodes of a run share, plus the package version.

    Parameters
    ----------
    specs
        The run's episodes.
    vary
        Key fields that vary within the run by design besides :data:`CYCLED_FIELDS`
        (a sweep's ``("epsilon", "delta")``); they are left out of the run key.

    Returns
    -------
    dict
        ``{field: value}`` for every other field of :data:`KEY_FIELDS` and
        ``"version"``; JSON-serialisable. The policy counts by its content
        (``policy_sha256``), not by its path.

    Raises
    ------
    InvalidParameterError
        If such a field differs between the specs.
    """
    key: dict[str, Any] = {}
    for name in (name for name in KEY_FIELDS if name not in {*CYCLED_FIELDS, *vary}):
        values = {getattr(spec, name) for spec in specs}
        if len(values) > 1:
            raise InvalidParameterError(
                f"the episodes of one run must share {name!r}, got {sorted(values, key=str)}")
        key[name] = values.pop() if values else None
    # The held-out calibration of conformal / epsilon="auto" (its defaults included).
    calibrations = {json.dumps(settings, sort_keys=True) for spec in specs
                    if (settings := calibration_settings(**spec.filter_kwargs())) is not None}
    if calibrations:
        key["calibration"] = [json.loads(text) for text in sorted(calibrations)]
    key["version"] = package_version()
    return key


def run_key_path(csv_path: str | Path) -> Path:
    """Where the run key of a results CSV is kept: ``episodes.csv`` -> ``episodes.run.json``."""
    return Path(csv_path).with_suffix(".run.json")


def check_run_key(csv_path: str | Path, key: Mapping[str, Any]) -> None:
    """Refuse to add to ``csv_path`` unless its stored run key equals ``key``.

    Writes the key if the CSV holds no rows yet.

    Raises
    ------
    RunMismatchError
        If the stored key differs (the message names every differing setting), or the
        CSV has rows but no key.
    """
    csv_path = Path(csv_path)
    key_path = run_key_path(csv_path)
    hint = "choose another output folder (--output), or discard it (--overwrite)"
    if not key_path.exists():
        if csv_path.exists() and csv_path.stat().st_size > 0:  # rows of an unknown run
            raise RunMismatchError(f"{csv_path} holds results but no run key {key_path.name} "
                                   f"(an older safe-nav wrote it?), so they cannot be reused; "
                                   f"{hint}")
        key_path.parent.mkdir(parents=True, exist_ok=True)
        key_path.write_text(json.dumps(dict(key), indent=2, sort_keys=True) + "\n")
        return
    try:
        stored = json.loads(key_path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RunMismatchError(f"{key_path} is not a readable run key ({exc}); {hint}") from None
    wanted = json.loads(json.dumps(dict(key)))
    differ = [f"{name} {stored.get(name)!r} != {wanted.get(name)!r}"
              for name in sorted({*stored, *wanted}) if stored.get(name) != wanted.get(name)]
    if differ:
        raise RunMismatchError(f"{csv_path.parent} holds a run with other settings "
                               f"({'; '.join(differ)} now); {hint}")
