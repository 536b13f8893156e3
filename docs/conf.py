"""Sphinx configuration of the motiontwin docs (``make docs`` -> build/docs; ``tests/test_docs.py``).

Why Sphinx + MyST rather than MkDocs + mkdocstrings: Sphinx's autodoc/napoleon read the numpy-style docstrings
the code already has, a small local extension (``_ext/motiontwin_docs.py``) executes the worked examples and
renders the JSON Schema at build time, and ``-W`` turns every broken reference or docstring into a failure.
Offline: no intersphinx, no remote images, no theme downloads (the built-in ``alabaster`` theme).
"""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

project = "motiontwin"
author = "the motiontwin engineers"
copyright = "motiontwin engineers; BSD-3-Clause"
extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "motiontwin_docs"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "README.md"]
html_theme = "alabaster"
html_title = "motiontwin"
highlight_language = "none"
smartquotes = False          # keep quotes as the code prints them
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence"]

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": False}
napoleon_google_docstring = False
napoleon_numpy_docstring = True

# worked examples (motiontwin_docs.mt-run): executed at build time in this folder (relative to the checkout)
mt_work_dir = "build/docs-work"
