"""What a survey log's sensors really do, measured against its ground truth.

Reads a range-bearing survey log with truth (`truth_pose`, `truth_object`, each detection's
`truth_id`) and prints the statistics a simulator must reproduce to stand for it: the range
error by bearing (a camera that reads depth along its axis, not range), the range spread
once that depth model is taken out, the bearing's robust sigma, tails and per-robot offset,
misread labels, the clock offset of the odometry against the truth and the camera's, the
odometry's heading and translation error over 1-30 s with its per-robot turn and forward
scales, and how long the robots go without a sighting. Truth is used only to measure.

    python benchmarks/real_statistics.py LOG.jsonl [--compare OTHER.jsonl] [--truth-step 1]

With `--compare` the two logs are printed side by side, statistic by statistic (a real log
against a simulated one). Both are measured alike: truth poses are thinned to one per
`--truth-step` seconds per robot (a converted real log has them at 1 Hz, a simulated one
at every odometry record) and interpolated between.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from agrislam.geometry.se2 import wrap_angle
from agrislam.io.sources.jsonl import read_log
from agrislam.records import Detections, Record, TruthObject, TruthPose
from real_scoring import Survey as LoggedSurvey

console = Console(width=200)
BEARING_BINS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, np.inf)  # |bearing|, rad
RANGE_BINS = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, np.inf)  # m
WINDOWS_S = (1.0, 5.0, 15.0, 30.0)  # odometry error growth
MISREAD_RAD = 1.0  # a bearing this far off is the sighting of another landmark
MAX_TRUTH_GAP_S = 2.5  # truth is not interpolated across a longer dropout
GAP_S = (10.0, 30.0)  # long stretches without a sighting
LAGS_S = np.arange(-1.0, 1.0 + 1e-9, 0.01)
MAD_TO_SIGMA = 1.4826  # robust sigma of a Gaussian from its median absolute deviation


@dataclass
class Track:
    """A robot's poses over time, headings unwrapped so they can be interpolated."""

    t: np.ndarray  # (m,)
    pose: np.ndarray  # (m, 3)

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Poses (k, 3) at times t and whether each is covered (no long gap around it)."""
        t = np.asarray(t, float)
        pose = np.column_stack([np.interp(t, self.t, self.pose[:, i]) for i in range(3)])
        k = np.clip(np.searchsorted(self.t, t), 1, len(self.t) - 1)
        span = self.t[k] - self.t[k - 1]
        ok = (t >= self.t[0]) & (t <= self.t[-1]) & (span <= MAX_TRUTH_GAP_S)
        return pose, ok


def _track(t: list[float], poses: list[np.ndarray]) -> Track:
    pose = np.array(poses, float).reshape(-1, 3)
    pose[:, 2] = np.unwrap(pose[:, 2])
    return Track(np.asarray(t, float), pose)


@dataclass
class Survey:
    """A log's robots: odometry and thinned truth tracks, detections as arrays."""

    odometry: dict[str, Track]
    truth: dict[str, Track]
    frames: dict[str, np.ndarray]  # times of the frames that saw something
    landmarks: dict[str, np.ndarray]
    # one row per detection: robot, time, measured range and bearing, landmark id
    robot: np.ndarray
    t: np.ndarray
    range: np.ndarray
    bearing: np.ndarray
    truth_id: np.ndarray


def survey(records: Iterable[Record], truth_step: float = 1.0) -> Survey:
    """A log's records as arrays; truth poses thinned to one per `truth_step` s per robot."""
    records = list(records)
    truth_t: dict[str, list[float]] = {}
    truth: dict[str, list[np.ndarray]] = {}
    frames: dict[str, list[float]] = {}
    landmarks: dict[str, np.ndarray] = {}
    rows: list[tuple[str, float, float, float, str]] = []
    for r in records:
        if isinstance(r, TruthPose):
            times = truth_t.setdefault(r.robot, [])
            if not times or r.t >= times[-1] + truth_step - 1e-9:
                times.append(r.t)
                truth.setdefault(r.robot, []).append(r.pose)
        elif isinstance(r, TruthObject):
            landmarks[r.id] = np.asarray(r.xy, float)
        elif isinstance(r, Detections) and r.objects:
            frames.setdefault(r.robot, []).append(r.t)
            rows += [(r.robot, r.t, d.range, d.bearing, d.truth_id) for d in r.objects]
    odometry = LoggedSurvey("", records).odometry_tracks()  # headings unwrapped
    robot, t, rng, bearing, ids = zip(*rows, strict=True)
    return Survey(
        odometry={k: Track(v[:, 0], v[:, 1:]) for k, v in odometry.items()},
        truth={k: _track(truth_t[k], truth[k]) for k in truth},
        frames={k: np.asarray(v) for k, v in frames.items()},
        landmarks=landmarks,
        robot=np.asarray(robot),
        t=np.asarray(t, float),
        range=np.asarray(rng, float),
        bearing=np.asarray(bearing, float),
        truth_id=np.asarray(ids),
    )


@dataclass
class Residuals:
    """Each detection against the truth: true range and bearing from the interpolated true
    pose, the errors, and the bearing's rate of change there (rad/s)."""

    robot: np.ndarray
    true_range: np.ndarray
    true_bearing: np.ndarray
    range_error: np.ndarray
    bearing_error: np.ndarray
    bearing_rate: np.ndarray


def _range_bearing(pose: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = xy - pose[:, :2]
    return np.hypot(d[:, 0], d[:, 1]), wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[:, 2])


def residuals(s: Survey) -> Residuals:
    keep = np.zeros(len(s.t), bool)
    r_true, b_true, rate = (np.full(len(s.t), np.nan) for _ in range(3))
    xy = np.array([s.landmarks.get(i, (np.nan, np.nan)) for i in s.truth_id], float)
    for name, track in s.truth.items():
        mine = np.flatnonzero(s.robot == name)
        pose, ok = track.at(s.t[mine])
        r_true[mine], b_true[mine] = _range_bearing(pose, xy[mine])
        before, _ = track.at(s.t[mine] - 0.5)
        after, _ = track.at(s.t[mine] + 0.5)
        rate[mine] = wrap_angle(
            _range_bearing(after, xy[mine])[1] - _range_bearing(before, xy[mine])[1]
        )
        keep[mine] = ok & np.isfinite(xy[mine, 0])
    return Residuals(
        robot=s.robot[keep],
        true_range=r_true[keep],
        true_bearing=b_true[keep],
        range_error=s.range[keep] - r_true[keep],
        bearing_error=wrap_angle(s.bearing[keep] - b_true[keep]),
        bearing_rate=rate[keep],
    )


def robust_sigma(x: np.ndarray) -> float:
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x)))) if len(x) else np.nan


def _bins(x: np.ndarray, edges: tuple[float, ...]) -> list[tuple[str, np.ndarray]]:
    out = []
    for lo, hi in pairwise(edges):
        name = f"{lo:g}-{hi:g}" if np.isfinite(hi) else f">{lo:g}"
        out.append((name, (x >= lo) & (x < hi)))
    return out


def depth_model(res: Residuals, good: np.ndarray) -> dict[str, tuple[float, float]]:
    """Per robot (s, k) of r_meas = s r - k r (1 - cos b): a range scale and how much of the
    off-axis shortening of a camera that reads depth along its axis (k = s: r_meas = s r cos b),
    fitted by least squares on the detections `good` with |error| < 0.5 m after a first fit."""
    out = {}
    for name in np.unique(res.robot):
        mine = good & (res.robot == name)
        a = np.column_stack([res.true_range, -res.true_range * (1 - np.cos(res.true_bearing))])
        y = res.range_error + res.true_range
        sel = mine
        for _ in range(3):  # refit without the gross errors of the previous fit
            coef = np.linalg.lstsq(a[sel], y[sel], rcond=None)[0]
            sel = mine & (np.abs(y - a @ coef) < 0.5)
        out[str(name)] = (float(coef[0]), float(coef[1]))
    return out


def camera_statistics(res: Residuals) -> dict[str, str]:
    """Range and bearing errors, misreads, and the camera's clock against the truth."""
    out: dict[str, str] = {"detections": f"{len(res.robot)}"}
    misread = np.abs(res.bearing_error) > MISREAD_RAD
    good = ~misread
    out["misread share (|bearing err| > 1 rad)"] = f"{misread.mean():.2%} ({misread.sum()})"
    out["range median / p95 (m)"] = (
        f"{np.median(res.true_range):.2f} / {np.percentile(res.true_range, 95):.2f}"
    )
    out["|bearing| p95 (rad)"] = f"{np.percentile(np.abs(res.true_bearing), 95):.2f}"
    ab = np.abs(res.true_bearing)
    for name, inside in _bins(ab, BEARING_BINS):
        sel = inside & good
        median = np.median(res.range_error[sel]) if sel.any() else np.nan
        out[f"range err median, |b| {name} (m)"] = f"{median:+.3f} (n {sel.sum()})"
    out["|range err| p95 (m)"] = f"{np.percentile(np.abs(res.range_error[good]), 95):.3f}"
    fit = depth_model(res, good)
    scales = np.array(list(fit.values()))
    out["depth model s per robot"] = " ".join(f"{s:.3f}" for s, _ in scales)
    out["depth model k / s per robot"] = " ".join(f"{k / s:.2f}" for s, k in scales)
    model_error = np.full(len(res.robot), np.nan)
    for name, (s, k) in fit.items():
        mine = res.robot == name
        r, b = res.true_range[mine], res.true_bearing[mine]
        model_error[mine] = res.range_error[mine] + r - (s * r - k * r * (1 - np.cos(b)))
    for name, inside in _bins(res.true_range, RANGE_BINS):
        sel = inside & good
        spread = robust_sigma(model_error[sel])
        out[f"range sigma after model, r {name} m"] = f"{spread:.3f} (n {sel.sum()})"
    sel = good & (res.true_range > 0.5)
    slope = np.polyfit(res.true_range[sel], np.abs(model_error[sel]) * np.sqrt(np.pi / 2), 1)[0]
    out["range sigma per m (slope)"] = f"{slope:.4f}"
    # bearing: per-robot offset, then the robust sigma and tails of what is left
    offset = {n: float(np.median(res.bearing_error[good & (res.robot == n)])) for n in fit}
    centred = res.bearing_error - np.array([offset[str(n)] for n in res.robot])
    c = centred[good]
    sigma = robust_sigma(c)
    per_robot = [robust_sigma(centred[good & (res.robot == n)]) for n in fit]
    out["bearing offset per robot (rad)"] = " ".join(f"{v:+.3f}" for v in offset.values())
    out["bearing robust sigma (rad)"] = f"{sigma:.4f}"
    out["bearing sigma per robot (rad)"] = " ".join(f"{v:.3f}" for v in per_robot)
    out["bearing |err| p95 / sigma"] = f"{np.percentile(np.abs(c), 95) / sigma:.2f}"
    out["bearing share beyond 3 sigma"] = f"{np.mean(np.abs(c) > 3 * sigma):.2%}"
    out["bearing share beyond 6 sigma"] = f"{np.mean(np.abs(c) > 6 * sigma):.2%}"
    # b_meas(t) = b_true(t - lag) = b_true(t) - lag * db/dt: the slope of the error on db/dt
    sel = good & (np.abs(centred) < 5 * sigma)
    lag = -np.polyfit(res.bearing_rate[sel], centred[sel], 1)[0]
    out["camera stamp late vs truth (s)"] = f"{lag:+.3f}"
    return out


def clock_offset(tracks: list[tuple[Track, Track]]) -> float:
    """The lag tau (s) at which the odometry's heading increments over the truth's intervals,
    shifted by tau, correlate best with the truth's, over every (odometry, truth) pair of
    `tracks`: truth(t) ~ odometry(t + tau). Negative: the odometry is stamped ahead (it
    shows a turn before the truth does)."""
    spans, d_truth = [], []
    for odometry, truth in tracks:
        t0, t1 = truth.t[:-1], truth.t[1:]
        ok = t1 - t0 <= MAX_TRUTH_GAP_S
        ok &= (t0 > odometry.t[0] + 1.0) & (t1 < odometry.t[-1] - 1.0)
        spans.append((odometry, t0[ok], t1[ok]))
        d_truth.append(np.diff(truth.pose[:, 2])[ok])
    truth_turn = np.concatenate(d_truth)
    best, score = np.nan, -np.inf
    for lag in LAGS_S:
        d_odom = np.concatenate(
            [
                np.interp(t1 + lag, o.t, o.pose[:, 2]) - np.interp(t0 + lag, o.t, o.pose[:, 2])
                for o, t0, t1 in spans
            ]
        )
        corr = float(np.corrcoef(d_odom, truth_turn)[0, 1]) if len(truth_turn) > 2 else np.nan
        if corr > score:
            best, score = float(lag), corr
    return best


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 (+) b row by row, headings unwrapped (no wrap of the turn)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    d = b[:, :2] - a[:, :2]
    return np.column_stack(
        [c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], b[:, 2] - a[:, 2]]
    )


def odometry_statistics(s: Survey) -> dict[str, str]:
    """Clock offset, error growth over WINDOWS_S and per-robot turn and forward scales."""
    out: dict[str, str] = {}
    pairs = {n: (s.odometry[n], s.truth[n]) for n in s.truth if n in s.odometry}
    lags = {n: clock_offset([pair]) for n, pair in pairs.items()}
    out["odometry clock lag, all robots (s)"] = f"{clock_offset(list(pairs.values())):+.2f}"
    out["odometry clock lag per robot (s)"] = " ".join(f"{v:+.2f}" for v in lags.values())
    heading: dict[float, list[np.ndarray]] = {w: [] for w in WINDOWS_S}
    shift: dict[float, list[np.ndarray]] = {w: [] for w in WINDOWS_S}
    driven: dict[float, list[np.ndarray]] = {w: [] for w in WINDOWS_S}
    turn_scale, forward_scale = [], []
    for name, lag in lags.items():
        truth, odom = s.truth[name], s.odometry[name]
        t = truth.t[(truth.t > odom.t[0]) & (truth.t < odom.t[-1])]
        for w in WINDOWS_S:
            p0, ok0 = truth.at(t)
            p1, ok1 = truth.at(t + w)
            q0, _ = odom.at(t)
            q1, ok2 = odom.at(t + w)
            ok = ok0 & ok1 & ok2
            real, seen = _relative(p0[ok], p1[ok]), _relative(q0[ok], q1[ok])
            heading[w].append(wrap_angle(seen[:, 2] - real[:, 2]))
            shift[w].append(np.hypot(*(seen[:, :2] - real[:, :2]).T))
            driven[w].append(np.hypot(*real[:, :2].T))
        # systematic scales over 5 s, the odometry aligned to the truth by its own lag
        p0, ok0 = truth.at(t)
        p1, ok1 = truth.at(t + 5.0)
        q0, _ = odom.at(t + lag)
        q1, ok2 = odom.at(t + 5.0 + lag)
        ok = ok0 & ok1 & ok2
        real, seen = _relative(p0[ok], p1[ok]), _relative(q0[ok], q1[ok])
        turn_scale.append(np.dot(seen[:, 2], real[:, 2]) / np.dot(real[:, 2], real[:, 2]))
        d_real, d_seen = np.hypot(*real[:, :2].T), np.hypot(*seen[:, :2].T)
        forward_scale.append(np.dot(d_seen, d_real) / np.dot(d_real, d_real))
    for w in WINDOWS_S:
        h = np.concatenate(heading[w])
        rms = np.degrees(np.sqrt(np.mean(h**2)))
        p95 = np.degrees(np.percentile(np.abs(h), 95))
        out[f"odometry heading err RMS / p95, {w:g} s (deg)"] = f"{rms:.1f} / {p95:.1f}"
    for w in WINDOWS_S:
        d, e = np.concatenate(driven[w]), np.concatenate(shift[w])
        moving = d > 0.2 * w * 0.1  # at least a tenth of a slow robot's way
        out[f"odometry translation err / distance, {w:g} s"] = (
            f"{np.median(e[moving] / d[moving]):.1%} median, "
            f"{np.sqrt(np.mean(e[moving] ** 2)) / np.sqrt(np.mean(d[moving] ** 2)):.1%} RMS"
        )
    out["odometry turn scale per robot"] = " ".join(f"{v:.3f}" for v in turn_scale)
    out["odometry forward scale per robot"] = " ".join(f"{v:.3f}" for v in forward_scale)
    return out


def gap_statistics(s: Survey) -> dict[str, str]:
    """How long the robots go without a frame that sees something, from their first
    odometry record to their last."""
    longest, counts, blind = [], {g: 0 for g in GAP_S}, 0.0
    total = 0.0
    for name, odom in s.odometry.items():
        times = np.r_[odom.t[0], s.frames.get(name, np.array([])), odom.t[-1]]
        gaps = np.diff(times)
        longest.append(gaps.max())
        for g in GAP_S:
            counts[g] += int((gaps > g).sum())
        blind += float(gaps[gaps > GAP_S[0]].sum())
        total += float(odom.t[-1] - odom.t[0])
    robots, frames = len(s.odometry), sum(map(len, s.frames.values()))
    return {
        "frames with sightings per robot-minute": f"{frames / (total / 60):.0f}",
        "longest gap per robot (s)": " ".join(f"{g:.0f}" for g in longest),
        **{f"gaps > {g:g} s per robot": f"{counts[g] / robots:.1f}" for g in GAP_S},
        f"time in gaps > {GAP_S[0]:g} s": f"{blind / total:.1%}",
    }


def statistics(records: Iterable[Record], truth_step: float = 1.0) -> dict[str, str]:
    """Every statistic of one log, by name, as printed."""
    s = survey(records, truth_step)
    return {
        **camera_statistics(residuals(s)),
        **odometry_statistics(s),
        **gap_statistics(s),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--compare", type=Path, nargs="*", default=[], help="other logs")
    parser.add_argument(
        "--truth-step", type=float, default=1.0, help="s between the truth poses used"
    )
    args = parser.parse_args()
    logs = [args.log, *args.compare]
    columns = [statistics(read_log(p), args.truth_step) for p in logs]
    table = Table(
        title=f"Residual statistics against the truth (truth every {args.truth_step:g} s)"
    )
    table.add_column("statistic")
    for p in logs:
        table.add_column(p.name)
    for name in columns[0]:
        table.add_row(name, *(c.get(name, "-") for c in columns))
    console.print(table)


if __name__ == "__main__":
    main()
