"""Mounting calibration entry point: EOPs + trajectory + events -> lever arm, boresight, delay (any method).

The methods, named for what they estimate (the seed paper's terms are accepted as aliases):

| name       | alias         | estimates                                                               |
|------------|---------------|-------------------------------------------------------------------------|
| `two-step` | `traditional` | per-epoch lever arm and boresight at the event time (delay 0), averaged |
| `joint`    | `proposed`    | delay, lever arm and boresight together from the per-epoch poses        |
| `iso`      |               | delay, lever arm, boresight (and intrinsics) in one bundle adjustment   |

`METHODS` is the registry (like dgcal.calib.camera.models.MODELS); `mounting_method(name)` resolves a
name or alias. A result's `method` is the name the caller asked for, `method_canonical` the registry's.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Callable

from dgcal.calib.mounting.common import POS_COMMON_FRACTION, Epochs, MountingResult, build_epochs
from dgcal.calib.mounting.integrated import calibrate_iso_files
from dgcal.calib.mounting.joint import calibrate_proposed
from dgcal.calib.mounting.observability import observability_warnings
from dgcal.calib.mounting.plausibility import check_epochs, result_warnings, unseen_delay_warning
from dgcal.calib.mounting.two_step import calibrate_traditional
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Events, Trajectory, read_eop
from dgcal.fields.processes import fork_map
from dgcal.pos.events import read_any_events
from dgcal.pos.ins.sbet import read_any_trajectory
from dgcal.fields.world import World


@dataclass(frozen=True)
class MountingMethod:
    """One mounting-calibration method of the registry: its name, aliases and what it needs."""

    name: str
    aliases: tuple[str, ...]
    summary: str
    needs_image_measurements: bool = False  # iso: measurements, ground points and camera
    uses_pos_common_fraction: bool = True   # the POS common-mode share enters its covariance
    references: tuple[str, ...] = ()        # simpler methods run on the same data for the report


METHODS: dict[str, MountingMethod] = {m.name: m for m in (
    MountingMethod("two-step", ("traditional",), "per-epoch lever arm and boresight at the event time (delay 0), "
                   "then their robust mean", uses_pos_common_fraction=False),
    MountingMethod("joint", ("proposed",), "exposure delay, lever arm and boresight in one weighted least-squares "
                   "fit of the per-epoch poses", references=("two-step",)),
    MountingMethod("iso", (), "exposure delay, lever arm, boresight (and intrinsics) in one bundle adjustment of "
                   "the image measurements", needs_image_measurements=True, references=("joint", "two-step")),
)}
ALIASES: dict[str, str] = {a: m.name for m in METHODS.values() for a in m.aliases}
METHOD_NAMES: tuple[str, ...] = tuple(METHODS) + tuple(ALIASES)  # every accepted name, canonical first
DEFAULT_METHOD = "joint"


def mounting_method(name: str, field_name: str = "method") -> MountingMethod:
    """The registry entry of a method name or alias (`traditional` = `two-step`, `proposed` = `joint`)."""
    key = str(name).strip().lower()
    try:
        return METHODS[ALIASES.get(key, key)]
    except KeyError:
        raise InputError(f"unknown mounting method {name!r} ({', '.join(METHODS)}; aliases "
                         + ", ".join(f"{a} = {c}" for a, c in ALIASES.items()) + ")", field=field_name) from None


def canonical_method(name: str) -> str:
    """The registry name of a method name or alias; an unknown name is returned unchanged."""
    key = str(name).strip().lower()
    key = ALIASES.get(key, key)
    return key if key in METHODS else str(name)


def prepare_epochs(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events) -> tuple[World, Epochs]:
    """The world (tangent at the centre of the EOPs) and the matched epochs in it."""
    world = World.at_map_points(grid, eop.xyz)
    ep = build_epochs(world, eop, events, traj)
    check_epochs(ep, eop.path)
    return world, ep


def calibrate_mounting(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events,
                       method: str = DEFAULT_METHOD, **kw) -> MountingResult:
    """Lever arm (body, m), boresight R_cam_to_body and delay (s) with covariance by `two-step` or `joint`.

    `kw` are the joint method's options (reject, fix_delay, pos_common_fraction); `iso` needs image
    measurements: `calibrate_mounting_files` or dgcal.calib.mounting.integrated.calibrate_iso.
    """
    m = mounting_method(method)
    if m.needs_image_measurements:
        raise InputError(f"method {method!r} needs image measurements: use calibrate_mounting_files "
                         "(dgcal mount --measurements --gcp --camera)", field="method")
    world, ep = prepare_epochs(eop, grid, traj, events)
    res = calibrate_traditional(ep) if m.name == "two-step" else calibrate_proposed(ep, **kw)
    res.warnings = list(ep.warnings) + observability_warnings(ep, res if m.name != "two-step" else None)
    res.warnings += result_warnings(res, ep, refuse=m.name != "two-step")
    if m.name == "two-step":            # the delay it cannot see, from the joint method on the same epochs
        unseen = unseen_delay_warning(res, calibrate_proposed(ep, pos_common_fraction=0.0), ep)
        if unseen:
            res.warnings.append(unseen)
    res.extra["skipped_images"] = ep.skipped
    res.extra["block_origin_lat_lon_h"] = [world.enu.lat0, world.enu.lon0, world.enu.h0]
    _name(res, method, m)
    return res


def _name(res: MountingResult, asked: str, m: MountingMethod) -> None:
    res.method = str(asked)
    res.method_canonical = m.name


@dataclass
class MountOptions:
    """Inputs and settings of `dgcal mount`: files, the method (name or alias) and its options."""

    eop: Path                        # EOP CSV of the calibration flight, in `crs`
    crs: str
    trajectory: Path                 # trajectory.csv (or the events.csv of dgcal pos)
    events: Path                     # image,gps_week,gps_sow
    method: str = DEFAULT_METHOD
    reject: bool = True              # joint: chi-square rejection of epochs
    fix_delay: bool = False          # joint, iso: hold the delay at 0
    pos_common_fraction: float = POS_COMMON_FRACTION  # joint, iso: share (0-1) of the POS error variance common to
    #                                                    the flight (common.POS_COMMON_FRACTION)
    measurements: Path | None = None  # iso: image measurements (CSV or ODM gcp_list.txt)
    gcp: Path | None = None          # iso: ground points
    camera: Path | None = None       # iso: camera file
    refine_intrinsics: tuple[str, ...] = ()  # iso: camera parameters estimated too


@dataclass
class MountingRun:
    """The calibration asked for, and the simpler methods on the same data (for the report)."""

    result: MountingResult
    references: dict[str, MountingResult] = field(default_factory=dict)


_SOLVERS: dict[str, Callable[[EOP, MapGrid, Trajectory, Events, MountOptions], MountingResult]] = {
    "two-step": lambda eop, grid, traj, events, o: calibrate_mounting(eop, grid, traj, events, "two-step"),
    "joint": lambda eop, grid, traj, events, o: calibrate_mounting(
        eop, grid, traj, events, "joint", reject=o.reject, fix_delay=o.fix_delay,
        pos_common_fraction=o.pos_common_fraction),
    "iso": lambda eop, grid, traj, events, o: calibrate_iso_files(
        eop, grid, traj, events, o.measurements, o.gcp, o.camera, fix_delay=o.fix_delay,
        refine_intrinsics=tuple(o.refine_intrinsics), pos_common_fraction=o.pos_common_fraction),
}


def calibrate_mounting_files(opts: MountOptions) -> MountingRun:
    """`dgcal mount`: read the EOPs, trajectory and events, calibrate by `opts.method`, and run its reference
    methods (joint and two-step for iso, two-step for joint) with their default options for comparison."""
    m = mounting_method(opts.method)
    if m.needs_image_measurements:
        missing = [o for o in ("measurements", "gcp", "camera") if getattr(opts, o) is None]
        if missing:
            raise InputError(f"--method {opts.method} needs --{missing[0]}", field=missing[0])
    grid = MapGrid(opts.crs)
    eop, events = read_eop(opts.eop), read_any_events(opts.events)
    traj = read_any_trajectory(opts.trajectory, near_t=float(events.t[0]) if len(events) else None)
    tasks = [partial(_SOLVERS[m.name], eop, grid, traj, events, opts)]
    for name in m.references:
        ref_opts = MountOptions(opts.eop, opts.crs, opts.trajectory, opts.events, name,
                                pos_common_fraction=opts.pos_common_fraction)
        tasks.append(partial(_SOLVERS[name], eop, grid, traj, events, ref_opts))
    res, *ref_results = fork_map(tasks)    # the reference methods beside the one asked for (independent)
    _name(res, opts.method, m)
    return MountingRun(res, dict(zip(m.references, ref_results)))
