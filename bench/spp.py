"""SPP on the real SEPT RINEX data: dgcal beside RTKLIB (pyrtklib) on the same files, time and accuracy.

Run: .venv/bin/python bench/spp.py [OBS NAV] [--repeats 5] [--as-is]

1. Per call, each in a fresh process (median of `--repeats` alternating runs, after one unmeasured run of each):
   `dgcal pos --mode spp --no-report`, the same with the HTML report, and RTKLIB's SPP as rnx2rtkp runs it. There is
   no rnx2rtkp executable here, so RTKLIB's peer is a Python process that imports pyrtklib (nothing else) and runs
   postpos, rnx2rtkp's engine, in single mode with dgcal's settings, writing its .pos file: process start included
   on both sides. postpos's own time is shown too (what a compiled rnx2rtkp spends after its start-up). Every
   process runs with its bytecode (Python's, numpy's, dgcal's) compiled into a private cache folder by the
   unmeasured runs, as an installed dgcal or `make bytecode` leaves it (this checkout sets PYTHONDONTWRITEBYTECODE:
   without bytecode a dgcal process compiles every module it imports); `--as-is` runs in the environment as it is.
2. In one process: dgcal's `spp_files` (read both files, position every epoch, summary) beside RTKLIB's postpos.
3. Accuracy of both against the known antenna position (3D RMS, mean and spread in E/N/U), and their difference.
4. dgcal's SPP on 600 simulated epochs (speed, error and sigma honesty).
5. Honest sigmas on real receivers (issue 27), dgcal beside RTKLIB's pntpos (its covariance): per file the epochs,
   3D RMS, error/sigma RMS and max per E/N/U axis, median sigmas, dgcal's code noise told by the residuals; pooled
   over the files. The static Septentrio and Trimble files of ../shared/data against their known positions and,
   when cssrlib-data's doy2021-265 drive is there (../shared/data/rinex-kinematic or DGCAL_KINEMATIC_DATA), the
   car's rover against dgcal's own PPK fixes and its static base. `--honesty-only` runs this part alone.
6. Precise orbits (issue 30): SPP with CODE's final SP3 of the day beside broadcast orbits, dgcal beside RTKLIB's
   pntpos with the same products. `--precise` runs this part alone.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT.parent / "shared" / "data" / "rinex-sept"
REF_ECEF = np.array([-3962108.673, 3381309.574, 3668678.638])
DGCAL = Path(sys.executable).with_name("dgcal")

# RTKLIB's SPP as rnx2rtkp runs it, in a process that imports pyrtklib and nothing else (no numpy, no dgcal):
# postpos in single mode with the settings of dgcal.pos.gnss.rtklib.rtklib_spp (GPS+Galileo+QZSS, 10 deg mask,
# Klobuchar, Saastamoinen, broadcast orbits), its .pos file written; prints postpos's own time and the epochs
_RTKLIB_PROCESS = """import math, sys, time
import pyrtklib as rk
obs, nav, out = sys.argv[1:4]
popt, sopt = rk.prcopt_default, rk.solopt_default
popt.mode, popt.soltype, popt.nf = rk.PMODE_SINGLE, 0, 1
popt.navsys = rk.SYS_GPS + rk.SYS_GAL + rk.SYS_QZS
popt.elmin = math.radians(10.0)
popt.ionoopt, popt.tropopt, popt.sateph, popt.refpos = rk.IONOOPT_BRDC, rk.TROPOPT_SAAS, rk.EPHOPT_BRDC, 0
sopt.posf = rk.SOLF_XYZ
buf = rk.Arr1Dchar(len(out) + 1)
for i, c in enumerate(out):
    buf[i] = c
buf[len(out)] = "\\0"
t0 = time.perf_counter()
rk.postpos(rk.gtime_t(), rk.gtime_t(), 0.0, 0.0, popt, sopt, rk.filopt_t(), [obs, nav], 2, buf, "", "")
run_s = time.perf_counter() - t0
with open(out) as fh:
    n = sum(1 for line in fh if line.strip() and not line.startswith("%"))
print(run_s, n)
"""


def enu_errors(p_ecef: np.ndarray) -> np.ndarray:
    from dgcal.fields.crs import R_ecef_to_enu_at
    return (p_ecef - REF_ECEF) @ R_ecef_to_enu_at(REF_ECEF).T


def summary(name: str, p: np.ndarray) -> str:
    e = enu_errors(p)
    rms3 = np.sqrt(np.mean(np.sum(e ** 2, axis=1)))
    return (f"{name:8s} epochs {len(p):4d}  3D RMS {rms3:6.3f} m  mean E/N/U "
            f"{e[:, 0].mean():+6.3f} {e[:, 1].mean():+6.3f} {e[:, 2].mean():+6.3f} m  "
            f"std E/N/U {e[:, 0].std():5.3f} {e[:, 1].std():5.3f} {e[:, 2].std():5.3f} m")


def _wall(cmd: list[str], env: dict) -> tuple[float, str]:
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
    return time.perf_counter() - t0, out.stdout


def per_call(obs_path: str, nav_path: str, repeats: int, as_is: bool = False) -> None:
    """Wall time of one call in a fresh process: dgcal's command (without and with the report) beside RTKLIB's SPP
    process (pyrtklib's postpos, as rnx2rtkp), alternating, after one unmeasured run of each."""
    try:
        import pyrtklib  # noqa: F401
        have_rtklib = True
    except ImportError:
        have_rtklib = False
    rows = {"dgcal --no-report": [], "dgcal (with report)": [], "RTKLIB process": [], "RTKLIB postpos": []}
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ)
        if not as_is:   # bytecode of every module, written by the unmeasured runs into a cache folder of ours
            env.pop("PYTHONDONTWRITEBYTECODE", None)
            env["PYTHONPYCACHEPREFIX"] = f"{d}/pycache"
        base = [str(DGCAL), "pos", "--mode", "spp", "--rinex-obs", obs_path, "--rinex-nav", nav_path,
                "--no-progress"]
        n_rtklib = None
        for k in range(repeats + 1):
            runs = {"dgcal --no-report": base + ["--out", f"{d}/a{k}", "--no-report"],
                    "dgcal (with report)": base + ["--out", f"{d}/b{k}"]}
            if have_rtklib:
                runs["RTKLIB process"] = [sys.executable, "-c", _RTKLIB_PROCESS, obs_path, nav_path, f"{d}/r{k}.pos"]
            for name, cmd in runs.items():
                dt, out = _wall(cmd, env)
                if k == 0:
                    continue               # writes the bytecode; not measured
                rows[name].append(dt)
                if name == "RTKLIB process":
                    run_s, n_rtklib = out.split()
                    rows["RTKLIB postpos"].append(float(run_s))
    med = {k: float(np.median(v)) for k, v in rows.items() if v}
    load = " ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"1. one call, fresh process ({len(obs_epochs(obs_path))} epochs; median of {repeats} alternating runs; "
          f"{'environment as it is' if as_is else 'with bytecode'}; load average {load})")
    peer = med.get("RTKLIB process")
    for k, v in med.items():
        ratio = f"  {v / peer:5.1f}x RTKLIB's process" if peer and k.startswith("dgcal") else ""
        print(f"   {k:22s} {v:6.3f} s{ratio}")
    if not have_rtklib:
        print("   (pyrtklib not installed: .venv/bin/pip install pyrtklib==0.2.7)")
        return
    exe = shutil.which("rnx2rtkp")
    print(f"   ({'no rnx2rtkp executable here' if exe is None else f'{exe} not used'}: RTKLIB's process is python + "
          f"pyrtklib + postpos in single mode writing its .pos, {n_rtklib} epochs; postpos: the engine's own time, "
          "reading included, i.e. what a compiled rnx2rtkp spends after its start-up)")


def obs_epochs(obs_path: str) -> list:
    from dgcal.pos.gnss.rinex import read_rinex_obs
    return read_rinex_obs(obs_path).epochs


def in_process(obs_path: str, nav_path: str, repeats: int):
    """dgcal's spp_files beside RTKLIB's postpos in this process (median of alternating runs); the last results."""
    from dgcal.pos.gnss.spp import SppOptions, spp_files
    try:
        from dgcal.pos.gnss.rtklib import rtklib_spp
        import pyrtklib  # noqa: F401
    except ImportError:
        rtklib_spp = None
    t_d, t_r, run, rk = [], [], None, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        run = spp_files(obs_path, [nav_path], SppOptions())
        t_d.append(time.perf_counter() - t0)
        if rtklib_spp is not None:
            rk = rtklib_spp(obs_path, nav_path)
            t_r.append(rk["run_s"])
    n = len(run.solution.t_gps)
    print(f"2. in one process (median of {repeats} alternating runs)")
    line = f"   dgcal spp_files {np.median(t_d):.3f} s ({1e3 * np.median(t_d) / n:.2f} ms/epoch)"
    if t_r:
        line += (f"; RTKLIB postpos {np.median(t_r):.3f} s ({1e3 * np.median(t_r) / n:.2f} ms/epoch); "
                 f"ratio {np.median(t_d) / np.median(t_r):.1f}x")
    print(line)
    return run, rk


def accuracy(run, rk) -> None:
    sol = run.solution
    print("3. accuracy against the known antenna position")
    print("   " + summary("dgcal", sol.p_ecef[sol.ok]))
    sig = np.sqrt(np.mean(np.diagonal(sol.cov_p, axis1=1, axis2=2)[sol.ok], axis=0))
    print(f"   dgcal    mean sigma X/Y/Z {sig[0]:.2f} {sig[1]:.2f} {sig[2]:.2f} m; mean n_sat "
          f"{sol.n_sat[sol.ok].mean():.1f}, PDOP {np.nanmean(sol.dop['pdop']):.2f}; "
          f"speed RMS {np.sqrt(np.nanmean(np.sum(sol.v_ecef ** 2, axis=1))):.3f} m/s")
    if rk is None:
        return
    print("   " + summary("RTKLIB", rk["p_ecef"]))
    common, ia, ib = np.intersect1d(np.round(sol.t_gps, 3), np.round(rk["t_gps"], 3), return_indices=True)
    d = sol.p_ecef[ia] - rk["p_ecef"][ib]
    rms = np.sqrt(np.mean(np.sum(d ** 2, axis=1)))
    print(f"   dgcal - RTKLIB over {len(common)} common epochs: RMS 3D {rms:.3f} m")


def simulated(nav_path: str) -> None:
    """A 10-minute circle at 1 Hz simulated from the same broadcast orbits."""
    from dgcal.pos.gnss.rinex import read_rinex_nav
    from dgcal.pos.gnss.spp import SppOptions, spp
    from dgcal.sim.gnss import DEFAULT_T0_GPS, circle_trajectory, simulate_gnss
    nav = read_rinex_nav(nav_path)
    t = DEFAULT_T0_GPS + np.arange(0.0, 600.0)
    p, v = circle_trajectory(t, 35.3, 139.5, 100.0, 200.0, 15.0)
    t5 = time.perf_counter()
    sim = simulate_gnss(t, p, v, nav, seed=3, systems=("G", "E", "J"), prepare=False)
    t6 = time.perf_counter()
    s2 = spp(sim, nav, SppOptions(code_sigma_zenith_m=0.5, doppler_sigma_zenith_mps=0.05, model_errors=False))
    t7 = time.perf_counter()
    err = s2.p_ecef - p
    sig = np.sqrt(np.diagonal(s2.cov_p, axis1=1, axis2=2))
    print(f"4. simulated 600 epochs in {t6 - t5:.2f} s; SPP {t7 - t6:.2f} s ({1e3 * (t7 - t6) / 600:.2f} ms/epoch); "
          f"error RMS X/Y/Z {np.sqrt(np.mean(err ** 2, axis=0)).round(3)} m; normalised RMS "
          f"{np.sqrt(np.mean((err / sig) ** 2, axis=0)).round(2)}")


BASE_3034_ECEF = np.array([-3959400.631, 3385704.533, 3667523.111])   # GSI 3034, as cssrlib's RTK examples
KINEMATIC_FILES = ("SEPT265G.21O", "SEPT2650.21P", "3034265G.21O")


def _honesty_row(name: str, t, p, cov, ref_t, ref_p, extra: str = "") -> np.ndarray:
    """Print one file's honesty line (epochs with a reference within 0.5 s: RTKLIB stamps its fixes at the
    clock-corrected time); its error/sigma RMS per E/N/U axis."""
    from dgcal.fields.crs import R_ecef_to_enu_at
    k = np.clip(np.searchsorted(ref_t, t - 0.5), 0, len(ref_t) - 1)
    have = np.abs(ref_t[k] - t) < 0.5
    r = ref_p[k[have]]
    R = R_ecef_to_enu_at(r)
    e = np.einsum("nij,nj->ni", R, p[have] - r)
    s = np.sqrt(np.diagonal(R @ cov[have] @ np.swapaxes(R, 1, 2), axis1=1, axis2=2))
    z = e / s
    zr = np.sqrt(np.mean(z ** 2, axis=0))
    print(f"   {name:45s} {int(have.sum()):4d} {np.sqrt(np.mean(np.sum(e ** 2, axis=1))):6.2f} m  "
          f"{zr[0]:5.2f} {zr[1]:5.2f} {zr[2]:5.2f}  {np.abs(z).max():4.1f}  "
          f"{' '.join(f'{x:4.2f}' for x in np.median(s, axis=0))} m{extra}")
    return zr


def honesty(shared: Path) -> None:
    """Error/sigma of dgcal's SPP and RTKLIB's pntpos on the real receivers with a known answer (section 5)."""
    from dgcal.pos.gnss.rinex import read_rinex_nav, read_rinex_obs
    from dgcal.pos.gnss.spp import SppOptions, spp
    from dgcal.pos.gnss.rtklib import rtklib_pntpos_cov
    try:
        import pyrtklib  # noqa: F401
        have_rtklib = True
    except ImportError:
        have_rtklib = False
    nav78 = str(shared / "rinex-sept" / "SEPT078M.21P")
    files = [("Septentrio static (rinex-sept)", str(shared / "rinex-sept" / "SEPT078M1.21O"), nav78, REF_ECEF),
             ("Trimble NetR9 static (rinex-3034)", str(shared / "rinex-3034" / "3034078M1.21O"), nav78,
              BASE_3034_ECEF)]
    d = Path(os.environ.get("DGCAL_KINEMATIC_DATA") or shared / "rinex-kinematic")
    rover, nav265, base = (str(d / f) for f in KINEMATIC_FILES)
    if all(Path(f).is_file() for f in (rover, nav265, base)):
        from dgcal.cli import main as dgcal_main
        with tempfile.TemporaryDirectory() as out:
            assert dgcal_main(["pos", "--mode", "ppk", "--rinex-obs", rover, "--rinex-nav", nav265, "--rinex-base",
                               base, "--base-position", *map(str, BASE_3034_ECEF), "--out", out, "--no-report",
                               "--no-progress"]) == 0
            tab = np.genfromtxt(Path(out) / "gnss.csv", delimiter=",", names=True, dtype=None, encoding=None)
        fixed = tab["fix"] == "fixed"
        ppk = ((tab["gps_week"] * 604800.0 + tab["gps_sow"])[fixed],
               np.column_stack([tab["x"], tab["y"], tab["z"]])[fixed])
        print(flush=True)
        files += [("mosaic-X5 in a car (vs its PPK fixes)", rover, nav265, ppk),
                  ("Trimble NetR9 static (the car's base)", base, nav265, BASE_3034_ECEF)]
    else:
        print(f"   (the doy2021-265 drive is not in {d}: static receivers only)")
    print("5. honest sigmas: epochs, 3D RMS, error/sigma RMS E N U, max |error/sigma|, median sigma E N U")
    pooled = {"dgcal": [], "RTKLIB": []}
    def reference(ref, t):
        """The reference epochs and positions: a PPK track (t, p) as it is, a static position at the times t."""
        return ref if isinstance(ref, tuple) else (t, np.tile(ref, (len(t), 1)))

    for name, obs_path, nav_path, ref in files:
        sol = spp(read_rinex_obs(obs_path), read_rinex_nav(nav_path), SppOptions())
        ok = sol.ok
        t = sol.t_gps[ok]
        pooled["dgcal"].append(_honesty_row(f"dgcal  {name}", t, sol.p_ecef[ok], sol.cov_p[ok], *reference(ref, t),
                                            f"; code noise {sol.code_noise['code_sigma_zenith_m']:.2f} m"))
        if have_rtklib:
            tr, pr, cr = rtklib_pntpos_cov(obs_path, nav_path)
            pooled["RTKLIB"].append(_honesty_row(f"RTKLIB {name}", tr, pr, cr, *reference(ref, tr)))
    for k, v in pooled.items():
        if v:
            z = np.array(v)
            zr = np.sqrt(np.mean(z ** 2, axis=0))
            print(f"   {k:6s} pooled error/sigma RMS E N U {zr[0]:.2f} {zr[1]:.2f} {zr[2]:.2f}, all axes "
                  f"{np.sqrt(np.mean(z ** 2)):.2f} ({len(v)} files; a static file is one draw of the hour's "
                  f"broadcast errors)")


PRECISE_SP3 = ROOT / "tests" / "pos" / "gnss" / "data" / "COD0MGXFIN_20210781100_02H_05M_ORB.SP3.gz"


def precise(obs_path: str, nav_path: str, repeats: int) -> None:
    """Section 6: SPP with CODE's final MGEX SP3 of the day (orbits and its 5-minute clocks) beside broadcast orbits,
    dgcal's `spp_files` beside RTKLIB's pntpos with the same products: 3D RMS against the known position, the
    engines' largest and mean distance, dgcal's time (median of `repeats`). RTKLIB 2.4.3 reads at most 85 satellites
    of an SP3 file: it gets the file's GPS/Galileo/QZSS records (the same values, dgcal's SP3 writer)."""
    from dgcal.pos.gnss.precise import read_sp3, write_sp3
    from dgcal.pos.gnss.rtklib import rtklib_pntpos
    from dgcal.pos.gnss.spp import SppOptions, spp_files
    d = read_sp3(PRECISE_SP3)
    keep = [j for j, s in enumerate(d.sats) if s[0] in "GEJ"]
    opts = SppOptions(systems=("G", "E", "J"))
    print("\n6. precise orbits (CODE final MGEX SP3, its clocks) beside broadcast, dgcal beside RTKLIB pntpos")
    with tempfile.TemporaryDirectory() as tmp:
        sub = str(Path(tmp) / "gej.sp3")
        write_sp3(sub, d.t, [d.sats[j] for j in keep], d.p[:, keep], d.clk[:, keep])
        for label, ours, theirs in (("broadcast", (), ()), ("CODE SP3", (str(PRECISE_SP3),), (sub,))):
            times = []
            for _ in range(max(repeats, 1)):
                t0 = time.perf_counter()
                run = spp_files(obs_path, (nav_path,) + ours, opts)
                times.append(time.perf_counter() - t0)
            sol = run.solution
            t, p = rtklib_pntpos(obs_path, nav_path, systems="GEJ", sp3=theirs)
            common, ia, ib = np.intersect1d(np.round(sol.t_gps[sol.ok], 3), np.round(t, 3), return_indices=True)
            apart = np.linalg.norm(sol.p_ecef[sol.ok][ia] - p[ib], axis=1)
            rms = np.sqrt(np.mean(np.sum((sol.p_ecef[sol.ok] - REF_ECEF) ** 2, axis=1)))
            rms_rk = np.sqrt(np.mean(np.sum((p - REF_ECEF) ** 2, axis=1)))
            print(f"  {label:10s} dgcal 3D RMS {rms:5.2f} m ({1e3 * np.median(times):5.1f} ms, reading included) | "
                  f"RTKLIB {rms_rk:5.2f} m | apart max {apart.max():5.2f} m, mean {apart.mean():5.2f} m over "
                  f"{len(common)} epochs | orbits: {run.summary['orbits']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", metavar="OBS NAV", help="RINEX observation and navigation files "
                    "(default: ../shared/data/rinex-sept)")
    ap.add_argument("--repeats", type=int, default=5, help="alternating runs of each (median time)")
    ap.add_argument("--as-is", action="store_true", help="per call: run in this environment as it is (without our "
                    "bytecode cache: where PYTHONDONTWRITEBYTECODE is set, dgcal's modules are compiled every call)")
    ap.add_argument("--honesty-only", action="store_true", help="section 5 alone (no timing)")
    ap.add_argument("--precise", action="store_true", help="section 6 alone: precise orbits beside broadcast")
    a = ap.parse_args()
    obs_path, nav_path = a.files if len(a.files) == 2 else (str(DATA / "SEPT078M1.21O"), str(DATA / "SEPT078M.21P"))
    if a.precise:
        precise(obs_path, nav_path, a.repeats)
        return
    if not a.honesty_only:
        per_call(obs_path, nav_path, a.repeats, a.as_is)
        run, rk = in_process(obs_path, nav_path, a.repeats)
        accuracy(run, rk)
        simulated(nav_path)
    honesty(DATA.parent)


if __name__ == "__main__":
    main()
