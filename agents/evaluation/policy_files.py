"""The PPO policies an evaluation runs: where the file is, its check, and one load per process.

:func:`check_policy` and :func:`load_policy` are the checks an evaluation makes *before*
anything runs; :func:`load_policy` keeps each policy (its numpy export,
:class:`agents.policies.numpy_policy.NumpyPolicy`, where possible) for the process, and
local workers take the parent's exports (:func:`exported_policies`,
:func:`preload_policies`) instead of loading the file again. The export is also kept on
disk (:func:`cache_folder`, one ``.npz`` per SHA-256 of a policy file's content), so that
later processes load it without importing torch and Stable-Baselines3.
"""

from __future__ import annotations

import functools
import os
import zipfile
from pathlib import Path
from typing import Any

from agents.errors import PolicyFileError
from agents.evaluation.records import file_sha256
from agents.policies.loading import load_ppo, pretrained_policy_path, set_torch_threads
from agents.policies.numpy_policy import NumpyPolicy, UnsupportedPolicyError

__all__ = ["cache_folder", "check_policy", "exported_policies", "load_policy", "policy_file",
           "preload_policies"]


def policy_file(policy_path: str | Path = "") -> Path:
    """The PPO policy file of ``policy_path`` (the shipped one if empty)."""
    return Path(policy_path) if policy_path else _pretrained_policy_path()


# importlib.resources: about 1 ms a call, 4 per episode
_pretrained_policy_path = functools.cache(pretrained_policy_path)


_SHA_CACHE: dict[tuple[str, int, int], str] = {}


def check_policy(policy_path: str | Path = "") -> str:
    """Check that a PPO policy file exists and is a zip; return the SHA-256 of its content.

    Raises
    ------
    PolicyFileError
        If the file is missing, is a folder, or is not a zip archive (a
        Stable-Baselines3 policy is one).
    """
    path = policy_file(policy_path)
    if not path.exists():
        raise PolicyFileError(f"no PPO policy file at {path}")
    if not path.is_file():
        raise PolicyFileError(f"the PPO policy {path} is not a file")
    stat = path.stat()
    cache_key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if cache_key not in _SHA_CACHE:
        if not zipfile.is_zipfile(path):
            raise PolicyFileError(f"the PPO policy {path} is not a Stable-Baselines3 .zip file "
                                  "(corrupt or of another kind)")
        _SHA_CACHE[cache_key] = file_sha256(path)
    return _SHA_CACHE[cache_key]


_POLICY_CACHE: dict[tuple[str, str], Any] = {}


def load_policy(policy_path: str | Path = "", *, sha256: str = "") -> tuple[Any, str]:
    """Load a PPO policy (cached per process); return it and the SHA-256 of its file.

    The numpy export of a file whose content was exported before is read from the cache
    folder (:func:`cache_folder`; keyed by the content's SHA-256, so an edited file is
    exported again); otherwise torch and SB3 load the file, and the export is saved there.

    Parameters
    ----------
    policy_path
        The policy's ``.zip``; empty for the one shipped with the package.
    sha256
        If given, the file's content must have this hash (it may not change during a run).

    Raises
    ------
    PolicyFileError
        If the file is missing or corrupt, does not load, or has another hash.
    """
    sha = check_policy(policy_path)
    if sha256 and sha != sha256:
        raise PolicyFileError(f"the PPO policy {policy_file(policy_path)} changed during the "
                              f"run (SHA-256 {sha[:12]}..., expected {sha256[:12]}...)")
    key = (str(policy_file(policy_path).resolve()), sha)
    if key not in _POLICY_CACHE:
        try:  # the export kept by an earlier process (unreadable or of another format: redone)
            _POLICY_CACHE[key] = NumpyPolicy.load(cache_folder() / "policies" / f"{sha}.npz")
        except (OSError, UnsupportedPolicyError):
            _POLICY_CACHE[key] = _export(policy_file(policy_path), sha)
    return _POLICY_CACHE[key], sha


def _export(path: Path, sha: str) -> Any:
    """Load ``path`` with Stable-Baselines3 and export it to numpy (kept in the cache folder),
    or return the SB3 model if it cannot be exported."""
    set_torch_threads(1)
    try:
        model = load_ppo(path)
    except Exception as exc:  # noqa: BLE001 - SB3/torch/zip raise many kinds
        raise PolicyFileError(f"cannot load the PPO policy {path} ({type(exc).__name__}: "
                              f"{exc})".replace("\n", " ")) from exc
    try:
        policy = NumpyPolicy.from_sb3(model)
    except UnsupportedPolicyError:
        return model
    try:
        folder = cache_folder() / "policies"
        folder.mkdir(parents=True, exist_ok=True)
        policy.save(folder / f"{sha}.npz")
    except OSError:  # a read-only or full disk: the next process exports again
        pass
    return policy


def cache_folder() -> Path:
    """Where safe-nav keeps what it can rebuild (numpy exports of policies): the folder
    ``SAFE_NAV_CACHE_DIR`` names, else ``$XDG_CACHE_HOME/safe-nav``, else
    ``~/.cache/safe-nav``. Deleting it costs one export (torch and SB3 load the file again)."""
    folder = os.environ.get("SAFE_NAV_CACHE_DIR")
    if folder:
        return Path(folder)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "safe-nav"


def exported_policies() -> dict[tuple[str, str], Any]:
    """The policies loaded in this process that another process can take as they are.

    Those exported to numpy (:class:`agents.policies.numpy_policy.NumpyPolicy`: a few
    arrays, no torch), keyed by (resolved file, SHA-256 of its content) as
    :func:`load_policy` keys them. A local worker started with them
    (:func:`preload_policies`) never imports torch or Stable-Baselines3.
    """
    return {key: policy for key, policy in _POLICY_CACHE.items()
            if isinstance(policy, NumpyPolicy)}


def preload_policies(policies: dict[tuple[str, str], Any]) -> None:
    """Put policies of :func:`exported_policies` (another process's) into this process's
    cache; :func:`load_policy` still checks the file's SHA-256 against the key."""
    _POLICY_CACHE.update(policies)
