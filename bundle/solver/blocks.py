"""Parameters and residual blocks of the least-squares engine.

Parameters (`State`): N poses (`dgcal.fields.pose.Poses`: 6 each, [dC (m, world), dtheta (rad, camera axes)],
a right perturbation of R_cam_to_world), M points (3 each, world, m, additive) and G global parameters
(additive: camera intrinsics, lever arm, boresight angles, delay, ...). The points are eliminated by Schur
complement; poses and globals form the reduced ("camera-side") system.

A residual block is a batch of k items of the same kind, each with `dim` whitened residuals that depend on at
most one pose, one point and some globals. `evaluate` returns them (and, on request, their Jacobians) as a
`BlockEval`; robust losses act on each item's squared whitened norm.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from dgcal.bundle.solver.kernels import pose_point_jacobians, to_camera
from dgcal.calib.camera.models import CameraModel
from dgcal.fields.pose import Poses

INVALID_COST = 1e12   # cost of an item that cannot be evaluated (a point behind its camera)


@dataclass
class State:
    """The unknowns: poses (N), points (M,3) m and globals (G,)."""

    poses: Poses
    points: np.ndarray
    globals: np.ndarray

    def copy(self) -> "State":
        return State(Poses(self.poses.R_world_to_cam.copy(), self.poses.C_world.copy()), self.points.copy(),
                     self.globals.copy())


@dataclass
class BlockEval:
    """Whitened residuals (k,dim) of a block's items and, when linearised, their Jacobians.

    pose/point: (k,) indices of the pose/point each item depends on (None: none); glob: (Gb,) global columns.
    """

    r: np.ndarray
    valid: np.ndarray
    pose: np.ndarray | None = None
    J_pose: np.ndarray | None = None        # (k,dim,6)
    point: np.ndarray | None = None
    J_point: np.ndarray | None = None       # (k,dim,3)
    glob: np.ndarray | None = None
    J_glob: np.ndarray | None = None        # (k,dim,Gb)


class Block:
    """Base of residual blocks: `name`, `dim`, robust `loss` and `loss_scale` (in whitened units).

    A block that can evaluate a part of its items (`chunkable`) gives the engine its parts (`chunks`) and
    `evaluate(state, jacobians, rows)` of one part (a slice of its items); the engine then never holds the
    Jacobians of more than one part (`dgcal.bundle.solver.normals.CHUNK_ITEMS`)."""

    name: str = "block"
    dim: int = 1
    loss: str = "none"
    loss_scale: float = 3.0
    chunkable: bool = False

    def __len__(self) -> int:
        raise NotImplementedError

    def evaluate(self, state: State, jacobians: bool) -> BlockEval:
        raise NotImplementedError

    def chunks(self, n_poses: int, size: int) -> list[slice]:
        """The parts of about `size` items each, in item order (one part unless `chunkable`)."""
        return [slice(0, len(self))]


def _indices(a) -> np.ndarray:
    """An index array as given when it is one of integers (int32 indices of 5 M observations stay 20 MB), else
    as int."""
    a = np.asarray(a)
    return a if a.dtype.kind in "iu" else np.asarray(a, int)


@dataclass
class BoardWarp:
    """A flat target board's bow (mrcal's model): every point moves along the board normal `normal_world` (3,) by
    shape (M,2) @ w, w = the globals `glob` (2,) in metres, shape = (1 - u^2, 1 - v^2) with u, v the point's
    coordinates along the board's axes scaled to [-1, 1] (0 at the edges, 1 at the centre lines)."""

    shape: np.ndarray
    normal_world: np.ndarray
    glob: np.ndarray

    def points(self, points: np.ndarray, globals_: np.ndarray) -> np.ndarray:
        """The bowed points (M,3) m of the flat ones `points` at the warp of `globals_`."""
        return points + (self.shape @ globals_[self.glob])[:, None] * self.normal_world[None, :]


class ImageObservations(Block):
    """Pixel measurements uv (k,2) of points by posed images through a camera model, whitened by sigma (k,2) px.

    `intrinsics` names the camera parameters that are unknowns; they are globals `glob_offset + 0..`;
    `points_fixed` marks the points as known (no point unknowns, e.g. a target field held fixed); `warp` (a
    `BoardWarp`, known points only) bows them by two more globals.
    Model: X_cam = R_world_to_cam[pose] (X[point] - C_world[pose]),  uv = camera.project(X_cam).
    """

    dim = 2

    def __init__(self, camera: CameraModel, pose: np.ndarray, point: np.ndarray, uv: np.ndarray,
                 sigma: np.ndarray, intrinsics: Sequence[str] = (), glob_offset: int = 0,
                 loss: str = "none", loss_scale: float = 3.0, name: str = "image", points_fixed: bool = False,
                 warp: BoardWarp | None = None):
        if warp is not None and not points_fixed:
            raise ValueError("a board warp bows known points: points_fixed must be True")
        self.warp = warp
        self.camera = camera
        self.pose = _indices(pose)
        self.point = _indices(point)
        self.uv = np.asarray(uv, float).reshape(-1, 2)
        sigma = np.asarray(sigma, float)
        # a (k,2) array is used as given (not copied: 80 MB at 5 M items); anything else is broadcast
        self.sigma = sigma if sigma.shape == self.uv.shape else np.broadcast_to(sigma, self.uv.shape).copy()
        self.intrinsics = tuple(intrinsics)
        self.param_idx = np.array([camera.PARAMS.index(p) for p in self.intrinsics], int)
        self.glob = glob_offset + np.arange(len(self.intrinsics))
        self.loss, self.loss_scale, self.name = loss, loss_scale, name
        self.points_fixed = points_fixed      # the points are known: no point Jacobian

    chunkable = True

    def __len__(self) -> int:
        return len(self.pose)

    def chunks(self, n_poses: int, size: int) -> list[slice]:
        """Parts of `size` items; of known points with per-pose runs (`_pose_runs`), parts of at least `size` items
        (the last may be smaller) that end where a pose's items end, so each pose's products are the whole
        block's."""
        k = len(self)
        if k <= size:
            return [slice(0, k)]
        runs = self._pose_runs(n_poses) if self.points_fixed else None
        if runs is None:
            return [slice(a, min(a + size, k)) for a in range(0, k, size)]
        out, start = [], 0
        for _, s in runs:
            if s.stop - start >= size:
                out.append(slice(start, s.stop))
                start = s.stop
        if start < k:
            out.append(slice(start, k))
        return out

    def _part(self, rows: slice | None, n_poses: int):
        """(pose, point, uv, sigma, runs) of the items `rows` (all: None): views, the same objects on every call
        for the same part (the engine caches by identity), runs relative to the part."""
        if rows is None or (rows.start == 0 and rows.stop == len(self)):
            return self.pose, self.point, self.uv, self.sigma, (self._pose_runs(n_poses) if self.points_fixed
                                                                else None)
        arrays = (self.pose, self.point, self.uv, self.sigma)
        cached = self.__dict__.get("_parts")
        if cached is None or any(a is not b for a, b in zip(cached[0], arrays)):
            cached = self._parts = (arrays, {})      # the items changed (or first use): new views
        parts = cached[1]
        key = (rows.start, rows.stop, n_poses)
        if key not in parts:
            runs = self._pose_runs(n_poses) if self.points_fixed else None
            if runs is not None:
                runs = [(i, slice(s.start - rows.start, s.stop - rows.start)) for i, s in runs
                        if s.start >= rows.start and s.stop <= rows.stop]
            parts[key] = (self.pose[rows], self.point[rows], self.uv[rows], self.sigma[rows], runs)
        return parts[key]

    def camera_at(self, globals_: np.ndarray) -> CameraModel:
        """The camera with the intrinsics of a state's globals."""
        cam = self.camera.copy()
        cam.sigmas = None
        if len(self.glob):
            cam.params[self.param_idx] = globals_[self.glob]
        return cam

    RUN_MIN = 32     # items per pose from which the pose products go pose by pose (self-calibration: ~1000)

    def _pose_runs(self, n_poses: int) -> list[tuple[int, slice]] | None:
        """(pose, rows) of every pose when the items are sorted by pose with RUN_MIN or more per pose, else None;
        cached while the pose array stays the same object."""
        cached = getattr(self, "_runs", None)
        if cached is not None and cached[0] is self.pose and cached[1] == n_poses:
            return cached[2]
        p = self.pose
        runs = None
        if (len(p) >= self.RUN_MIN * max(n_poses, 1) and p.min() >= 0 and p.max() < n_poses
                and np.all(p[1:] >= p[:-1])):
            b = np.searchsorted(p, np.arange(n_poses + 1))
            runs = [(i, slice(int(b[i]), int(b[i + 1]))) for i in range(n_poses) if b[i + 1] > b[i]]
        self._runs = (p, n_poses, runs)
        return runs

    def evaluate(self, state: State, jacobians: bool, rows: slice | None = None) -> BlockEval:
        """Whitened residuals (and Jacobians) of every item, or of the part `rows` (a slice of `chunks`)."""
        cam = self.camera_at(state.globals)
        R_world_to_cam, C_world = state.poses.R_world_to_cam, state.poses.C_world
        points = state.points if self.warp is None else self.warp.points(state.points, state.globals)
        # per-pose products for known points (self-calibration: numba never loaded); compiled otherwise
        pose, point, uv_m, sigma, runs = self._part(rows, len(C_world))
        if runs is None:
            R_world_to_cam = np.ascontiguousarray(R_world_to_cam)
            Xc = to_camera(R_world_to_cam, np.ascontiguousarray(C_world), np.ascontiguousarray(points),
                           pose.astype(np.int64, copy=False), point.astype(np.int64, copy=False))
        else:                       # many items per pose, sorted: one small matrix product per pose
            Xc = points[point]
            for i, s in runs:
                Xc[s] -= C_world[i]
                Xc[s] = Xc[s] @ R_world_to_cam[i].T
        valid = Xc[:, 2] > 0
        if not jacobians:
            with np.errstate(all="ignore"):
                r = (cam.project(Xc) - uv_m) / sigma
            return BlockEval(r, valid & np.isfinite(r).all(1))
        with np.errstate(all="ignore"):
            uv, J_int, JX = cam.project_with_jacobians(Xc, params=len(self.glob) > 0)
        w = 1.0 / sigma
        J_pose = np.empty((len(Xc), 2, 6))
        JR = np.empty((len(Xc), 2, 3))
        if runs is None:             # one compiled pass per item (aerial blocks: ~10 items per pose-point pair)
            pose_point_jacobians(np.ascontiguousarray(JX), w, R_world_to_cam, pose.astype(np.int64, copy=False), Xc,
                                 J_pose, JR)
        else:
            JXw = JX * w[:, :, None]
            JXw2, JR2 = JXw.reshape(-1, 3), JR.reshape(-1, 3)
            for i, s in runs:
                np.matmul(JXw2[2 * s.start:2 * s.stop], R_world_to_cam[i], out=JR2[2 * s.start:2 * s.stop])
            # dX_cam/dC = -R;  dX_cam/dtheta = [X_cam]x (R_cam_to_world <- R_cam_to_world Exp(dtheta))
            np.negative(JR, out=J_pose[:, :, :3])
            _times_cross_matrices(JXw, Xc, J_pose[:, :, 3:])
        r = (uv - uv_m) / sigma
        valid &= np.isfinite(r).all(1)
        glob, J_glob = self.glob, (self._intrinsic_jacobian(J_int, w) if len(self.glob) else None)
        if self.warp is not None:     # d r / d w = (d r / d X_world . normal) shape(point): JR is whitened dr/dX
            J_w = (JR @ self.warp.normal_world)[:, :, None] * self.warp.shape[point][:, None, :]
            glob = np.r_[glob, self.warp.glob]
            J_glob = J_w if J_glob is None else np.concatenate([J_glob, J_w], axis=2)
        return BlockEval(r, valid, pose, J_pose, None if self.points_fixed else point,
                         None if self.points_fixed else JR, glob if len(glob) else self.glob, J_glob)

    def _intrinsic_jacobian(self, J_int: np.ndarray, w: np.ndarray) -> np.ndarray:
        """The whitened Jacobian of the unknown intrinsics (all of the model's, or a selection)."""
        if len(self.param_idx) == J_int.shape[2] and np.array_equal(self.param_idx, np.arange(J_int.shape[2])):
            J_int *= w[:, :, None]            # the camera's fresh array: whitened in place
            return J_int
        return J_int[:, :, self.param_idx] * w[:, :, None]


def _times_cross_matrices(J: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """out = J_k [v_k]x for J (k,d,3), v (k,3), out (k,d,3): each row of J crossed with v_k (row j: j x v),
    written out (NumPy's batched matmul of 3x3 stacks costs several times the arithmetic)."""
    j0, j1, j2 = J[:, :, 0], J[:, :, 1], J[:, :, 2]
    v0, v1, v2 = v[:, 0, None], v[:, 1, None], v[:, 2, None]
    np.subtract(j1 * v2, j2 * v1, out=out[:, :, 0])
    np.subtract(j2 * v0, j0 * v2, out=out[:, :, 1])
    np.subtract(j0 * v1, j1 * v0, out=out[:, :, 2])


class PointPriors(Block):
    """Observed point coordinates, one item per coordinate: point (k,), axis (k,) 0-2, value (k,) m, sigma (k,) m.

    Residual (X[point, axis] - value) / sigma. `from_arrays` builds it from (m,3) arrays with NaN = no prior."""

    dim = 1

    def __init__(self, point: np.ndarray, axis: np.ndarray, value: np.ndarray, sigma: np.ndarray,
                 name: str = "point_prior"):
        self.point = np.asarray(point, int)
        self.axis = np.asarray(axis, int)
        self.value = np.asarray(value, float)
        self.w = 1.0 / np.broadcast_to(np.asarray(sigma, float), self.value.shape)
        self.name = name

    @classmethod
    def from_arrays(cls, xyz: np.ndarray, sigma: np.ndarray, points: np.ndarray | None = None,
                    name: str = "point_prior") -> "PointPriors":
        """Priors of points `points` (default 0..m-1) from (m,3) coordinates and sigmas; NaN coordinates skipped."""
        xyz = np.asarray(xyz, float).reshape(-1, 3)
        pts = np.arange(len(xyz)) if points is None else np.asarray(points, int)
        j, a = np.nonzero(np.isfinite(xyz))
        sig = np.broadcast_to(np.asarray(sigma, float), xyz.shape)
        return cls(pts[j], a, xyz[j, a], sig[j, a], name)

    def __len__(self) -> int:
        return len(self.point)

    def evaluate(self, state: State, jacobians: bool) -> BlockEval:
        r = ((state.points[self.point, self.axis] - self.value) * self.w)[:, None]
        ev = BlockEval(r, np.ones(len(r), bool))
        if jacobians:
            J = np.zeros((len(r), 1, 3))
            J[np.arange(len(r)), 0, self.axis] = self.w
            ev.point, ev.J_point = self.point, J
        return ev


class CentrePriors(Block):
    """Observed projection centres (e.g. GNSS), one item per coordinate: pose (k,), axis (k,), value, sigma (m).

    Residual (C_world[pose, axis] - value) / sigma. `from_arrays` takes (n,3) arrays with NaN = no prior.
    An antenna not at the projection centre: `offset_cam` (3,) m, the antenna in camera axes, observed at
    C + R_cam_to_world offset_cam (known, applied with each pose's rotation). A shift common to a flight's centres
    (a GNSS base or datum offset): `flight` (k,) index per item and `shift_glob` (3F,) the globals of the shifts
    (E, N, Up per flight, world axes, m), observed at ... + shift[flight]."""

    dim = 1

    def __init__(self, pose: np.ndarray, axis: np.ndarray, value: np.ndarray, sigma: np.ndarray,
                 name: str = "centre_prior", offset_cam: np.ndarray | None = None, flight: np.ndarray | None = None,
                 shift_glob: np.ndarray | None = None):
        self.pose = np.asarray(pose, int)
        self.axis = np.asarray(axis, int)
        self.value = np.asarray(value, float)
        self.w = 1.0 / np.broadcast_to(np.asarray(sigma, float), self.value.shape)
        self.name = name
        self.offset_cam = None if offset_cam is None or not np.any(offset_cam) else np.asarray(offset_cam, float)
        self.flight = None if flight is None else np.asarray(flight, int)
        self.shift_glob = None if shift_glob is None else np.asarray(shift_glob, int)

    @classmethod
    def from_arrays(cls, C: np.ndarray, sigma: np.ndarray, name: str = "centre_prior",
                    offset_cam: np.ndarray | None = None, flight: np.ndarray | None = None,
                    shift_glob: np.ndarray | None = None) -> "CentrePriors":
        """Priors from (n,3) centres and sigmas; NaN coordinates skipped; `flight` (n,) per pose (with
        `shift_glob`: a shift per flight)."""
        C = np.asarray(C, float).reshape(-1, 3)
        i, a = np.nonzero(np.isfinite(C))
        sig = np.broadcast_to(np.asarray(sigma, float), C.shape)
        fl = None if flight is None else np.asarray(flight, int)[i]
        return cls(i, a, C[i, a], sig[i, a], name, offset_cam, fl, shift_glob)

    def __len__(self) -> int:
        return len(self.pose)

    def evaluate(self, state: State, jacobians: bool) -> BlockEval:
        k = np.arange(len(self.pose))
        pred = state.poses.C_world[self.pose, self.axis]
        R_cam_to_world = None
        if self.offset_cam is not None:
            R_cam_to_world = np.swapaxes(state.poses.R_world_to_cam[self.pose], -1, -2)
            pred = pred + (R_cam_to_world @ self.offset_cam)[k, self.axis]
        if self.shift_glob is not None:
            pred = pred + state.globals[self.shift_glob[3 * self.flight + self.axis]]
        r = ((pred - self.value) * self.w)[:, None]
        ev = BlockEval(r, np.ones(len(r), bool))
        if jacobians:
            J = np.zeros((len(r), 1, 6))
            J[k, 0, self.axis] = self.w
            if R_cam_to_world is not None:
                # R <- R Exp(dtheta): d(R a) = -R [a]x dtheta
                a = self.offset_cam
                ax = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
                J[:, 0, 3:] = -(R_cam_to_world @ ax)[k, self.axis] * self.w[:, None]
            ev.pose, ev.J_pose = self.pose, J
            if self.shift_glob is not None:
                g = np.unique(self.shift_glob)
                Jg = np.zeros((len(r), 1, len(g)))
                Jg[k, 0, np.searchsorted(g, self.shift_glob[3 * self.flight + self.axis])] = self.w
                ev.glob, ev.J_glob = g, Jg
        return ev


class GlobalPriors(Block):
    """Prior values of globals, one item each: glob (k,) columns, value (k,), sigma (k,)."""

    dim = 1

    def __init__(self, glob: np.ndarray, value: np.ndarray, sigma: np.ndarray, name: str = "global_prior"):
        self.glob_idx = np.asarray(glob, int)
        self.value = np.asarray(value, float)
        self.w = 1.0 / np.asarray(sigma, float)
        self.name = name

    def __len__(self) -> int:
        return len(self.glob_idx)

    def evaluate(self, state: State, jacobians: bool) -> BlockEval:
        r = ((state.globals[self.glob_idx] - self.value) * self.w)[:, None]
        ev = BlockEval(r, np.ones(len(r), bool))
        if jacobians:
            g = np.unique(self.glob_idx)
            J = np.zeros((len(r), 1, len(g)))
            J[np.arange(len(r)), 0, np.searchsorted(g, self.glob_idx)] = self.w
            ev.glob, ev.J_glob = g, J
        return ev


@dataclass
class FunctionBlock(Block):
    """A block defined by a function `fun(state, jacobians) -> BlockEval` (pose priors from a POS, ...)."""

    fun: Callable[[State, bool], BlockEval]
    n: int
    dim: int
    name: str = "function"
    loss: str = "none"
    loss_scale: float = 3.0
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return self.n

    def evaluate(self, state: State, jacobians: bool) -> BlockEval:
        return self.fun(state, jacobians)
