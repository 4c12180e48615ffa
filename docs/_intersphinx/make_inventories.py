"""Write the small offline intersphinx inventories in this folder.

The docs link to numpy, Gymnasium, Stable-Baselines3 and CVXPY through intersphinx.
``conf.py`` asks each project's published ``objects.inv`` first; where the build has
no network (CI here), Sphinx falls back to the inventories written by this script.
They hold only the targets these docs reference, each with the page and anchor it
has on the project's published site (as of the versions named below), so a
link built offline points where the online build would point.

Run ``python docs/_intersphinx/make_inventories.py`` after adding a target.
"""

from __future__ import annotations

import zlib
from pathlib import Path

HERE = Path(__file__).resolve().parent

# project key -> (project name, version, [(name, role, relative uri)])
TARGETS: dict[str, tuple[str, str, list[tuple[str, str, str]]]] = {
    "numpy": ("NumPy", "2.4", [
        ("numpy.ndarray", "py:class", "reference/generated/numpy.ndarray.html#$"),
        ("numpy.random.Generator", "py:class", "reference/random/generator.html#$"),
        ("numpy.partition", "py:function", "reference/generated/numpy.partition.html#$"),
    ]),
    "gymnasium": ("Gymnasium", "1.4", [
        ("gymnasium.Env", "py:class", "api/env/#$"),
        ("gymnasium.Wrapper", "py:class", "api/wrappers/#$"),
        ("gymnasium.make", "py:function", "api/registry/#$"),
    ]),
    "stable_baselines3": ("Stable Baselines3", "2.9", [
        ("stable_baselines3.ppo.PPO", "py:class", "modules/ppo.html#$"),
    ]),
    "cvxpy": ("CVXPY", "1.9", [
        ("cvxpy.problems.problem.Problem", "py:class", "api_reference/cvxpy.problems.html#$"),
    ]),
}


def write(key: str) -> Path:
    project, version, entries = TARGETS[key]
    header = (f"# Sphinx inventory version 2\n# Project: {project}\n# Version: {version}\n"
              "# The remainder of this file is compressed using zlib.\n").encode()
    body = "".join(f"{name} {role} 1 {uri} -\n" for name, role, uri in entries).encode()
    path = HERE / f"{key}.inv"
    path.write_bytes(header + zlib.compress(body, 9))
    return path


if __name__ == "__main__":
    for key in TARGETS:
        print(write(key))
