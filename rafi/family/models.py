"""A small family of compensation models behind one interface (see ``docs/models.md``).

Every model here behaves like :class:`rafi.method.model.RafiModel`:

* the constructor takes the hyperparameters (nothing is fitted there);
* ``fit(runs_table, runs_frame)`` uses **only** the runs whose ``role`` is ``training``
  and returns ``self``; fitted attributes end in ``_``;
* ``predict(frame) -> ndarray`` and ``predict_detail(frame) -> DataFrame`` (columns
  ``predicted_um``, ``outside_speed_range``, ``outside_temp_range`` and model specific
  extras, same index as ``frame``) are evaluated with NumPy only;
* ``to_dict()`` / ``from_dict()`` write / read the JSON model artefact of
  ``docs/design.md`` (``schema: rafi.model/1``, a ``kind``, ``model_id`` = SHA-256 of the
  canonical JSON without ``model_id``/``created``).

Kinds:

``rafi``          RAFI as published: one polynomial regression per training speed on the key
                  sensors, blended with triangular fuzzy memberships. Fitted by
                  ``rafi.method.fit.fit_rafi`` when that module is installed; the artefact is
                  the one ``rafi.method.model.RafiModel`` reads.
``rafi_linear``   the same key sensors and blend, linear terms only.
``ridge_global``  one ridge regression on every usable temperature rise plus speed terms,
                  RMS-scaled inputs, penalty chosen by whole-run cross-validation on the
                  training runs.
``dynamic``       like ``ridge_global`` on first-order low-pass filtered rises (time constants
                  chosen by whole-run cross-validation), so the model can represent the lag
                  between the housing temperatures and the spindle's growth. Displacement is
                  never an input: the compensation runs without the displacement sensor.

``grey_box``      ridge on (filtered) rises plus causal first-order filtered speed powers
                  ``(n/10^4)^p`` (heat input to the unmeasured shaft/bearings/stator), filter
                  constants and penalty by whole-run CV (max-abs metric); the instantaneous
                  ``n^2`` centrifugal term only where the training runs identify it.

``load_any(dict_or_path)`` dispatches on ``kind``.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import itertools
import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from rafi import SENSORS, __version__
from rafi.family.crossval import split_runs, training_runs

SCHEMA = "rafi.model/1"
RAFI_TERMS = ["1", "x1", "x2", "x3", "x1*x2", "x1*x3", "x2*x3", "x1^2", "x2^2", "x3^2", "x1*x2*x3"]
LINEAR_TERMS = ["1", "x1", "x2", "x3"]
DEFAULT_ALPHAS = [float(f"{m}e{e}") for e in range(-8, 1) for m in (1, 2, 5)] + [10.0]  # 1-2-5 per decade
DEFAULT_TAUS_S = [0.0, 300.0, 600.0, 1200.0, 2400.0, 4800.0]
DEFAULT_REFERENCE = {"rule": "run_start", "window_s": 60.0}
SPEED_SCALE_RPM = 1000.0  # speed features are in krpm and krpm^2


# --------------------------------------------------------------------------- artefact helpers


def canonical_json(obj) -> str:
    """Canonical JSON text: sorted keys, no whitespace, ASCII, NaN forbidden (as ``rafi.method.model``)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def compute_model_id(artefact: dict) -> str:
    """SHA-256 (hex) of the canonical JSON of ``artefact`` without ``model_id`` / ``created``."""
    body = {k: v for k, v in artefact.items() if k not in ("model_id", "created")}
    return hashlib.sha256(canonical_json(body).encode("ascii")).hexdigest()


def _finish_artefact(body: dict) -> dict:
    out = dict(body)
    out["schema"] = SCHEMA
    out["created"] = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
    out["model_id"] = compute_model_id(out)
    return out


def _check_artefact(d: dict, kind: str) -> None:
    if d.get("schema") != SCHEMA:
        raise ValueError(f"not a {SCHEMA} artefact: schema={d.get('schema')!r}")
    if d.get("kind") != kind:
        raise ValueError(f"artefact kind {d.get('kind')!r}, expected {kind!r}")
    if "model_id" in d and d["model_id"] != compute_model_id(d):
        raise ValueError("model_id does not match the artefact content (edited or corrupted)")


def _floats(a) -> list:
    """NumPy array -> nested list of Python floats (exact JSON round trip)."""
    return np.asarray(a, dtype=float).tolist()


def _rise_column(sensor: str) -> str:
    return f"d{sensor}"


def _data_hashes(runs_table: pd.DataFrame, run_ids: Iterable[str]) -> dict:
    if not {"file", "sha256"} <= set(runs_table.columns):
        return {}
    sub = runs_table[runs_table["run_id"].astype(str).isin(set(map(str, run_ids)))]
    return {str(f): str(h) for f, h in zip(sub["file"], sub["sha256"]) if isinstance(f, str)}


def usable_sensors(runs_frame: pd.DataFrame, sensors: Sequence[str] = SENSORS) -> list[str]:
    """Sensors whose rise column exists, has no NaN and is not constant in ``runs_frame``."""
    out = []
    for s in sensors:
        col = _rise_column(s)
        if col not in runs_frame.columns:
            continue
        v = runs_frame[col].to_numpy(dtype=float)
        if len(v) and np.isfinite(v).all() and np.ptp(v) > 1e-9:
            out.append(s)
    return out


class PublishedRafi:
    """Kind ``rafi``: RAFI as published, fitted by :func:`rafi.method.fit.fit_rafi`.

    After ``fit`` the attribute ``model_`` is the :class:`rafi.method.model.RafiModel`;
    ``predict``/``predict_detail``/``to_dict`` delegate to it, so the family evaluates the
    published method with exactly the pipeline's own code (fuzzy blend, out-of-range flags).
    """

    kind = "rafi"
    default_terms = RAFI_TERMS

    def __init__(
        self,
        key_sensors: Sequence[str] = ("T6", "T8", "T9"),
        terms: Sequence[str] | None = None,
        *,
        reference: dict | None = None,
        machine: str | None = None,
        hac_maxlags: int = 60,
    ):
        self.key_sensors = list(key_sensors)
        self.terms = list(self.default_terms if terms is None else terms)
        self.reference = dict(reference or DEFAULT_REFERENCE)
        self.machine = machine
        self.hac_maxlags = int(hac_maxlags)

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        from rafi.method.fit import fit_rafi

        table, frame = training_runs(runs_table, runs_frame)
        # the artefact needs the coefficients only: the diagnostics belong to rule fit
        res = fit_rafi(
            table,
            frame,
            key_sensors=self.key_sensors,
            terms=self.terms,
            hac_maxlags=self.hac_maxlags,
            reference=self.reference,
            machine=self.machine,
            diagnostics=False,
        )
        self.model_ = res.model
        self.train_runs_ = sorted(map(str, table["run_id"]))
        return self

    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        return self.model_.predict_detail(frame)

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        return np.asarray(self.model_.predict(frame), dtype=float)

    def to_dict(self) -> dict:
        d = self.model_.to_dict()
        if self.kind != d.get("kind"):
            d["kind"] = self.kind
            d["model_id"] = compute_model_id(d)
        return d

    @classmethod
    def from_dict(cls, d: dict):
        from rafi.method.model import RafiModel

        _check_artefact(d, cls.kind)
        inner = RafiModel.from_dict({**d, "kind": "rafi"}, verify_id=False)
        m = cls(inner.key_sensors, inner.terms, reference=inner.reference, machine=inner.machine)
        m.model_ = inner
        m.train_runs_ = sorted({r for sp in d["speeds"] for r in sp.get("train_runs", [])})
        return m


class RafiLinear(PublishedRafi):
    """Kind ``rafi_linear``: RAFI's key sensors and fuzzy blend, linear terms ``1, x1, x2, x3``.

    The artefact is RAFI's layout with ``kind: rafi_linear`` (and its own ``model_id``).
    """

    kind = "rafi_linear"
    default_terms = LINEAR_TERMS


# --------------------------------------------------------------------------- filters and features


def lowpass_runs(
    values: np.ndarray,
    t_s: np.ndarray,
    run_codes: np.ndarray,
    taus_s: Sequence[float],
    initial: str = "settled",
) -> np.ndarray:
    """Causal first-order low-pass of every column of ``values`` for every ``tau``.

    ``y[k] = y[k-1] + (1 - exp(-(t[k] - t[k-1]) / tau)) * (x[k] - y[k-1])``, evaluated sample
    by sample inside each run (rows must be sorted by run then time). Initial condition: the
    filter starts *settled* on the run's first sample, ``y[0] = x[0]``; for a run referenced
    at its own start (``run_start``) that first rise is ~0, i.e. the filter starts from the
    reference state. ``tau = 0`` passes the input through. Returns
    ``(n, n_columns * len(taus))`` ordered tau-major. A NaN input holds the filter state.
    ``initial="zero"``: the state before the run's first sample is 0 (a cold start from rest:
    the first sample is then ``g0 * x[0]`` with ``g0`` the gain of one nominal sample step).
    """
    if initial not in ("settled", "zero"):
        raise ValueError(f"initial={initial!r}: use settled or zero")
    x = np.asarray(values, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    n, p = x.shape
    taus = np.asarray(list(taus_s), dtype=float)
    if len(taus) and (taus <= 0).all():
        return np.tile(x, (1, len(taus)))
    if (taus <= 0).any():  # pass-through columns need no loop
        parts = [x if tau <= 0 else lowpass_runs(x, t_s, run_codes, [tau], initial) for tau in taus]
        return np.column_stack(parts)
    out = np.empty((n, p * len(taus)))
    xx = np.tile(x, (1, len(taus)))
    tau_col = np.repeat(taus, p)
    dt = np.diff(np.asarray(t_s, dtype=float), prepend=np.nan)
    new_run = np.ones(n, dtype=bool)
    new_run[1:] = run_codes[1:] != run_codes[:-1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        gain = np.where(
            tau_col[None, :] > 0, -np.expm1(-np.clip(dt, 0, None)[:, None] / tau_col[None, :]), 1.0
        )
    tt = np.asarray(t_s, dtype=float)
    step = float(np.median(np.diff(tt))) if n > 1 and np.isfinite(np.diff(tt)).any() else 1.0
    gain0 = -np.expm1(-max(step, 0.0) / tau_col)
    starts = np.flatnonzero(new_run)
    ends = np.append(starts[1:], n)
    for a, b in zip(starts, ends):
        seg = xx[a:b]
        dts = dt[a + 1 : b]
        if np.isfinite(seg).all() and (dts.size == 0 or np.allclose(dts, dts[0], rtol=1e-9, atol=0)):
            # regular grid, no gaps: the recursion is a first-order IIR filter per column
            out[a:b] = _lowpass_regular(seg, gain[a + 1] if b - a > 1 else gain0, gain0, initial)
            continue
        y = np.zeros(p * len(taus))
        for k in range(a, b):
            xk = xx[k]
            if k == a:
                y = np.where(np.isfinite(xk), gain0 * xk if initial == "zero" else xk, 0.0)
            else:
                y = np.where(np.isfinite(xk), y + gain[k] * (xk - y), y)
            out[k] = y
    return out


def _lowpass_regular(x: np.ndarray, gain: np.ndarray, gain0: np.ndarray, initial: str) -> np.ndarray:
    """:func:`lowpass_runs` on one run sampled on a regular grid with no missing value:
    ``y[k] = (1 - g) y[k-1] + g x[k]`` per column (same numbers as the sample loop, to
    rounding), computed by :func:`first_order_recursion`."""
    g = np.asarray(gain, dtype=float)
    y0 = np.asarray(gain0, dtype=float) * x[0] if initial == "zero" else x[0].astype(float)
    out = np.empty_like(x, dtype=float)
    out[0] = y0
    if len(x) > 1:
        out[1:] = first_order_recursion(x[1:], 1.0 - g, g, y0)
    return out


#: Largest growth of the scaling factor ``a**-k`` inside one block of :func:`first_order_recursion`.
_MAX_LOG_SCALE = 600.0


def first_order_recursion(x: np.ndarray, a: np.ndarray, b: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """``y[k] = a y[k-1] + b x[k]`` down the rows of ``x``, per column, with ``y[-1] = y0``.

    Vectorised without a sample loop (and without importing scipy.signal, whose import alone
    costs about a second per job): inside a block of rows,
    ``y[k] = a^k (y0 + sum_{j<=k} b a^-j x[j])``, a cumulative sum. Blocks are short enough
    that ``a^-k`` stays below ``exp(600)``; the rounding error is then of the order of
    ``eps * max|x| * b / (1 - a)``, as for the recursion itself.
    """
    x = np.asarray(x, dtype=float)
    a = np.broadcast_to(np.asarray(a, dtype=float), x.shape[1:]).copy()
    b = np.broadcast_to(np.asarray(b, dtype=float), x.shape[1:])
    y_prev = np.broadcast_to(np.asarray(y0, dtype=float), x.shape[1:]).copy()
    out = np.empty_like(x)
    through = a <= 1e-300  # no memory: y = b x
    a[through] = 0.5  # any value: those columns are overwritten below
    log_a = np.log(a)
    block = max(1, int(_MAX_LOG_SCALE / max(float(np.max(-log_a)), 1e-300)))
    for start in range(0, len(x), block):
        seg = x[start : start + block]
        k = np.arange(1, len(seg) + 1, dtype=float).reshape((-1,) + (1,) * (x.ndim - 1))
        scale = np.exp(-k * log_a)  # a^-k
        y = (y_prev + np.cumsum(seg * (b * scale), axis=0)) / scale
        out[start : start + len(seg)] = y
        y_prev = y[-1]
    if through.any():
        out[:, through] = x[:, through] * b[through]
    return out


def _run_order(frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Positions that sort ``frame`` by (run, t_s) and the run code per sorted row."""
    if "run_id" in frame.columns:
        runs = pd.factorize(frame["run_id"].astype(str))[0]
    else:
        runs = np.zeros(len(frame), dtype=int)
    t = frame["t_s"].to_numpy(dtype=float) if "t_s" in frame.columns else np.arange(len(frame), dtype=float)
    order = np.lexsort((t, runs))
    return order, runs[order]


def reference_speed(frame: pd.DataFrame, rule: str, window_s: float) -> np.ndarray:
    """Speed of each row's reference state (r/min), the origin of the speed features.

    ``run_start``: median speed over the first ``window_s`` of the row's run (the same window
    the rises were referenced to); ``zero``: 0 r/min (a log that starts with the spindle at rest).
    """
    if rule not in ("run_start", "zero"):
        raise ValueError(f"speed reference rule {rule!r}: use run_start, zero or auto")
    n = len(frame)
    if rule == "zero" or n == 0:
        return np.zeros(n)
    codes = pd.factorize(frame["run_id"])[0] if "run_id" in frame.columns else np.zeros(n, dtype=int)
    t = frame["t_s"].to_numpy(dtype=float) if "t_s" in frame.columns else np.arange(n, dtype=float)
    speed = frame["speed_rpm"].to_numpy(dtype=float)
    out = np.empty(n)
    for c in np.unique(codes):
        rows = np.flatnonzero(codes == c)
        tr = t[rows]
        out[rows] = np.median(speed[rows[tr <= tr.min() + window_s]])
    return out


#: A term relative to the reference speed needs this many training runs that show a speed change.
MIN_IDENTIFYING_RUNS = 2


def speed_change_evidence(
    frame: pd.DataFrame, n0: np.ndarray, tolerance_rpm: float, window_s: float
) -> list[str]:
    """Training runs that show a speed change relative to their reference speed ``n0``.

    A run counts when it has at least ``window_s`` (the reference window; at least one
    samples) of samples within ``tolerance_rpm`` of its reference speed **and** at least as
    long more than ``tolerance_rpm`` away from it: a step such as the spindle start after a
    rest. Only such a step separates an instantaneous speed term (the centrifugal draw-in,
    ``n^2 - n0^2``) from the reference and from the slow thermal terms. A run referenced while
    already spinning shows only speed jitter (never > tolerance); a run without any sample at
    its reference speed (e.g. ``n0 = 0`` for a log segment that starts spinning) shows no
    step either.
    """
    n = frame["speed_rpm"].to_numpy(dtype=float)
    if not len(n):
        return []
    runs = frame["run_id"].astype(str).to_numpy() if "run_id" in frame.columns else np.full(len(n), "run")
    t = frame["t_s"].to_numpy(dtype=float) if "t_s" in frame.columns else np.arange(len(n), dtype=float)
    away = np.abs(n - np.asarray(n0, dtype=float)) > float(tolerance_rpm)
    at = np.abs(n - np.asarray(n0, dtype=float)) <= float(tolerance_rpm)
    out = []
    for r in pd.unique(runs):
        i = np.flatnonzero(runs == r)
        dt = np.diff(np.sort(t[i]))
        period = float(np.median(dt[dt > 0])) if (dt > 0).any() else 1.0
        need = max(1, int(math.ceil(float(window_s) / period - 1e-9)))
        if at[i].sum() >= need and away[i].sum() >= need:
            out.append(str(r))
    return out


class _RidgeBase:
    """Shared machinery of ``ridge_global`` and ``dynamic``: features, scaling, ridge, CV."""

    kind = "ridge_base"

    def __init__(
        self,
        *,
        sensors: Sequence[str] | None = None,
        alphas: Sequence[float] = DEFAULT_ALPHAS,
        cv: str = "leave_one_run_out",
        cv_metric: str = "rmse",
        speed_terms: bool = True,
        speed_gain: bool | str = "cv",
        speed_reference: str = "auto",
        reference: dict | None = None,
        machine: str | None = None,
        speed_tolerance_rpm: float = 50.0,
    ):
        self.sensors = None if sensors is None else list(sensors)
        self.speed_tolerance_rpm = float(speed_tolerance_rpm)
        self.alphas = [float(a) for a in alphas]
        self.cv = cv
        self.cv_metric = cv_metric
        self.speed_terms = bool(speed_terms)
        if speed_gain not in (True, False, "cv"):
            raise ValueError(f"speed_gain={speed_gain!r}: use true, false or cv")
        self.speed_gain = speed_gain
        self.speed_reference = speed_reference
        self.reference = dict(reference or DEFAULT_REFERENCE)
        self.machine = machine

    # -- features
    def _features(self, frame: pd.DataFrame, sensors: Sequence[str], taus: Sequence[float]):
        """Feature matrix in ``frame`` row order and the feature names."""
        order, codes = _run_order(frame)
        x = frame[[_rise_column(s) for s in sensors]].to_numpy(dtype=float)[order]
        t = (
            frame["t_s"].to_numpy(dtype=float)[order]
            if "t_s" in frame.columns
            else np.arange(len(frame), dtype=float)
        )
        filtered = lowpass_runs(x, t, codes, taus)
        n = frame["speed_rpm"].to_numpy(dtype=float)[order] / SPEED_SCALE_RPM
        p = len(sensors)
        parts, names = [], []
        for i, tau in enumerate(taus):  # one block per tau: rises (and rises x speed)
            block = filtered[:, i * p : (i + 1) * p]
            parts.append(block)
            names += [f"{_rise_column(s)}@{tau:g}s" for s in sensors]
            if getattr(self, "speed_gain_", self.speed_gain) is True:
                parts.append(block * n[:, None])
                names += [f"{_rise_column(s)}@{tau:g}s*n_krpm" for s in sensors]
        if getattr(self, "speed_terms_", self.speed_terms):
            n0 = (
                reference_speed(frame, self._speed_rule(), float(self.reference.get("window_s", 60)))[order]
                / SPEED_SCALE_RPM
            )
            parts.append(np.column_stack([n - n0, n**2 - n0**2]))
            names += ["n_krpm", "n2_krpm2"]
        f_sorted = np.column_stack(parts)
        f = np.empty_like(f_sorted)
        f[order] = f_sorted
        return f, names

    def _identifiable(self, frame: pd.DataFrame) -> bool:
        """Speed terms relative to the reference speed are used only if the training runs identify
        them: at least ``MIN_IDENTIFYING_RUNS`` runs with a step from their reference speed
        (:func:`speed_change_evidence`). Sets ``identifying_runs_``."""
        window = float(self.reference.get("window_s", 60))
        n0 = reference_speed(frame, self._speed_rule(), window)
        self.identifying_runs_ = speed_change_evidence(frame, n0, self.speed_tolerance_rpm, window)
        return len(self.identifying_runs_) >= MIN_IDENTIFYING_RUNS

    def _speed_rule(self) -> str:
        """``auto``: the run's start window under ``reference.rule: run_start``, else 0 r/min."""
        if self.speed_reference != "auto":
            return self.speed_reference
        return "run_start" if self.reference.get("rule", "run_start") == "run_start" else "zero"

    @staticmethod
    def _scale(x: np.ndarray) -> np.ndarray:
        s = np.sqrt(np.mean(x**2, axis=0))
        return np.where(s > 1e-12, s, 1.0)

    @staticmethod
    def _ridge_gram(g: np.ndarray, c: np.ndarray, n: int, alphas: Sequence[float]) -> np.ndarray:
        """Coefficients (p x n_alphas) of ``min |y - Xb|^2/n + alpha |b|^2`` from ``X'X``, ``X'y``.

        ``X`` is already scaled; ``(X'X + n alpha I) b = X'y`` is solved through the
        eigendecomposition of ``X'X`` for all alphas at once.
        """
        w, v = np.linalg.eigh(g)
        w = np.clip(w, 0.0, None)
        vc = v.T @ c
        return v @ (vc[:, None] / (w[:, None] + n * np.asarray(alphas, dtype=float)[None, :]))

    def _cv_setup(self, feats: np.ndarray, y: np.ndarray, run_ids: np.ndarray, table: pd.DataFrame) -> dict:
        """Per fold, once per fit: the training runs' Gram matrix ``X'X``, ``X'y`` and sample
        count (sums of per-run parts), the test runs' rows of ``X`` and ``y`` (for ``max_abs``)
        and their ``X'X``, ``X'y``, ``y'y`` (for ``rmse``)."""
        rows = {r: np.flatnonzero(run_ids == r) for r in np.unique(run_ids)}
        gram = {r: (feats[i].T @ feats[i], feats[i].T @ y[i], len(i)) for r, i in rows.items()}
        folds = []
        for train_ids, test_ids in split_runs(table, self.cv):
            train = [gram[r] for r in train_ids if r in gram]
            te = [rows[r] for r in test_ids if r in rows]
            if not train or not te:
                continue
            test = [gram[r] for r in test_ids if r in gram]
            te = np.concatenate(te)
            folds.append(
                {
                    "g": sum(t[0] for t in train),
                    "c": sum(t[1] for t in train),
                    "n": sum(t[2] for t in train),
                    "x_test": feats[te],
                    "y_test": y[te],
                    "g_test": sum(t[0] for t in test),
                    "c_test": sum(t[1] for t in test),
                    "yy_test": float(y[te] @ y[te]),
                }
            )
        return {"folds": folds}

    def _cv_scores(self, cvd: dict, cols: np.ndarray) -> np.ndarray:
        """CV score per alpha (lower is better) of the feature columns ``cols``, whole-run folds:
        ``rmse`` over every held-out sample, or ``max_abs``, the mean over folds of the held-out
        runs' max |residual|."""
        if self.cv_metric not in ("rmse", "max_abs"):
            raise ValueError(f"cv_metric {self.cv_metric!r}: use rmse or max_abs")
        sq = np.zeros(len(self.alphas))
        fold_max, count = [], 0
        ix = np.ix_(cols, cols)
        for fold in cvd["folds"]:
            g, c, n = fold["g"][ix], fold["c"][cols], fold["n"]
            if n == 0:
                continue
            sc = np.sqrt(np.diag(g) / n)
            sc = np.where(sc > 1e-12, sc, 1.0)
            b = self._ridge_gram(g / np.outer(sc, sc), c / sc, n, self.alphas) / sc[:, None]
            if self.cv_metric == "rmse":
                # |y - Xb|^2 = y'y - 2 b'X'y + b'X'Xb from the test fold's Gram matrix: no pass
                # over the test samples per candidate
                sq += (
                    fold["yy_test"]
                    - 2.0 * (fold["c_test"][cols] @ b)
                    + np.einsum("ia,ij,ja->a", b, fold["g_test"][ix], b)
                )
                count += len(fold["y_test"])
            else:
                res = fold["y_test"][:, None] - fold["x_test"][:, cols] @ b
                fold_max.append(np.max(np.abs(res), axis=0))
        if self.cv_metric == "rmse":
            return np.sqrt(np.clip(sq, 0.0, None) / count) if count else np.zeros(len(self.alphas))
        return np.mean(fold_max, axis=0) if fold_max else np.zeros(len(self.alphas))

    def _prepare(self, runs_table, runs_frame):
        table, frame = training_runs(runs_table, runs_frame)
        frame = frame[np.isfinite(frame["dz_um"].to_numpy(dtype=float))]
        sensors = self.sensors if self.sensors is not None else usable_sensors(frame)
        if not sensors:
            raise ValueError("no usable temperature sensor in the training runs")
        return table, frame, sensors

    def _fit_final(self, table, frame, sensors, taus, alpha, cv_table):
        feats, names = self._features(frame, sensors, taus)
        y = frame["dz_um"].to_numpy(dtype=float)
        sc = self._scale(feats)
        b = self._ridge_gram((feats / sc).T @ (feats / sc), (feats / sc).T @ y, len(y), [alpha])[:, 0]
        self.sensors_ = list(sensors)
        self.taus_ = [float(t) for t in taus]
        self.alpha_ = float(alpha)
        self.feature_names_ = names
        self.scale_ = sc
        self.coef_ = b / sc
        self.train_runs_ = sorted(map(str, table["run_id"]))
        x = frame[[_rise_column(s) for s in sensors]].to_numpy(dtype=float)
        self.regressor_ranges_ = {
            s: [float(x[:, i].min()), float(x[:, i].max())] for i, s in enumerate(sensors)
        }
        self.speed_range_rpm_ = [float(table["speed_rpm"].min()), float(table["speed_rpm"].max())]
        self.rmse_um_ = float(np.sqrt(np.mean((y - feats @ self.coef_) ** 2)))
        self.n_ = int(len(y))
        self.cv_table_ = cv_table
        self.data_ = _data_hashes(table, self.train_runs_)
        return self

    # -- evaluation (NumPy only)
    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        feats, _ = self._features(frame, self.sensors_, self.taus_)
        pred = feats @ self.coef_
        x = frame[[_rise_column(s) for s in self.sensors_]].to_numpy(dtype=float)
        lo = np.array([self.regressor_ranges_[s][0] for s in self.sensors_])
        hi = np.array([self.regressor_ranges_[s][1] for s in self.sensors_])
        n = frame["speed_rpm"].to_numpy(dtype=float)
        return pd.DataFrame(
            {
                "predicted_um": pred,
                "outside_speed_range": (n < self.speed_range_rpm_[0]) | (n > self.speed_range_rpm_[1]),
                "outside_temp_range": ((x < lo) | (x > hi)).any(axis=1),
            },
            index=frame.index,
        )

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        return self.predict_detail(frame)["predicted_um"].to_numpy()

    # -- artefact
    def _hyper(self) -> dict:
        return {
            "sensors": self.sensors,
            "alphas": self.alphas,
            "cv": self.cv,
            "cv_metric": self.cv_metric,
            "speed_terms": self.speed_terms,
            "speed_gain": self.speed_gain,
            "speed_reference": self.speed_reference,
            "speed_tolerance_rpm": self.speed_tolerance_rpm,
        }

    def to_dict(self) -> dict:
        body = {
            "kind": self.kind,
            "machine": self.machine,
            "key_sensors": self.sensors_,
            "inputs": self._inputs_text(),
            "target": "displacement change dz (um) from the reference state",
            "reference": self.reference,
            "speed_reference": {
                "rule": self._speed_rule(),
                "window_s": float(self.reference.get("window_s", 60)),
            },
            "hyperparameters": self._hyper(),
            "selected": {
                "alpha": self.alpha_,
                "taus_s": self.taus_,
                "speed_gain": self.speed_gain_,
                "speed_terms": bool(getattr(self, "speed_terms_", self.speed_terms)),
                "identifying_runs": list(getattr(self, "identifying_runs_", [])),
            },
            "cv": self.cv_table_,
            "features": self.feature_names_,
            "coefficients": _floats(self.coef_),
            "scale": _floats(self.scale_),
            "filter": {
                "type": "first_order_lowpass",
                "initial_condition": "settled on the run's first sample",
                "update": "y += (1 - exp(-dt/tau)) * (x - y)",
            },
            "regressor_ranges": self.regressor_ranges_,
            "speed_range_rpm": self.speed_range_rpm_,
            "train_runs": self.train_runs_,
            "rmse_um": self.rmse_um_,
            "n": self.n_,
            "data": self.data_,
            "code_version": f"rafi {__version__}",
        }
        return _finish_artefact(body)

    @classmethod
    def from_dict(cls, d: dict):
        _check_artefact(d, cls.kind)
        h = dict(d.get("hyperparameters", {}))
        m = cls(reference=d.get("reference"), machine=d.get("machine"), **h)
        m.sensors_ = list(d["key_sensors"])
        m.taus_ = [float(t) for t in d["selected"]["taus_s"]]
        m.alpha_ = float(d["selected"]["alpha"])
        m.speed_gain_ = bool(d["selected"].get("speed_gain", False))
        m.speed_terms_ = bool(d["selected"].get("speed_terms", m.speed_terms))
        m.identifying_runs_ = list(d["selected"].get("identifying_runs", []))
        m.feature_names_ = list(d["features"])
        m.coef_ = np.asarray(d["coefficients"], dtype=float)
        m.scale_ = np.asarray(d["scale"], dtype=float)
        m.regressor_ranges_ = d["regressor_ranges"]
        m.speed_range_rpm_ = d["speed_range_rpm"]
        m.train_runs_ = d["train_runs"]
        m.rmse_um_ = d.get("rmse_um")
        m.n_ = d.get("n")
        m.cv_table_ = d.get("cv", [])
        m.data_ = d.get("data", {})
        return m


class RidgeGlobal(_RidgeBase):
    """Kind ``ridge_global``: one ridge model on all usable rises + speed terms.

    ``dz = sum_i (b_i + g_i n) dT_i + c1 (n - n0) + c2 (n^2 - n0^2)`` with ``n`` in krpm and
    ``n0`` the speed of the reference state. The speed-dependent gains ``g_i n`` (RAFI's
    per-speed coefficients, as one smooth linear law) are used if ``speed_gain`` is true, not
    used if false, and kept or dropped by CV if ``"cv"``. No intercept (at the reference state
    every input is 0, so the compensation is 0). Inputs are scaled by their RMS over the
    training runs; ``alpha`` (and ``speed_gain: cv``) are chosen by whole-run CV (``cv``) on
    the training runs only.
    """

    kind = "ridge_global"
    _taus_grid = (0.0,)
    _max_taus = 1

    def _inputs_text(self) -> str:
        return "temperature rises dT (K) of all usable sensors; speed (krpm) relative to the reference state"

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        self.__dict__.pop("speed_gain_", None)  # a refit starts from the hyperparameters
        table, frame, sensors = self._prepare(runs_table, runs_frame)
        # speed terms only where the training runs identify them (same rule as grey_box)
        self.speed_terms_ = self.speed_terms and self._identifiable(frame)
        taus_grid = [float(t) for t in getattr(self, "taus_s", self._taus_grid)]
        max_taus = int(getattr(self, "max_taus", self._max_taus))
        gains = [False, True] if self.speed_gain == "cv" else [bool(self.speed_gain)]
        y = frame["dz_um"].to_numpy(dtype=float)
        run_ids = frame["run_id"].astype(str).to_numpy()
        saved = self.speed_gain
        self.speed_gain = max(gains)  # compute the superset of the columns once
        all_feats, _ = self._features(frame, sensors, taus_grid)
        self.speed_gain = saved
        p = len(sensors)
        width = p * (2 if max(gains) else 1)
        speed = np.arange(len(taus_grid) * width, all_feats.shape[1])
        cvd = self._cv_setup(all_feats, y, run_ids, table)
        cv_table, best = [], (math.inf, None, None, None)
        for gain in gains:
            for k in range(1, max(1, max_taus) + 1):
                for subset in itertools.combinations(range(len(taus_grid)), k):
                    cols = [np.arange(i * width, i * width + (width if gain else p)) for i in subset]
                    cols = np.concatenate(cols + [speed])
                    scores = self._cv_scores(cvd, cols)
                    taus = [taus_grid[i] for i in subset]
                    for a, sc in zip(self.alphas, scores):
                        cv_table.append(
                            {"taus_s": taus, "speed_gain": gain, "alpha": a, "score_um": float(sc)}
                        )
                        if sc < best[0] - 1e-12:
                            best = (float(sc), taus, a, gain)
        _, taus, alpha, gain = best
        self.speed_gain_ = bool(gain)
        return self._fit_final(table, frame, sensors, taus, alpha, cv_table)


class DynamicRidge(RidgeGlobal):
    """Kind ``dynamic``: ridge on low-pass filtered rises (lag model) + speed terms.

    Features: ``L_tau(dT_i)`` (and ``L_tau(dT_i) * n`` with ``speed_gain``) for every usable
    sensor ``i`` and every ``tau`` of the chosen set, where ``L_tau`` is the causal
    first-order filter of :func:`lowpass_runs` (``tau = 0`` is the unfiltered rise), plus the
    speed terms of :class:`RidgeGlobal`. The set of time constants (every subset of
    ``taus_s`` with at most ``max_taus`` members), ``alpha`` (and ``speed_gain: cv``) are
    chosen jointly by whole-run CV on the training runs.
    """

    kind = "dynamic"

    def __init__(self, *, taus_s: Sequence[float] = DEFAULT_TAUS_S, max_taus: int = 2, **kw):
        super().__init__(**kw)
        self.taus_s = [float(t) for t in taus_s]
        self.max_taus = int(max_taus)

    def _inputs_text(self) -> str:
        return (
            "first-order low-pass filtered temperature rises dT (K) of all usable sensors; "
            "speed (krpm) relative to the reference state; displacement is not an input"
        )

    def _hyper(self) -> dict:
        h = super()._hyper()
        h.update({"taus_s": self.taus_s, "max_taus": self.max_taus})
        return h


DEFAULT_SPEED_TAUS_S = [60.0, 180.0, 600.0, 2400.0]
DEFAULT_SPEED_POWERS = [0.0, 1.0, 5.0 / 3.0, 2.0]  # 0: "running" (magnetising loss ~ constant)
DEFAULT_GREY_TAUS_S = [0.0, 120.0, 600.0]
DEFAULT_CENTRIFUGAL_LAGS_S = [0.0, 5.0, 10.0, 20.0]  # first-order lag of the draw-in n^2 term (by CV)
SPEED_POWER_SCALE_RPM = 10000.0  # speed-power features use (n / 10000 r/min)^p


def _reference_median(
    values: np.ndarray, t_s: np.ndarray, run_codes: np.ndarray, window_s: float
) -> np.ndarray:
    """Per row, the median of ``values`` over the first ``window_s`` of the row's run (sorted rows)."""
    out = np.empty_like(values)
    starts = np.flatnonzero(np.r_[True, run_codes[1:] != run_codes[:-1]])
    ends = np.r_[starts[1:], len(run_codes)]
    for a, b in zip(starts, ends):
        w = a + np.flatnonzero(t_s[a:b] <= t_s[a] + window_s)
        out[a:b] = np.median(values[w], axis=0) if len(w) else 0.0
    return out


class GreyBox(RidgeGlobal):
    """Kind ``grey_box``: ridge on filtered rises + filtered speed-power (heat input) terms.

    ``dz = sum_{tau in T} sum_i b_{i,tau} L_tau(dT_i) + sum_{tau in S} sum_p c_{p,tau} L_tau((n/10^4)^p)
    [+ d (n^2 - n0^2)]`` with ``L_tau`` the causal first-order filter of :func:`lowpass_runs`.
    The speed powers (``speed_powers``, default 0, 1, 5/3, 2: spindle running (magnetising
    loss, ~constant; ``n^0`` is 0 at rest), motor/windage, bearing friction,
    rotor losses) stand for the heat input to the *unmeasured* fast parts (shaft, bearings,
    stator); their filters represent the lag with which those parts follow a speed change.

    Initial condition of the speed-power filters: ``reference.rule: run_start`` (cold start):
    the state before the first sample is zero (machine at rest), and the feature is then
    referenced like ``dz`` (minus its median over the reference window); ``log_start``: the
    filter starts settled on the first sample's speed (the run's history is not in the frame;
    exact when the speed was steady for a few tau before the run started).

    The instantaneous centrifugal term ``n^2 - n0^2`` (krpm^2) is used only if it is
    identifiable: at least ``MIN_IDENTIFYING_RUNS`` training runs show a step from their
    reference speed (:func:`speed_change_evidence`: at least a reference window of samples
    within ``speed_tolerance_rpm`` of the reference speed and as many beyond it), e.g. a cold
    start logged from rest. Constant-speed runs referenced while already spinning do not
    identify it (the reference absorbs the draw-in), so it is left out rather than fitted to
    speed jitter. ``ridge_global`` and ``dynamic`` apply the same rule to their speed terms.

    Chosen jointly by whole-run CV on the training runs only (``cv_metric``, default
    ``max_abs``): the set of rise filter constants (subsets of ``taus_s``, at most
    ``max_taus``), the set of speed filter constants (subsets of ``speed_taus_s``, at most
    ``max_speed_taus``) and ``alpha``.
    """

    kind = "grey_box"

    def __init__(
        self,
        *,
        taus_s: Sequence[float] = DEFAULT_GREY_TAUS_S,
        max_taus: int = 1,
        speed_taus_s: Sequence[float] = DEFAULT_SPEED_TAUS_S,
        max_speed_taus: int = 2,
        speed_powers: Sequence[float] = DEFAULT_SPEED_POWERS,
        speed_tolerance_rpm: float = 50.0,
        cv_metric: str = "max_abs",
        speed_gain: bool | str = False,
        filter_search: str = "all",
        centrifugal_lags_s: Sequence[float] = DEFAULT_CENTRIFUGAL_LAGS_S,
        **kw,
    ):
        super().__init__(
            cv_metric=cv_metric, speed_gain=speed_gain, speed_tolerance_rpm=speed_tolerance_rpm, **kw
        )
        self.taus_s = [float(t) for t in taus_s]
        self.max_taus = int(max_taus)
        self.speed_taus_s = [float(t) for t in speed_taus_s]
        self.max_speed_taus = int(max_speed_taus)
        self.speed_powers = [float(p) for p in speed_powers]
        if filter_search not in ("all", "subsets"):
            raise ValueError(f"filter_search={filter_search!r}: use all or subsets")
        self.filter_search = filter_search
        self.centrifugal_lags_s = [float(t) for t in centrifugal_lags_s] or [0.0]
        if min(self.centrifugal_lags_s) < 0:
            raise ValueError(f"centrifugal_lags_s={centrifugal_lags_s!r}: lags must be >= 0")

    def _inputs_text(self) -> str:
        return (
            "first-order low-pass filtered temperature rises dT (K) of all usable sensors; first-order "
            "low-pass filtered speed powers (n/10000 r/min)^p; displacement is not an input"
        )

    def _hyper(self) -> dict:
        h = super()._hyper()
        h.update(
            {
                "taus_s": self.taus_s,
                "max_taus": self.max_taus,
                "speed_taus_s": self.speed_taus_s,
                "max_speed_taus": self.max_speed_taus,
                "speed_powers": self.speed_powers,
                "filter_search": self.filter_search,
                "centrifugal_lags_s": self.centrifugal_lags_s,
            }
        )
        return h

    def _features(
        self,
        frame: pd.DataFrame,
        sensors: Sequence[str],
        taus: Sequence[float],
        centrifugal_lags: Sequence[float] | None = None,
    ):
        """As :meth:`_RidgeBase._features`; the ``n^2`` draw-in column is given once per lag of
        ``centrifugal_lags`` (while :meth:`fit` searches), by default for the chosen lag only."""
        order, codes = _run_order(frame)
        x = frame[[_rise_column(s) for s in sensors]].to_numpy(dtype=float)[order]
        t = (
            frame["t_s"].to_numpy(dtype=float)[order]
            if "t_s" in frame.columns
            else np.arange(len(frame), dtype=float)
        )
        rpm = frame["speed_rpm"].to_numpy(dtype=float)[order]
        parts, names = [lowpass_runs(x, t, codes, taus)], []
        for tau in taus:
            names += [f"{_rise_column(s)}@{tau:g}s" for s in sensors]
        speed_taus = list(getattr(self, "speed_taus_", []))
        if speed_taus:
            r = np.abs(rpm) / SPEED_POWER_SCALE_RPM
            pw = np.column_stack(
                [
                    (np.abs(rpm) > self.speed_tolerance_rpm).astype(float) if p == 0 else r**p
                    for p in self.speed_powers
                ]
            )  # p = 0: running (1) / at rest (0)
            cold = self.reference.get("rule", "run_start") == "run_start"
            f = lowpass_runs(pw, t, codes, speed_taus, initial="zero" if cold else "settled")
            if cold:
                f = f - _reference_median(f, t, codes, float(self.reference.get("window_s", 60)))
            parts.append(f)
            for tau in speed_taus:
                names += [f"L{tau:g}s(n^{p:.4g})" for p in self.speed_powers]
        if getattr(self, "instantaneous_", False):
            n0 = reference_speed(frame, self._speed_rule(), float(self.reference.get("window_s", 60)))[order]
            n2 = ((rpm / SPEED_SCALE_RPM) ** 2 - (n0 / SPEED_SCALE_RPM) ** 2)[:, None]
            lags = (
                [float(getattr(self, "centrifugal_lag_s_", 0.0))]
                if centrifugal_lags is None
                else list(centrifugal_lags)
            )
            parts.append(lowpass_runs(n2, t, codes, lags))
            names += ["n2_krpm2" if lag <= 0 else f"L{lag:g}s(n2_krpm2)" for lag in lags]
        f_sorted = np.column_stack(parts)
        out = np.empty_like(f_sorted)
        out[order] = f_sorted
        return out, names

    def _filter_sets(self) -> tuple[list, list]:
        """Candidate (rise tau indices, speed tau indices) sets. ``all``: every rise filter at
        once, with every heat-input filter at once or with none (the ridge penalty sorts out
        redundant constants; CV decides whether the heat-input terms help at all, e.g. they do
        not for runs referenced while already spinning). ``subsets``: every subset of at most
        ``max_taus`` / ``max_speed_taus`` of them."""
        if self.filter_search == "all":
            return [tuple(range(len(self.taus_s)))], [(), tuple(range(len(self.speed_taus_s)))]
        rise_sets = [
            c
            for k in range(1, max(1, self.max_taus) + 1)
            for c in itertools.combinations(range(len(self.taus_s)), k)
        ]
        speed_sets = [
            c
            for k in range(0, self.max_speed_taus + 1)
            for c in itertools.combinations(range(len(self.speed_taus_s)), k)
        ]
        return rise_sets, speed_sets

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        table, frame, sensors = self._prepare(runs_table, runs_frame)
        self.speed_gain_ = False
        self.instantaneous_ = self.speed_terms and self._identifiable(frame)
        self.speed_terms_ = self.instantaneous_  # grey_box's only reference-speed term is n^2 - n0^2
        y = frame["dz_um"].to_numpy(dtype=float)
        run_ids = frame["run_id"].astype(str).to_numpy()
        self.speed_taus_ = list(self.speed_taus_s)
        lags = self.centrifugal_lags_s if self.instantaneous_ else [0.0]
        feats, _ = self._features(frame, sensors, self.taus_s, centrifugal_lags=lags)
        p, q = len(sensors), len(self.speed_powers)
        n_rise = p * len(self.taus_s)
        n_speed = q * len(self.speed_taus_s)
        inst_cols = (
            [np.arange(n_rise + n_speed + k, n_rise + n_speed + k + 1) for k in range(len(lags))]
            if self.instantaneous_
            else [np.arange(0)]
        )
        cvd = self._cv_setup(feats, y, run_ids, table)
        cv_table, best = [], (math.inf, None, None, None, 0.0)
        rise_sets, speed_sets = self._filter_sets()
        for rs in rise_sets:
            rcols = [np.arange(i * p, (i + 1) * p) for i in rs]
            for ss in speed_sets:
                scols = [n_rise + np.arange(j * q, (j + 1) * q) for j in ss]
                for lag, inst in zip(lags, inst_cols):
                    cols = np.concatenate(rcols + scols + [inst])
                    scores = self._cv_scores(cvd, cols)
                    taus = [self.taus_s[i] for i in rs]
                    staus = [self.speed_taus_s[j] for j in ss]
                    for a, sc in zip(self.alphas, scores):
                        cv_table.append(
                            {
                                "taus_s": taus,
                                "speed_taus_s": staus,
                                "centrifugal_lag_s": lag,
                                "alpha": a,
                                "score_um": float(sc),
                            }
                        )
                        if sc < best[0] - 1e-12:
                            best = (float(sc), taus, staus, a, lag)
        _, taus, staus, alpha, lag = best
        self.speed_taus_ = staus
        self.centrifugal_lag_s_ = float(lag)
        return self._fit_final(table, frame, sensors, taus, alpha, cv_table)

    def to_dict(self) -> dict:
        d = {k: v for k, v in super().to_dict().items() if k not in ("model_id", "created", "schema")}
        d["selected"] = {
            **d["selected"],
            "speed_taus_s": self.speed_taus_,
            "instantaneous_n2": bool(self.instantaneous_),
            "centrifugal_lag_s": float(getattr(self, "centrifugal_lag_s_", 0.0)),
        }
        d["filter"] = {
            "type": "first_order_lowpass",
            "update": "y += (1 - exp(-dt/tau)) * (x - y)",
            "initial_condition": {
                "rises": "settled on the run's first sample (~0 at a cold start)",
                "speed_powers": (
                    "zero before the first sample (cold start from rest), then minus the "
                    "median over the reference window"
                    if self.reference.get("rule", "run_start") == "run_start"
                    else "settled on the first sample's speed"
                ),
            },
        }
        return _finish_artefact(d)

    @classmethod
    def from_dict(cls, d: dict):
        m = super().from_dict(d)
        m.speed_taus_ = [float(t) for t in d["selected"].get("speed_taus_s", [])]
        m.instantaneous_ = bool(d["selected"].get("instantaneous_n2", False))
        m.centrifugal_lag_s_ = float(d["selected"].get("centrifugal_lag_s", 0.0))
        m.speed_terms_ = m.instantaneous_
        return m


# --------------------------------------------------------------------------- registry

KINDS = {
    "rafi": PublishedRafi,
    "rafi_linear": RafiLinear,
    "ridge_global": RidgeGlobal,
    "dynamic": DynamicRidge,
    "grey_box": GreyBox,
}


def make_model(
    kind: str,
    *,
    key_sensors: Sequence[str] = ("T6", "T8", "T9"),
    terms: Sequence[str] = RAFI_TERMS,
    reference: dict | None = None,
    machine: str | None = None,
    options: dict | None = None,
):
    """An unfitted model of ``kind`` built from the pipeline settings.

    ``options`` is the config ``models:`` section (``cv``, ``cv_metric``, ``ridge_alphas``,
    ``dynamic_taus_s``, ``dynamic_max_taus``, ``speed_reference``).
    """
    o = dict(options or {})
    common = dict(reference=reference, machine=machine)
    ridge_kw = dict(
        alphas=o.get("ridge_alphas", DEFAULT_ALPHAS),
        cv=o.get("cv", "leave_one_run_out"),
        cv_metric=o.get("cv_metric", "rmse"),
        speed_reference=o.get("speed_reference", "auto"),
        **common,
    )
    ridge_kw["speed_gain"] = o.get("speed_gain", "cv")
    if kind == "rafi":
        return PublishedRafi(key_sensors, terms, **common)
    if kind == "rafi_linear":
        return RafiLinear(key_sensors, LINEAR_TERMS, **common)
    if kind == "ridge_global":
        return RidgeGlobal(**ridge_kw)
    if kind == "dynamic":
        return DynamicRidge(
            taus_s=o.get("dynamic_taus_s", DEFAULT_TAUS_S), max_taus=o.get("dynamic_max_taus", 2), **ridge_kw
        )
    if kind == "grey_box":
        kw = {k: v for k, v in ridge_kw.items() if k not in ("speed_gain", "cv_metric")}
        return GreyBox(
            taus_s=o.get("grey_box_taus_s", DEFAULT_GREY_TAUS_S),
            max_taus=o.get("grey_box_max_taus", 1),
            speed_taus_s=o.get("grey_box_speed_taus_s", DEFAULT_SPEED_TAUS_S),
            max_speed_taus=o.get("grey_box_max_speed_taus", 2),
            speed_powers=o.get("grey_box_speed_powers", DEFAULT_SPEED_POWERS),
            cv_metric=o.get("grey_box_cv_metric", "max_abs"),
            filter_search=o.get("grey_box_filter_search", "all"),
            centrifugal_lags_s=o.get("grey_box_centrifugal_lags_s", DEFAULT_CENTRIFUGAL_LAGS_S),
            **kw,
        )
    raise ValueError(f"unknown model kind {kind!r}; known: {sorted(KINDS)}")


def load_any(source):
    """A fitted model from an artefact dict or a path to ``model.json``, by its ``kind``.

    Kind ``rafi`` is read by :meth:`rafi.method.model.RafiModel.from_dict` (the published method's
    own evaluator); the other kinds by their class in this module.
    """
    if isinstance(source, (str, os.PathLike)):
        source = json.loads(Path(source).read_text(encoding="utf-8"))
    kind = source.get("kind")
    if kind == "rafi":
        from rafi.method.model import RafiModel

        return RafiModel.from_dict(source)
    if kind in KINDS:
        return KINDS[kind].from_dict(source)
    raise ValueError(f"unknown model kind {kind!r}; known: {sorted(KINDS)}")


def save_any(model, path) -> None:
    """Write ``model.to_dict()`` atomically as pretty JSON."""
    from rafi.artefact import write_text_atomic

    write_text_atomic(path, json.dumps(model.to_dict(), indent=2, sort_keys=True, allow_nan=False) + "\n")


# --------------------------------------------------------------------------- the comparison step

DEFAULT_OPTIONS = {
    "enabled": ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box"],
    "cv": "leave_one_run_out",
    "cv_metric": "rmse",
    "ridge_alphas": DEFAULT_ALPHAS,
    "dynamic_taus_s": DEFAULT_TAUS_S,
    "dynamic_max_taus": 2,
    "speed_reference": "auto",
    "speed_gain": "cv",
    "cv_report": True,
}

GATE_KEYS = ("max_residual_um", "min_improvement_pct", "never_worse_than_uncompensated")


def _seconds(values) -> str:
    return "/".join(f"{float(v):g}" for v in values) + " s"


def describe_selection(model) -> str:
    """What cross-validation chose for a fitted model of the family, in one line for people."""
    if not hasattr(model, "alpha_"):
        return "nothing to choose (one OLS per training speed, fuzzy blend)"
    parts = [
        f"alpha {model.alpha_:g}",
        "rises " + ", ".join("as is" if t <= 0 else f"filtered {t:g} s" for t in model.taus_),
    ]
    if isinstance(model, GreyBox):
        parts.append(
            f"heat-input filters {_seconds(model.speed_taus_)}"
            if model.speed_taus_
            else "no heat-input filters"
        )
        if model.instantaneous_:
            lag = float(getattr(model, "centrifugal_lag_s_", 0.0))
            parts.append("draw-in n\u00b2 term" + (f" with a {lag:g} s lag" if lag > 0 else ""))
        else:
            parts.append("no draw-in term (not identified)")
    else:
        parts.append("speed gain dT\u00b7n" if model.speed_gain_ else "no speed gain")
        parts.append("speed terms" if model.speed_terms_ else "no speed terms (not identified)")
    return "; ".join(parts)


def run_family(
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    *,
    key_sensors: Sequence[str],
    terms: Sequence[str] = RAFI_TERMS,
    reference: dict | None = None,
    machine: str | None = None,
    options: dict | None = None,
    gates: dict | None = None,
    rafi_model=None,
    log=print,
) -> dict:
    """Fit, validate, cross-validate and rank the enabled models (what ``rule compare`` runs).

    ``rafi_model`` is the pipeline's fitted ``model.json`` (a ``RafiModel``); when given it is
    the ``rafi`` entry (no refit), else RAFI is fitted here. Hyperparameters are chosen on the
    training runs only; the validation runs are only predicted.

    Returns a dict: ``summary`` (one row per model, with ``fit_time_s``, ``selected`` (what CV
    chose, :func:`describe_selection`) and the CV scores
    ``cv_rmse_um`` / ``cv_max_abs_um``), ``per_run``, ``residuals``, ``cv``, ``champion``
    (name or None), ``best_name`` and ``best_artefact`` (the champion's artefact; when no model
    passes the gates, the one with the lowest worst-case residual, and ``champion`` is None).
    """
    import time

    from rafi.family.crossval import choose_champion, compare_models, cross_validate

    opts = {**DEFAULT_OPTIONS, **(options or {})}
    gates = {k: v for k, v in (gates or {}).items() if k in GATE_KEYS}
    models, fit_time, cv_parts = {}, {}, []
    for kind in opts["enabled"]:

        def factory(kind=kind):
            return make_model(
                kind, key_sensors=key_sensors, terms=terms, reference=reference, machine=machine, options=opts
            )

        t0 = time.perf_counter()
        if kind == "rafi" and rafi_model is not None:
            models[kind] = rafi_model
        else:
            models[kind] = factory().fit(runs_table, runs_frame)
        fit_time[kind] = time.perf_counter() - t0
        m = models[kind]
        extra = f" alpha={m.alpha_:g} taus_s={m.taus_}" if hasattr(m, "alpha_") else ""
        if hasattr(m, "speed_taus_"):
            extra += (
                f" speed_taus_s={m.speed_taus_} instantaneous_n2={m.instantaneous_}"
                f" centrifugal_lag_s={getattr(m, 'centrifugal_lag_s_', 0.0):g}"
            )
        log(f"{kind}: fitted in {fit_time[kind]:.2f} s{extra}")
        if opts.get("cv_report", True):
            t0 = time.perf_counter()
            cv = cross_validate(factory, runs_table, runs_frame, opts["cv"], name=kind)
            cv_parts.append(cv)
            log(
                f"{kind}: {opts['cv']} CV in {time.perf_counter() - t0:.1f} s, "
                f"max |residual| {cv['max_abs_after_um'].max():.2f} um"
            )
    table, residuals = compare_models(models, runs_table, runs_frame, gates, return_residuals=True)
    cv = pd.concat(cv_parts, ignore_index=True) if cv_parts else pd.DataFrame()
    summary = table.loc[table["scope"] == "model"].drop(columns=["scope", "run_id", "role", "speed_rpm"])
    summary = summary.assign(
        fit_time_s=summary["model"].map(fit_time),
        selected=summary["model"].map({k: describe_selection(m) for k, m in models.items()}),
    )
    if len(cv):
        agg = cv.groupby("model").agg(
            cv_rmse_um=("rmse_um", lambda v: float(np.sqrt(np.mean(np.square(v))))),
            cv_max_abs_um=("max_abs_after_um", "max"),
        )
        summary = summary.join(agg, on="model")
    per_run = table.loc[table["scope"] == "run"].drop(columns=["scope"])
    champion = choose_champion(table)
    best = champion or choose_champion(table, require_pass=False) or "rafi"
    return {
        "summary": summary.reset_index(drop=True),
        "per_run": per_run.reset_index(drop=True),
        "residuals": residuals,
        "cv": cv,
        "champion": champion,
        "best_name": best,
        "best_artefact": models[best].to_dict(),
        "models": models,
    }


# --------------------------------------------------------------------------- synthetic data
