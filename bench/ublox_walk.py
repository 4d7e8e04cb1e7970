"""A real low-cost receiver through dgcal's TC: a u-blox walk with a MEMS IMU, against its RTK reference (issue 12).

    .venv/bin/python bench/ublox_walk.py DIR

DIR is `data/walk_0827` of rtklibexplorer/GNSS_IMU (BSD-3-Clause; not in ../shared/data: bring it with the
workplace's fetch tool): a handheld u-blox receiver and IMU carried in tight turns in a backyard, 2 min 14 s,
`gnss_1730.ubx` (raw UBX), `imu_1730.csv` + `.tag` (the logger of ../shared/data/gnss-imu-drive) and
`gnss_1730_sf.pos` (RTKLIB RTK against a base, 4 Hz, mostly fixed). The UBX log is converted to RINEX 3.04 with
RTKLIB's convbin engine (pyrtklib `convrnx`); its navigation file holds only the ephemerides the receiver decoded in
those two minutes (4 GPS satellites, no ionosphere coefficients); dgcal also reads the log itself (its own UBX reader
decodes more of the subframes: 9 satellites), printed beside. The reference's heights sit ~17-19 m above every GNSS
solution's ellipsoidal height (geoid heights, it seems) and ~8 m away horizontally from all of them (its RTK base
position, it seems): the solutions' variations are compared after the mean offset, which is printed.

Printed: SPP (dgcal beside RTKLIB), TC with and without the satellites' code-bias states, and the forward pass,
each as NED error RMS against the RTK positions and error/sigma RMS per axis.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dgcal.fields.crs import ecef_to_geodetic  # noqa: E402
from dgcal.fields.frames import R_ecef_to_ned  # noqa: E402
from dgcal.fields.io.formats import read_trajectory  # noqa: E402
from dgcal.pos.gnss.solution_files import read_rtklib_pos  # noqa: E402

IMU_FORMAT = ROOT / "docs" / "examples" / "gnss_imu_drive_imu.toml"
IMU_GRADE = ROOT / "docs" / "examples" / "gnss_imu_drive_grade.toml"
# walk_config.py of GNSS_IMU: imu_misalign [180, 0, -90] (no further mounting), IMU 5 cm right of the antenna
IMU_AXES = ("axes.euler_zyx_deg=[180,0,-90]", "axes.mounting_deg=[0,0,0]")
LEVER_ARM = (0.0, -0.05, 0.0)


def ubx_to_rinex(ubx: Path, out: Path) -> tuple[Path, Path]:
    """RINEX 3.04 observation and navigation files of a UBX log, by RTKLIB's convbin engine (pyrtklib)."""
    import pyrtklib as rk
    opt = rk.rnxopt_t()
    opt.rnxver = 304
    opt.navsys = rk.SYS_GPS | rk.SYS_GAL | rk.SYS_QZS | rk.SYS_CMP | rk.SYS_GLO
    opt.obstype = rk.OBSTYPE_PR | rk.OBSTYPE_CP | rk.OBSTYPE_DOP | rk.OBSTYPE_SNR
    opt.freqtype = 0xFF
    obs, nav = out / "walk.obs", out / "walk.nav"
    if rk.convrnx(rk.STRFMT_UBX, opt, str(ubx), [str(obs), str(nav)] + [""] * 7) != 1:
        raise SystemExit(f"convrnx failed on {ubx}")
    return obs, nav


def errors(t: np.ndarray, p_ecef: np.ndarray, sigma_ned: np.ndarray, ref) -> str:
    """NED error RMS against the reference (interpolated to t) and error/sigma RMS per axis."""
    fixed = ref.quality <= 2
    tr, pr = ref.t[fixed], ref.p_ecef[fixed]
    ok = (t >= tr[0]) & (t <= tr[-1])
    i = np.clip(np.searchsorted(tr, t[ok]), 1, len(tr) - 1)
    w = ((t[ok] - tr[i - 1]) / (tr[i] - tr[i - 1]))[:, None]
    p_ref = pr[i - 1] * (1 - w) + pr[i] * w
    lat, lon, _ = ecef_to_geodetic(pr[0])
    d = (p_ecef[ok] - p_ref) @ R_ecef_to_ned(lat, lon).T
    # the reference is offset from every GNSS solution by a constant (N, E, D) ~ (+5, +6, +18) m: its heights are
    # geoid heights (Boulder, CO: N ~ -17 m; its header does not say) and its RTK base position is not the one the
    # receivers' own positions give (RTKLIB's SPP on 4 satellites and dgcal's on 9 both sit 8 m off, scatter < 1 m):
    # the solutions are compared with it after the mean offset, which is printed
    d_off = d.mean(axis=0)
    d = d - d_off
    z = d / sigma_ned[ok]
    rms = np.sqrt(np.mean(d ** 2, 0)).round(2)
    return (f"NED error RMS {rms} m (3D {np.sqrt(np.mean(np.sum(d ** 2, 1))):.2f}, after the mean offset "
            f"{d_off.round(1)} m), median sigma {np.median(sigma_ned[ok], 0).round(2)} m, error/sigma RMS "
            f"{np.sqrt(np.mean(z ** 2, 0)).round(2)}")


def trajectory_ecef(path: Path):
    """Times (GPS s), antenna-free IMU positions (ECEF m) and NED sigmas of a dgcal trajectory CSV."""
    from dgcal.fields.crs import geodetic_to_ecef
    tr = read_trajectory(path)
    return tr.t, geodetic_to_ecef(tr.lat, tr.lon, tr.h), tr.sigma[:, :3]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dir", type=Path, help="GNSS_IMU data/walk_0827")
    a = ap.parse_args()
    from dgcal.pos.gnss.rtklib import rtklib_spp
    from dgcal.pos.gnss.spp import SppOptions, spp_files
    from dgcal.pos.mode_options import ImuInput, InsModeOptions, RinexInput
    from dgcal.pos.pipeline import run_pos
    from dgcal.commands.pos import INS_OUTPUTS
    from dgcal.reports.pos import write_pos_outputs
    ref = read_rtklib_pos(a.dir / "gnss_1730_sf.pos")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        obs, nav = ubx_to_rinex(a.dir / "gnss_1730.ubx", tmp)
        ubx = a.dir / "gnss_1730.ubx"
        for label, o, n in (("RTKLIB's RINEX", obs, nav), ("the UBX log itself", ubx, ubx)):
            s = spp_files(o, [n], SppOptions()).solution
            lat, lon, _ = ecef_to_geodetic(s.p_ecef[s.ok][0])
            R = R_ecef_to_ned(lat, lon)
            sig_ned = np.sqrt(np.einsum("ij,kjl,il->ki", R, s.cov_p, R))
            print(f"SPP dgcal on {label} ({int(s.ok.sum())} epochs, {np.median(s.n_sat[s.ok]):.0f} satellites): "
                  + errors(s.t_gps[s.ok], s.p_ecef[s.ok], sig_ned[s.ok], ref))
        r = rtklib_spp(str(obs), str(nav))
        print(f"SPP RTKLIB ({len(r['t_gps'])} epochs): "
              + errors(r["t_gps"], r["p_ecef"], np.ones((len(r["t_gps"]), 3)), ref).split(", median")[0])
        runs = (("TC with code-bias states", True, obs, nav), ("TC, code errors as white noise", False, obs, nav),
                ("TC with code-bias states on the UBX log itself", True, ubx, ubx))
        for label, code_bias, o, n in runs:
            out = tmp / label.split(",")[0].replace(" ", "_")
            opts = InsModeOptions(mode="tc", rover=RinexInput(o, (n,)),
                                  imu=ImuInput(a.dir / "imu_1730.csv", str(IMU_FORMAT), tuple(IMU_AXES)),
                                  imu_grade=str(IMU_GRADE), lever_arm_m=LEVER_ARM, progress=False)
            opts.smoother.code_bias = code_bias
            res = run_pos(opts)
            write_pos_outputs(out, res, INS_OUTPUTS)
            print(f"{label}: " + errors(*trajectory_ecef(out / "trajectory.csv"), ref))
            if (out / "trajectory_forward.csv").exists():
                print("  its forward pass: " + errors(*trajectory_ecef(out / "trajectory_forward.csv"), ref))
            nis = res.summary.get("normalised_innovations", {})
            print("  normalised innovations per dimension: "
                  + ", ".join(f"{k} {v['nis_per_dim']:.2f}" for k, v in nis.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
