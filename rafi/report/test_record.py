"""Section "Test record and conditions": when, how long and under which conditions each log was
recorded, and how far the displacement drifted in each run.

Reads ``runs.parquet`` (every sample of every log lies in exactly one run, docs/design.md),
``runs.csv`` (role and speed of each run) and the machine's settings: ``report.ambient_sensor``
(the sensor in the room air), ``report.instruments`` (machine serial, controller, probe, sensor
positions, calibration dates), ``sample_period_s`` (the configured logger period, shown beside
the one found in the data) and ``report.coolant_sensors``.

ISO 230-3 terms (docs/report.md, "Test record"), computed from the recorded logs:

* **environmental temperature variation** of a log or run: ``max - min`` of the ambient
  sensor's temperature over its samples (the temperature variation the ETVE test of ISO
  230-3 Clause 5 records; the ETVE itself, a displacement measured with the machine at rest,
  is not computed here);
* **thermal drift** of a run: ``max - min`` of the displacement change ``dz`` over the run's
  samples (the drift of the spindle test of ISO 230-3 Clause 6, in the direction the unit's
  probe measures: :func:`rafi.report.probe.probe_words` names it, as the verdict does).

Nothing here is evaluated from a model; the numbers are the recorded data's own.
"""

from __future__ import annotations

import datetime as dt

import numpy as np
import pandas as pd

from rafi.report.format import DASH, fmt_num, fmt_run_speed, isnum, records
from rafi.report.probe import probe_words

UM = "\u00b5m"

#: The settings of ``report.instruments`` shown as single values: key -> label.
INSTRUMENT_FIELDS = {
    "machine_serial": "machine serial number",
    "controller": "controller",
    "probe": "displacement probe",
}

LOG_COLUMNS = [
    "log",
    "first_time",
    "last_time",
    "first_s",
    "last_s",
    "duration_s",
    "n_samples",
    "period_s",
    "ambient_min_c",
    "ambient_max_c",
    "ambient_variation_k",
]

RUN_COLUMNS = [
    "run_id",
    "log",
    "role",
    "speed_rpm",
    "speed_min_rpm",
    "speed_max_rpm",
    "kind",
    "first_time",
    "last_time",
    "first_s",
    "last_s",
    "duration_s",
    "dz_min_um",
    "dz_max_um",
    "thermal_drift_um",
    "ambient_variation_k",
]


def sample_period(t_s) -> float:
    """The sample period found in the data: the median of the positive steps of the sorted
    times ``t_s`` (s); NaN with fewer than two distinct times."""
    t = np.sort(np.asarray(t_s, dtype=float))
    t = t[np.isfinite(t)]
    steps = np.diff(t)
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else float("nan")


def fmt_period(seconds) -> str:
    """A sample period: ``15 s``, ``0.50 s``; an en dash for none."""
    if not isnum(seconds):
        return DASH
    return fmt_num(seconds, 0 if float(seconds).is_integer() else 2, "s")


def _ambient(values) -> tuple[float, float, float]:
    """``(min, max, max - min)`` of the finite values (NaN for none)."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if not x.size:
        return (np.nan, np.nan, np.nan)
    lo, hi = float(x.min()), float(x.max())
    return lo, hi, hi - lo


def _times(g: pd.DataFrame):
    """First and last logged time (``None`` where the log has no clock)."""
    if "time" not in g:
        return None, None
    t = pd.to_datetime(g["time"], errors="coerce")
    t = t[t.notna()]
    if not len(t):
        return None, None
    return t.min(), t.max()


def log_record(frame: pd.DataFrame, ambient: str | None = None) -> pd.DataFrame:
    """One row per log: its span, samples, sample period and ambient temperature.

    Parameters
    ----------
    frame : DataFrame
        ``runs.parquet``: ``log``, ``log_t_s`` (s on the log's clock), ``time`` (may be NaT),
        the sensor columns.
    ambient : str, optional
        The ambient sensor's column (``report.ambient_sensor``); ``None``: the ambient columns
        are NaN.

    Returns
    -------
    DataFrame
        :data:`LOG_COLUMNS`, logs in order of first appearance. ``duration_s`` = last - first
        sample + one sample period (the time the samples cover, as ``runs.csv`` counts a
        run's duration); ``ambient_variation_k`` = max - min of the ambient sensor over the
        log (ISO 230-3's environmental temperature variation).
    """
    rows = []
    if frame is None or not len(frame):
        return pd.DataFrame(columns=LOG_COLUMNS)
    for log, g in frame.groupby(frame["log"].astype(str), sort=False):
        t = pd.to_numeric(g["log_t_s"], errors="coerce")
        period = sample_period(t)
        first_s, last_s = float(t.min()), float(t.max())
        span = last_s - first_s + (period if isnum(period) else 0.0)
        first, last = _times(g)
        amb = _ambient(g[ambient]) if ambient and ambient in g else (np.nan, np.nan, np.nan)
        rows.append([log, first, last, first_s, last_s, span, len(g), period, *amb])
    return pd.DataFrame(rows, columns=LOG_COLUMNS)


def run_record(frame: pd.DataFrame, runs: pd.DataFrame | None, ambient: str | None = None) -> pd.DataFrame:
    """One row per run: role, speed, span, the thermal drift of dz and the ambient variation.

    Parameters
    ----------
    frame : DataFrame
        ``runs.parquet`` (``run_id``, ``t_s``, ``time``, ``dz_um``, the sensor columns).
    runs : DataFrame, optional
        ``runs.csv`` (order, ``log``/``file``, ``role``, ``speed_rpm``, ``speed_min_rpm``,
        ``speed_max_rpm``, ``kind``); without it the runs of ``frame`` in order of appearance.
    ambient : str, optional
        The ambient sensor's column.

    Returns
    -------
    DataFrame
        :data:`RUN_COLUMNS`; ``thermal_drift_um`` = max - min of ``dz_um`` over the run (ISO
        230-3's thermal drift of the test, on the unit's probe), ``ambient_variation_k`` = max - min of the
        ambient sensor over the run. A run of ``runs.csv`` with no samples has NaN values.
    """
    if frame is None:
        return pd.DataFrame(columns=RUN_COLUMNS)
    groups = {str(k): g for k, g in frame.groupby(frame["run_id"].astype(str), sort=False)}
    meta = {}
    if runs is not None and len(runs):
        for r in runs.to_dict("records"):
            meta[str(r["run_id"])] = r
    order = list(meta) or list(groups)
    rows = []
    for rid in order:
        g = groups.get(rid)
        m = meta.get(rid, {})
        if g is None or not len(g):
            g = frame.iloc[0:0]
        dz = pd.to_numeric(g["dz_um"], errors="coerce") if "dz_um" in g else pd.Series(dtype=float)
        dz = dz[np.isfinite(dz)]
        lo, hi = (float(dz.min()), float(dz.max())) if len(dz) else (np.nan, np.nan)
        speed = pd.to_numeric(g["speed_rpm"], errors="coerce") if "speed_rpm" in g else pd.Series(dtype=float)
        first, last = _times(g)
        on_log = pd.to_numeric(g["log_t_s"], errors="coerce") if "log_t_s" in g else pd.Series(dtype=float)
        first_s, last_s = (on_log.min(), on_log.max()) if on_log.notna().any() else (np.nan, np.nan)
        t = pd.to_numeric(g["t_s"], errors="coerce") if "t_s" in g else pd.Series(dtype=float)
        dur = m.get("duration_s")
        if not isnum(dur) and len(t):
            per = sample_period(t)
            dur = float(t.max() - t.min()) + (per if isnum(per) else 0.0)
        amb = _ambient(g[ambient])[2] if ambient and ambient in g else np.nan
        log = (
            m.get("file")
            if m.get("file") is not None
            else (g["log"].iloc[0] if "log" in g and len(g) else "")
        )
        rows.append(
            [
                rid,
                str(log),
                str(m.get("role", "")),
                m.get("speed_rpm", speed.median() if len(speed) else np.nan),
                m.get("speed_min_rpm", speed.min() if len(speed) else np.nan),
                m.get("speed_max_rpm", speed.max() if len(speed) else np.nan),
                str(m.get("kind") or ""),
                first,
                last,
                first_s,
                last_s,
                dur,
                lo,
                hi,
                hi - lo,
                amb,
            ]
        )
    return pd.DataFrame(rows, columns=RUN_COLUMNS)


def _date(x) -> dt.date | None:
    try:
        return dt.date.fromisoformat(str(x)[:10])
    except ValueError:
        return None


def instrument_record(
    instruments: dict, ambient: str | None, sensors: list, roles: dict, last_log=None
) -> dict:
    """The test conditions of ``report.instruments`` and what is missing.

    Parameters
    ----------
    instruments : dict
        ``report.instruments`` (every key present: ``rafi.settings``).
    ambient : str or None
        ``report.ambient_sensor``.
    sensors : list of str
        The temperature sensors with readings in the logs.
    roles : dict
        sensor -> what the report uses it for (key sensor, coolant, ambient).
    last_log : datetime, optional
        The last logged sample: a calibration dated after it is flagged.

    Returns
    -------
    dict
        ``fields`` (label, value or ``None``), ``positions`` (sensor, position or ``None``,
        role), ``calibration`` (instrument, date, flag) and ``missing`` (labels of what the
        configuration does not give; empty when complete).
    """
    missing = []
    fields = []
    given = {
        "machine_serial": instruments.get("machine_serial"),
        "controller": instruments.get("controller"),
        "probe": instruments.get("probe"),
    }
    for key, label in INSTRUMENT_FIELDS.items():
        v = given[key]
        v = None if v is None or str(v).strip() == "" else str(v)
        fields.append((label, v, key))
        if v is None:
            missing.append(f"{label} (report.instruments.{key})")
    if not ambient:
        missing.append("ambient sensor (report.ambient_sensor)")
    pos = {str(k): str(v) for k, v in (instruments.get("sensor_positions") or {}).items()}
    positions = [(s, pos.get(s), roles.get(s, "")) for s in sensors]
    unplaced = [s for s in sensors if s not in pos]
    if sensors and len(unplaced) == len(sensors):
        missing.append("sensor positions (report.instruments.sensor_positions)")
    elif unplaced:
        missing.append("positions of " + ", ".join(unplaced) + " (report.instruments.sensor_positions)")
    cal = []
    last_date = pd.Timestamp(last_log).date() if last_log is not None and pd.notna(last_log) else None
    for name, date in (instruments.get("calibration") or {}).items():
        d = _date(date)
        flag = ""
        if d is None:
            flag = "not an ISO 8601 date"
        elif last_date is not None and d > last_date:
            flag = "after the last logged sample"
        cal.append((str(name), str(date), flag))
    if not cal:
        missing.append("calibration dates (report.instruments.calibration)")
    return {"fields": fields, "positions": positions, "calibration": cal, "missing": missing}


def has_time(t) -> bool:
    """Whether ``t`` is a logged clock time (not ``None`` or ``NaT``)."""
    return t is not None and not pd.isna(t)


def fmt_elapsed(seconds) -> str:
    """Seconds since a log's first sample as the report shows them for a log without a clock:
    ``+12.50 h``; an en dash for none."""
    return fmt_num(float(seconds) / 3600.0, 2, "h", signed=True) if isnum(seconds) else DASH


def _day(t) -> dt.date | None:
    return None if t is None or pd.isna(t) else pd.Timestamp(t).date()


def _fmt_time(t, day=None) -> str:
    if t is None or pd.isna(t):
        return DASH
    t = pd.Timestamp(t)
    return t.strftime("%H:%M:%S") if day is not None and t.date() == day else t.strftime("%Y-%m-%d %H:%M:%S")


def _sensor_roles(res: dict, settings: dict, ambient) -> dict:
    key = [str(s) for s in (res.get("key_sensors_json") or {}).get("sensors") or []]
    roles: dict = {}
    for s in key:
        roles.setdefault(s, []).append("key sensor of RAFI")
    for s in settings["report"].get("coolant_sensors") or []:
        roles.setdefault(str(s), []).append("coolant")
    if ambient:
        roles.setdefault(str(ambient), []).append("ambient")
    return {s: ", ".join(v) for s, v in roles.items()}


def with_log_clock(frame: pd.DataFrame, runs: pd.DataFrame | None) -> pd.DataFrame:
    """``frame`` with ``log`` and ``log_t_s``: from ``runs.csv`` (``file``, ``start_s``) where a
    ``runs.parquet`` written before those columns existed lacks them (``log_t_s`` = the run's
    ``t_s`` + its ``start_s``; a run without ``start_s`` keeps its own clock)."""
    if "log" in frame and "log_t_s" in frame:
        return frame
    meta = runs.assign(run_id=runs["run_id"].astype(str)).set_index("run_id") if runs is not None else None
    rid = frame["run_id"].astype(str)
    out = frame.copy()
    if "log" not in out:
        has = meta is not None and "file" in meta
        out["log"] = rid.map(meta["file"]).fillna(rid) if has else rid
    if "log_t_s" not in out:
        start = rid.map(meta["start_s"]) if meta is not None and "start_s" in meta else 0.0
        out["log_t_s"] = pd.to_numeric(out["t_s"], errors="coerce") + pd.to_numeric(
            start, errors="coerce"
        ).fillna(0.0)
    return out


def _logged_sensors(frame: pd.DataFrame) -> list:
    """The machine's sensors (:func:`rafi.contract.sensors.run_sensors`) with a value, in order."""
    from rafi.contract.sensors import run_sensors

    return [c for c in run_sensors(frame) if pd.to_numeric(frame[c], errors="coerce").notna().any()]


def _role_text(role) -> str:
    return str(role).replace("validation_", "valid.\u00a0") or DASH


def _percent(widths) -> list:
    """Column widths as percentages summing to at most 100 (rounded down to 0.1)."""
    total = float(sum(widths))
    return [float(np.floor(1000.0 * w / total)) / 10.0 for w in widths]


def _span(r: dict) -> dict:
    """The first and last sample of a log or run as the tables show them (the last one without
    its date when on the day of the first); hours since the log's first sample where the log has
    no clock (:func:`fmt_elapsed`), never a date."""
    if not has_time(r["first_time"]) and not has_time(r["last_time"]):
        return {"first_sample": fmt_elapsed(r.get("first_s")), "last_sample": fmt_elapsed(r.get("last_s"))}
    return {
        "first_sample": _fmt_time(r["first_time"]),
        "last_sample": _fmt_time(r["last_time"], _day(r["first_time"])),
    }


def _logs_rows(logs: pd.DataFrame, one_run) -> list[dict]:
    """The Logs table's rows; ``one_run`` (:func:`run_record` indexed by log, each log one run)
    adds the run's ``role``, ``speed`` and ``thermal_drift_um``."""
    rows = []
    for r, orig in zip(records(logs), logs.to_dict("records")):
        row = {**r, **_span(orig), "period": fmt_period(orig["period_s"])}
        if one_run is not None:
            rr = one_run.loc[orig["log"]].to_dict()
            row.update(
                role=_role_text(rr["role"]), speed=fmt_run_speed(rr), thermal_drift_um=rr["thermal_drift_um"]
            )
        rows.append(row)
    return rows


def _logs_widths(one_run: bool, ambient) -> list:
    """The Logs table's column widths (%): the columns ``test_record.html.j2`` sets."""
    widths = [19] + ([13, 11] if one_run else []) + [18, 10, 7, 8, 7]
    widths += [10] if one_run else []
    widths += [7, 7, 9] if ambient else []
    return _percent(widths)


def _runs_rows(rr: pd.DataFrame) -> list[dict]:
    """Thermal drift per run (logs cut into several runs): :func:`run_record`'s rows."""
    return [
        {**r, **_span(orig), "role": _role_text(orig["role"]), "speed": fmt_run_speed(orig)}
        for r, orig in zip(records(rr), rr.to_dict("records"))
    ]


def section_test_record(res: dict, settings: dict) -> dict:
    """The section's context.

    Parameters
    ----------
    res : dict
        Loaded inputs (:func:`rafi.report.inputs.load_results`): ``runs_parquet``,
        ``runs_csv``, ``key_sensors_json``.
    settings : dict
        The machine's settings (``report.ambient_sensor``, ``report.instruments``,
        ``report.coolant_sensors``, ``sample_period_s``; ``input`` and ``report.paper_rig`` name
        the probe).

    Returns
    -------
    dict
        ``measured`` (where the probe measured dz, :func:`rafi.report.probe.probe_words`),
        ``logs`` and ``runs`` (rows: :func:`log_record`'s and :func:`run_record`'s, with the
        span, role, speed and period as text; ``None`` without ``runs.parquet``; ``runs``
        ``None`` too when each log is one run, ``logs_one_run``: then the logs carry the run's
        role, speed and drift) and their ``logs_widths`` / ``runs_widths``, ``ambient`` (the
        sensor or ``None``), ``ambient_missing`` (logs where the named sensor has no reading),
        ``period_note`` (the configured period differs from the one found), ``no_clock`` (logs
        without a clock: their spans are hours since their first sample), ``instruments``
        (``label``, ``value`` or ``None``), ``positions`` (one or two lists of ``sensor``,
        ``position`` or ``None``, ``role``), ``calibration`` (``instrument``, ``date``,
        ``flag``, ``flagged``; or ``None``) and ``missing``.
    """
    rep = settings["report"]
    ambient = rep.get("ambient_sensor") or None
    frame = res.get("runs_parquet")
    runs = res.get("runs_csv")
    out: dict = {
        "measured": probe_words(settings),
        "logs": None,
        "logs_one_run": False,
        "logs_widths": [],
        "runs": None,
        "runs_widths": [],
        "ambient": ambient,
        "ambient_missing": [],
        "period_note": "",
        "n_logs": 0,
        "n_runs": 0,
        "no_clock": [],
    }
    sensors: list = []
    last_log = None
    if frame is not None and len(frame):
        frame = with_log_clock(frame, runs)
        logs = log_record(frame, ambient)
        out["n_logs"] = len(logs)
        sensors = _logged_sensors(frame)
        out["no_clock"] = [str(lg) for lg, t in zip(logs["log"], logs["first_time"]) if not has_time(t)]
        ends = [t for t in logs["last_time"] if t is not None and pd.notna(t)]
        last_log = max(ends) if ends else None
        rr = run_record(frame, runs, ambient)
        out["n_runs"] = len(rr)
        # each log one run: one table (the run's role, speed and drift beside its log's span)
        whole = len(rr) == len(logs) and rr["log"].nunique() == len(rr) and set(rr["log"]) == set(logs["log"])
        out["logs"] = _logs_rows(logs, rr.set_index("log") if whole else None)
        out["logs_one_run"] = whole
        out["logs_widths"] = _logs_widths(whole, ambient)
        out["runs"] = None if whole else _runs_rows(rr)
        out["runs_widths"] = _percent([20, 12, 11, 18, 10, 7, 7, 7, 9] + ([9] if ambient else []))
        out["ambient_missing"] = [
            str(lg) for lg, v in zip(logs["log"], logs["ambient_variation_k"]) if ambient and not isnum(v)
        ]
        configured = settings.get("sample_period_s")
        found = sorted({float(p) for p in logs["period_s"] if isnum(p)})
        if isnum(configured) and found and any(abs(p - float(configured)) > 1e-6 for p in found):
            out["period_note"] = (
                f"The configured sample period (sample_period_s = {fmt_period(configured)}) differs "
                "from the period found in the data (" + ", ".join(fmt_period(p) for p in found) + ")."
            )
    inst = instrument_record(
        rep.get("instruments") or {}, ambient, sensors, _sensor_roles(res, settings, ambient), last_log
    )
    out["missing"] = inst["missing"]
    out["instruments"] = [{"label": label, "value": v} for label, v, _ in inst["fields"]]
    placed = [
        {"sensor": s, "position": p, "role": role}
        for s, p, role in inst["positions"]
        if p is not None or role
    ]
    half = (len(placed) + 1) // 2 if len(placed) > 6 else len(placed)
    out["positions"] = (
        [part for part in (placed[:half], placed[half:]) if part]
        if any(p[1] is not None for p in inst["positions"])
        else []
    )
    out["calibration"] = [
        {"instrument": name, "date": date, "flag": flag, "flagged": bool(flag)}
        for name, date, flag in inst["calibration"]
    ] or None
    return out
