"""The simulated camera and detector (sec. 2.3, App. A): which plants a frame sees, where it
puts them (depth noise growing with range, a depth bias towards the robot, small bearing
noise), false detections, and semantic measurements with confusion and noisy confidences;
with its effects on, a real camera's depth-like range, heavy-tailed and offset bearings,
misread plants (`effects.py`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from agrislam.config import DiscreteAttribute
from agrislam.records import ContinuousMeasurement, Detection, DiscreteMeasurement, Measurement
from agrislam.sim.config import DetectorConfig
from agrislam.sim.effects import (
    CameraBias,
    bearing_noise,
    measured_range,
    misread_labels,
    range_sigma,
)
from agrislam.sim.field import Field

P_MIN, P_MAX = 0.001, 0.999  # a reported p of exactly 0 or 1 would freeze a belief (eq. 1)


class Detector:
    """One camera over one field; `frame(pose, rng)` is what a frame at that true pose yields."""

    def __init__(self, field: Field, cfg: DetectorConfig) -> None:
        self.field = field
        self.cfg = cfg
        self.tree = cKDTree(field.xy)
        self.half_fov = np.deg2rad(cfg.fov_deg) / 2
        self.confusion = {
            name: confusion_weights(spec.n_values, name in cfg.ordinal_attributes)
            for name, spec in field.schema.discrete.items()
        }

    def frame(
        self, pose: np.ndarray, rng: np.random.Generator, camera: CameraBias | None = None
    ) -> tuple[Detection, ...]:
        """The detections of a frame at the true `pose`, by the robot's `camera` (its range
        scale and bearing offset; none without effects)."""
        cfg = self.cfg
        camera = camera or CameraBias()
        c, s = np.cos(pose[2]), np.sin(pose[2])
        cam = pose[:2] + np.array(
            [
                c * cfg.camera_xy[0] - s * cfg.camera_xy[1],
                s * cfg.camera_xy[0] + c * cfg.camera_xy[1],
            ]
        )
        near = np.array(self.tree.query_ball_point(cam, cfg.max_range), dtype=int)
        rng_, bearing = self._polar(cam, pose[2], self.field.xy[near])
        seen = near[self._in_view(rng_, bearing) & (rng.random(len(near)) < self.p_detect(rng_))]
        twice = seen[rng.random(len(seen)) < cfg.double_detection_p]
        # the second, split-mask detection of a plant lies a little off it (sec. 2.6.3)
        twice_xy = self.field.xy[twice] + rng.normal(0.0, cfg.double_offset_sigma, (len(twice), 2))
        plants = np.concatenate([seen, twice])
        xy = np.vstack([self.field.xy[seen], twice_xy])
        r, b = self._polar(cam, pose[2], xy)
        gross = self._gross_errors(r, rng)
        dets = self._measure(r, b, self.field.length[plants], rng, gross, camera)
        sem = self._semantics(plants, r, rng)
        # a misread detection is labelled (and so its truth_id) as another plant
        label = misread_labels(plants, len(self.field.ids), cfg.effects, rng)
        out = [
            self._detection(dets[k], {n: v[k] for n, v in sem.items()}, str(self.field.ids[i]))
            for k, i in enumerate(label)
        ]
        out += self._clutter(rng, cfg.clutter_rate + cfg.clutter_fraction * len(seen), camera)
        return tuple(out[k] for k in rng.permutation(len(out)))

    def p_detect(self, r: np.ndarray) -> np.ndarray:
        """Detection probability, falling linearly with range to p_detect_far at max_range."""
        cfg = self.cfg
        return cfg.p_detect_near + (cfg.p_detect_far - cfg.p_detect_near) * r / cfg.max_range

    def accuracy(self, name: str, r: np.ndarray) -> np.ndarray:
        near, far = self.cfg.accuracy.get(name, self.cfg.default_accuracy)
        return near + (far - near) * np.clip(r / self.cfg.max_range, 0.0, 1.0)

    def sigma_depth(self, r: np.ndarray) -> np.ndarray:
        return self.cfg.sigma_depth_0 + self.cfg.sigma_depth_per_m2 * r**2

    def sigma_length(self, r: np.ndarray) -> np.ndarray:
        return self.cfg.sigma_length_0 + self.cfg.sigma_length_per_m * r

    def _polar(self, cam: np.ndarray, heading: float, xy: np.ndarray) -> tuple[np.ndarray, ...]:
        d = xy - cam
        return np.hypot(d[:, 0], d[:, 1]), _wrap(np.arctan2(d[:, 1], d[:, 0]) - heading)

    def _in_view(self, r: np.ndarray, bearing: np.ndarray) -> np.ndarray:
        return (
            (r >= self.cfg.min_range)
            & (r <= self.cfg.max_range)
            & (np.abs(bearing) <= self.half_fov)
        )

    def _gross_errors(self, r: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(k,) range errors of the detections at ranges r: 0, or for `outlier_fraction`
        of them a jump of `outlier_range` metres either way along the ray."""
        cfg = self.cfg
        if cfg.outlier_fraction == 0.0:  # no draws: the clean survey's stream is unchanged
            return np.zeros(len(r))
        size = rng.uniform(*cfg.outlier_range, len(r)) * rng.choice([-1.0, 1.0], len(r))
        return np.where(rng.random(len(r)) < cfg.outlier_fraction, size, 0.0)

    def _measure(
        self,
        r: np.ndarray,
        b: np.ndarray,
        length: np.ndarray,
        rng: np.random.Generator,
        gross: np.ndarray | float = 0.0,
        camera: CameraBias | None = None,
    ) -> list[dict]:
        """Noisy positions in the robot base frame, with the uncertainty the detector
        reports (that of a good detection, also for a gross range error `gross`, and without
        the `camera`'s effects)."""
        cfg, fx = self.cfg, self.cfg.effects
        camera = camera or CameraBias()
        bias = cfg.depth_bias_fraction * length  # mask averaging sees the near side (sec. 2.3)
        sd = self.sigma_depth(r)
        noise = rng.normal(0.0, 1.0, len(r)) * range_sigma(r, sd, fx)
        r_m = np.maximum(measured_range(r, b, fx, camera) - bias + noise + gross, 0.05)
        lateral = rng.normal(0.0, cfg.sigma_lateral_0, len(r))
        b_m = (
            b
            + bearing_noise(len(r), cfg.sigma_bearing, fx, rng)
            + np.arctan2(lateral, np.maximum(r, 0.05))
            + camera.bearing_offset
        )
        xy = np.asarray(cfg.camera_xy) + r_m[:, None] * np.column_stack([np.cos(b_m), np.sin(b_m)])
        # reported: a depth std that covers noise and bias, a lateral one from the bearing
        s_depth = cfg.report_sigma_scale * np.hypot(sd, bias)
        s_lat = cfg.report_sigma_scale * np.hypot(cfg.sigma_bearing * r_m, cfg.sigma_lateral_0)
        if cfg.geometry == "xy":
            return [
                {"xy": xy[k], "cov": c} for k, c in enumerate(ray_covariance(b_m, s_depth, s_lat))
            ]
        # range/bearing from the base origin; the camera offset puts the ray slightly off it
        rb = np.hypot(xy[:, 0], xy[:, 1])
        return [
            {
                "range": float(rb[k]),
                "bearing": float(np.arctan2(xy[k, 1], xy[k, 0])),
                "sigma_range": float(s_depth[k]),
                "sigma_bearing": float(s_lat[k] / max(rb[k], 0.05)),
            }
            for k in range(len(r))
        ]

    def _semantics(
        self, plants: np.ndarray, r: np.ndarray, rng: np.random.Generator
    ) -> dict[str, list[Measurement]]:
        """One measurement per schema attribute for each detected plant."""
        out: dict[str, list[Measurement]] = {}
        for name, spec in self.field.schema.attributes.items():
            if isinstance(spec, DiscreteAttribute):
                truth = self.field.discrete[name][plants]
                value, p = self._discrete(name, truth, r, rng)
                out[name] = [
                    DiscreteMeasurement(spec.values[v], float(q))
                    for v, q in zip(value, p, strict=True)
                ]
            else:
                truth = self.field.continuous[name][plants]
                sigma = self.sigma_length(r)
                value = np.clip(truth + rng.normal(0.0, 1.0, len(r)) * sigma, spec.min, None)
                out[name] = [
                    ContinuousMeasurement(float(v), float(s**2))
                    for v, s in zip(value, sigma, strict=True)
                ]
        return out

    def _discrete(
        self, name: str, truth: np.ndarray, r: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Measured value indices and the reported p. Each detection's chance of being right is
        drawn around the range-dependent accuracy; it is right with exactly that chance, and
        reports it with noise: calibrated on average, not per detection (sec. 2.3)."""
        cfg = self.cfg
        acc = np.clip(self.accuracy(name, r), 1e-3, 1 - 1e-3)
        p_true = rng.beta(acc * cfg.p_concentration, (1 - acc) * cfg.p_concentration)
        right = rng.random(len(r)) < p_true
        weights = self.confusion[name][truth]  # (k, n) over the wrong values
        cum = np.cumsum(weights, axis=1)
        wrong = (cum <= rng.random(len(r))[:, None] * cum[:, -1:]).sum(axis=1)
        value = np.where(right, truth, wrong)
        p = np.clip(p_true + rng.normal(0.0, cfg.p_noise, len(r)), P_MIN, P_MAX)
        return value, p

    def _clutter(
        self, rng: np.random.Generator, rate: float, camera: CameraBias | None = None
    ) -> list[Detection]:
        """False detections of nothing (a leaf, a shadow): Poisson with mean `rate` per
        frame, anywhere in view, with random semantics reported as confidently as real ones."""
        cfg = self.cfg
        n = rng.poisson(rate)
        if n == 0:
            return []
        r = np.sqrt(rng.uniform(cfg.min_range**2, cfg.max_range**2, n))
        b = rng.uniform(-self.half_fov, self.half_fov, n)
        length = rng.uniform(self.field.length.min(), self.field.length.max(), n)
        dets = self._measure(r, b, length, rng, camera=camera)
        schema = self.field.schema
        out = []
        for k in range(n):
            attrs: dict[str, Measurement] = {}
            for name, spec in schema.attributes.items():
                if isinstance(spec, DiscreteAttribute):
                    _, p = self._discrete(name, np.zeros(1, int), r[k : k + 1], rng)
                    attrs[name] = DiscreteMeasurement(
                        spec.values[rng.integers(spec.n_values)], float(p[0])
                    )
                else:
                    sigma = float(self.sigma_length(r[k : k + 1])[0])
                    attrs[name] = ContinuousMeasurement(
                        float(rng.uniform(spec.min, spec.max)), sigma**2
                    )
            out.append(self._detection(dets[k], attrs, None))
        return out

    def _detection(
        self, geometry: dict, attrs: dict[str, Measurement], truth_id: str | None
    ) -> Detection:
        if not self.cfg.emit_label:
            return Detection(**geometry, attributes=attrs, truth_id=truth_id)
        # one combined label for the discrete attributes, as the experiments' YOLO model (App. A)
        discrete = {n: m for n, m in attrs.items() if isinstance(m, DiscreteMeasurement)}
        label = "_".join(m.value for m in discrete.values())
        score = float(np.prod([m.p for m in discrete.values()])) if discrete else None
        rest = {n: m for n, m in attrs.items() if n not in discrete}
        return Detection(
            **geometry, attributes=rest, label=label or None, label_p=score, truth_id=truth_id
        )


def ray_covariance(bearing: np.ndarray, s_depth: np.ndarray, s_lat: np.ndarray) -> np.ndarray:
    """(k, 2, 2) covariances R diag(s_depth^2, s_lat^2) R^T of points seen along rays at
    `bearing`: large along the ray, small across it (sec. 2.6); exactly symmetric."""
    c, s = np.cos(bearing), np.sin(bearing)
    a, b = s_depth**2, s_lat**2
    cov = np.empty((len(c), 2, 2))
    cov[:, 0, 0] = c * c * a + s * s * b
    cov[:, 1, 1] = s * s * a + c * c * b
    cov[:, 0, 1] = cov[:, 1, 0] = c * s * (a - b)
    return cov


def confusion_weights(n: int, ordinal: bool) -> np.ndarray:
    """(n, n) relative chance of reading value j when the truth is i, over the wrong values
    only: uniform (Assumption 1), or for an ordered attribute 4x likelier one step away."""
    i, j = np.indices((n, n))
    w = np.where(i == j, 0.0, 1.0)
    if ordinal:
        w = np.where(i == j, 0.0, 4.0 ** -(np.abs(i - j) - 1.0))
    return w


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi
