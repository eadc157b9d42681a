"""Offline estimation: every online Jacobian estimator run over a recorded (Delta s, Delta r).

`rodctl estimate RUN_OR_RECORDING` (docs/recordings.md). The estimators see the pairs exactly as
the live loop feeds them (`rodctl.method.Method`): the moves made while a frame was lost are
summed into the next good frame's pair, J_0 is the least-squares fit of the first pairs (a
rodctl run's own probing moves; the first `init` pairs of a recording) and every later pair is
one `update`. Before each update the current estimate predicts the pair's Delta s from its
Delta r; the one-step-ahead prediction error ||Delta s - J Delta r|| is compared with two
references: the zero-motion predictor (Delta s = 0, error ||Delta s||) and one J fitted by least
squares in hindsight over all the pairs (what a constant Jacobian could do at best).

On a rodctl run with the logged feature (`feature="logged"`) the estimates reproduce the live
run's J bit for bit (tests/test_estimate.py), since the same code folds the same float64 pairs.
An estimator that fails ends its own row with a named outcome (`diverged`, `failed`), never the
command.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rodctl import fixedla as fla
from rodctl.errors import UserError
from rodctl.estimation.base import EstimatorDiverged
from rodctl.estimation.probing import fit_jacobian

__all__ = [
    "EstimateResult",
    "Pairs",
    "data_scaled_settings",
    "estimate",
    "online_estimators",
    "pairs_from_recording",
    "pairs_from_run",
    "write_results",
]

#: results.csv columns of `rodctl estimate`, one row per estimator and reference.
RESULT_COLUMNS = [
    "estimator",
    "feature",
    "outcome",
    "updates",
    "median_error",
    "mean_error",
    "ratio_to_zero_motion",
    "ratio_to_hindsight_ls",
    "wall_time_s",
    "note",
]


@dataclass
class Pairs:
    """The (Delta s, Delta r) pairs of a recording, in the order the live loop folds them.

    Attributes:
        init_ds: (n0, p) the pairs J_0 is fitted from (probing), and init_dr (n0, q).
        ds: (n, p) the later pairs' feature changes, dr (n, q) their moves.
        steps: (n,) the record/frame index each later pair ends at.
        feature: the feature space's name.
        logged_J: (n, p, q) the live run's J after each pair (rodctl runs with the logged
            feature), else None.
        run_settings: {estimator type: its settings} of the run's own estimator (a rodctl
            run): `estimate` runs that type with them, as the live loop did.
    """

    init_ds: np.ndarray
    init_dr: np.ndarray
    ds: np.ndarray
    dr: np.ndarray
    steps: np.ndarray
    feature: str
    logged_J: np.ndarray | None = None
    run_settings: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def p(self) -> int:
        return int(self.ds.shape[1])

    @property
    def q(self) -> int:
        return int(self.dr.shape[1])


def _fold(
    s: np.ndarray, u: np.ndarray, ok: np.ndarray
) -> tuple[list[np.ndarray], list[np.ndarray], list[int]]:
    """Pairs (s_k - s_last_good, sum of u since) at every good frame k >= 1 (Method._fold)."""
    ds, dr, at = [], [], []
    unseen = np.zeros(u.shape[1])
    last = None
    for k in range(len(s)):
        if k > 0:
            unseen = unseen + u[k]
        if not ok[k]:
            continue
        if last is not None:
            ds.append(s[k] - s[last])
            dr.append(unseen.copy())
            at.append(k)
        unseen = np.zeros(u.shape[1])
        last = k
    return ds, dr, at


def _encoder(feature: str, points: int, checkpoint: str | None = None) -> Any:
    """The registered feature map `feature` (its default config, with `checkpoint` when
    given: an autoencoder's encoder.npz) for `points` points."""
    from rodctl.features import make_feature_map
    from rodctl.registry import FEATURES, load_plugins

    load_plugins()
    if feature not in FEATURES.names():
        raise UserError(
            f"--feature {feature}: not a feature space; choose points, logged or one of "
            f"{', '.join(FEATURES.names())}"
        )
    model = FEATURES.get(feature).config
    extra = {}
    if checkpoint is not None:
        if "checkpoint" not in model.model_fields:
            raise UserError(f"--checkpoint: the {feature} feature takes no checkpoint")
        if not Path(checkpoint).is_file():
            raise UserError(f"--checkpoint {checkpoint}: no such file")
        extra = _trained_feature(checkpoint, feature)
        extra["checkpoint"] = str(checkpoint)
    try:
        cfg = model(**extra)
    except Exception as exc:  # noqa: BLE001 - e.g. the autoencoder needs a checkpoint path
        raise UserError(f"--feature {feature}: needs settings of its own ({exc})") from None
    try:
        return make_feature_map(cfg, points=points)
    except UserError as exc:
        if "checkpoint" not in model.model_fields:
            raise
        # The run's advice (feature.checkpoint, --set) names config keys estimate has not: keep
        # what does not fit (its indented lines), and say what estimate takes instead.
        text = str(exc)
        misfit = [line for line in text.splitlines()[1:] if line.startswith("  ")]
        which = f"--checkpoint {checkpoint}" if checkpoint else "the packaged encoder"
        raise UserError(
            "\n".join(
                [f"--feature {feature}: {which} does not fit this input ({points} points):"]
                + (misfit or ["  " + text.splitlines()[0]])
                + [
                    f"give --checkpoint an encoder.npz trained for {points} points "
                    f"(`rodctl train-encoder CONFIG --quick --set camera.points={points}`)"
                ]
            )
        ) from None


def _trained_feature(checkpoint: str, feature: str) -> dict[str, Any]:
    """The feature settings a checkpoint was trained with (its architecture: hidden layers,
    latent size), from the config it stores, so the map is built as it was trained."""
    import yaml

    from rodctl.features.autoencoder import EncoderCheckpoint

    ckpt = EncoderCheckpoint.load(checkpoint)  # a UserError naming the file when unreadable
    try:
        trained = (yaml.safe_load(ckpt.config_yaml) or {}).get("feature") or {}
    except yaml.YAMLError:
        trained = {}
    if trained.get("type") not in (None, feature):
        raise UserError(
            f"--checkpoint {checkpoint}: trained for feature {trained.get('type')}, not {feature}"
        )
    return {k: v for k, v in trained.items() if k not in ("checkpoint", "type")}


def pairs_from_run(
    run: Any, feature: str = "logged", init: int | None = None, checkpoint: str | None = None
) -> Pairs:
    """The pairs of a rodctl run read back (`rodctl.replay.read_run`).

    Args:
        run: a `ReadRun`.
        feature: "logged" (the run's own s, which reproduces its J), "points" (the extracted
            pixel centerline flattened) or a registered feature type (default settings).
        init: fit J_0 from the first `init` pairs instead of the run's probing moves (the
            default for an imported recording, which has none: 10 q pairs).
    """
    recs = run.records
    if len(recs) < 2:
        raise UserError(f"{run.path}: the run has {len(recs)} step(s); estimate needs two")
    u = np.array([np.asarray(r.u, dtype=float) for r in recs])
    ok = np.array([bool(r.extraction_ok) for r in recs])
    if feature == "logged":
        s = np.array([np.asarray(r.s, dtype=float) for r in recs])
    elif feature == "points":
        s = np.array([np.asarray(r.extracted, dtype=float).reshape(-1) for r in recs])
    else:
        s = _encode_ok(_encoder(feature, len(recs[0].extracted), checkpoint), recs)
    ds, dr, at = _fold(s, u, ok)
    phases = [recs[k].phase for k in at]
    n0 = sum(1 for ph in phases if ph == "probe")
    probed = init is None and n0 > 0
    if not probed:  # --init, or an imported recording (no probing): the first pairs
        n0 = 10 * u.shape[1] if init is None else int(init)
    if n0 < u.shape[1] or n0 >= len(at):
        if not probed:  # what to pass, as for a points file
            raise UserError(
                _init_refusal(
                    n0, u.shape[1], len(at), given=init is not None, source=run.path, run=True
                )
            )
        raise UserError(
            f"{run.path}: J_0 from its {n0} probing pairs needs control steps after them; the "
            f"run has {len(at)} pairs (--init N fits J_0 from the first N instead)"
        )
    logged = None
    if (
        feature == "logged"
        and recs[-1].phase == "control"
        and any(np.any(np.asarray(recs[k].J) != 0.0) for k in at[n0:])
    ):
        logged = np.array([np.asarray(recs[k].J, dtype=float) for k in at[n0:]])
    return Pairs(
        init_ds=np.array(ds[:n0]),
        init_dr=np.array(dr[:n0]),
        ds=np.array(ds[n0:]),
        dr=np.array(dr[n0:]),
        steps=np.array(at[n0:]),
        feature=feature,
        logged_J=logged,
        run_settings=_run_estimator(run.header.config_yaml),
    )


def _run_estimator(config_yaml: str) -> dict[str, dict[str, Any]]:
    """{type: settings} of the estimator in a run's resolved config (empty if unreadable)."""
    import yaml

    try:
        cfg = yaml.safe_load(config_yaml) or {}
        est = dict(cfg.get("estimator") or {})
        kind = est.pop("type")
    except Exception:  # noqa: BLE001 - a run without a readable config: defaults
        return {}
    return {str(kind): est}


def _encode_ok(fmap: Any, recs: Sequence[Any]) -> np.ndarray:
    """Features of the good frames; lost frames repeat the last good one (never paired)."""
    out, last = [], None
    for r in recs:
        if r.extraction_ok or last is None:
            last = fmap.encode(np.asarray(r.extracted, dtype=float))
        out.append(last)
    return np.array(out)


def pairs_from_recording(
    rec: Any,
    *,
    init: int | None = None,
    feature: str = "points",
    checkpoint: str | None = None,
    source: str | None = None,
) -> Pairs:
    """The pairs of a points recording (`rodctl.recordings.points.read_points`); `source` (its
    file) names it in a refusal.

    Every frame is good; pair k is (points_k - points_{k-1}, pose_k - pose_{k-1}) with the
    pose angles unwrapped. J_0 is fitted from the first `init` pairs (default 10 q: smooth
    motion barely spans all q axes in fewer; 2 q pairs of the test recording give J_0 entries
    three orders of magnitude off).
    """
    pts = np.asarray(rec.points, dtype=float)
    if feature == "points":
        s = pts.reshape(len(pts), -1)
    else:
        fmap = _encoder(feature, pts.shape[1], checkpoint)
        s = np.array([fmap.encode(c) for c in pts])
    r = np.asarray(rec.r, dtype=float)
    u = np.vstack([np.zeros((1, r.shape[1])), np.diff(r, axis=0)])
    ok = np.ones(len(s), dtype=bool)
    ds, dr, at = _fold(s, u, ok)
    q = r.shape[1]
    n0 = 10 * q if init is None else int(init)
    if n0 < q or n0 >= len(ds):
        raise UserError(_init_refusal(n0, q, len(ds), given=init is not None, source=source))
    return Pairs(
        init_ds=np.array(ds[:n0]),
        init_dr=np.array(dr[:n0]),
        ds=np.array(ds[n0:]),
        dr=np.array(dr[n0:]),
        steps=np.array(at[n0:]),
        feature=feature,
    )


def _init_refusal(
    n0: int, q: int, pairs: int, *, given: bool, source: str | None, run: bool = False
) -> str:
    """Why a recording's (or an imported `run`'s) J_0 cannot be fitted from `n0` of its
    `pairs`, and what to do."""
    where = f"{source}: " if source else ""
    what = f"--init {n0}" if given else f"--init (not given) defaults to 10 q = {n0} pairs"
    have = (
        f"the run has {pairs} pairs (Delta s, Delta r)"
        if run
        else f"the recording has {pairs + 1} frames, i.e. {pairs} pairs (Delta s, Delta r)"
    )
    if n0 < q:
        need = f"J_0 needs at least q = {q} pairs"
    else:
        need = f"J_0 is fitted from the first {n0} pairs and at least one pair must follow them"
    if pairs > q and n0 < q:  # too few asked for: the recording has enough
        fix = f"pass --init N with {q} <= N < {pairs}"
    elif pairs > q:
        fix = f"record more frames (at least {n0 + 2}), or pass --init N with {q} <= N < {pairs}"
    else:
        fix = f"record more frames: at least {q + 2} with --init {q}, {10 * q + 2} without --init"
    return f"{where}{what}: {need}; {have}: {fix}"


def noise_level(ds: np.ndarray) -> float:
    """A robust estimate of the per-coordinate noise (std) of s from its changes ds.

    Second differences of s (first differences of ds) cancel a smooth motion and leave
    noise of variance 6 sigma^2 per coordinate (white noise on s): sigma = 1.4826 MAD / sqrt 6.
    """
    dd = np.diff(np.asarray(ds, dtype=float), axis=0)
    if dd.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(dd)) / math.sqrt(6.0))


def data_scaled_settings(pairs: Pairs) -> dict[str, dict[str, float]]:
    """Settings of the baselines' estimators scaled to this recording's motion and noise.

    Their defaults assume rodctl's simulated 1 cm moves and a noise-free extractor. Here, with
    m = median ||dr|| over the pairs (mixed units, as the dead zone's norm):
    - dead zone (every estimator): 0.1 m, a move a tenth of a typical one carries little;
    - Broyden's step gamma: SNR^2 / (1 + SNR^2), SNR = median ||ds|| / (sigma sqrt(2 p)) the
      ratio of a typical feature change to the noise of one (sigma from `noise_level`), so a
      noisy recording averages over about 1/gamma moves instead of fitting each exactly;
    - windowed least squares: a ridge of (0.1 m)^2 (a pseudo-move a tenth of a typical one),
      and a window of 4 q pairs (at least 10).
    The AKF keeps its defaults: it estimates its noise (R, Q) itself.
    """
    m = float(np.median(np.sqrt((pairs.dr**2).sum(axis=1))))
    sig = noise_level(np.vstack([pairs.init_ds, pairs.ds]))
    typical = float(np.median(np.sqrt((pairs.ds**2).sum(axis=1))))
    noise = sig * math.sqrt(2.0 * pairs.p)
    snr2 = (typical / noise) ** 2 if noise > 0.0 else math.inf
    gamma = 1.0 if math.isinf(snr2) else max(snr2 / (1.0 + snr2), 0.05)
    dz = min(0.1 * m, 1.0)
    return {
        "akf": {"dead_zone": dz},
        "broyden": {"dead_zone": dz, "gamma": min(gamma, 1.0)},
        "windowed_ls": {
            "dead_zone": dz,
            "ridge": min((0.1 * m) ** 2, 1e6),
            "window": max(10, 4 * pairs.q),
        },
    }


def online_estimators(names: Sequence[str] | None = None) -> dict[str, Any]:
    """The registered estimators' config models, by name (all of them, or `names`)."""
    from rodctl.registry import ESTIMATORS, load_plugins

    load_plugins()
    known = ESTIMATORS.names()
    if names:
        bad = [n for n in names if n not in known]
        if bad:
            raise UserError(
                f"--estimator {', '.join(bad)}: not a registered estimator; registered: "
                f"{', '.join(known)}"
            )
        known = list(names)
    return {n: ESTIMATORS.get(n).config for n in known}


@dataclass
class EstimatorRun:
    """One estimator's pass over the pairs."""

    name: str
    outcome: str
    errors: np.ndarray  # (n,) one-step errors, NaN after a failure
    J: list[np.ndarray] = field(default_factory=list)
    note: str = ""
    wall_time_s: float = 0.0


@dataclass
class EstimateResult:
    """Everything `estimate` computed: per-estimator runs and the two references."""

    pairs: Pairs
    runs: list[EstimatorRun]
    zero: np.ndarray  # (n,) ||ds||
    hindsight: np.ndarray  # (n,) ||ds - J_ls dr||
    J_ls: np.ndarray | None
    settings: dict[str, dict[str, Any]]

    def rows(self) -> list[dict[str, Any]]:
        """results.csv rows: the references first, then one per estimator."""
        z = float(np.median(self.zero)) if len(self.zero) else math.nan
        finite = self.hindsight[np.isfinite(self.hindsight)]  # all NaN: a short recording
        h = float(np.median(finite)) if len(finite) else math.nan

        def row(name: str, outcome: str, e: np.ndarray, wall: float, note: str) -> dict:
            good = e[np.isfinite(e)]
            med = float(np.median(good)) if len(good) else math.nan
            return {
                "estimator": name,
                "feature": self.pairs.feature,
                "outcome": outcome,
                "updates": int(len(good)),
                "median_error": med,
                "mean_error": float(good.mean()) if len(good) else math.nan,
                "ratio_to_zero_motion": med / z if z > 0 else math.nan,
                "ratio_to_hindsight_ls": med / h if h > 0 else math.nan,
                "wall_time_s": round(wall, 4),
                "note": note,
            }

        out = [
            row("zero_motion", "reference", self.zero, 0.0, "predicts ds = 0"),
            row(
                "hindsight_ls",
                "reference" if self.J_ls is not None else "undetermined",
                self.hindsight,
                0.0,
                "one J fitted to all pairs afterwards",
            ),
        ]
        for r in self.runs:
            out.append(row(r.name, r.outcome, r.errors, r.wall_time_s, r.note))
        return out


def _one(name: str, est: Any, pairs: Pairs, J0: np.ndarray) -> EstimatorRun:
    n = len(pairs.ds)
    errors = np.full(n, np.nan)
    Js: list[np.ndarray] = []
    t0 = time.perf_counter()
    outcome, note = "completed", ""
    try:
        est.reset(J0)
        J = np.asarray(est.J, dtype=float)
        for k in range(n):
            errors[k] = fla.norm(pairs.ds[k] - fla.matvec(J, pairs.dr[k]))
            J = np.asarray(est.update(pairs.ds[k], pairs.dr[k]), dtype=float)
            if not np.isfinite(J).all():
                raise EstimatorDiverged(f"{name}: J became non-finite")
            Js.append(J)
    except EstimatorDiverged as exc:
        outcome, note = "diverged", f"at pair {len(Js) + 1}: {exc}"
    except Exception as exc:  # noqa: BLE001 - a failing estimator ends its own row only
        outcome, note = "failed", f"at pair {len(Js) + 1}: {type(exc).__name__}: {exc}"
    return EstimatorRun(name, outcome, errors, Js, note, time.perf_counter() - t0)


def estimate(
    pairs: Pairs,
    names: Sequence[str] | None = None,
    *,
    scaled: bool = False,
    settings: dict[str, dict[str, Any]] | None = None,
    progress: Any = None,
) -> EstimateResult:
    """Run the online estimators over `pairs` (see the module docstring).

    Args:
        pairs: from `pairs_from_run` or `pairs_from_recording`.
        names: registered estimator names (default: all of them; those that cannot run on a
            recording, the offline ASAP model and the simulator's oracle, get the outcome
            `not_applicable`).
        scaled: use `data_scaled_settings` instead of each estimator's defaults (and instead
            of a rodctl run's own estimator settings, which are used otherwise).
        settings: explicit settings per estimator name (override both).
        progress: called with each estimator's name before it runs.
    """
    try:
        J0 = fit_jacobian(pairs.init_ds, pairs.init_dr)
    except ValueError as exc:
        raise UserError(f"J_0 from the first pairs: {exc}") from None
    chosen = dict(data_scaled_settings(pairs)) if scaled else dict(pairs.run_settings)
    for k, v in (settings or {}).items():
        chosen[k] = {**chosen.get(k, {}), **v}
    runs = []
    for name, model in online_estimators(names).items():
        if progress is not None:
            progress(name)
        est = _build(name, model, chosen.get(name, {}), pairs)
        runs.append(est if isinstance(est, EstimatorRun) else _one(name, est, pairs, J0))
    zero = np.sqrt((pairs.ds**2).sum(axis=1))
    try:
        J_ls = fit_jacobian(pairs.ds, pairs.dr)
        hind = np.array(
            [fla.norm(pairs.ds[k] - fla.matvec(J_ls, pairs.dr[k])) for k in range(len(zero))]
        )
    except ValueError:
        J_ls, hind = None, np.full(len(zero), np.nan)
    return EstimateResult(pairs, runs, zero, hind, J_ls, chosen)


def _build(name: str, model: Any, settings: dict[str, Any], pairs: Pairs) -> Any:
    """The estimator `name` built with `settings` for the pairs' p and q, or, when it cannot
    run here (it needs a simulator or settings `rodctl estimate` does not take, or it is an
    offline model), its `not_applicable` row saying why."""
    from rodctl.registry import BuildContext

    try:
        cfg = model(**settings)
        from rodctl.registry import ESTIMATORS

        est = ESTIMATORS.build(cfg, BuildContext(points=0, p=pairs.p, q=pairs.q))
    except Exception as exc:  # noqa: BLE001 - e.g. the oracle needs a simulator
        from pydantic import ValidationError

        if isinstance(exc, ValidationError):  # e.g. `learned` without its checkpoint
            fields = ", ".join(".".join(map(str, e["loc"])) for e in exc.errors())
            note = f"needs settings that `rodctl estimate` does not take: {fields}"
        else:
            note = " ".join(str(exc).split())[:200]
        return EstimatorRun(name, "not_applicable", np.full(len(pairs.ds), np.nan), note=note)
    if getattr(est, "prepare", None) is not None:
        return EstimatorRun(
            name,
            "not_applicable",
            np.full(len(pairs.ds), np.nan),
            note="an offline model of the rod and camera, not an online estimate",
        )
    return est


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return str(v)


def format_table(result: EstimateResult) -> str:
    """The results as an aligned text table (the columns a reader compares)."""
    cols = [
        "estimator",
        "outcome",
        "updates",
        "median_error",
        "ratio_to_zero_motion",
        "ratio_to_hindsight_ls",
        "wall_time_s",
    ]
    rows = [[_fmt(r[c]) for c in cols] for r in result.rows()]
    width = [max(len(c), *(len(r[i]) for r in rows)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(cols, width, strict=True))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(r, width, strict=True)) for r in rows]
    return "\n".join(lines)


#: The files `estimate` writes in its folder (`write_results`, `write_plots`).
RESULT_FILES = ("results.csv", "steps.csv", "errors.png", "medians.png")


def result_files(out: Path) -> list[Path]:
    """The paths `estimate` writes in `out`; the command never writes over any of them unless
    told --force (a second estimate of a run would otherwise overwrite the first)."""
    return [Path(out) / name for name in RESULT_FILES]


def free_folder(base: Path) -> Path:
    """`base`, or `base-2`, `base-3`, ...: the first that holds none of an estimate's files."""
    base = Path(base)
    k = 1
    while True:
        path = base if k == 1 else base.with_name(f"{base.name}-{k}")
        if not any(p.exists() for p in result_files(path)):
            return path
        k += 1


def write_results(result: EstimateResult, out: Path) -> list[Path]:
    """results.csv (one row per estimator and reference) and steps.csv (per-step errors)."""
    out.mkdir(parents=True, exist_ok=True)
    res = out / "results.csv"
    with res.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=RESULT_COLUMNS)
        w.writeheader()
        for r in result.rows():
            w.writerow(r)
    steps = out / "steps.csv"
    with steps.open("w", newline="") as fh:
        rows = csv.writer(fh)
        names = ["zero_motion", "hindsight_ls", *(r.name for r in result.runs)]
        rows.writerow(["step", *names])
        series = [result.zero, result.hindsight, *(r.errors for r in result.runs)]
        for k, step in enumerate(result.pairs.steps):
            rows.writerow([int(step), *(repr(float(e[k])) for e in series)])
    return [res, steps]


def _finite_median(values: np.ndarray) -> float:
    """The median of the finite values, NaN when there is none (`nanmedian` warns then)."""
    kept = values[np.isfinite(values)]
    return float(np.median(kept)) if len(kept) else math.nan


def write_plots(result: EstimateResult, out: Path) -> list[Path]:
    """errors.png (each estimator's and reference's one-step error per pair, log scale, with a
    running median) and medians.png (a box of each one's errors, the median marked), in `out`.
    matplotlib is imported here, only when plots are asked for."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    out.mkdir(parents=True, exist_ok=True)
    series = [("zero_motion", result.zero), ("hindsight_ls", result.hindsight)]
    series += [(r.name, r.errors) for r in result.runs if np.isfinite(r.errors).any()]
    steps = np.asarray(result.pairs.steps)
    unit = f"units of the {result.pairs.feature} feature"
    paths = []

    fig = Figure(figsize=(9, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    win = max(1, len(steps) // 50)
    for k, (name, e) in enumerate(series):
        e = np.asarray(e, dtype=float)
        good = np.isfinite(e) & (e > 0)
        if not good.any():
            continue
        style: dict[str, Any] = {
            "color": "0.4" if k < 2 else f"C{k - 2}",
            "ls": "--" if k < 2 else "-",
        }
        ax.plot(steps[good], e[good], lw=0.5, alpha=0.25, color=style["color"])
        # running median over 2 win + 1 pairs
        run = np.array([_finite_median(e[max(0, i - win) : i + win + 1]) for i in range(len(e))])
        ok = np.isfinite(run) & (run > 0)
        ax.plot(steps[ok], run[ok], lw=1.4, label=name, **style)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel(f"‖Δs − J Δr‖ ({unit})")
    ax.set_title(f"One-step prediction error, feature {result.pairs.feature} (running median)")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    paths.append(out / "errors.png")
    fig.savefig(paths[-1])

    fig = Figure(figsize=(max(5.0, 1.1 * len(series) + 2), 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    data = [np.asarray(e, float)[np.isfinite(e) & (np.asarray(e) > 0)] for _, e in series]
    keep = [i for i, d in enumerate(data) if len(d)]
    ax.boxplot([data[i] for i in keep], showfliers=False, medianprops={"color": "C3", "lw": 2})
    ax.set_xticks(range(1, len(keep) + 1), [series[i][0] for i in keep], rotation=30, ha="right")
    ax.set_yscale("log")
    ax.set_ylabel(f"one-step error ({unit})")
    ax.set_title("One-step error per estimator (box: quartiles, line: median)")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    paths.append(out / "medians.png")
    fig.savefig(paths[-1])
    return paths
