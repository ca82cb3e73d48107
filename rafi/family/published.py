"""Kind ``rafi``: RAFI as published, fitted by :func:`rafi.method.fit.fit_rafi`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.artefact import compute_model_id
from rafi.family.base import FamilyModel, check_artefact
from rafi.family.crossval import training_runs
from rafi.family.feature_memo import active_memo
from rafi.settings import MACHINE_DEFAULTS


class PublishedRafi(FamilyModel):
    """Kind ``rafi``: one polynomial regression per training speed on the key sensors, blended
    with triangular fuzzy memberships.

    After ``fit`` the attribute ``model_`` is the :class:`rafi.method.model.RafiModel`;
    ``predict``/``predict_detail``/``to_dict`` delegate to it, so the family evaluates the
    published method with exactly the pipeline's own code (fuzzy blend, out-of-range flags).

    Parameters
    ----------
    key_sensors : sequence of str
        The sensors ``x1, x2, x3`` (``rank/key_sensors.json``).
    terms : sequence of str
        Regression terms per training speed (``fit: terms``).
    reference : dict
        The ``reference:`` settings (``rule``, ``window_s``).
    machine : str or None
        Machine name recorded in the artefact.
    hac_maxlags : int
        ``fit: hac_maxlags`` (passed to ``fit_rafi``).
    speed_tolerance_rpm : float
        The machine's ``speed_tolerance_rpm`` (passed to ``fit_rafi``).
    """

    kind = "rafi"

    def __init__(
        self,
        *,
        key_sensors: Sequence[str],
        terms: Sequence[str] = MACHINE_DEFAULTS["fit"]["terms"],
        reference: dict = MACHINE_DEFAULTS["reference"],
        machine: str | None = None,
        hac_maxlags: int = MACHINE_DEFAULTS["fit"]["hac_maxlags"],
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
    ):
        self.key_sensors = key_sensors
        self.terms = terms
        self.reference = reference
        self.machine = machine
        self.hac_maxlags = hac_maxlags
        self.speed_tolerance_rpm = speed_tolerance_rpm

    def can_fit(self, runs_table: pd.DataFrame) -> bool:
        """RAFI learns from constant-speed training runs only (not cool-downs or varying stretches)."""
        from rafi.method.rank import speed_training_runs

        return bool(len(speed_training_runs(runs_table)))

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        """Fit on the training runs of ``runs_table``; returns ``self``."""
        from rafi.method.fit import fit_rafi

        table, frame = training_runs(runs_table, runs_frame)
        # a run once (time-blocked folds give a row per block; frame holds the fold's rows only)
        table = table.drop_duplicates("run_id")
        # the artefact needs the coefficients only: the diagnostics belong to rule fit
        res = fit_rafi(
            table,
            frame,
            key_sensors=list(self.key_sensors),
            terms=list(self.terms),
            hac_maxlags=int(self.hac_maxlags),
            reference=dict(self.reference),
            machine=self.machine,
            speed_tolerance_rpm=float(self.speed_tolerance_rpm),
            diagnostics=False,
            # the CV folds that keep a speed's runs share its solution (the fit's scope)
            solutions=active_memo(),
        )
        self.model_ = res.model
        self.train_runs_ = sorted(map(str, table["run_id"]))
        self.grid_edges_ = []  # no hyperparameter grid
        return self

    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        """The fitted :class:`~rafi.method.model.RafiModel`'s ``predict_detail``."""
        return self.model_.predict_detail(frame)

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        """The fitted :class:`~rafi.method.model.RafiModel`'s ``predict``, as floats."""
        return np.asarray(self.model_.predict(frame), dtype=float)

    def to_dict(self) -> dict:
        """RAFI's artefact with this ``kind`` (and its own ``model_id``)."""
        d = self.model_.to_dict()
        if self.kind != d.get("kind"):
            d["kind"] = self.kind
            d["model_id"] = compute_model_id(d)
        return d

    @classmethod
    def from_dict(cls, d: dict):
        """A fitted model from its artefact (refused if edited)."""
        from rafi.method.model import RafiModel

        check_artefact(d, cls.kind)
        inner = RafiModel.from_dict({**d, "kind": "rafi"}, verify_id=False)
        m = cls(
            key_sensors=inner.key_sensors, terms=inner.terms, reference=inner.reference, machine=inner.machine
        )
        m.model_ = inner
        m.grid_edges_ = []
        m.train_runs_ = sorted({r for sp in d["speeds"] for r in sp.get("train_runs", [])})
        return m
