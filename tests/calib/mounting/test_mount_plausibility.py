"""A plausible-looking wrong input gives no confident answer (issue 31): a trajectory shifted in time, EOPs in
another UTM zone, events in UTC instead of GPS time are refused with their likely cause; the two-step method says
what the delay it cannot see does to its lever arm."""
from __future__ import annotations

from dataclasses import replace

import pytest

from dgcal.calib.mounting.methods import calibrate_mounting
from dgcal.fields.crs import MapGrid
from dgcal.fields.errors import InputError, ResultError
from dgcal.sim.mounting import simulate_mounting


@pytest.fixture(scope="module")
def sim():
    return simulate_mounting(3)


def test_the_clean_flight_passes_without_plausibility_warnings(sim):
    c = sim.calibration
    res = calibrate_mounting(c.eop, MapGrid(sim.crs), c.traj, c.events, "joint")
    assert not [w for w in res.warnings if "shutter lag" in w or "longer than usual" in w]
    two = calibrate_mounting(c.eop, MapGrid(sim.crs), c.traj, c.events, "two-step")
    # the simulated -0.14 s delay (seed 003's platform) is what two-step cannot see: it says so, with its effect
    unseen = [w for w in two.warnings if "two-step assumes no exposure delay" in w]
    assert len(unseen) == 1 and "-0.14" in unseen[0] and "m along the track" in unseen[0]


def test_a_trajectory_shifted_by_one_second_is_refused_by_joint_and_flagged_by_two_step(sim):
    c = sim.calibration
    traj = replace(c.traj, t=c.traj.t + 1.0)
    with pytest.raises(ResultError, match="time scales"):
        calibrate_mounting(c.eop, MapGrid(sim.crs), traj, c.events, "joint")
    two = calibrate_mounting(c.eop, MapGrid(sim.crs), traj, c.events, "two-step")
    assert any("longer than usual" in w for w in two.warnings)
    assert any("two-step assumes no exposure delay" in w for w in two.warnings)


def test_events_seconds_off_are_named_as_a_time_shift(sim):
    """Events 2.5 s early (a logger offset; 18 s would be UTC for GPS): the camera centres lie along the track from
    the POS positions, so the error names the shift, not the CRS."""
    c = sim.calibration
    events = replace(c.events, t=c.events.t - 2.5)
    with pytest.raises(InputError, match=r"shifted by about [+-]2\.\d+ s") as exc:
        calibrate_mounting(c.eop, MapGrid(sim.crs), c.traj, events, "joint")
    assert "another zone" not in str(exc.value)


def test_eops_in_the_wrong_utm_zone_are_refused(sim):
    c = sim.calibration
    zone = int(sim.crs.split(":")[1])
    with pytest.raises(InputError, match="another zone") as exc:
        calibrate_mounting(c.eop, MapGrid(f"EPSG:{zone + 1}"), c.traj, c.events, "two-step")
    assert exc.value.field == "crs"
