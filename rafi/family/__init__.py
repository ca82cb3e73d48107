"""The model family compared with RAFI as published, whole-run cross-validation and the
choice of the best model (docs/models.md)."""
