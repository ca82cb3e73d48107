"""The training envelope of a ridge kind: outside it, each feature is held at the envelope's edge.

A linear model extrapolates without limit: a `dynamic` ridge whose penalty sat at the edge of its
grid scored 228 um test MAE (864 um max) on a turning centre whose test days lay mostly above the
training temperatures, where no compensation was 23 um (issue 46). So every ridge kind records, at
its fit, the range of each of its features over the training rows (a rise, a filtered rise, a
speed term, a heat input), and predicts from the features *bounded* to that range widened by
:data:`ENVELOPE_MARGIN` of its span on each side: inside the envelope nothing changes, outside it
the model holds the value it has at the envelope's edge instead of extrapolating freely.

A box per feature cannot catch a combination of in-range features the fit never saw (on the turning
centre, features held exactly inside their training range still gave 172 um), so the prediction
itself is also held inside the training displacement range (``output_range``) widened by
:data:`OUTPUT_MARGIN` of its span on each side: a cap on the worst case, chosen one level up (a
study archived 2026-11-29: ``git show 62841e2:benchmarks/bench_envelope.py``) as the widest margin
that costs nothing measurable.

A combination can also be bounded where it happens: with ``components`` (``models:
component_envelope``, on by default) the envelope records the principal components of the
standardised training features and holds each component's score inside its training range widened
by the same margin times the larger of its span and what it would add to the prediction
(:func:`fit_components`, :func:`component_bounds`, :func:`bound_components`), before the
per-feature box; a row inside is unchanged to the bit, a row outside moves along the clipped
components only.

The artefact carries the envelope (``envelope``: ``margin``, ``feature_ranges``, from
2026-11-29 ``output_margin`` and ``output_range``, and with the components ``components``), so the
streaming compensator bounds exactly as the batch code does (:mod:`rafi.deploy.compensator`); an
artefact without it is evaluated unbounded, as it was fitted.

NumPy only (the compensator imports it).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ENVELOPE_MARGIN",
    "OUTPUT_MARGIN",
    "bound_components",
    "bound_features",
    "bound_output",
    "component_bounds",
    "component_excess",
    "component_reach",
    "component_scores",
    "envelope_bounds",
    "fit_components",
    "fit_envelope",
    "join_envelope",
    "key_range_excess",
    "key_range_inputs",
    "output_bounds",
    "range_excess",
]

#: The share of a feature's training span the envelope extends beyond it on each side. One span:
#: on the twin's linear physics a test at 1.5 x the highest trained speed loses 0.03 um against the
#: free extrapolation (0.1 of a span lost 3.5 um, ``tests/test_envelope.py``), while a model whose
#: features leave their training range far (a runaway) is held at most one span beyond it.
ENVELOPE_MARGIN = 1.0

#: The share of the training displacement span the prediction may go beyond it on each side.
#: Judged one level up (2026-11-29, an archived study, ``docs/decisions.md``: whole-run CV of the training
#: runs of 6 real logs and 22 foreign machines, and the foreign machines' test days): 2, 1 and 0.5
#: spans cost nothing measurable (mean ratio to the free prediction 1.0000, 1.0000, 1.0001), a
#: quarter of a span already 7 % (the foreign machines' physics does extrapolate); by the criterion
#: written before the run the widest of those.
OUTPUT_MARGIN = 2.0

#: The smallest span (K) a rise's excess beyond its training range is measured in
#: (:func:`range_excess`): a sensor that barely moved in training is not "far outside" by 0.01 K.
MIN_SPAN_K = 0.1


def _range(values: np.ndarray) -> list:
    finite = values[np.isfinite(values)]
    return [float(finite.min()), float(finite.max())] if finite.size else [None, None]


def _join(a: list, b: list) -> list:
    lows = [v for v in (a[0], b[0]) if v is not None]
    highs = [v for v in (a[1], b[1]) if v is not None]
    return [min(lows) if lows else None, max(highs) if highs else None]


#: A component whose singular value is below this share of the largest has no training variance
#: to speak of (exactly collinear features): it is left out, never bounded.
COMPONENT_RTOL = 1e-10


def fit_envelope(
    features: np.ndarray,
    target: np.ndarray | None = None,
    margin: float = ENVELOPE_MARGIN,
    *,
    components: bool = False,
) -> dict:
    """The envelope of training ``features`` (rows x features) and, given, of the training
    ``target`` (the displacement) as the artefact records it; with ``components``, also the
    principal components of the features (:func:`fit_components`).

    A feature without a finite training value gets ``[null, null]`` (never bounded).
    """
    x = np.asarray(features, dtype=float)
    env = {"margin": float(margin), "feature_ranges": [_range(column) for column in x.T]}
    if target is not None:
        env["output_margin"] = OUTPUT_MARGIN
        env["output_range"] = _range(np.asarray(target, dtype=float))
    if components:
        fitted = fit_components(x)
        if fitted is not None:
            env["components"] = fitted
    return env


def fit_components(features: np.ndarray) -> dict | None:
    """The principal components of training ``features`` (rows x features) as the envelope
    records them: ``columns`` (the features that spread beyond rounding), their ``center`` and ``scale``
    (mean and standard deviation), ``vectors`` (one list per component, over those columns; the
    components of non-zero variance, :data:`COMPONENT_RTOL`) and ``score_ranges`` (each
    component's training range). Rows with a NaN are left out; None with fewer than two rows or
    two varying features (nothing to combine)."""
    x = np.asarray(features, dtype=float)
    x = x[np.isfinite(x).all(axis=1)]
    if len(x) < 2:
        return None
    center = x.mean(axis=0)
    scale = x.std(axis=0)
    # a spread below rounding of the feature's size is none (it would divide rounding noise)
    columns = np.flatnonzero(scale > COMPONENT_RTOL * np.abs(x).max(axis=0))
    if len(columns) < 2:
        return None
    z = (x[:, columns] - center[columns]) / scale[columns]
    _, singular, vt = np.linalg.svd(z, full_matrices=False)
    vectors = vt[singular > singular[0] * COMPONENT_RTOL]
    scores = z @ vectors.T
    return {
        "columns": [int(c) for c in columns],
        "center": [float(v) for v in center[columns]],
        "scale": [float(v) for v in scale[columns]],
        "vectors": vectors.tolist(),
        "score_ranges": [[float(lo), float(hi)] for lo, hi in zip(scores.min(axis=0), scores.max(axis=0))],
    }


def _components(envelope: dict | None, n_features: int, coef=None) -> tuple | None:
    """The envelope's components as arrays: ``(columns, center, scale, vectors, ranges, gain,
    span)``, ``ranges`` their training score ranges (components x 2), ``gain`` the model's
    ``|gain|`` along each (um per unit score; None without ``coef`` or an output range) and
    ``span`` the training displacement span (None without an output range). None without
    components.

    Raises
    ------
    ValueError
        Components of a column the model does not have.
    """
    comp = (envelope or {}).get("components")
    if not comp:
        return None
    columns = np.asarray(comp["columns"], dtype=int)
    if columns.size and columns.max() >= n_features:
        raise ValueError(f"the envelope's components read column {columns.max()}, the model has {n_features}")
    rng = np.asarray(comp["score_ranges"], dtype=float).reshape(-1, 2)
    vectors = np.asarray(comp["vectors"], dtype=float).reshape(len(rng), len(columns))
    scale = np.asarray(comp["scale"], dtype=float)
    out = envelope.get("output_range") or [None, None]
    span = float(out[1]) - float(out[0]) if out[0] is not None and out[1] is not None else None
    gain = None
    if coef is not None and span is not None:
        gain = np.abs(vectors @ (scale * np.asarray(coef, dtype=float)[columns]))
    return columns, np.asarray(comp["center"], dtype=float), scale, vectors, rng, gain, span


def component_bounds(envelope: dict | None, n_features: int, coef=None) -> tuple | None:
    """``(columns, center, scale, vectors, low, high)`` of the envelope's components; None
    without components (the default, or an artefact fitted before them).

    Each score range is widened by the envelope's margin ``m`` times the larger of its own span
    and ``Y / |g|``: ``g`` the model's gain along the component (``coef``, the model's
    coefficients, in um per unit score) and ``Y`` the training displacement span. A direction the
    model reads with a small gain is held only where it would add more than ``m`` training spans
    to the prediction; without ``coef`` or an output range, the score span alone.

    Raises
    ------
    ValueError
        Components of a column the model does not have.
    """
    parts = _components(envelope, n_features, coef)
    if parts is None:
        return None
    columns, center, scale, vectors, rng, gain, span = parts
    reach = rng[:, 1] - rng[:, 0]
    if gain is not None:
        with np.errstate(divide="ignore"):
            reach = np.maximum(reach, span / gain)
    pad = float(envelope["margin"]) * reach
    return columns, center, scale, vectors, rng[:, 0] - pad, rng[:, 1] + pad


def component_reach(envelope: dict | None, n_features: int, coef=None) -> tuple | None:
    """What :func:`component_excess` measures against, constants of a fitted model:
    ``(columns, center, scale, vectors, low, high, weight)``, the envelope's components with
    their training score ranges (no margin) and per component ``|g| / Y`` (``g`` the model's gain
    along it in um per unit score, ``Y`` the training displacement span). None without components,
    coefficients or a training displacement span (the excess is then 0).

    Raises
    ------
    ValueError
        Components of a column the model does not have.
    """
    parts = _components(envelope, n_features, coef)
    if parts is None or parts[5] is None or not parts[6] > 0:
        return None
    columns, center, scale, vectors, rng, gain, span = parts
    return columns, center, scale, vectors, rng[:, 0], rng[:, 1], gain / span


def component_scores(features: np.ndarray, parts) -> np.ndarray | None:
    """The principal-component scores of ``features`` (rows x components) on the components of
    ``parts``: what :func:`component_bounds` or :func:`component_reach` returned for one envelope
    (they share its components, so one set of scores serves both). None without components."""
    if parts is None:
        return None
    columns, center, scale, vectors = parts[:4]
    return ((np.asarray(features, dtype=float)[..., columns] - center) / scale) @ vectors.T


def component_excess(features: np.ndarray, reach, scores: np.ndarray | None = None) -> np.ndarray:
    """Per row, how far the prediction reaches beyond the combinations of features the model was
    trained on: over the principal components of its standardised features (:func:`component_reach`),
    the sum of each score's distance beyond its training range times the model's gain along it, in
    training displacement spans. 0 inside every range, for a row with a NaN and without ``reach``.
    The prediction interval widens with it beside the key sensors' :func:`range_excess`
    (:mod:`rafi.family.interval_rule`): a direction of the temperatures the training never showed
    (a heat source nobody put a sensor on, a sensor reseated, a warm start) is one the model was
    never checked on, though every sensor may be inside its own range. ``scores``: the rows'
    :func:`component_scores` if already computed."""
    x = np.asarray(features, dtype=float)
    if reach is None:
        return np.zeros(x.shape[:-1])
    lo, hi, weight = reach[4:]
    if scores is None:
        scores = component_scores(x, reach)
    with np.errstate(invalid="ignore"):
        beyond = np.maximum(lo - scores, scores - hi)
    beyond = np.where(np.isfinite(beyond), np.maximum(beyond, 0.0), 0.0)
    total = beyond @ weight
    return np.where(np.isfinite(x).all(axis=-1), total, 0.0)


def bound_components(
    features: np.ndarray, bounds, scores: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``features`` with each principal component's score held inside ``bounds``
    (:func:`component_bounds`) and, per row, whether any score was outside. A row inside is
    returned unchanged to the bit; a row outside moves along its clipped components only (the
    other components' scores stay as they were). A row with a NaN is never outside. Without
    bounds: unchanged. ``scores``: the rows' :func:`component_scores` if already computed."""
    x = np.asarray(features, dtype=float)
    if bounds is None:
        return x, np.zeros(x.shape[:-1], dtype=bool)
    columns, center, scale, vectors, lo, hi = bounds
    if scores is None:
        scores = component_scores(x, bounds)
    with np.errstate(invalid="ignore"):
        outside = ((scores < lo) | (scores > hi)).any(axis=-1)
    if not outside.any():
        return x, outside
    shift = ((np.clip(scores, lo, hi) - scores) @ vectors) * scale
    out = x.copy()
    out[..., columns] = np.where(outside[..., None], x[..., columns] + shift, x[..., columns])
    return out, outside


def join_envelope(envelope: dict | None, features: np.ndarray, target: np.ndarray | None = None) -> dict:
    """``envelope`` (a prior's) joined with the range of new training ``features`` and ``target``:
    an adapted model stands on both (:mod:`rafi.family.adapted`); the prior's components, if it
    has them, keep their directions and widen their score ranges by the new rows'. Without a prior
    envelope: the new one."""
    margin = ENVELOPE_MARGIN if not envelope else float(envelope["margin"])
    new = fit_envelope(features, target, margin)
    if not envelope or len(envelope["feature_ranges"]) != len(new["feature_ranges"]):
        return new
    joined = {
        "margin": new["margin"],
        "feature_ranges": [_join(a, b) for a, b in zip(envelope["feature_ranges"], new["feature_ranges"])],
    }
    if "output_range" in new:
        prior = envelope.get("output_range", [None, None])
        joined["output_margin"] = float(envelope.get("output_margin", OUTPUT_MARGIN))
        joined["output_range"] = _join(prior, new["output_range"])
    if envelope.get("components"):
        joined["components"] = _join_components(envelope["components"], np.asarray(features, dtype=float))
    return joined


def _join_components(comp: dict, features: np.ndarray) -> dict:
    """The prior's components with their score ranges widened by the scores of ``features``."""
    columns = np.asarray(comp["columns"], dtype=int)
    x = features[np.isfinite(features).all(axis=1)]
    if not len(x):
        return comp
    vectors = np.asarray(comp["vectors"], dtype=float).reshape(-1, len(columns))
    scores = ((x[:, columns] - np.asarray(comp["center"])) / np.asarray(comp["scale"])) @ vectors.T
    ranges = [
        _join(list(r), [float(lo), float(hi)])
        for r, lo, hi in zip(comp["score_ranges"], scores.min(axis=0), scores.max(axis=0))
    ]
    return {**comp, "score_ranges": ranges}


def envelope_bounds(envelope: dict | None, n_features: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``(low, high)`` per feature: the training range widened by the margin (infinite where a
    feature has no range); None without an envelope (an artefact fitted before it).

    Raises
    ------
    ValueError
        An envelope of another number of features than the model's.
    """
    if not envelope:
        return None
    ranges = envelope["feature_ranges"]
    if len(ranges) != n_features:
        raise ValueError(f"the envelope has {len(ranges)} features, the model {n_features}")
    lo = np.array([-np.inf if a is None else float(a) for a, _ in ranges])
    hi = np.array([np.inf if b is None else float(b) for _, b in ranges])
    with np.errstate(invalid="ignore"):
        pad = float(envelope["margin"]) * np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    return lo - pad, hi + pad


def bound_features(features: np.ndarray, bounds) -> tuple[np.ndarray, np.ndarray]:
    """``features`` held inside ``bounds`` (:func:`envelope_bounds`) and, per row, whether any
    feature was outside (NaN stays NaN and is never outside). Without bounds: unchanged."""
    x = np.asarray(features, dtype=float)
    if bounds is None:
        return x, np.zeros(x.shape[:-1], dtype=bool)
    lo, hi = bounds
    with np.errstate(invalid="ignore"):
        outside = ((x < lo) | (x > hi)).any(axis=-1)
    return np.clip(x, lo, hi), outside


def output_bounds(envelope: dict | None) -> tuple[float, float] | None:
    """``(low, high)`` of a prediction: the training displacement range widened by the output
    margin; None without one (an artefact fitted before it, or no finite training target)."""
    rng = (envelope or {}).get("output_range")
    if not rng or rng[0] is None or rng[1] is None:
        return None
    lo, hi = float(rng[0]), float(rng[1])
    pad = float(envelope.get("output_margin", OUTPUT_MARGIN)) * (hi - lo)
    return lo - pad, hi + pad


def bound_output(predicted, bounds) -> tuple[np.ndarray, np.ndarray]:
    """``predicted`` held inside ``bounds`` (:func:`output_bounds`) and whether it was outside
    (NaN stays NaN and is never outside). Without bounds: unchanged."""
    p = np.asarray(predicted, dtype=float)
    if bounds is None:
        return p, np.zeros(p.shape, dtype=bool)
    lo, hi = bounds
    with np.errstate(invalid="ignore"):
        outside = (p < lo) | (p > hi)
    return np.clip(p, lo, hi), outside


def range_excess(values: np.ndarray, ranges: np.ndarray, spans: np.ndarray) -> np.ndarray:
    """Per row, how far ``values`` (rows x inputs) lie beyond their training ``ranges``
    (inputs x 2), in training ``spans`` (per input): the largest of ``(low - x) / span`` and
    ``(x - high) / span`` over the inputs, 0 inside every range. NaN counts as inside. The
    prediction interval widens with it (:mod:`rafi.family.interval_rule`)."""
    x = np.asarray(values, dtype=float)
    rng = np.asarray(ranges, dtype=float).reshape(-1, 2)
    span = np.asarray(spans, dtype=float)
    with np.errstate(invalid="ignore"):
        beyond = np.maximum(rng[:, 0] - x, x - rng[:, 1]) / span
    beyond = np.where(np.isfinite(beyond), np.maximum(beyond, 0.0), 0.0)
    return beyond.max(axis=-1) if beyond.shape[-1] else np.zeros(beyond.shape[:-1])


def input_spans(ranges: np.ndarray, *, speed_last: bool) -> np.ndarray:
    """The span each input's excess is measured in (:func:`range_excess`): its training range,
    at least :data:`MIN_SPAN_K` for a temperature rise; the speed (the last input when
    ``speed_last``) in its trained range or, trained at one speed, in that speed."""
    rng = np.asarray(ranges, dtype=float).reshape(-1, 2)
    span = np.maximum(rng[:, 1] - rng[:, 0], MIN_SPAN_K)
    if speed_last and len(span):
        lo, hi = rng[-1]
        span[-1] = max(hi - lo, abs(hi), 1.0)
    return span


def key_range_inputs(rise_ranges, speed_range) -> tuple[np.ndarray, np.ndarray]:
    """The ranges and spans :func:`key_range_excess` measures against: the key sensors' rise
    ranges then the speed range, the speed's span in :func:`input_spans`' way (constants of an
    artefact: the streaming compensator computes them once)."""
    ranges = np.vstack(
        [np.asarray(rise_ranges, dtype=float).reshape(-1, 2), np.asarray(speed_range, dtype=float)]
    )
    return ranges, input_spans(ranges, speed_last=True)


def key_range_excess(
    rises: np.ndarray, speed_rpm: np.ndarray, rise_ranges, speed_range, *, inputs=None
) -> np.ndarray:
    """:func:`range_excess` of the key sensors' ``rises`` (rows x sensors, ranges per sensor) and
    the speed together, the speed measured in :func:`input_spans`' way: a ridge kind's
    ``range_excess``, the same in ``predict_detail`` and the streaming compensator (``inputs``:
    :func:`key_range_inputs` of the ranges, computed once by the caller; default: here)."""
    ranges, spans = key_range_inputs(rise_ranges, speed_range) if inputs is None else inputs
    values = np.column_stack(
        [np.atleast_2d(np.asarray(rises, dtype=float)), np.asarray(speed_rpm, dtype=float)]
    )
    return range_excess(values, ranges, spans)
