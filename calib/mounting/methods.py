"""Mounting calibration entry point: EOPs + trajectory + events -> lever arm, boresight, delay (any method)."""
from __future__ import annotations

from dgcal.calib.mounting.common import BlockFrame, Epochs, MountingResult, build_epochs
from dgcal.calib.mounting.observability import observability_warnings
from dgcal.calib.mounting.joint import calibrate_proposed
from dgcal.calib.mounting.two_step import calibrate_traditional
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError
from dgcal.fields.io.formats import EOP, Events, Trajectory

METHODS = ("traditional", "proposed", "iso")


def prepare_epochs(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events) -> tuple[BlockFrame, Epochs]:
    """The block frame (centred on the EOPs) and the matched epochs in it."""
    frame = BlockFrame.at_map_points(grid, eop.xyz)
    return frame, build_epochs(frame, eop, events, traj)


def calibrate_mounting(eop: EOP, grid: MapGrid, traj: Trajectory, events: Events,
                       method: str = "proposed", **kw) -> MountingResult:
    """Lever arm (body, m), boresight R_cam_to_body and delay (s) with covariance, by `traditional` or `proposed`."""
    if method not in ("traditional", "proposed"):
        raise InputError(f"method must be traditional or proposed here, got {method!r}", field="--method")
    frame, ep = prepare_epochs(eop, grid, traj, events)
    res = calibrate_traditional(ep) if method == "traditional" else calibrate_proposed(ep, **kw)
    res.warnings = list(ep.warnings) + observability_warnings(ep, res if method != "traditional" else None)
    res.extra["skipped_images"] = ep.skipped
    res.extra["block_origin_lat_lon_h"] = [frame.local.lat0, frame.local.lon0, frame.local.h0]
    return res
