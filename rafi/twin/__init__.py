"""The spindle's digital twin and every generator of synthetic data (one place; map in docs/twin.md).

Twin: ``machines`` (constants) -> ``physics`` -> ``simulate`` (+ ``defects``) -> ``recipes``
(shipped data) -> ``writers`` / ``day`` / ``calibration`` / ``plots`` / ``cli``. Synthetic
generators for tests: ``synthetic_logs`` and ``synthetic_runs``. Shared by both: ``schedules``
and ``signals``.
"""
