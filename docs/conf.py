"""Sphinx configuration of the tunnelsim documentation site.

Build it (warnings are errors, as CI does)::

    .venv/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html

DECISION: Sphinx, because the API reference comes from the numpydoc docstrings the
code already has (autodoc + autosummary + numpydoc), and laspy, SciPy, trimesh and
py4dgeo users know Sphinx sites. MyST lets the user guide stay Markdown (moved from the
README). Theme: pydata-sphinx-theme, the one NumPy, SciPy and pandas use: a reader from
those projects finds the guide / tutorials / API tabs, the per-page outline and the
search where they expect them, and it handles an API of several hundred pages.

DECISION: nitpicky is off. Numpydoc types such as ``(n, 3) float64`` or ``path-like``
are prose, not cross-reference targets; with nitpicky on each would be an error.
Internal links of the guide are still checked: a MyST link to a missing page or
heading anchor is a warning, and ``-W`` makes it an error.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

import survey  # noqa: E402  (the installed package: its version is the docs' version)

project = "tunnelsim"
author = "the tunnelsim authors"
copyright = "the tunnelsim authors, Apache-2.0"
release = version = survey.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "apipages",
    "docstrings",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path = ["_templates"]

# -- MyST ----------------------------------------------------------------------------
# Headings up to level 3 get anchors (``guide/survey.md#m3c2``); a link to a missing
# anchor is a warning (an error under -W).
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]

# -- API reference -------------------------------------------------------------------
autosummary_generate = True
autosummary_generate_overwrite = True
autosummary_imported_members = True
autodoc_typehints = "none"          # the numpydoc Parameters sections give the types
autodoc_member_order = "bysource"
autodoc_default_options = {"undoc-members": False}
numpydoc_show_class_members = False  # autodoc's :members: lists them, once
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = True
numpydoc_xref_param_type = False
nitpicky = False

# -- HTML ----------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"tunnelsim {release}"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
}
html_show_sourcelink = False
