"""Sphinx configuration of the sb3-icrl documentation (``sphinx-build -W -b html docs docs/_build/html``)."""

import os
import sys

# The package itself, importable without installing it (autodoc imports every documented module)
DOCS_DIR = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.abspath(os.path.join(DOCS_DIR, "..")))

with open(os.path.join(DOCS_DIR, "..", "sb3_icrl", "version.txt")) as file_handler:
    __version__ = file_handler.read().strip()

# -- Project information -----------------------------------------------------

project = "sb3-icrl"
copyright = "2026, the sb3-icrl authors"
author = "the sb3-icrl authors"
version = __version__  # the short X.Y version
release = __version__  # the full version, including alpha/beta/rc tags

# -- General configuration ---------------------------------------------------

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.viewcode",
    "sphinx.ext.mathjax",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
master_doc = "index"
language = "en"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
pygments_style = "sphinx"

# Docstrings use Sphinx ``:param:`` fields (no napoleon), as in Stable-Baselines3
autoclass_content = "both"
autodoc_member_order = "bysource"
autodoc_typehints = "description"
# Methods without a docstring of their own (``step``, ``reset``...) would inherit gymnasium's Google-style ones
autodoc_inherit_docstrings = False
autodoc_default_options = {"members": True, "show-inheritance": True}

# ``$...$`` maths and ``:::`` fences in the Markdown guides; anchors for their section titles
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# -- Options for HTML output -------------------------------------------------

html_theme = "sphinx_rtd_theme"
html_title = f"sb3-icrl {release}"
html_static_path: list[str] = []
html_show_sourcelink = False
