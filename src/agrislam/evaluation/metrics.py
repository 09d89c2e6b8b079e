"""Scoring a map against ground truth: plants mapped, missed, duplicated or invented, their
position and attribute errors, the data association's purity, and the trajectory with and
without optimisation. As in evo, alignment is explicit (`align=True`: the least-squares
rigid 2D transform first), and the metrics say so."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from agrislam.evaluation.ground_truth import TruthObjects
from agrislam.geometry.se2 import rotation, wrap_angle
from agrislam.records import TruthObject, TruthPose
from agrislam.snapshot import MapSnapshot, Trajectory

# m: radii a map's objects are counted within of their plants or landmarks, one to one (a
# user's fixed yardsticks, beside the matching radius that follows the plant spacing)
WITHIN_M = (0.3, 0.15)

# ------------------------------------------------------------------------------ geometry


def rigid_fit(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray]:
    """Rotation angle and translation minimising sum |R src + t - dst|^2 (2D Kabsch)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    h = (src - cs).T @ (dst - cd)
    angle = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    return angle, cd - rotation(angle) @ cs


def _transform_poses(poses: np.ndarray, angle: float, t: np.ndarray) -> np.ndarray:
    out = poses.copy()
    out[:, :2] = poses[:, :2] @ rotation(angle).T + t
    out[:, 2] = wrap_angle(poses[:, 2] + angle)
    return out


def match_objects(
    est: np.ndarray, truth: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one assignment of estimates to truths within `radius`: the most pairs, and of
    those the smallest total distance (linear_sum_assignment per cluster of candidates)."""
    est, truth = est.reshape(-1, 2), truth.reshape(-1, 2)
    if len(est) == 0 or len(truth) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    dist = cKDTree(est).sparse_distance_matrix(cKDTree(truth), radius, output_type="coo_matrix")
    e_idx, t_idx, d = dist.row, dist.col, dist.data
    if len(d) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    n_e = len(est)
    graph = coo_matrix((np.ones(len(d)), (e_idx, n_e + t_idx)), shape=(n_e + len(truth),) * 2)
    _, label = connected_components(graph, directed=False)
    comp = label[e_idx]
    order = np.argsort(comp, kind="stable")
    bounds = np.flatnonzero(np.diff(comp[order])) + 1
    out_e, out_t = [], []
    for edges in np.split(order, bounds):
        ce, ct, cd = e_idx[edges], t_idx[edges], d[edges]
        if len(edges) == 1:
            out_e.append(ce)
            out_t.append(ct)
            continue
        ue, ie = np.unique(ce, return_inverse=True)
        ut, it = np.unique(ct, return_inverse=True)
        big = radius * (len(edges) + 1) + 1.0  # a forbidden pair costs more than all allowed
        cost = np.full((len(ue), len(ut)), big)
        cost[ie, it] = cd
        r, c = linear_sum_assignment(cost)
        ok = cost[r, c] < big
        out_e.append(ue[r[ok]])
        out_t.append(ut[c[ok]])
    return np.concatenate(out_e).astype(int), np.concatenate(out_t).astype(int)


# ------------------------------------------------------------------------------ metrics


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def _truth_tracks(
    poses: Iterable[TruthPose] | Mapping[str, Trajectory],
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each robot's true (times, poses) in time order; trajectories are taken as they are."""
    if isinstance(poses, Mapping):
        return {robot: (track.t, track.poses) for robot, track in poses.items()}
    by_robot: dict[str, list[TruthPose]] = {}
    for p in poses:
        by_robot.setdefault(p.robot, []).append(p)
    out = {}
    for robot, ps in by_robot.items():
        t = np.array([p.t for p in ps])
        order = np.argsort(t, kind="stable")
        out[robot] = (t[order], np.array([p.pose for p in ps])[order])
    return out


def truth_trajectories(poses: Iterable[TruthPose]) -> dict[str, Trajectory]:
    """The true poses of each robot as trajectories, in time order."""
    return {robot: Trajectory(robot, t, p) for robot, (t, p) in _truth_tracks(poses).items()}


def truth_at(t_truth: np.ndarray, truth: np.ndarray, t: np.ndarray) -> np.ndarray:
    """True poses at times t, linearly interpolated (the heading unwrapped first)."""
    theta = np.unwrap(truth[:, 2])
    return np.column_stack(
        [
            np.interp(t, t_truth, truth[:, 0]),
            np.interp(t, t_truth, truth[:, 1]),
            wrap_angle(np.interp(t, t_truth, theta)),
        ]
    )


def _paired_poses(
    est: Trajectory, track: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Estimated poses inside the truth's time span and the true poses at their times."""
    t_truth, truth = track
    inside = _inside(est, t_truth)
    return est.poses[inside], truth_at(t_truth, truth, est.t[inside])


def _paired_times(est: Trajectory, track: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The times of `_paired_poses`."""
    return est.t[_inside(est, track[0])]


def _inside(est: Trajectory, t_truth: np.ndarray) -> np.ndarray:
    return (est.t >= t_truth[0]) & (est.t <= t_truth[-1])


def trajectory_errors(
    trajectories: Mapping[str, Trajectory], tracks: Mapping[str, tuple[np.ndarray, np.ndarray]]
) -> dict[str, Any]:
    """RMS position and heading error over all robots, and per robot; the position's also
    over the first and the second half of the survey's time (of the poses compared): a map
    that degrades over time has the second larger."""
    per_robot, pos, head, times = {}, [], [], []
    for robot, est in sorted(trajectories.items()):
        if robot not in tracks or len(est.t) == 0:
            continue
        e, t = _paired_poses(est, tracks[robot])
        dp, dh = np.linalg.norm(e[:, :2] - t[:, :2], axis=1), wrap_angle(e[:, 2] - t[:, 2])
        per_robot[robot] = {"rms_position": _rms(dp), "rms_heading": _rms(dh), "n": len(dp)}
        pos.append(dp)
        head.append(dh)
        times.append(_paired_times(est, tracks[robot]))
    dp = np.concatenate(pos) if pos else np.zeros(0)
    dh = np.concatenate(head) if head else np.zeros(0)
    t = np.concatenate(times) if times else np.zeros(0)
    second = t > 0.5 * (t.min() + t.max()) if len(t) else np.zeros(0, bool)
    return {
        "rms_position": _rms(dp),
        "rms_heading": _rms(dh),
        "rms_position_first_half": _rms(dp[~second]),
        "rms_position_second_half": _rms(dp[second]),
        "n": len(dp),
        "per_robot": per_robot,
    }


def association_scores(associations: Sequence[tuple[str | None, int]]) -> dict[str, Any]:
    """Purity (the share of each object's detections that are of its main plant) and
    completeness (the share of each plant's detections that went to its main object),
    weighted by detections; clutter (no truth id) is counted apart."""
    numbers: dict[str, int] = {}
    truths = [numbers.setdefault(str(t), len(numbers)) if t else -1 for t, _ in associations]
    objects = [int(o) for _, o in associations]
    return association_counts(np.array(truths, dtype=np.int64), np.array(objects, dtype=np.int64))


def association_counts(truths: np.ndarray, objects: np.ndarray) -> dict[str, Any]:
    """`association_scores` of each detection's truth number (-1: clutter) and object, as
    arrays: a whole field's detections without a Python object each."""
    n_detections = len(truths)
    keep = truths >= 0
    if not keep.any():
        return {"n_detections": n_detections, "n_clutter": n_detections}
    # a (truth, object) pair as one int64: a 1-D unique, not a row-wise one of a copy
    objects = np.asarray(objects)[keep].astype(np.int64)
    objects -= objects.min()  # from 0, whatever ids come: only which pairs match counts
    span = int(objects.max()) + 1
    pairs = np.asarray(truths)[keep].astype(np.int64) * span + objects
    pairs, counts = np.unique(pairs, return_counts=True)
    total = int(counts.sum())
    per_truth = _group_max_and_size(pairs // span, counts)
    per_object = _group_max_and_size(pairs % span, counts)
    return {
        "n_detections": n_detections,
        "n_clutter": n_detections - total,
        "purity": float(per_object[0].sum() / total),
        "completeness": float(per_truth[0].sum() / total),
        "truths": len(per_truth[1]),
        "truths_split": int((per_truth[1] > 1).sum()),
        "objects_mixed": int((per_object[1] > 1).sum()),
        "truths_one_object_fraction": float((per_truth[1] == 1).mean()),
    }


def _group_max_and_size(group: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per distinct value of `group`: the largest of its `counts` and how many it has."""
    _, inverse, size = np.unique(group, return_inverse=True, return_counts=True)
    largest = np.zeros(len(size), dtype=counts.dtype)
    np.maximum.at(largest, inverse, counts)
    return largest, size


def within_counts(
    est_xy: np.ndarray, truth_xy: np.ndarray, radii: Iterable[float] = WITHIN_M
) -> list[dict[str, Any]]:
    """For each radius: how many truths have an object within it, one to one
    (`match_objects`), and the RMS distance of those pairs."""
    out = []
    for radius in radii:
        ei, ti = match_objects(est_xy, truth_xy, radius)
        rms = _rms(np.linalg.norm(est_xy[ei] - truth_xy[ti], axis=1))
        out.append({"radius": float(radius), "matched": len(ti), "position_rms": rms})
    return out


def _attribute_scores(
    snapshot: MapSnapshot, matched_est: np.ndarray, truth: TruthObjects, matched_rows: np.ndarray
) -> dict[str, Any]:
    out: dict[str, Any] = {}
    schema = snapshot.schema
    for name, probs in snapshot.objects.discrete.items():
        values = schema.discrete[name].values if schema and name in schema.discrete else None
        known = truth.text(name, matched_rows)
        has = known != None  # noqa: E711 (elementwise on an object array)
        hits = np.zeros(0, bool)
        if values is not None:
            guessed = np.asarray(values, dtype=object)[np.argmax(probs[matched_est[has]], axis=1)]
            hits = guessed == known[has]
        out[name] = {"accuracy": float(np.mean(hits)) if len(hits) else None, "n": len(hits)}
    for name, (mean, _) in snapshot.objects.continuous.items():
        known = truth.values(name, matched_rows)
        has = np.isfinite(known)
        err = mean[matched_est[has]] - known[has]
        out[name] = {
            "rms": _rms(err),
            "bias": float(err.mean()) if len(err) else None,
            "n": len(err),
        }
    return out


def _timings(step_times: Mapping[str, np.ndarray]) -> dict[str, Any]:
    out = {}
    for stage, times in step_times.items():
        x = np.asarray(times, float)
        if len(x):
            out[stage] = {
                "p50_s": float(np.percentile(x, 50)),
                "p95_s": float(np.percentile(x, 95)),
                "max_s": float(x.max()),
                "total_s": float(x.sum()),
                "n": len(x),
            }
    return out


def default_radius(truth_xy: np.ndarray, min_plant_distance: float | None = None) -> float:
    """Half the minimum plant distance; without one given, the 5th percentile of the true
    nearest-neighbour distances stands in for it (robust to a few doubled plants)."""
    if min_plant_distance is None:
        if len(truth_xy) < 2:
            return 0.2
        nn = cKDTree(truth_xy).query(truth_xy, k=2)[0][:, 1]
        min_plant_distance = float(np.percentile(nn, 5))
    return 0.5 * min_plant_distance


def _alignment_pairs(
    snapshot: MapSnapshot, tracks: Mapping[str, tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray]:
    src, dst = [], []
    for robot, est in snapshot.trajectories.items():
        if robot in tracks and len(est.t):
            e, t = _paired_poses(est, tracks[robot])
            src.append(e[:, :2])
            dst.append(t[:, :2])
    if not src:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.vstack(src), np.vstack(dst)


def _icp(est: np.ndarray, truth: np.ndarray, radius: float) -> tuple[float, np.ndarray, int]:
    """Align objects to truth without a trajectory: nearest neighbours with a shrinking gate."""
    angle, t = 0.0, np.zeros(2)
    tree = cKDTree(truth)
    n = 0
    for gate in np.geomspace(max(1.0, 4 * radius), radius, 15):
        moved = est @ rotation(angle).T + t
        d, j = tree.query(moved, distance_upper_bound=gate)
        ok = np.isfinite(d)
        if ok.sum() < 3:
            break
        angle, t = rigid_fit(est[ok], truth[j[ok]])
        n = int(ok.sum())
    return angle, t, n


# ------------------------------------------------------------------------------ entry


def evaluate(
    snapshot: MapSnapshot,
    truth_objects: TruthObjects | Iterable[TruthObject],
    truth_poses: Mapping[str, Trajectory] | Iterable[TruthPose] = (),
    associations: Sequence[tuple[str | None, int]] | None = None,
    *,
    radius: float | None = None,
    min_plant_distance: float | None = None,
    align: bool = False,
    within: Iterable[float] = WITHIN_M,
) -> dict[str, Any]:
    """Every metric of the map against the truth, as a JSON-ready dict.

    The truth: its objects as records or a `TruthObjects` table (a later record of an id
    replaces it: a later survey day's truth), its poses as records or each robot's true
    trajectory in time order. `associations`: (truth_id, final object id) of each
    detection. `radius`: matching radius, default half the minimum plant distance;
    `within`: radii of `within_counts`, the objects' fixed yardsticks."""
    truth = (
        truth_objects if isinstance(truth_objects, TruthObjects) else TruthObjects.of(truth_objects)
    )
    truth_rows = truth.placed()
    truth_xy = truth.xy(truth_rows)
    tracks = _truth_tracks(truth_poses)
    radius = radius if radius is not None else default_radius(truth_xy, min_plant_distance)
    est_xy = np.asarray(snapshot.objects.xy, float).reshape(-1, 2)
    optimised = dict(snapshot.trajectories)
    dead = dict(snapshot.dead_reckoning)

    alignment: dict[str, Any] = {"applied": False}
    if align:
        src, dst = _alignment_pairs(snapshot, tracks)
        if len(src) >= 2:
            angle, shift = rigid_fit(src, dst)
            source, n_pairs = "trajectory", len(src)
        else:
            angle, shift, n_pairs = _icp(est_xy, truth_xy, radius)
            source = "objects"
        alignment = {
            "applied": True,
            "source": source,
            "rotation_deg": math.degrees(angle),
            "translation": [float(shift[0]), float(shift[1])],
            "n_pairs": n_pairs,
        }
        est_xy = est_xy @ rotation(angle).T + shift
        optimised = {
            r: Trajectory(r, tr.t, _transform_poses(tr.poses, angle, shift))
            for r, tr in optimised.items()
        }
        dead = {
            r: Trajectory(r, tr.t, _transform_poses(tr.poses, angle, shift))
            for r, tr in dead.items()
        }

    ei, ti = match_objects(est_xy, truth_xy, radius)
    unmatched = np.setdiff1d(np.arange(len(est_xy)), ei)
    near_truth = np.zeros(len(unmatched), bool)
    if len(unmatched) and len(truth_xy):
        near_truth = cKDTree(truth_xy).query(est_xy[unmatched], distance_upper_bound=radius)[0]
        near_truth = np.isfinite(near_truth)
    n_truth = len(truth_rows)
    objects = {
        "n_truth": n_truth,
        "n_estimated": len(est_xy),
        "mapped": len(ti),
        "missed": n_truth - len(ti),
        "mapped_fraction": len(ti) / n_truth if n_truth else None,
        "duplicates": int(near_truth.sum()),
        "duplicate_fraction": float(near_truth.sum()) / n_truth if n_truth else None,
        "false_objects": int((~near_truth).sum()),
        "position_rms": _rms(np.linalg.norm(est_xy[ei] - truth_xy[ti], axis=1)),
        "match_radius": radius,
        "within": within_counts(est_xy, truth_xy, within),
    }
    metrics: dict[str, Any] = {
        "objects": objects,
        "attributes": _attribute_scores(snapshot, ei, truth, truth_rows[ti]),
        "trajectory": {
            "optimised": trajectory_errors(optimised, tracks),
            "dead_reckoning": trajectory_errors(dead, tracks),
        },
        "alignment": alignment,
    }
    if associations:
        metrics["association"] = association_scores(associations)
    if snapshot.step_times:
        metrics["timings"] = _timings(snapshot.step_times)
    return metrics


def _json_ready(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_json_ready(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


def write_metrics(metrics: Mapping[str, Any], path: str | Path) -> Path:
    """metrics.json: the dict of `evaluate`, NaN as null."""
    path = Path(path)
    path.write_text(json.dumps(_json_ready(metrics), indent=2, allow_nan=False) + "\n")
    return path


def _fmt(x: Any, unit: str = "", pct: bool = False) -> str:
    if x is None:
        return "-"
    if pct:
        return f"{100 * x:.1f} %"
    if isinstance(x, float):
        return f"{x:.3f}{unit}"
    return f"{x}{unit}"


def print_metrics(metrics: Mapping[str, Any], console: Any = None) -> None:
    """A small table of the headline numbers on the terminal."""
    from rich.console import Console
    from rich.table import Table

    console = console or Console()
    o = metrics["objects"]
    table = Table(title="Map against ground truth", show_header=True)
    table.add_column("metric")
    table.add_column("value", justify="right")
    if o["n_truth"]:  # a log may know only which plant each detection saw
        mapped = f"{o['mapped']} / {o['n_truth']} ({_fmt(o['mapped_fraction'], pct=True)})"
        table.add_row("plants mapped", mapped)
        table.add_row("missed", str(o["missed"]))
        duplicates = f"{o['duplicates']} ({_fmt(o['duplicate_fraction'], pct=True)})"
        table.add_row("duplicates", duplicates)
        table.add_row("false objects", str(o["false_objects"]))
        table.add_row("object position RMS", _fmt(o["position_rms"], " m"))
        for w in o.get("within", []):
            rms = _fmt(w["position_rms"], " m")
            table.add_row(f"within {w['radius']:g} m", f"{w['matched']} (RMS {rms})")
        for name, a in metrics.get("attributes", {}).items():
            if "accuracy" in a:
                table.add_row(f"{name} accuracy", _fmt(a["accuracy"], pct=True))
            else:
                table.add_row(f"{name} RMS", _fmt(a["rms"], " m"))
    assoc = metrics.get("association")
    if assoc and "purity" in assoc:
        table.add_row("association purity", _fmt(assoc["purity"], pct=True))
        table.add_row("association completeness", _fmt(assoc["completeness"], pct=True))
    al = metrics.get("alignment", {})
    if al.get("applied"):
        table.add_row(
            "aligned by",
            f"{al['rotation_deg']:.2f} deg, "
            f"({al['translation'][0]:.3f}, {al['translation'][1]:.3f}) m",
        )
    console.print(table)
    traj = metrics.get("trajectory", {})
    if traj and traj["optimised"]["n"]:
        t = Table(title="Trajectory error (RMS)", show_header=True)
        t.add_column("")
        t.add_column("optimised", justify="right")
        t.add_column("dead reckoning", justify="right")
        opt, dr = traj["optimised"], traj["dead_reckoning"]
        t.add_row("position", _fmt(opt["rms_position"], " m"), _fmt(dr["rms_position"], " m"))
        heading = [
            None if x is None else math.degrees(x) for x in (opt["rms_heading"], dr["rms_heading"])
        ]
        t.add_row("heading", *(_fmt(h, " deg") for h in heading))
        for half in ("first", "second"):
            key = f"rms_position_{half}_half"
            t.add_row(f"position, {half} half", _fmt(opt.get(key), " m"), _fmt(dr.get(key), " m"))
        console.print(t)
