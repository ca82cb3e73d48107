"""The RAFI model artefact (rafi.method.model): terms, prediction, blending, JSON round trip."""

import hashlib
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rafi.method.model import (
    SCHEMA,
    RafiModel,
    design_matrix,
    load_model,
    parse_term,
    parse_terms,
    save_model,
)

ROOT = Path(__file__).resolve().parents[1]
TERMS = ["1", "x1", "x2", "x1*x2", "x1^2", "x2^2*x1"]


def two_speed_model(**kw):
    m = RafiModel(
        ["T6", "T8"],
        TERMS,
        reference={"rule": "run_start", "window_s": 60},
        machine="m",
        created="2026-01-01T00:00:00Z",
        code_version="rafi test",
        **kw,
    )
    m.add_speed_model(
        6000,
        [1.0, 2.0, 0.5, 0.1, -0.05, 0.01],
        {"T6": (0, 10), "T8": (0, 8)},
        train_runs=["b"],
        rmse_um=0.3,
        n=100,
    )
    m.add_speed_model(
        3000,
        [0.5, 1.0, 0.2, 0.0, 0.02, 0.0],
        {"T6": (0, 4), "T8": (0, 3)},
        train_runs=["a"],
        rmse_um=0.2,
        n=90,
    )
    return m


def frame(speed, t6, t8):
    return pd.DataFrame(
        {"speed_rpm": np.asarray(speed, float), "dT6": np.asarray(t6, float), "dT8": np.asarray(t8, float)}
    )


def poly(c, x1, x2):
    return c[0] + c[1] * x1 + c[2] * x2 + c[3] * x1 * x2 + c[4] * x1**2 + c[5] * x2**2 * x1


def test_terms_grammar():
    assert parse_term("1", 3) == (0, 0, 0)
    assert parse_term("x1*x2*x3", 3) == (1, 1, 1)
    assert parse_term("x2^2", 3) == (0, 2, 0)
    assert parse_term(" x1^2 * x3 ", 3) == (2, 0, 1)
    for bad in ["y1", "x0", "x1^", "x1**2", "", "x1+x2"]:
        with pytest.raises(ValueError):
            parse_term(bad, 3)
    with pytest.raises(ValueError, match="only 2 key sensor"):
        parse_term("x3", 2)
    with pytest.raises(ValueError, match="same monomial"):
        parse_terms(["x1*x2", "x2*x1"], 2)
    x = np.array([[2.0, 3.0]])
    np.testing.assert_array_equal(design_matrix(x, parse_terms(TERMS, 2)), [[1, 2, 3, 6, 4, 18]])


def test_predict_blends_per_speed_polynomials():
    m = two_speed_model()
    np.testing.assert_array_equal(m.speeds_rpm_, [3000, 6000])
    c3, c6 = m.coef_
    f = frame([3000, 4000, 6000, 9000, 1000], [1, 2, 3, 4, 5], [0.5, 1, 1.5, 2, 2.5])
    x1, x2 = f["dT6"].to_numpy(), f["dT8"].to_numpy()
    w6 = np.array([0, 1 / 3, 1, 1, 0])
    expected = (1 - w6) * poly(c3, x1, x2) + w6 * poly(c6, x1, x2)
    np.testing.assert_allclose(m.predict(f), expected, rtol=1e-14)


def test_predict_detail_flags_and_weights():
    m = two_speed_model()
    f = frame(
        [6000, 5000, 6000, 7000, 3000, 4000, np.nan],
        [5.0, 5.0, 10.05, 1.0, -0.05, 1.0, 1.0],
        [1.0, 1.0, 1.0, 1.0, 0.0, np.nan, 1.0],
    )
    f.index = [10, 11, 12, 13, 14, 15, 16]
    d = m.predict_detail(f)
    assert list(d.columns) == [
        "predicted_um",
        "w_3000",
        "w_6000",
        "outside_speed_range",
        "outside_temp_range",
    ]
    assert list(d.index) == list(f.index)
    # 6000 r/min, dT6=5: outside the 3000 model's range but that model has weight 0
    assert not d.loc[10, "outside_temp_range"]
    # 5000 r/min: the 3000 model has weight 1/3 and dT6=5 > 4 + 0.1
    assert d.loc[11, "outside_temp_range"]
    assert d.loc[11, "w_3000"] == pytest.approx(1 / 3)
    # within the 0.1 K tolerance
    assert not d.loc[12, "outside_temp_range"] and not d.loc[14, "outside_temp_range"]
    assert d.loc[13, "outside_speed_range"] and d.loc[13, "w_6000"] == 1.0
    assert not d.loc[10, "outside_speed_range"]
    # missing rise or speed -> NaN prediction
    assert np.isnan(d.loc[15, "predicted_um"]) and np.isnan(d.loc[16, "predicted_um"])
    np.testing.assert_array_equal(d["predicted_um"].to_numpy(), m.predict(f))


def test_speed_tolerance_only_affects_flag():
    m = two_speed_model()
    d = m.predict_detail(frame([6030, 6080, 2990], [1, 1, 1], [1, 1, 1]))
    assert list(d["outside_speed_range"]) == [False, True, False]


def test_to_dict_schema_and_model_id():
    m = two_speed_model()
    d = m.to_dict()
    assert d["schema"] == SCHEMA and d["kind"] == "rafi"
    for key in [
        "model_id",
        "created",
        "machine",
        "key_sensors",
        "variables",
        "terms",
        "inputs",
        "target",
        "reference",
        "speeds",
        "fuzzy",
        "data",
        "code_version",
        "config",
    ]:
        assert key in d
    assert d["variables"] == {"x1": "T6", "x2": "T8"}
    assert [s["speed_rpm"] for s in d["speeds"]] == [3000, 6000]
    assert d["speeds"][0]["regressor_ranges"] == {"T6": [0.0, 4.0], "T8": [0.0, 3.0]}
    assert d["fuzzy"]["membership"] == "triangular" and d["fuzzy"]["outside"] == "edge"
    content = {k: v for k, v in d.items() if k not in ("model_id", "created")}
    canonical = json.dumps(content, sort_keys=True, separators=(",", ":"))
    assert d["model_id"] == hashlib.sha256(canonical.encode()).hexdigest()
    # created does not change the id; content does
    other = two_speed_model()
    other.created = "2030-01-01T00:00:00Z"
    assert other.to_dict()["model_id"] == d["model_id"]
    other.config = {"rank": {"threshold": 0.9}}
    assert other.to_dict()["model_id"] != d["model_id"]


def test_round_trip_save_load(tmp_path):
    m = two_speed_model(data={"a.csv": "ab" * 32})
    m.rmse_um_[1] = np.nan  # NaN is written as null and read back
    path = tmp_path / "sub" / "model.json"
    save_model(m, path)
    text = path.read_text()
    assert text.endswith("\n") and "NaN" not in text
    loaded = load_model(path)
    f = frame(np.linspace(2000, 7000, 51), np.linspace(0, 5, 51), np.linspace(0, 3, 51))
    np.testing.assert_array_equal(loaded.predict(f), m.predict(f))
    pd.testing.assert_frame_equal(loaded.predict_detail(f), m.predict_detail(f))
    assert loaded.to_dict() == m.to_dict()
    assert np.isnan(loaded.rmse_um_[1])
    assert not list(path.parent.glob("*.part"))


def test_load_model_errors_name_the_file(tmp_path):
    d = two_speed_model().to_dict()
    bad = tmp_path / "old.json"
    bad.write_text(json.dumps({**d, "schema": "rafi.model/0"}))
    with pytest.raises(ValueError, match=r"old\.json.*schema is 'rafi.model/0'.*rafi.model/1"):
        load_model(bad)
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(ValueError, match=r"broken\.json.*not valid JSON"):
        load_model(broken)
    edited = tmp_path / "edited.json"
    d["speeds"][0]["coefficients"][0] = 99.0
    edited.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=r"edited\.json.*model_id"):
        load_model(edited)


def test_unfitted_and_bad_inputs():
    m = RafiModel(["T6"], ["1", "x1"])
    with pytest.raises(ValueError, match="no per-speed models"):
        m.predict(frame([3000], [1], [1]))
    m.add_speed_model(3000, [0, 1], {"T6": (0, 1)})
    with pytest.raises(ValueError, match="dT6"):
        m.predict(pd.DataFrame({"speed_rpm": [3000.0]}))
    with pytest.raises(ValueError, match="2 coefficients"):
        RafiModel(["T6"], ["1", "x1", "x1^2"]).add_speed_model(3000, [0, 1], {"T6": (0, 1)})


def test_works_without_statsmodels(tmp_path):
    m = two_speed_model()
    path = tmp_path / "model.json"
    save_model(m, path)
    f = frame([3500, 4000, 8000], [1, 2, 3], [0.5, 1, 1.5])
    code = textwrap.dedent(f"""
        import sys
        sys.modules["statsmodels"] = None     # any import of statsmodels now fails
        import numpy as np, pandas as pd
        from rafi.method.model import load_model
        m = load_model({str(path)!r})
        f = pd.DataFrame({{"speed_rpm": [3500.0, 4000.0, 8000.0], "dT6": [1.0, 2.0, 3.0],
                           "dT8": [0.5, 1.0, 1.5]}})
        print(repr(m.predict(f).tolist()))
        m.predict_detail(f)
        assert not any(k.startswith("statsmodels.") for k in sys.modules), "statsmodels loaded"
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert eval(out.stdout.strip()) == m.predict(f).tolist()
