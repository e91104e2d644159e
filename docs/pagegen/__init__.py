"""The builders of the generated documentation pages, one module per page (docs/gen_pages.py runs them)."""
