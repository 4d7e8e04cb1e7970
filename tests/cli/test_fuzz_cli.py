"""Fuzzing every `dgcal` verb through its input files (issue 16): `dgcal.cli.main([...])` on a small valid data
set of each verb with one input file mutated (truncated, random bytes, invalid UTF-8, NaN / inf / 1e308 numbers,
missing columns, unclosed quotes; tests/fields/test_fuzz_readers.py's mutations). Every run exits 0 (or 1 where the
verb says so) or 2 with one `dgcal VERB: error: ...` line naming a file; never a traceback, never the
internal-error exit 3, never a native abort.

The default run tries `DEFAULT_CASES` mutations per verb; `pytest -m fuzz` runs `LONG_CASES` each.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from test_fuzz_readers import BOARD, OPS, mutate
from test_gnss_rinex2 import NAV_304, OBS_304

DEFAULT_CASES = 12
LONG_CASES = int(os.environ.get("DGCAL_FUZZ_CASES", 2000))   # `pytest -m fuzz` (DGCAL_FUZZ_CASES=N to change)
CRS = "EPSG:32651"


# ---------------------------------------------------------------------------------------------
# one small valid data set for every verb
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    from dgcal.calib.mounting.common import MountingResult
    from dgcal.fields.io.formats import Measurements, write_measurements
    from dgcal.fields.targets.plate import TargetField, write_field
    from dgcal.sim.camera_field import calibration_field_camera, plan_shots
    from dgcal.sim.logger import simulate_logger, write_logger_sim
    from dgcal.sim.mounting import simulate_mounting, write_mounting_sim
    from test_camera_ba_simulated import simulate_measurements
    from test_formats_fuzz import GNSS_CSV
    from test_fuzz_readers import GNSS_VELOCITY, s_imu_csv

    d = tmp_path_factory.mktemp("fuzz_cli_data")
    small = dict(n_strips=2, length_m=400, rate_hz=5, photo_interval_s=3)
    sim = simulate_mounting(5, n_ground=16, calibration=small, mapping=small)
    write_mounting_sim(sim, d / "ms")
    cov = np.diag([1e-6, 4e-4, 4e-4, 9e-4, 1e-8, 1e-8, 4e-8])
    m = MountingResult("joint", np.asarray(sim.lever_arm_m, float), np.asarray(sim.R_cam_to_body, float),
                       float(sim.delay_s), cov, 20)
    (d / "mounting.json").write_text(json.dumps(m.to_json(), indent=2))
    # camera calibration: 8 photos of the rotating plate, measurements only
    rng = np.random.default_rng(5)
    tf = TargetField(square_m=0.16, marker_m=0.12)
    pts = write_field(d / "field.csv", tf)
    size = (1200, 800)
    truth = calibration_field_camera(size)
    img, idx, xy = simulate_measurements(truth, pts.xyz, plan_shots(8, truth, tf, rng), 0.1, rng)
    write_measurements(d / "field_measurements.csv", Measurements(img, pts.ids[idx], xy, np.full_like(xy, 0.1)))
    (d / "campaign.toml").write_text(
        f'crs = "{CRS}"\n[camera]\nfield = "field.csv"\nmeasurements = "field_measurements.csv"\n'
        f'image_size = [{size[0]}, {size[1]}]\nmodel = "fraser7"\nargs = ["--no-report"]\n')
    # GNSS: a RINEX 3 observation and navigation file; LC inputs of the pos verb
    (d / "obs.rnx").write_text(OBS_304)
    (d / "nav.rnx").write_text(NAV_304)
    (d / "imu.csv").write_bytes(s_imu_csv(d))
    (d / "gnss.csv").write_text(GNSS_CSV)
    (d / "pos_events.csv").write_text("image,gps_week,gps_sow\nIMG_1.JPG,2150,302000.2\nIMG_2.JPG,2150,302000.3\n")
    # time synchronisation: two minutes of a simulated low-cost logger
    write_logger_sim(d / "logger", simulate_logger(0, duration_s=120.0))
    (d / "board.toml").write_bytes(BOARD)
    (d / "velocity.csv").write_bytes(GNSS_VELOCITY)
    return {"eop": d / "ms/calibration/eop.csv", "trajectory": d / "ms/calibration/trajectory.csv",
            "events": d / "ms/calibration/events.csv", "cal_measurements": d / "ms/calibration/measurements.csv",
            "map_eop": d / "ms/mapping/eop.csv", "map_trajectory": d / "ms/mapping/trajectory.csv",
            "map_events": d / "ms/mapping/events.csv", "map_measurements": d / "ms/mapping/measurements.csv",
            "gcp": d / "ms/ground.csv", "camera": d / "ms/camera.json", "mounting": d / "mounting.json",
            "mounting2": d / "mounting.json", "field": d / "field.csv",
            "field_measurements": d / "field_measurements.csv",
            "campaign": d / "campaign.toml", "obs": d / "obs.rnx", "nav": d / "nav.rnx", "imu": d / "imu.csv",
            "gnss": d / "gnss.csv", "pos_events": d / "pos_events.csv", "gnss_log": d / "logger/gnss_log.csv",
            "logger": d / "logger/logger.csv", "images_csv": d / "logger/images.csv", "board": d / "board.toml"}


# verb -> (argv with {role} for input files and {out} for the output folder, the roles that get mutated)
VERBS = {
    "mount": ("mount --eop {eop} --crs " + CRS + " --trajectory {trajectory} --events {events} --out {out}",
              ("eop", "trajectory", "events")),
    "mount-iso": ("mount --method iso --eop {eop} --crs " + CRS + " --trajectory {trajectory} --events {events} "
                  "--measurements {cal_measurements} --gcp {gcp} --camera {camera} --out {out}",
                  ("cal_measurements", "gcp", "camera")),
    "check": ("check --mounting {mounting} --trajectory {map_trajectory} --events {map_events} --measurements "
              "{map_measurements} --gcp {gcp} --camera {camera} --crs " + CRS + " --out {out}",
              ("mounting", "map_trajectory", "map_events", "map_measurements", "gcp", "camera")),
    "export": ("export --mounting {mounting} --trajectory {map_trajectory} --events {map_events} --crs " + CRS
               + " --camera {camera} --out {out}", ("mounting", "map_trajectory", "map_events", "camera")),
    "export-calibration": ("export --calibration --mounting {mounting} --out {out}", ("mounting",)),
    "compare": ("compare {mounting} {mounting2} --out {out}/compare.json", ("mounting", "mounting2")),
    "georef": ("georef --camera {camera} --measurements {map_measurements} --crs " + CRS + " --eop {map_eop} "
               "--height 20 --out {out}", ("camera", "map_measurements", "map_eop")),
    "triangulate": ("triangulate --camera {camera} --gcp {gcp} --measurements {map_measurements} --crs " + CRS
                    + " --approx {map_eop} --no-mapper --formats eop --no-progress --out {out}",
                    ("camera", "gcp", "map_measurements", "map_eop")),
    "camera": ("camera --field {field} --measurements {field_measurements} --image-size 1200 800 --no-report "
               "--out {out}", ("field", "field_measurements")),
    "pos-spp": ("pos --mode spp --rinex-obs {obs} --rinex-nav {nav} --no-progress --out {out}", ("obs",)),
    "pos-spp-nav": ("pos --mode spp --rinex-obs {obs} --rinex-nav {nav} --no-progress --out {out}", ("nav",)),
    "pos-lc": ("pos --mode lc --imu {imu} --gnss {gnss} --events {pos_events} --imu-grade adis16488 --no-progress "
               "--out {out}", ("pos_events",)),
    "pos-lc-imu-gnss": ("pos --mode lc --imu {imu} --gnss {gnss} --events {pos_events} --imu-grade adis16488 "
                        "--no-progress --out {out}", ("imu", "gnss")),
    "sync": ("sync --gnss-log {gnss_log} --logger {logger} --images {images_csv} --end-gap 0.3 "
             "--max-time-error 0.02 --out {out}",
             ("gnss_log", "logger", "images_csv")),
    "run": ("run {campaign} --out {out}", ("campaign",)),
    "field": ("field --board {board} --no-png --out {out}", ("board",)),
}
# verbs whose valid data set takes more than a fraction of a second: fewer cases in the default run
SLOW = {"camera": 6, "run": 6, "mount-iso": 6, "pos-lc": 6, "pos-lc-imu-gnss": 6, "sync": 6}
def _argv(template: str, files: dict[str, Path], out: Path) -> list[str]:
    return [t.format(out=out, **{k: str(v) for k, v in files.items()}) for t in template.split()]


@contextlib.contextmanager
def _result_errors():
    """The messages of every ResultError raised meanwhile: an untrusted result (sigma0, a failed check) is about
    the data as a whole and need not name one file."""
    from dgcal.fields.errors import InputError, ResultError
    seen: list[str] = []
    had = ResultError.__dict__.get("__init__")

    def init(self, *a, **kw):
        InputError.__init__(self, *a, **kw)
        seen.append(str(self))
    ResultError.__init__ = init
    try:
        yield seen
    finally:
        if had is None:
            del ResultError.__init__
        else:
            ResultError.__init__ = had


def run_cli(argv: list[str]) -> tuple[int, str, list[str]]:
    """`dgcal.cli.main(argv)` with its output captured: (exit status, stderr, ResultError messages)."""
    from dgcal.cli import main
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err), _result_errors() as results:
        rc = main(argv)
    return rc, err.getvalue(), results


def check_run(verb: str, argv: list[str], names: list[str]) -> None:
    """One run: exit 0/1, or 2 with one error line naming a file (a ResultError: the data as a whole); never
    exit 3, never a traceback."""
    rc, err, results = run_cli(argv)
    word = argv[0]
    assert "Traceback" not in err, err
    assert rc in (0, 1, 2), f"exit {rc}: {err.strip()[-500:]}"
    assert rc != 1 or verb == "compare", err
    if rc == 2:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        errors = [ln for ln in lines if ln.startswith(f"dgcal {word}: error: ")]
        assert len(errors) == 1 and lines[-1] == errors[0], err
        msg = errors[0].split(": error: ", 1)[1]
        assert msg in results or any(n in msg for n in names), f"no file named: {errors[0]}"


def _fuzz(verb: str, data: dict[str, Path], tmp_path_factory, n: int) -> None:
    template, roles = VERBS[verb]
    root = tmp_path_factory.mktemp(f"fuzz_{verb}")
    samples = {r: data[r].read_bytes() for r in roles}
    counter = iter(range(10 ** 9))

    @settings(max_examples=n, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(st.sampled_from(roles), OPS)
    def run(role, ops):
        case = root / f"case{next(counter)}"
        case.mkdir()
        files = dict(data)
        p = case / data[role].name
        p.write_bytes(mutate(samples[role], ops))
        files[role] = p
        if verb == "run":                                 # the campaign's paths are relative to it
            for f in ("field.csv", "field.json", "field_measurements.csv"):
                shutil.copy(data["campaign"].parent / f, case / f)
        argv = _argv(template, files, case / "out")
        names = [str(v) for v in files.values()] + [Path(v).name for v in files.values()] + [str(case)]
        try:
            check_run(verb, argv, names)
        finally:
            shutil.rmtree(case, ignore_errors=True)
    run()


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_valid_inputs_run(verb, data, tmp_path):
    """The unmutated data set of each verb runs (exit 0, or 2 with one error line where the tiny data set cannot
    give a result, e.g. SPP on two epochs)."""
    template, _ = VERBS[verb]
    argv = _argv(template, data, tmp_path / "out")
    check_run(verb, argv, [str(v) for v in data.values()] + [str(tmp_path)])


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_verb_fuzz(verb, data, tmp_path_factory):
    _fuzz(verb, data, tmp_path_factory, SLOW.get(verb, DEFAULT_CASES))


@pytest.mark.fuzz
@pytest.mark.parametrize("verb", sorted(VERBS))
def test_verb_fuzz_long(verb, data, tmp_path_factory):
    _fuzz(verb, data, tmp_path_factory, LONG_CASES)
