"""``ws.calibrate``: fit a design's material and IPAM parameters to scans of the built device.

Damped Gauss-Newton (Levenberg-Marquardt) on the signed point-to-surface residuals of every scan,
with a Huber loss (iteratively reweighted) and each scan's rigid pose fitted jointly; the Jacobian of
the parameters by forward finite differences (one replay per parameter, every observation a world of
it), updated by Broyden's rank-one rule between fresh ones. docs/calibration.md gives the algorithm.
"""

from __future__ import annotations

import hashlib
import warnings

import numpy as np

from ..display import Design
from ..errors import DesignError, ShapeError
from ..scan import ICP_POINTS, IcpConvergenceWarning, closest_points_query, compare_scan, icp
from .observations import ScanObservation
from .parameters import ParameterSet, check_wrt, default_wrt
from .regions import region_faces
from .held_replay import HOLD_S, replay_held
from .result import CalibrationResult, ScanResidual

__all__ = ["calibrate", "scan_residuals", "FIT_POINTS", "MIN_COVERAGE", "MAX_MEDIAN_DISTANCE", "FLAG_Z"]

#: scan points used per observation (a fixed random subset)
FIT_POINTS = 20000
#: a scan must cover at least this share of the modelled membrane
MIN_COVERAGE = 0.1
#: a scan whose points lie farther than this (median, as a fraction of the membrane's mean radius) from
#: the modelled surface after alignment is not a scan of this display
MAX_MEDIAN_DISTANCE = 0.1
#: random starting rotations of the unknown-pose alignment
POSE_TRIALS = 32
#: poses that differ by more than this are different turns of the scan (alternatives of the alignment)
REPOSE_DEGREES = 5.0
#: the other turns kept per scan, tried when the fit leaves the scan's RMS residual above MISFIT_RATIO
#: times the best-fitting scan's
POSE_ALTERNATIVES = 2
MISFIT_RATIO = 1.25
#: an other turn is kept as an alternative only where it aligns nearly as well as the best (trimmed RMS
#: within this ratio): the start model could not tell them apart
AMBIGUOUS_RATIO = 1.5
#: half turns of the best pose tried about this many axes (the membrane's near symmetries)
HALF_TURN_AXES = 24
#: forward-difference step in the logarithm of a parameter
FD_STEP = 1e-2
#: Huber loss threshold in robust standard deviations; residuals beyond REJECT_SIGMAS weigh nothing
HUBER_SIGMAS = 1.345
REJECT_SIGMAS = 6.0
#: a parameter combination whose normal-matrix eigenvalue (correlation form) is below this is not identifiable
NULL_EIGENVALUE = 1e-6
#: a parameter whose Jacobian column is below this fraction of the largest is not seen at all
NULL_COLUMN = 1e-4
#: a direction of the fitted logarithms whose standard error exceeds this (a relative change) is named
#: poorly determined
LOOSE_STDERR = 0.05
#: a parameter moved by more than this many standard errors is flagged
FLAG_Z = 3.0
#: a change larger than this (%) within FLAG_Z standard errors is flagged as not established
NOTED_CHANGE_PCT = 3.0


class _Fit:
    """The observations, their fixed point subsets and poses, and the model replays."""

    def __init__(self, design: Design, observations, params: ParameterSet, device: str, hold_s: float, seed: int):
        self.design, self.params, self.device, self.hold_s = design, params, device, hold_s
        self.obs = observations
        self.seqs = [o.sequence(design) for o in observations]  # checks every state first
        rng = np.random.default_rng(seed)
        self.points = [o.points[rng.choice(len(o.points), size=min(FIT_POINTS, len(o.points)), replace=False)]
                       for o in observations]
        self.replays = 0
        self.seed = seed
        self.pressures = {}  # id of a shapes array -> its chamber pressures
        self.sigma = 3e-4  # m: a scan point's noise, what a pressure reading's row is scaled to (set_sigma)
        self.other_turns = []  # per scan, the alignment's other turns [(R, t), ...] (robust_poses)
        self.say = lambda line: None  # a progress line per iteration (calibrate's ``progress``)

    def set_sigma(self, r: np.ndarray) -> None:
        """The scans' robust residual scale (1.4826 median |r| of the scan rows of ``r``), m."""
        n = sum(len(p) for p in self.points)
        self.sigma = max(1.4826 * float(np.median(np.abs(r[:n]))), 1e-9)

    def shapes(self, x: np.ndarray) -> np.ndarray:
        """(W, V, 3) the replayed membranes at parameters ``x``; their chamber pressures (W,) Pa in
        ``self.pressures[id of the array]``."""
        self.replays += 1
        shapes, p = replay_held(self.params.design(self.design, x), self.seqs, hold_s=self.hold_s,
                                device=self.device, pressures=True)
        self.pressures[id(shapes)] = p
        return shapes

    def residuals(self, shapes: np.ndarray, poses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r (M,), aligned points (M, 3), d r / d point (M, 3)) of every scan at its pose on ``shapes``, then
        one row per pressure reading: (model - reading) / its standard deviation x ``self.sigma`` (m), so
        that it weighs as a scan point does (points and normals zero there)."""
        rs, ps, ns = [], [], []
        for x, pts, (rot, t) in zip(shapes, self.points, poses):
            p = pts @ rot.T + t
            q, _, n = closest_points_query((x, self.design.rest.faces), device=self.device)(p, normals=True)
            r, u = signed_distances(p, q, n)
            rs.append(r)
            ps.append(p)
            ns.append(u)
        read = [(w, o) for w, o in enumerate(self.obs) if o.pressure is not None]
        if read:
            model = self.pressures[id(shapes)]
            rs.append(np.array([(model[w] - o.pressure) / o.pressure_stderr * self.sigma for w, o in read]))
            ps.append(np.zeros((len(read), 3)))
            ns.append(np.zeros((len(read), 3)))
        return np.concatenate(rs), np.concatenate(ps), np.concatenate(ns)


def signed_distances(p: np.ndarray, q: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r (N,), u (N, 3)): the distance from each point ``p`` to its closest surface point ``q``, signed by
    the side of the closest face (normal ``n``): continuous as the closest face changes (n . (p - q) is
    not: it jumps at the edges of a coarse mesh), and u = d r / d p, the unit vector (p - q) / r (the
    face normal on the surface)."""
    v = p - q
    d = np.linalg.norm(v, axis=1)
    r = np.where((v * n).sum(axis=1) < 0.0, -d, d)
    small = d < 1e-12
    u = np.where(small[:, None], n, v / np.where(small, 1.0, r)[:, None])
    return r, u


def _robust_weights(r: np.ndarray, sizes: list[int]) -> np.ndarray:
    """Huber IRLS weights per scan (robust scale 1.4826 median |r|), zero beyond ``REJECT_SIGMAS``;
    the rows after the scans' (pressure readings) weigh 1."""
    out, start = [], 0
    for n in sizes:
        a = np.abs(r[start:start + n])
        s = max(1.4826 * float(np.median(a)), 1e-9)
        w = np.minimum(1.0, HUBER_SIGMAS * s / np.maximum(a, 1e-30))
        w[a > REJECT_SIGMAS * s] = 0.0
        out.append(w)
        start += n
    out.append(np.ones(len(r) - start))
    return np.concatenate(out)


def _pose_block(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(m, 6) d r / d (rotation vector, shift) of one scan's pose at its points ``p`` with normals ``n``:
    r = n . (p - q)."""
    return np.concatenate([np.cross(p, n), n], axis=1)


def _rotation(omega: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(omega))
    if a < 1e-15:
        return np.eye(3)
    k = omega / a
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


def _moved(poses, delta: np.ndarray):
    out = []
    for w, (rot, t) in enumerate(poses):
        dr = _rotation(delta[6 * w:6 * w + 3])
        out.append((dr @ rot, dr @ t + delta[6 * w + 3:6 * w + 6]))
    return out


def _random_rotations(n: int, seed: int) -> list[np.ndarray]:
    """``n`` rotations spread uniformly (random unit quaternions, seeded)."""
    q = np.random.default_rng(seed).normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    a, b, c, d = q.T
    return list(np.stack([np.stack([a*a + b*b - c*c - d*d, 2*(b*c - a*d), 2*(b*d + a*c)], -1),
                          np.stack([2*(b*c + a*d), a*a - b*b + c*c - d*d, 2*(c*d - a*b)], -1),
                          np.stack([2*(b*d - a*c), 2*(c*d + a*b), a*a - b*b - c*c + d*d], -1)], 1))


def _trimmed(d: np.ndarray) -> float:
    d = np.sort(d)[: max(1, int(0.8 * len(d)))]
    return float(np.sqrt(np.mean(d * d)))


def _spread_axes(n: int) -> np.ndarray:
    """(n, 3) unit axes spread over a hemisphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = k / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _turn(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between rotations ``a`` and ``b``, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1.0) / 2.0, -1.0, 1.0))))


def robust_poses(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, *, device: str = "cpu",
                 seed: int = 0, alternatives: int = 0) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """[(trimmed RMS distance m, R, t), ...] taking ``points`` (a partial scan, any pose) onto the surface
    (``vertices``, ``faces``), the best first: ``POSE_TRIALS`` random rotations and the scan's own, each
    refined by point-to-plane ICP on 300 points; the best two by trimmed RMS, the best trial of each of
    ``POSE_ALTERNATIVES`` other turns (more than ``REPOSE_DEGREES`` apart), and the best two half turns
    of the best about ``HALF_TURN_AXES`` axes refined on ``ICP_POINTS`` points (as ``compare`` refines;
    ``calibrate`` then refines the pose on all its points, ``_realign``) and ranked by trimmed RMS on
    all points, the first ``alternatives + 1`` returned. A nearly round membrane has no clear principal axes, so the
    random starts are what find its pose; its other turns are what ``calibrate`` tries when a scan
    will not fit."""
    q = closest_points_query((vertices, faces), device=device)
    scale = float(np.max(np.linalg.norm(vertices - vertices.mean(axis=0), axis=1)))
    rng = np.random.default_rng(seed)
    sub = points[rng.choice(len(points), size=min(300, len(points)), replace=False)]
    dense = points[rng.choice(len(points), size=min(ICP_POINTS, len(points)), replace=False)]
    cs, cm = points.mean(axis=0), vertices.mean(axis=0)
    trials = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IcpConvergenceWarning)
        for rot in _random_rotations(POSE_TRIALS, seed) + [np.eye(3)]:
            r1, t1, _, _ = icp(sub, q, rot, cm - rot @ cs, max_iterations=30, tolerance=1e-6, scale=scale)
            trials.append((_trimmed(q(sub @ r1.T + t1)[1]), r1, t1))
        trials.sort(key=lambda e: e[0])

        def refine(r0, t0):
            r1, t1, _, _ = icp(dense, q, r0, t0, max_iterations=40, tolerance=1e-6, scale=scale)
            return _trimmed(q(points @ r1.T + t1)[1]), r1, t1

        out = [min((refine(r0, t0) for _, r0, t0 in trials[:2]), key=lambda e: e[0])]
        for _, r0, t0 in trials:
            if len(out) > max(alternatives, POSE_ALTERNATIVES):
                break
            if all(_turn(r0, r) > REPOSE_DEGREES for _, r, _ in out):
                e = refine(r0, t0)
                if all(_turn(e[1], r) > REPOSE_DEGREES for _, r, _ in out):
                    out.append(e)
        # half turns of the best about HALF_TURN_AXES axes spread over the sphere: where the membrane is
        # nearly symmetric, the random starts may all fall into a half-turned pose's basin
        _, r0, t0 = min(out, key=lambda e: e[0])
        turned = []
        for a in _spread_axes(HALF_TURN_AXES):
            flip = 2.0 * np.outer(a, a) - np.eye(3)  # 180 degrees about a, about the model's centroid
            r1, t1, _, _ = icp(sub, q, flip @ r0, flip @ (t0 - cm) + cm, max_iterations=30, tolerance=1e-6,
                               scale=scale)
            turned.append((_trimmed(q(sub @ r1.T + t1)[1]), r1, t1))
        for _, r1, t1 in sorted(turned, key=lambda e: e[0])[:2]:
            e = refine(r1, t1)
            if all(_turn(e[1], r) > REPOSE_DEGREES for _, r, _ in out):
                out.append(e)
    out.sort(key=lambda e: e[0])  # by the trimmed RMS on all points
    return out[:alternatives + 1]


#: robust_poses' last results by their inputs (the same scans calibrated again, with other parameters
#: or regions, start from the same replayed shapes: their alignment is the same)
_POSES_CACHE: dict = {}
_POSES_CACHE_SIZE = 16


def _cached_robust_poses(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, **kwargs) -> list:
    """``robust_poses`` of these exact inputs, computed once (copies returned)."""
    key = (hashlib.sha1(b"".join(np.ascontiguousarray(a).tobytes() for a in (points, vertices, faces))).hexdigest(),
           points.shape, vertices.shape, tuple(sorted(kwargs.items())))
    if key not in _POSES_CACHE:
        if len(_POSES_CACHE) >= _POSES_CACHE_SIZE:
            _POSES_CACHE.pop(next(iter(_POSES_CACHE)))
        _POSES_CACHE[key] = robust_poses(points, vertices, faces, **kwargs)
    return [(d, r.copy(), t.copy()) for d, r, t in _POSES_CACHE[key]]


def _initial_poses(fit: _Fit, shapes: np.ndarray) -> list:
    """Each scan aligned to its replayed shape (``robust_poses``: unknown pose); a scan that does not
    match the display (too far from it after alignment, or covering too little of it, measured as
    ``compare`` does) is an error."""
    poses, faces = [], fit.design.rest.faces
    for o, pts, x in zip(fit.obs, fit.points, shapes):
        (score, rot, t), *others = _cached_robust_poses(pts, x, faces, device=str(fit.device), seed=fit.seed,
                                                        alternatives=POSE_ALTERNATIVES)
        fit.other_turns.append([(r, u) for d, r, u in others if d < AMBIGUOUS_RATIO * score])
        radius = float(np.mean(np.linalg.norm(x - x.mean(axis=0), axis=1)))
        d = closest_points_query((x, faces), device=fit.device)(pts @ rot.T + t)[1]
        med = float(np.median(d))
        if med > MAX_MEDIAN_DISTANCE * radius:
            raise ShapeError(f"scan {o.name} does not match the display: after alignment its points lie "
                             f"{med * 1e3:.1f} mm (median) from the modelled membrane ({radius * 1e3:.0f} mm radius); "
                             f"is it a scan of this device, in the right units?")
        tf = np.eye(4)
        tf[:3, :3], tf[:3, 3] = rot, t
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IcpConvergenceWarning)
            cmp = compare_scan(pts, fit.design.rest.copy_with(x), device=fit.device, scan_units="m",
                               initial_transform=tf, max_iterations=5)
        if cmp.covered_fraction < MIN_COVERAGE:
            raise ShapeError(f"scan {o.name} covers {100 * cmp.covered_fraction:.1f} % of the modelled membrane "
                             f"(at least {100 * MIN_COVERAGE:.0f} % needed): no overlap to fit; scan more of the device")
        poses.append((rot, t))
    return poses


def _scan_rms(s) -> np.ndarray:
    """(W,) RMS residual of each scan's kept points (m)."""
    out, start = [], 0
    for m in s.sizes:
        r, w = s.r[start:start + m], s.w[start:start + m]
        out.append(float(np.sqrt(np.mean(r[w > 0] ** 2))) if np.any(w > 0) else np.inf)
        start += m
    return np.array(out)


def _other_turns(fit: _Fit, s, info: dict, max_iterations: int, tolerance: float):
    """The fit, with each scan it leaves misfitted (RMS above ``MISFIT_RATIO`` times the best scan's)
    aligned in its other turns (``robust_poses``' alternatives) and fitted again from there; a turn is
    kept where the scans' summed RMS falls. On the start model a scan of a much softer or stiffer device
    may fit best in a wrong turn of the nearly round membrane, and the IPAMs' parameters then bend the
    model towards it: a local minimum that the residual shows. ``info["realigned"]``: the scans turned."""
    info["realigned"] = []
    if len(s.sizes) < 2:
        return s
    rms = _scan_rms(s)
    for k in np.argsort(rms)[::-1]:
        if not rms[k] > MISFIT_RATIO * rms.min():
            break
        for pose in fit.other_turns[k]:
            poses = list(s.poses)
            poses[k] = pose
            trial = _State(fit, s.x, _realign(fit, s.shapes, poses), s.shapes)
            trial, more = _levenberg_marquardt(fit, trial, max_iterations, tolerance)
            for key in ("iterations", "jacobians"):
                info[key] += more[key]
            if _scan_rms(trial).sum() < rms.sum():
                info["costs"] += more["costs"]
                info["converged"] = more["converged"]
                info["realigned"].append(fit.obs[int(k)].name)
                s, rms = trial, _scan_rms(trial)
                break
    return s


def _realign(fit: _Fit, shapes: np.ndarray, poses) -> list:
    """Each pose refined by ICP onto the current replayed shape (a few point-to-plane iterations)."""
    out, faces = [], fit.design.rest.faces
    for pts, x, (rot, t) in zip(fit.points, shapes, poses):
        q = closest_points_query((x, faces), device=fit.device)
        scale = float(np.max(np.linalg.norm(x, axis=1)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IcpConvergenceWarning)
            r1, t1, _, _ = icp(pts, q, rot, t, max_iterations=20, tolerance=1e-6, inlier_sigmas=REJECT_SIGMAS,
                               scale=scale)
        out.append((r1, t1))
    return out


def _jacobian(fit: _Fit, x: np.ndarray, poses, r0: np.ndarray) -> np.ndarray:
    """(M, P) forward differences of the residuals in the parameters' logarithms (poses held)."""
    cols = []
    for k in range(len(x)):
        step = FD_STEP if x[k] + FD_STEP <= fit.params.upper[k] else -FD_STEP
        xk = x.copy()
        xk[k] += step
        cols.append((fit.residuals(fit.shapes(xk), poses)[0] - r0) / step)
    return np.stack(cols, axis=1)


class _State:
    """The fit's current point: parameters, poses, shapes, residuals, normals, weights and Jacobian."""

    def __init__(self, fit: _Fit, x, poses, shapes):
        self.x, self.poses, self.shapes = x, poses, shapes
        self.r, self.p, self.n = fit.residuals(shapes, poses)
        self.sizes = [len(p) for p in fit.points]
        self.w = _robust_weights(self.r, self.sizes)
        self.jp = None  # (M, P) parameter Jacobian
        self.fresh = False

    def cost(self, r=None) -> float:
        r = self.r if r is None else r
        return float(np.sum(self.w * r * r))

    def normal(self) -> tuple[np.ndarray, np.ndarray]:
        """(J^T W J, J^T W r) of the full Jacobian (parameters, then 6 pose columns per scan), summed scan
        by scan: a scan's rows see only its own pose, so the full Jacobian's zero blocks are never formed.
        Summed by ``np.einsum`` (no BLAS threads: on a busy machine a threaded product of these tall
        matrices waits for a core, measured 30 x slower and more on two cores with one taken)."""
        n_par, n_pose = self.jp.shape[1], 6 * len(self.sizes)
        a, g = np.zeros((n_par + n_pose,) * 2), np.zeros(n_par + n_pose)
        start = 0
        for w, m in enumerate(self.sizes + [len(self.r) - sum(self.sizes)]):
            sl = slice(start, start + m)
            start += m
            if w < len(self.sizes):  # a scan: its parameters' and its pose's columns
                idx = np.r_[0:n_par, n_par + 6 * w:n_par + 6 * w + 6]
                jb = np.concatenate([self.jp[sl], _pose_block(self.p[sl], self.n[sl])], axis=1)
            else:  # the pressure readings: no pose
                idx = np.arange(n_par)
                jb = self.jp[sl]
            jw = jb * self.w[sl, None]
            a[np.ix_(idx, idx)] += np.einsum("ij,ik->jk", jw, jb)
            g[idx] += np.einsum("ij,i->j", jw, self.r[sl])
        return a, g

    def predicted(self, dx: np.ndarray) -> np.ndarray:
        """r + J dx, the residuals the linearisation predicts after the step ``dx`` (parameters, poses)."""
        n_par = self.jp.shape[1]
        out = self.r + np.einsum("ij,j->i", self.jp, dx[:n_par])
        start = 0
        for w, m in enumerate(self.sizes):
            sl = slice(start, start + m)
            start += m
            out[sl] += np.einsum("ij,j->i", _pose_block(self.p[sl], self.n[sl]), dx[n_par + 6 * w:n_par + 6 * w + 6])
        return out


def _step(s: _State, lam: float, n_par: int) -> tuple[np.ndarray, float]:
    """(the damped step, the largest gain of the robust cost that any step can make on the linearised
    model: the undamped step's, which bounds every damped one's)."""
    a, g = s.normal()
    d = np.diag(a).copy()
    d = d + 1e-9 * max(float(d.max()), 1e-30)
    full = np.linalg.solve(a + np.diag(d - np.diag(a)), -g)  # only the tiny regularisation
    return np.linalg.solve(a + lam * np.diag(d), -g), float(-(2.0 * g @ full + full @ a @ full))


def _levenberg_marquardt(fit: _Fit, s: _State, max_iterations: int, tolerance: float) -> tuple[_State, dict]:
    """Damped Gauss-Newton with IRLS weights; every step re-aligns each scan (its pose is an unknown of the
    step, the closest points recomputed: a point-to-plane ICP update within the fit). A fresh
    finite-difference Jacobian at the start; Broyden updates after each accepted step; a fresh one when
    a step fails or gains less than ``tolerance`` noise variances; converged when a step on a fresh
    Jacobian gains less than that, or fails where the linearised model's largest gain (the undamped
    step's) is below that: a larger damping would only shorten the step (each try costs a replay)."""
    n_par, lam = len(s.x), 1e-3
    info = dict(iterations=0, jacobians=0, costs=[s.cost()], converged=False)
    while info["iterations"] < max_iterations:
        info["iterations"] += 1
        if s.jp is None or info.pop("refresh", False):
            fit.say(f"iteration {info['iterations']}: finite-difference Jacobian ({len(s.x)} replays)")
            s.jp, s.fresh = _jacobian(fit, s.x, s.poses, s.r), True
            info["jacobians"] += 1
        fit.say(f"iteration {info['iterations']}: RMS residual {1e3 * np.sqrt(np.mean(s.r ** 2)):.4f} mm")
        delta, most = _step(s, lam, n_par)
        x1 = fit.params.clip(s.x + delta[:n_par])
        poses1 = _moved(s.poses, delta[n_par:])
        shapes1 = fit.shapes(x1)
        r1 = fit.residuals(shapes1, poses1)[0]
        c0, c1 = s.cost(), s.cost(r1)
        sigma2 = c0 / max(float((s.w > 0).sum()), 1.0)
        if c1 < c0:
            dx = np.concatenate([x1 - s.x, delta[n_par:]])
            pred = s.predicted(dx)
            jp = s.jp + np.outer(r1 - pred, (x1 - s.x)) / max(float((x1 - s.x) @ (x1 - s.x)), 1e-30)
            fresh = s.fresh
            s = _State(fit, x1, poses1, shapes1)  # re-aligned: the poses are unknowns of the step (ICP's update)
            s.jp, s.fresh = jp, False
            lam = max(lam / 3.0, 1e-7)
            info["costs"].append(s.cost())
            if c0 - c1 < tolerance * sigma2:
                if fresh:
                    info["converged"] = True
                    break
                info["refresh"] = True
        elif s.fresh:
            lam *= 4.0
            if lam > 1e4 or most < tolerance * sigma2:  # no step on this Jacobian can gain the tolerance
                info["converged"] = True
                break
        else:
            info["refresh"] = True
    return s, info


def _parameter_normal(s: _State) -> np.ndarray:
    """The parameters' normal matrix with the poses eliminated (Schur complement of J^T W J)."""
    n_par = s.jp.shape[1]
    a = s.normal()[0]
    app, apq, aqq = a[:n_par, :n_par], a[:n_par, n_par:], a[n_par:, n_par:]
    return app - apq @ np.linalg.pinv(aqq) @ apq.T


def _why(labels: list[str], members: list[int], fit: _Fit) -> str:
    names = [labels[i] for i in members]
    if len(members) == 1:
        lab = names[0]
        if lab.startswith("ipam_area["):
            i = int(lab[len("ipam_area["):-1])
            if all(seq.pressure_range()[i] == 0 for seq in fit.seqs):
                return f"{lab}: IPAM {i}'s pressure never changed in the observations (A acts only through A P)"
        return f"{lab}: no observation moves the scanned surface with it"
    if set(names) == {"youngs_modulus", "thickness"}:
        return "youngs_modulus ~ thickness: only their product E t acts on the membrane's springs"
    if any(n.startswith("region_stretch[") for n in names) and {"youngs_modulus", "thickness"} & set(names):
        return (f"{' ~ '.join(names)}: the regions cover the membrane once, so only E t times each region's "
                f"multiplier acts: fit E or the regions, not both")
    return f"{' ~ '.join(names)}: the observations move the surface the same way for this combination"


def _loose(cov: np.ndarray, idx: np.ndarray, labels: list[str], fit: _Fit) -> list[str]:
    """The directions of the identifiable logarithms (covariance ``cov`` over ``idx``) whose standard error
    exceeds ``LOOSE_STDERR``: each named by its members (weight >= 0.25), with what would fix it where
    the direction's members say (one IPAM's k with its A; bending alone); and, fitted without pressure
    readings, E t with IPAM sizes: their common scale."""
    lam, vec = np.linalg.eigh(cov)
    out = []
    for k in np.argsort(lam)[::-1]:
        if not np.sqrt(max(lam[k], 0.0)) > LOOSE_STDERR:
            break
        big = np.flatnonzero(np.abs(vec[:, k]) >= 0.25)
        members = [labels[int(idx[i])] for i in big]
        text = f"{' ~ '.join(members)}: determined only to +-{100 * np.sqrt(lam[k]):.0f} % along this combination"
        ipams = {m[m.index("[") + 1:-1] for m in members if m.startswith("ipam_")}
        if members == ["bending_stiffness"]:
            text += "; these states barely bend the membrane"
        elif len(ipams) == 1 and all(m.startswith("ipam_") for m in members):
            i = ipams.pop()
            text += (f"; IPAM {i}'s stiffness and area act together at one pressure: scan states with IPAM {i} "
                     f"at different pressures and the chamber at different inflations")
        out.append(text)
    fitted = {lab.split("[")[0] for lab in labels}
    if not any(o.pressure is not None for o in fit.obs) and fitted & {"youngs_modulus", "thickness", "region_stretch"} \
            and fitted & {"ipam_stiffness", "ipam_area"}:
        out.append("the stiffnesses' common scale (E t with every IPAM's k and A): without chamber pressure readings "
                   "it rests on the air's small compressibility alone (errors up to 5 % seen at 0.3 mm noise, beyond "
                   "their standard errors); give a chamber pressure reading with each scan")
    return out


def _structural_nulls(params: ParameterSet, idx: np.ndarray, n_faces: int) -> list[np.ndarray]:
    """Directions (over the seen parameters ``idx``, in log space) that leave the model unchanged by
    construction: regions covering every one of the ``n_faces`` faces once, fitted with E (or t), act
    only as E t s_region."""
    labels = [params.labels[i] for i in idx]
    regions = [k for k, lab in enumerate(labels) if lab.startswith("region_stretch[")]
    scale = [k for k, lab in enumerate(labels) if lab in ("youngs_modulus", "thickness")]
    if not regions or not scale or len(regions) != len(params.regions):
        return []
    count = np.bincount(np.concatenate(list(params.regions.values())), minlength=n_faces)
    if not np.all(count == 1):
        return []
    v = np.zeros(len(idx))
    v[scale[0]] = 1.0
    v[regions] = -1.0
    return [v]


def _identify(s: _State, fit: _Fit, scale2: float = 1.0) -> tuple[np.ndarray, list, list, np.ndarray, list]:
    """(stderr of log-parameters (P,), unidentifiable names, notes, correlation matrix, poorly determined
    directions); the covariance multiplied by ``scale2`` (the model error's share, ``_error_scale``)."""
    labels = fit.params.labels
    npar = len(labels)
    keep = s.w > 0
    dof = max(int(keep.sum()) - npar - 6 * len(fit.points), 1)
    sigma2 = float(np.sum(s.w * s.r ** 2)) / dof
    norm = _parameter_normal(s)
    d = np.sqrt(np.maximum(np.diag(norm), 0.0))
    seen = d > NULL_COLUMN * max(float(d.max()), 1e-30)
    names, notes, free = [], [], np.zeros(npar, bool)
    for i in np.flatnonzero(~seen):
        names.append(labels[i])
        notes.append(_why(labels, [int(i)], fit))
        free[i] = True
    idx = np.flatnonzero(seen)
    c = norm[np.ix_(idx, idx)] / np.outer(d[idx], d[idx])
    # exact null directions, where finite differences see them only nearly
    for v in _structural_nulls(fit.params, idx, fit.design.rest.n_faces):
        u = d[idx] * v
        u /= np.linalg.norm(u)
        proj = np.eye(len(idx)) - np.outer(u, u)
        c = proj @ c @ proj
    lam, vec = np.linalg.eigh(c)
    cov = np.zeros((len(idx), len(idx)))
    for k in range(len(lam)):
        if lam[k] < NULL_EIGENVALUE * max(float(lam.max()), 1e-30):
            members = [int(idx[i]) for i in np.flatnonzero(np.abs(vec[:, k]) >= 0.25)]
            names.append(" ~ ".join(labels[i] for i in members))
            notes.append(_why(labels, members, fit))
            free[members] = True
        else:
            cov += np.outer(vec[:, k], vec[:, k]) / lam[k]
    cov = scale2 * sigma2 * cov / np.outer(d[idx], d[idx])
    loose = _loose(cov, idx, labels, fit)
    se = np.full(npar, np.inf)
    se[idx] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    se[free] = np.inf
    corr = np.full((npar, npar), np.nan)
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr[np.ix_(idx, idx)] = cov / np.outer(sd, sd)
    return se, names, notes, corr, loose


def _noise_and_model_error(s: _State, noise: float | None) -> tuple[float, float, float]:
    """(noise variance, model error variance, points per vertex patch) of the kept scan points at the
    fit's end, m^2: each point's residual is the mean residual of the points nearest its vertex (the
    smooth part: the model error, correlated over the patch) plus its scatter about that mean (the
    scanner's noise, unless ``noise`` (m) is stated). The patch size is sum n_v^2 / sum n_v."""
    within, total, n_all, patches, sq = 0.0, 0.0, 0, 0, 0.0
    start = 0
    for x, m in zip(s.shapes, s.sizes):
        sl = slice(start, start + m)
        start += m
        keep = s.w[sl] > 0
        p, r = s.p[sl][keep], s.r[sl][keep]
        if not len(r):
            continue
        near = np.argmin(((p[:, None, :] - x[None, :, :]) ** 2).sum(axis=2), axis=1)
        count = np.bincount(near, minlength=len(x))
        mean = np.bincount(near, weights=r, minlength=len(x)) / np.maximum(count, 1)
        within += float(np.sum((r - mean[near]) ** 2))
        total += float(np.sum(r * r))
        n_all += len(r)
        patches += int(np.count_nonzero(count))
        sq += float(np.sum(count.astype(np.float64) ** 2))
    if not n_all:
        return 1.0, 0.0, 1.0
    noise2 = float(noise) ** 2 if noise is not None else within / max(n_all - patches, 1)
    return noise2, max(total / n_all - noise2, 0.0), sq / n_all


def _error_scale(noise2: float, model2: float, patch: float) -> float:
    """The factor on the parameters' covariance for model error: the residual's variance is noise2 +
    model2, but the model error is shared by the ``patch`` points of a vertex patch, so it weighs as
    noise of variance patch x model2 would (a fit to 20000 points of 0.1 mm correlated error knows a
    parameter no better than a fit to the patches' means); at least 1."""
    return max((noise2 + patch * model2) / max(noise2 + model2, 1e-30), 1.0)


def _flags(params, x: np.ndarray, se: np.ndarray, noise_mm: float, model_mm: float) -> tuple[dict, list]:
    """({label: z}, flag lines): parameters moved by more than ``FLAG_Z`` standard errors, parameters at
    a bound, and a model error above the noise."""
    z, flags = {}, []
    for i, lab in enumerate(params.labels):
        move = float(x[i] - params.x0[i])
        change = 100.0 * np.expm1(move)
        if np.isfinite(se[i]) and se[i] > 0:
            z[lab] = abs(move) / float(se[i])
            if z[lab] > FLAG_Z:
                flags.append(f"{lab} moved {change:+.1f} %, {z[lab]:.1f} standard errors: more than the scans support "
                             f"unless the device changed; the model's error ({model_mm:.3f} mm RMS beyond the "
                             f"{noise_mm:.3f} mm noise) may have moved it: check it on a held-out scan")
            elif abs(change) > NOTED_CHANGE_PCT:
                flags.append(f"{lab} changed {change:+.1f} % but only {z[lab]:.1f} standard errors (+-"
                             f"{100 * float(se[i]):.1f} %): the change is not established; scan more states")
        for bound, side in ((params.lower[i], "lower"), (params.upper[i], "upper")):
            if abs(x[i] - bound) < 1e-6:
                flags.append(f"{lab} stopped at its {side} bound ({change:+.1f} %): the fit wanted to go further; "
                             f"the value is a limit, not a measurement")
    if model_mm > noise_mm:
        flags.append(f"model error: the residual keeps {model_mm:.3f} mm RMS the model cannot follow, more than the "
                     f"scans' {noise_mm:.3f} mm noise; the standard errors are widened for it")
    return z, flags


def _held_out_check(design: Design, calibrated: Design, held: list, device: str, hold_s: float) -> tuple[list, list]:
    """([(name, RMS before, RMS after) mm], flag lines) of the held-out scans on the start and the
    calibrated model."""
    rows, flags = [], []
    for o in held:
        a = scan_residuals(design, o, device=device, hold_s=hold_s).rms_mm
        b = scan_residuals(calibrated, o, device=device, hold_s=hold_s).rms_mm
        rows.append((o.name, a, b))
        if not b < a - 1e-3:
            flags.append(f"held-out scan {o.name}: the calibrated model predicts it {'worse' if b > a + 1e-3 else 'no better'}"
                         f" ({a:.3f} -> {b:.3f} mm RMS): no change of the fit is confirmed by a scan it did not see")
    return rows, flags


def _vertex_residual(vertices: np.ndarray, points: np.ndarray, r: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(V,) mean signed residual of the kept scan points nearest each vertex (NaN where none)."""
    keep = w > 0
    near = np.argmin(((points[keep, None, :] - vertices[None, :, :]) ** 2).sum(axis=2), axis=1)
    total = np.bincount(near, weights=r[keep], minlength=len(vertices))
    count = np.bincount(near, minlength=len(vertices))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _maps(fit: _Fit, s: _State) -> list[ScanResidual]:
    out, start = [], 0
    for o, x, (rot, t), m in zip(fit.obs, s.shapes, s.poses, s.sizes):
        sl = slice(start, start + m)
        tf = np.eye(4)
        tf[:3, :3], tf[:3, 3] = rot, t
        out.append(ScanResidual(o.name, s.p[sl], s.r[sl], s.w[sl], tf, x,
                                _vertex_residual(x, s.p[sl], s.r[sl], s.w[sl])))
        start += m
    return out


def _checked_observations(design, observations) -> list:
    if not isinstance(design, Design):
        raise DesignError(f"calibrate needs a ws.Design, got {type(design).__name__}")
    obs = list(observations) if isinstance(observations, (list, tuple)) else [observations]
    if not obs:
        raise DesignError("calibrate needs at least one ws.ScanObservation")
    bad = [type(o).__name__ for o in obs if not isinstance(o, ScanObservation)]
    if bad:
        raise DesignError(f"calibrate needs ws.ScanObservation objects, got {bad[0]}")
    return obs


def calibrate(design: Design, observations, wrt=None, *, regions=None, device: str = "cpu",
              max_iterations: int = 20, tolerance: float = 0.5, hold_s: float = HOLD_S,
              seed: int = 0, noise: float | None = None, progress=None) -> CalibrationResult:
    """Fit ``design``'s parameters ``wrt`` (names of ``CALIBRATION_PARAMETERS``; None: ``default_wrt``, the
    membrane law's) to the scans of
    ``observations`` (``ScanObservation``): each observation's sequence is replayed on the model and held
    ``hold_s`` s until at rest, its scan aligned to it (unknown pose, as ``compare``), and the signed
    point-to-surface residuals minimised by damped Gauss-Newton with a Huber loss, the poses fitted
    jointly, every parameter within its bounds. Every input is checked before the fit (a state that does
    not fit the design, a scan of another object or without overlap: one-line errors). Returns a
    ``CalibrationResult``; ``tolerance``: a step on a fresh Jacobian that lowers the robust cost by less
    than this many residual variances ends the fit. ``regions``: parts of the membrane whose E t is fitted
    on its own (``region_stretch``, added to ``wrt``): names of ``calibration.regions.REGION_KINDS``
    (``"plug"``, ``"cell_boundaries"``, ``"patches:N"``) or {name: face indices}. ``noise``: the
    scanner's noise per coordinate, m (None: estimated from the scans); a residual above it is model
    error and widens the standard errors (``CalibrationResult.flags`` names what moved beyond them).
    Observations marked ``held_out`` are not fitted: each is predicted before and after the fit.
    ``progress(line)``: called with a line per phase and iteration.
    docs/calibration.md gives the algorithm and its measured accuracy."""
    every = _checked_observations(design, observations)
    obs = [o for o in every if not o.held_out]
    if not obs:
        raise DesignError("every observation is held out: fit at least one (\"held_out\": false)")
    say = progress or (lambda line: None)
    faces = region_faces(design, regions)
    wrt = check_wrt(default_wrt(design) if wrt is None else wrt)
    if faces and "region_stretch" not in wrt:
        wrt += ("region_stretch",)
    params = ParameterSet(design, wrt, faces)
    fit = _Fit(design, obs, params, device, hold_s, seed)
    fit.say = say  # the first line once every scan is checked (an input error stays one line)
    shapes = fit.shapes(params.x0)
    s = _State(fit, params.x0.copy(), _initial_poses(fit, shapes), shapes)
    fit.set_sigma(s.r)
    s = _State(fit, s.x, _realign(fit, shapes, s.poses), shapes)
    initial = [m.rms_mm for m in _maps(fit, s)]
    say(f"aligned {len(obs)} scan(s): RMS residual {', '.join(f'{a:.3f}' for a in initial)} mm; fitting "
        f"{len(params.labels)} parameter(s)")
    s, info = _levenberg_marquardt(fit, s, max_iterations, tolerance)
    s = _other_turns(fit, s, info, max_iterations, tolerance)
    say(f"fitted: {info['iterations']} iteration(s), {info['jacobians']} Jacobian(s), {fit.replays} replays")
    if any(o.pressure is not None for o in obs):  # the readings weighed at the final noise
        jp, sigma0 = s.jp.copy(), fit.sigma
        fit.set_sigma(s.r)
        s2 = _State(fit, s.x, s.poses, s.shapes)
        n = len(s.r) - sum(s.sizes)
        jp[len(jp) - n:] *= fit.sigma / sigma0
        s2.jp, s2.fresh, s = jp, s.fresh, s2
    result = _result(fit, s, info, initial, faces, noise)
    held = [o for o in every if o.held_out]
    if held:
        say(f"predicting {len(held)} held-out scan(s) on the start and the calibrated model")
        result.held_out, late = _held_out_check(design, result.design, held, device, hold_s)
        result.flags += late
    return result


def _result(fit: _Fit, s: _State, info: dict, initial: list, faces: dict, noise: float | None) -> CalibrationResult:
    """The fit's outcome: values, standard errors widened for the model error, flags, residual maps."""
    params = fit.params
    noise2, model2, patch = _noise_and_model_error(s, noise)
    scale2 = _error_scale(noise2, model2, patch)
    se, names, notes, corr, loose = _identify(s, fit, scale2)
    noise_mm, model_mm = 1e3 * np.sqrt(noise2), 1e3 * np.sqrt(model2)
    z, flags = _flags(params, s.x, se, noise_mm, model_mm)
    if not info["converged"]:
        flags.append(f"the fit stopped at its iteration limit ({info['iterations']}) before converging: the values "
                     f"are where it stopped, not a minimum")
    maps = _maps(fit, s)
    return CalibrationResult(values=params.values(s.x), stderr=params.per_name(se * np.exp(s.x)),
                             start=params.values(params.x0), design=params.design(fit.design, s.x),
                             residual_mm=[m.rms_mm for m in maps],
                             initial_residual_mm=initial, unidentifiable=names, notes=notes, residuals=maps,
                             labels=params.labels, correlation=corr, iterations=info["iterations"],
                             jacobians=info["jacobians"], converged=info["converged"], costs=info["costs"],
                             wrt=params.names, observation_names=[o.name for o in fit.obs], regions=faces,
                             poorly_determined=loose, realigned=info["realigned"], noise_mm=float(noise_mm),
                             model_error_mm=float(model_mm), error_scale=float(np.sqrt(scale2)), z=z, flags=flags)


def scan_residuals(design: Design, observation: ScanObservation, *, device: str = "cpu", hold_s: float = HOLD_S,
                   seed: int = 0) -> ScanResidual:
    """The residual map of one observation on ``design`` (no fit): replayed, aligned as ``calibrate``
    aligns, signed point-to-surface residuals with the robust weights. ``.rms_mm`` is the prediction error."""
    obs = _checked_observations(design, [observation])
    params = ParameterSet(design, ("rest_scale",))
    fit = _Fit(design, obs, params, device, hold_s, seed)
    shapes = fit.shapes(params.x0)
    poses = _realign(fit, shapes, _initial_poses(fit, shapes))
    poses = _realign(fit, shapes, poses)
    return _maps(fit, _State(fit, params.x0, poses, shapes))[0]
