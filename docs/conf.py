"""Sphinx configuration of the documentation site.

Build it (warnings are errors, the gallery and the tutorial executed)::

    .venv/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html

``WTO_DOCS_RERUN=1`` runs again the examples that did not change since the last build;
``WTO_DOCS_SLOW=1`` also executes the gallery's slow scripts (``*_slow.py``); without it
they are shown with their code, not run. ``tests/test_docs.py`` builds the site this way.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(ROOT))  # scenes/ and the packages of a checkout

os.environ.setdefault("MPLBACKEND", "Agg")

project = "windtunnel-optics"
author = "windtunnel-optics contributors"
copyright = "the windtunnel-optics contributors, BSD-3-Clause"
release = version = "0.1.0"

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinxarg.ext",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "apiref",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "_templates", "**/README.md", "**/GALLERY_HEADER.rst"]
templates_path = ["_templates"]

# Markdown pages (MyST): headings get anchors, so that page#section links resolve
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath"]

# API reference: autosummary pages written from apiref's lists, numpydoc docstrings
autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types and units
autodoc_use_type_comments = False  # the code has annotations, no type comments: no re-parse
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# The gallery (examples/) and the tutorial (docs/tutorial/): executed at every build
_slow = os.environ.get("WTO_DOCS_SLOW", "") not in ("", "0")
sphinx_gallery_conf = {
    "examples_dirs": [str(ROOT / "examples"), str(HERE / "tutorial")],
    "gallery_dirs": ["gallery", "tutorial_built"],
    "filename_pattern": r"/(plot|tutorial)_" if _slow else r"/(plot|tutorial)_(?!.*_slow\.py$)",
    "ignore_pattern": r"(__init__|_helpers)\.py",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "matplotlib_animations": False,
    # the library's own Figures first, while pyplot's still have their manager (skipped)
    "image_scrapers": ("figure_scraper", "matplotlib"),
    "reset_modules": ("matplotlib",),
    # WTO_DOCS_RERUN=1 (the tests): run every example again, even if unchanged
    "run_stale_examples": os.environ.get("WTO_DOCS_RERUN", "") == "1",
    "plot_gallery": "True",
    "capture_repr": (),
    "min_reported_time": 1e9,
    "show_memory": False,
}

html_theme = "pydata_sphinx_theme"
html_title = "windtunnel-optics"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_depth": 2,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_show_sourcelink = False
# The page of each public name (api/generated/, some 680 pages) has no left sidebar: its
# stage page (``resection.camera`` ...) lists and links the names. pydata's sidebar there
# would hold every name of the API, written out again for every page, about half of the
# whole build's time.
html_sidebars = {"api/generated/*": []}
