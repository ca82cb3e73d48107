"""The RAFI model artefact: per-speed polynomials blended by triangular fuzzy weights.

This module is what a deployment needs: it evaluates the fitted polynomials with
NumPy only (no statsmodels import here or in :mod:`rafi.method.fuzzy`), so a controller
PC can run ``load_model(path).predict(frame)`` with numpy and pandas alone.

Terms grammar (``docs/design.md``): ``"1"`` is the intercept, ``"xi"`` the rise of
the i-th key sensor (1-based), products are joined by ``*`` and powers written
``xi^k``; e.g. ``"x1*x2"``, ``"x1^2"``, ``"x1*x2*x3"``, ``"x1^2*x3"``.

Out-of-range flags (:meth:`RafiModel.predict_detail`)
-----------------------------------------------------
* ``outside_speed_range``: the speed is more than ``speed_tolerance_rpm`` below
  the lowest or above the highest training speed (edge model used, weight 1).
* ``outside_temp_range``: some key sensor rise lies outside
  ``[min - temp_tolerance_k, max + temp_tolerance_k]`` of the training range of
  *any* per-speed model that has a nonzero weight for that sample. The polynomial
  is then extrapolating, which with collinear, quadratic-plus-interaction terms
  can go badly wrong; the flag lets the report and the controller see it. The
  tolerance (default 0.1 K) absorbs sensor noise around the reference state,
  where a rise of ~0 K sits on the edge of every training range.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.artefact import (
    code_version,
    compute_model_id,
    json_text,
    jsonable,
    model_id_verifies,
    write_text_atomic,
)
from rafi.method.fuzzy import triangular_weights
from rafi.settings import MACHINE_DEFAULTS

__all__ = [
    "SCHEMA",
    "RafiModel",
    "parse_term",
    "parse_terms",
    "design_matrix",
    "save_model",
    "load_model",
]

SCHEMA = "rafi.model/1"
"""Schema tag written to and required in ``model.json``."""

_FACTOR = re.compile(r"^x([1-9][0-9]*)(?:\^([0-9]+))?$")


# --------------------------------------------------------------------------- terms


def parse_term(term: str, n_vars: int) -> tuple[int, ...]:
    """Parse one term of the grammar into an exponent vector.

    Parameters
    ----------
    term : str
        ``"1"``, ``"x1"``, ``"x1*x2"``, ``"x1^2"``, ``"x1*x2*x3"``, ... (spaces ignored).
    n_vars : int
        Number of key sensors; ``xi`` with ``i > n_vars`` is an error.

    Returns
    -------
    tuple of int
        Exponent of each variable, e.g. ``"x1^2*x3"`` -> ``(2, 0, 1)``.

    Raises
    ------
    ValueError
        On anything outside the grammar.
    """
    text = str(term).replace(" ", "")
    exps = [0] * n_vars
    if text == "1":
        return tuple(exps)
    if not text:
        raise ValueError("empty term; expected '1', 'xi', 'xi*xj' or 'xi^k'")
    for factor in text.split("*"):
        m = _FACTOR.match(factor)
        if not m:
            raise ValueError(
                f"term {term!r}: factor {factor!r} is not 'xi' or 'xi^k' (i = 1-based key sensor number)"
            )
        i = int(m.group(1))
        k = int(m.group(2)) if m.group(2) is not None else 1
        if i > n_vars:
            raise ValueError(
                f"term {term!r} uses x{i} but only {n_vars} key sensor(s) are defined (x1..x{n_vars})"
            )
        if k < 1:
            raise ValueError(f"term {term!r}: power must be >= 1")
        exps[i - 1] += k
    return tuple(exps)


def parse_terms(terms, n_vars: int) -> np.ndarray:
    """Parse a list of terms into an integer exponent matrix ``[n_terms, n_vars]``.

    Raises ``ValueError`` for an empty list, a bad term or two terms that are the
    same monomial (e.g. ``"x1*x2"`` and ``"x2*x1"``: the design would be singular).
    """
    terms = list(terms)
    if not terms:
        raise ValueError("terms is empty")
    exps = [parse_term(t, n_vars) for t in terms]
    seen: dict[tuple[int, ...], str] = {}
    for t, e in zip(terms, exps):
        if e in seen:
            raise ValueError(f"terms {seen[e]!r} and {t!r} are the same monomial")
        seen[e] = t
    return np.asarray(exps, dtype=int).reshape(len(terms), n_vars)


def design_matrix(x, exponents) -> np.ndarray:
    """Evaluate the monomials: ``D[:, j] = prod_i x[:, i] ** exponents[j, i]``.

    Parameters
    ----------
    x : array_like, shape (n, n_vars)
        Regressors (key sensor rises, K).
    exponents : array_like of int, shape (n_terms, n_vars)
        From :func:`parse_terms`.

    Returns
    -------
    ndarray, shape (n, n_terms)
    """
    x = np.asarray(x, dtype=float)
    exponents = np.asarray(exponents, dtype=int)
    if x.ndim == 1:
        x = x[:, None]
    out = np.ones((x.shape[0], exponents.shape[0]))
    for j, row in enumerate(exponents):
        for i, p in enumerate(row):
            if p:
                out[:, j] *= x[:, i] ** p
    return out


# --------------------------------------------------------------------------- helpers


def _speed_value(v) -> int | float:
    v = float(v)
    return int(v) if v.is_integer() else v


_code_version = code_version  # the constructor's ``code_version`` argument shadows the function


# --------------------------------------------------------------------------- the model


class RafiModel:
    """Per-speed polynomial regressions blended by triangular fuzzy memberships.

    Built by :func:`rafi.method.fit.fit_rafi` (or by hand with
    :meth:`add_speed_model`), saved with :func:`save_model`, loaded with
    :func:`load_model`. Constructor arguments are stored unchanged; fitted
    attributes end in ``_``.

    Parameters
    ----------
    key_sensors : sequence of str
        Key sensors in variable order (``x1`` = first), e.g. ``["T6", "T8", "T9"]``.
        The model reads their rises from columns ``"d" + sensor`` (``dT6``).
    terms : sequence of str
        Polynomial terms (grammar in the module docstring), in coefficient order.
    reference : dict, optional
        Reference-state rule, e.g. ``{"rule": "run_start", "window_s": 60}``.
    machine : str, optional
        Machine name (the folder under ``raw/``).
    fuzzy_outside : {"edge"}, default "edge"
        What to do outside the trained speeds (only ``"edge"`` is implemented).
    speed_tolerance_rpm : float, default 50
        Slack before a sample is flagged ``outside_speed_range``.
    temp_tolerance_k : float, default 0.1
        Slack before a sample is flagged ``outside_temp_range``.
    data : dict, optional
        Input files used, ``{file: sha256}``.
    config : dict, optional
        The configuration the model was built with (stored for provenance).
    code_version : str, optional
        Defaults to :func:`code_version`.
    created : str, optional
        ISO-8601 UTC creation time; defaults to now.

    Attributes
    ----------
    speeds_rpm_ : ndarray, shape (k,)
        Training speeds, increasing.
    coef_ : ndarray, shape (k, n_terms)
        Coefficients of each per-speed model in ``terms`` order (um).
    regressor_ranges_ : ndarray, shape (k, n_sensors, 2)
        Min and max rise (K) of each key sensor in the training data of each speed.
    train_runs_ : list of list of str
        Training run ids per speed.
    rmse_um_ : ndarray, shape (k,)
        Training RMSE per speed (um).
    n_ : ndarray of int, shape (k,)
        Training samples per speed.
    """

    def __init__(
        self,
        key_sensors,
        terms,
        *,
        reference: dict | None = None,
        machine: str | None = None,
        fuzzy_outside: str = MACHINE_DEFAULTS["fuzzy"]["outside"],
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
        temp_tolerance_k: float = 0.1,
        data: dict | None = None,
        config: dict | None = None,
        code_version: str | None = None,
        created: str | None = None,
    ):
        self.key_sensors = list(key_sensors)
        self.terms = list(terms)
        self.reference = dict(reference) if reference is not None else {}
        self.machine = machine
        self.fuzzy_outside = fuzzy_outside
        self.speed_tolerance_rpm = float(speed_tolerance_rpm)
        self.temp_tolerance_k = float(temp_tolerance_k)
        self.data = dict(data) if data is not None else {}
        self.config = dict(config) if config is not None else {}
        self.code_version = code_version if code_version is not None else _code_version()
        if created is None:
            created = pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ")
        self.created = created
        if not self.key_sensors:
            raise ValueError("key_sensors is empty")
        if len(set(self.key_sensors)) != len(self.key_sensors):
            raise ValueError(f"key_sensors has duplicates: {self.key_sensors}")
        if fuzzy_outside != "edge":
            raise ValueError(f"fuzzy_outside={fuzzy_outside!r}; only 'edge' is implemented")
        self._exponents = parse_terms(self.terms, len(self.key_sensors))
        self.speeds_rpm_ = np.empty(0)
        self.coef_ = np.empty((0, len(self.terms)))
        self.regressor_ranges_ = np.empty((0, len(self.key_sensors), 2))
        self.train_runs_: list[list[str]] = []
        self.rmse_um_ = np.empty(0)
        self.n_ = np.empty(0, dtype=int)
        #: The prediction interval's block (``rafi.family.intervals``), or None: no interval.
        self.interval_: dict | None = None
        #: The ``adaptation`` block of a re-qualified prior (``rafi.family.adapted``), or None.
        self.adaptation_: dict | None = None
        #: A re-qualified prior's ``speed_range_rpm`` (``rafi.family.adapted``): the prior's speeds
        #: joined with the new runs', for people (what was tested here and what the prior covers
        #: are the ``adaptation.fitness`` block's); None otherwise. The out-of-range flag stays the
        #: per-speed models'.
        self.speed_range_rpm_: list[float] | None = None

    # ------------------------------------------------------------------ building
    def add_speed_model(
        self, speed_rpm, coefficients, regressor_ranges, *, train_runs=(), rmse_um=float("nan"), n: int = 0
    ) -> RafiModel:
        """Add (or replace) the regression of one training speed; returns ``self``.

        Parameters
        ----------
        speed_rpm : float
            Training speed, r/min.
        coefficients : array_like, shape (n_terms,)
            In ``terms`` order.
        regressor_ranges : dict or array_like
            ``{sensor: (min, max)}`` for every key sensor, or an array
            ``[n_sensors, 2]`` in key-sensor order.
        train_runs : sequence of str
        rmse_um : float
        n : int
        """
        coef = np.asarray(coefficients, dtype=float).ravel()
        if coef.size != len(self.terms):
            raise ValueError(f"{coef.size} coefficients for {len(self.terms)} terms at {speed_rpm} r/min")
        if isinstance(regressor_ranges, dict):
            missing = [s for s in self.key_sensors if s not in regressor_ranges]
            if missing:
                raise ValueError(f"regressor_ranges at {speed_rpm} r/min lacks {missing}")
            ranges = np.asarray([regressor_ranges[s] for s in self.key_sensors], dtype=float)
        else:
            ranges = np.asarray(regressor_ranges, dtype=float)
        ranges = ranges.reshape(len(self.key_sensors), 2)
        speed = float(speed_rpm)
        keep = self.speeds_rpm_ != speed
        speeds = np.append(self.speeds_rpm_[keep], speed)
        coefs = np.vstack([self.coef_[keep], coef[None, :]])
        rngs = np.concatenate([self.regressor_ranges_[keep], ranges[None]], axis=0)
        runs = [r for r, k in zip(self.train_runs_, keep) if k] + [[str(r) for r in train_runs]]
        rmse = np.append(self.rmse_um_[keep], float(rmse_um) if rmse_um is not None else np.nan)
        ns = np.append(self.n_[keep], int(n))
        order = np.argsort(speeds, kind="stable")
        self.speeds_rpm_ = speeds[order]
        self.coef_ = coefs[order]
        self.regressor_ranges_ = rngs[order]
        self.train_runs_ = [runs[i] for i in order]
        self.rmse_um_ = rmse[order]
        self.n_ = ns[order].astype(int)
        return self

    def _check_fitted(self) -> None:
        if self.speeds_rpm_.size == 0:
            raise ValueError(
                "RafiModel has no per-speed models; fit it (rafi.method.fit."
                "fit_rafi) or load one (rafi.method.model.load_model) first"
            )

    @property
    def input_columns(self) -> list[str]:
        """Frame columns the model reads: ``dT..`` of the key sensors (plus ``speed_rpm``)."""
        return [f"d{s}" for s in self.key_sensors]

    # ------------------------------------------------------------------ prediction
    def _inputs(self, frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
        cols = self.input_columns + ["speed_rpm"]
        missing = [c for c in cols if c not in frame.columns]
        if missing:
            raise ValueError(
                f"frame lacks column(s) {missing} needed by the model (key sensors {self.key_sensors})"
            )
        x = frame[self.input_columns].to_numpy(dtype=float, na_value=np.nan)
        speed = frame["speed_rpm"].to_numpy(dtype=float, na_value=np.nan)
        return x, speed

    def _evaluate(self, x: np.ndarray, speed: np.ndarray):
        self._check_fitted()
        per_speed = design_matrix(x, self._exponents) @ self.coef_.T  # [n, k]
        weights, outside = triangular_weights(speed, self.speeds_rpm_, tolerance_rpm=self.speed_tolerance_rpm)
        active = weights > 0
        contrib = np.where(active, weights * np.where(active, per_speed, 0.0), 0.0)
        pred = contrib.sum(axis=1)
        bad = ~np.isfinite(speed) | np.any(active & ~np.isfinite(per_speed), axis=1)
        pred[bad] = np.nan
        return pred, weights, outside

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        """Predicted displacement change ``dz`` (um) for every row of ``frame``.

        Parameters
        ----------
        frame : pandas.DataFrame
            Needs ``speed_rpm`` and the rises ``dT<i>`` of the key sensors.

        Returns
        -------
        ndarray, shape (n,)
            NaN where the speed or a needed rise is NaN.
        """
        x, speed = self._inputs(frame)
        return self._evaluate(x, speed)[0]

    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Prediction with membership weights and out-of-range flags.

        Returns
        -------
        pandas.DataFrame
            Same index as ``frame``; columns ``predicted_um``, ``w_<speed>`` (one
            membership weight per training speed, e.g. ``w_3000``),
            ``outside_speed_range`` and ``outside_temp_range`` (see module docstring).
        """
        x, speed = self._inputs(frame)
        pred, weights, outside = self._evaluate(x, speed)
        lo = self.regressor_ranges_[:, :, 0] - self.temp_tolerance_k  # [k, s]
        hi = self.regressor_ranges_[:, :, 1] + self.temp_tolerance_k
        with np.errstate(invalid="ignore"):
            out_model = np.any((x[:, None, :] < lo[None]) | (x[:, None, :] > hi[None]), axis=2)
        outside_temp = np.any(out_model & (weights > 0), axis=1)
        out = pd.DataFrame({"predicted_um": pred}, index=frame.index)
        for j, s in enumerate(self.speeds_rpm_):
            out[f"w_{_speed_value(s)}"] = weights[:, j]
        out["outside_speed_range"] = outside
        out["outside_temp_range"] = outside_temp
        return out

    # ------------------------------------------------------------------ serialisation
    def _content(self) -> dict:
        self._check_fitted()
        speeds = []
        for j, s in enumerate(self.speeds_rpm_):
            speeds.append(
                {
                    "speed_rpm": _speed_value(s),
                    "coefficients": [float(c) for c in self.coef_[j]],
                    "regressor_ranges": {
                        sensor: [float(v) for v in self.regressor_ranges_[j, i]]
                        for i, sensor in enumerate(self.key_sensors)
                    },
                    "train_runs": list(self.train_runs_[j]),
                    "rmse_um": float(self.rmse_um_[j]),
                    "n": int(self.n_[j]),
                }
            )
        content = {
            "schema": SCHEMA,
            "kind": "rafi",
            "machine": self.machine,
            "key_sensors": list(self.key_sensors),
            "variables": {f"x{i + 1}": s for i, s in enumerate(self.key_sensors)},
            "terms": list(self.terms),
            "inputs": "temperature rises dT (K) of the key sensors",
            "target": "displacement change dz (um) from the reference state",
            "reference": dict(self.reference),
            "speeds": speeds,
            "fuzzy": {
                "membership": "triangular",
                "outside": self.fuzzy_outside,
                "speed_tolerance_rpm": self.speed_tolerance_rpm,
                "temp_tolerance_k": self.temp_tolerance_k,
            },
            "data": dict(self.data),
            "code_version": self.code_version,
            "config": dict(self.config),
        }
        if self.interval_ is not None:  # absent in older artefacts (no interval: NaN bounds)
            content["interval"] = dict(self.interval_)
        if self.adaptation_ is not None:  # a re-qualified prior (rafi.family.adapted)
            content["adaptation"] = dict(self.adaptation_)
        if self.speed_range_rpm_ is not None:  # absent in older artefacts and unadapted models
            content["speed_range_rpm"] = [float(v) for v in self.speed_range_rpm_]
        return content

    @property
    def model_id(self) -> str:
        """SHA-256 of the canonical JSON of the content (without ``model_id``/``created``)."""
        return compute_model_id(self._content())

    def to_dict(self) -> dict:
        """The ``model.json`` content (schema ``rafi.model/1``, ``docs/design.md``).

        NaN values (e.g. an unknown RMSE) are written as ``null``.
        """
        content = jsonable(self._content())
        content["model_id"] = compute_model_id(content)
        content["created"] = self.created
        return content

    @classmethod
    def from_dict(cls, d: dict, *, verify_id: bool = True) -> RafiModel:
        """Rebuild a model from :meth:`to_dict` output.

        Parameters
        ----------
        d : dict
        verify_id : bool, default True
            Recompute ``model_id`` and raise if it differs (the file was edited).

        Raises
        ------
        ValueError
            Wrong ``schema``/``kind``, missing keys, or a ``model_id`` mismatch.
        """
        if not isinstance(d, dict):
            raise ValueError(f"model content must be a JSON object, got {type(d).__name__}")
        schema = d.get("schema")
        if schema != SCHEMA:
            raise ValueError(f"schema is {schema!r}; this version of rafi reads {SCHEMA!r}")
        if d.get("kind") != "rafi":
            raise ValueError(f"kind is {d.get('kind')!r}; expected 'rafi'")
        missing = [k for k in ("key_sensors", "terms", "speeds") if k not in d]
        if missing:
            raise ValueError(f"model content lacks key(s) {missing}")
        fuzzy = d.get("fuzzy") or {}
        model = cls(
            d["key_sensors"],
            d["terms"],
            reference=d.get("reference"),
            machine=d.get("machine"),
            fuzzy_outside=fuzzy.get("outside", "edge"),
            speed_tolerance_rpm=fuzzy.get("speed_tolerance_rpm", 50.0),
            temp_tolerance_k=fuzzy.get("temp_tolerance_k", 0.1),
            data=d.get("data"),
            config=d.get("config"),
            code_version=d.get("code_version", ""),
            created=d.get("created"),
        )
        if not d["speeds"]:
            raise ValueError("model content has no per-speed models ('speeds' is empty)")
        for sp in d["speeds"]:
            rmse = sp.get("rmse_um")
            model.add_speed_model(
                sp["speed_rpm"],
                sp["coefficients"],
                sp["regressor_ranges"],
                train_runs=sp.get("train_runs", ()),
                rmse_um=float("nan") if rmse is None else rmse,
                n=sp.get("n", 0),
            )
        if isinstance(d.get("interval"), dict):
            model.interval_ = d["interval"]
        if isinstance(d.get("adaptation"), dict):
            model.adaptation_ = d["adaptation"]
        if d.get("speed_range_rpm") is not None:
            model.speed_range_rpm_ = [float(v) for v in d["speed_range_rpm"]]
        if verify_id and "model_id" in d and not model_id_verifies(model._content(), d["model_id"]):
            raise ValueError(
                f"model_id {d['model_id']} does not match the content "
                f"({model.model_id}); the model was edited after it was saved"
            )
        return model

    def __repr__(self) -> str:
        speeds = ", ".join(str(_speed_value(s)) for s in self.speeds_rpm_)
        return f"RafiModel(key_sensors={self.key_sensors}, n_terms={len(self.terms)}, speeds_rpm=[{speeds}])"


# --------------------------------------------------------------------------- files


def save_model(model: RafiModel, path: str | os.PathLike) -> None:
    """Write ``model.json`` atomically (indented JSON, sorted keys, trailing newline)."""
    write_text_atomic(path, json_text(model.to_dict()))


def load_model(path: str | os.PathLike) -> RafiModel:
    """Read a ``model.json`` written by :func:`save_model`.

    Raises
    ------
    ValueError
        Naming the file, if it is not JSON, has another schema version, or is
        otherwise not a valid RAFI model.
    """
    path = Path(path)
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(
            f"{path}: not valid JSON ({exc}); expected a RAFI model (schema {SCHEMA!r})"
        ) from None
    try:
        return RafiModel.from_dict(content)
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from None
