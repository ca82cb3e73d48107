"""rafi diff (rafi.ops.result_diff): the tool that shows a change of layout changed no result."""

from __future__ import annotations

import base64
import json

import pandas as pd

from rafi.ops.result_diff import diff_trees, report_tokens


def _tree(root, value: float, created: str, html_number: str):
    (root / "m" / "benchmarks").mkdir(parents=True)
    pd.DataFrame({"run_id": ["a", "b"], "max_abs_after_um": [1.25, value]}).to_csv(
        root / "m" / "summary.csv", index=False
    )
    pd.DataFrame({"t_s": [0.0, 5.0], "r": [0.1, value]}).to_parquet(root / "m" / "residuals.parquet")
    model = {"kind": "rafi", "created": created, "model_id": created * 3, "speeds": [{"rmse_um": value}]}
    (root / "m" / "model.json").write_text(json.dumps(model))
    (root / "m" / "benchmarks" / "fit.tsv").write_text(f"s\n{created}\n")  # timings: never compared
    figure = base64.b64encode(created.encode()).decode()
    (root / "m" / "report.html").write_text(
        f"<p>max residual <b>{html_number}</b> µm, created {created}</p>"
        f"<img src='data:image/png;base64,{figure}'>"
    )


def test_identical_results_differ_only_in_what_must_differ(tmp_path):
    _tree(tmp_path / "old", 2.5, "2026-01-01T00:00:00Z", "2.50")
    _tree(tmp_path / "new", 2.5, "2026-02-02T10:00:00Z", "2.50")
    assert diff_trees(tmp_path / "old", tmp_path / "new") == {}


def test_a_changed_number_is_found_in_every_kind_of_file(tmp_path):
    _tree(tmp_path / "old", 2.5, "2026-01-01T00:00:00Z", "2.50")
    _tree(tmp_path / "new", 2.5000001, "2026-01-01T00:00:00Z", "2.51")
    found = diff_trees(tmp_path / "old", tmp_path / "new")
    assert set(found) == {"m/summary.csv", "m/residuals.parquet", "m/model.json", "m/report.html"}
    assert "max_abs_after_um" in found["m/summary.csv"][0]
    assert diff_trees(tmp_path / "old", tmp_path / "new", rtol=1e-6).keys() == {"m/report.html"}


def test_a_missing_file_is_a_difference(tmp_path):
    _tree(tmp_path / "old", 2.5, "2026-01-01T00:00:00Z", "2.50")
    _tree(tmp_path / "new", 2.5, "2026-01-01T00:00:00Z", "2.50")
    (tmp_path / "new" / "m" / "model.json").unlink()
    assert diff_trees(tmp_path / "old", tmp_path / "new") == {"m/model.json": ["only in old"]}


def test_report_tokens_mask_figures_ids_and_times():
    a = report_tokens("<p>id 0123456789abcdef at 2026-01-01T00:00:00Z</p><svg><path d='M0'/></svg>")
    b = report_tokens("<p>id fedcba9876543210 at 2027-05-05 10:00</p><svg><path d='M1'/></svg>")
    assert a == b


def test_a_text_column_with_empty_cells_is_the_same_and_a_changed_word_is_found(tmp_path):
    """An empty cell of a text column reads back as missing (pandas 3 keeps it missing through
    ``astype(str)``): empty on both sides is no difference, a word against an empty cell is."""
    for side, second in (("old", "T11"), ("new", "T11"), ("changed", "")):
        (tmp_path / side).mkdir()
        pd.DataFrame({"run_id": ["a", "b", "c"], "inputs": ["", second, "T8, speed"]}).to_csv(
            tmp_path / side / "per_run.csv", index=False
        )
    assert diff_trees(tmp_path / "old", tmp_path / "new") == {}
    found = diff_trees(tmp_path / "old", tmp_path / "changed")
    assert (
        list(found) == ["per_run.csv"]
        and "column inputs: 1 cell(s) differ, first at row 1" in found["per_run.csv"][0]
    )
