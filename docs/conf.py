"""Sphinx configuration of the safe-nav documentation.

Build (warnings are errors, as in CI):
``python -m sphinx -W -b html docs docs/_build/html``. The gallery in ``examples/``
is executed during the build; the CSV glossary is generated from
``agents.evaluation.records.COLUMN_DOCS`` (``_ext/csv_glossary.py``).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))  # document this checkout's packages, not another install
sys.path.insert(0, str(DOCS / "_ext"))
os.environ.setdefault("MPLBACKEND", "Agg")

project = "safe-nav"
author = "safe-nav developers"
copyright = "2024-2026, safe-nav developers"
try:
    from importlib.metadata import version as _version

    release = _version("safe-nav")
except Exception:  # not installed: the docs still build
    release = "0.1.0"
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinx_gallery.gen_gallery",
    "csv_glossary",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "_intersphinx", "figures/*.mp4",
                    "auto_examples/*.ipynb", "auto_examples/*.py", "auto_examples/*.zip",
                    "auto_examples/*.md5", "auto_examples/*.json"]
templates_path: list[str] = []

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# --- autodoc / napoleon: numpy docstrings of the public names -------------------
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autodoc_preserve_defaults = True
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True  # "Attributes" as fields: no duplicate object descriptions

# --- intersphinx --------------------------------------------------------------------
# Each project's published inventory first; when the build has no network (CI here),
# Sphinx falls back to a small local inventory in _intersphinx/ (written by
# _intersphinx/make_inventories.py) that lists only the targets these docs use, with
# the same page and anchor as the published site. A failed first location with a working
# fallback is logged as information, not as a warning, so `-W` stays green offline.
_LOCAL = DOCS / "_intersphinx"
intersphinx_mapping = {
    "numpy": ("https://numpy.org/doc/stable/", (None, str(_LOCAL / "numpy.inv"))),
    "gymnasium": ("https://gymnasium.farama.org/", (None, str(_LOCAL / "gymnasium.inv"))),
    "stable_baselines3": ("https://stable-baselines3.readthedocs.io/en/master/",
                          (None, str(_LOCAL / "stable_baselines3.inv"))),
    "cvxpy": ("https://www.cvxpy.org/", (None, str(_LOCAL / "cvxpy.inv"))),
}
intersphinx_timeout = 10

# --- sphinx-gallery: the examples, executed at build time ---------------------------
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "matplotlib_animations": False,
    "image_scrapers": ("matplotlib",),
    "reset_modules": ("matplotlib",),
    "abort_on_example_error": True,
    "show_memory": False,
}

# --- HTML -------------------------------------------------------------------------
html_theme = "furo"
html_title = "safe-nav"
html_static_path: list[str] = []
suppress_warnings = ["config.cache"]  # sphinx_gallery_conf holds callables' reprs



# --- type hints spelled as in the code (np.ndarray, gym.Env) -> the projects' names ----
_ALIASES = {
    "np.ndarray": "numpy.ndarray",
    "numpy.random._generator.Generator": "numpy.random.Generator",
    "np.random.Generator": "numpy.random.Generator",
    "gym.Env": "gymnasium.Env",
    "gymnasium.core.Env": "gymnasium.Env",
    "gym.Wrapper": "gymnasium.Wrapper",
    "gymnasium.core.Wrapper": "gymnasium.Wrapper",
}


def _resolve_alias(app, env, node, contnode):
    target = _ALIASES.get(node.get("reftarget", ""))
    if target is None:
        return None
    from sphinx.ext.intersphinx import missing_reference

    node["reftarget"] = target
    return missing_reference(app, env, node, contnode)


def setup(app):
    app.connect("missing-reference", _resolve_alias)
