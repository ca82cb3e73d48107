"""The qualification report: context from result tables, figures, templates, HTML and PDF."""
