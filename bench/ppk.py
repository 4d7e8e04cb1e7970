"""PPK beside RTKLIB demo5 (pyrtklib5) on the same files: static real baseline, a real moving rover, simulated rovers.

Run:
    .venv/bin/python bench/ppk.py                       # the static 5.3 km baseline (rinex-sept / rinex-3034)
    .venv/bin/python bench/ppk.py ROVER NAV BASE X Y Z  # any rover + base (ECEF m of the base), e.g. a moving one:
                                                        # two and three frequencies
    .venv/bin/python bench/ppk.py sim uav|car [SEEDS]   # simulated rovers (dgcal.sim.rover_motion), truth known
    .venv/bin/python bench/ppk.py precise               # the static baseline with CODE's SP3 beside RTKLIB 2.4.3
                                                        # (pyrtklib) with the same SP3, and both with broadcast

Prints per engine: epochs, fix rate (combined, forward, backward), time per epoch; against the truth (static
point or simulation): fixed-epoch 3D RMS, wrong fixes (> 10 cm while fixed) and dgcal's error/sigma RMS and maximum;
on a moving rover without truth: the agreement of dgcal's and demo5's fixed epochs (3D RMS, largest, share within
2 cm) and dgcal's error/sigma against demo5's fixed positions. Same settings on both sides: kinematic, broadcast
orbits, Saastamoinen, broadcast ionosphere, 10 deg mask, ratio 3, fix and hold, GPS + Galileo + QZSS.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = ROOT.parent / "shared" / "data"
STATIC = (DATA / "rinex-sept" / "SEPT078M1.21O", DATA / "rinex-sept" / "SEPT078M.21P",
          DATA / "rinex-3034" / "3034078M1.21O", [-3959400.631, 3385704.533, 3667523.111])
STATIC_REF = np.array([-3962108.673, 3381309.574, 3668678.638])


def run_dgcal(rover, nav, base, base_pos, n_freq: int = 3):
    """dgcal's PPK with its defaults; (result, seconds)."""
    from dgcal.pos.gnss.carrier import carrier_observations
    from dgcal.pos.gnss.ppk import PpkOptions, ppk
    from dgcal.pos.gnss.rinex import read_rinex_nav
    from dgcal.pos.gnss.rinex_obs import read_obs_file
    nv = read_rinex_nav(nav)
    r = carrier_observations(read_obs_file(rover), n_freq=n_freq)
    b = carrier_observations(read_obs_file(base), n_freq=n_freq)
    t0 = time.perf_counter()
    res = ppk(r, b, nv, base_pos, PpkOptions(n_freq=n_freq), p_init=r.p_approx_ecef)
    return res, time.perf_counter() - t0


def run_demo5(rover, nav, base, base_pos, n_freq: int = 3) -> dict | None:
    """demo5's combined, forward and backward solutions (None without pyrtklib5)."""
    from dgcal.pos.gnss.rtklib import rtklib_ppk
    try:
        return {s: rtklib_ppk(rover, nav, base, base_pos, systems="GEJ", n_freq=n_freq, solution=s, engine="demo5")
                for s in ("combined", "forward", "backward")}
    except ImportError:
        return None


def _on(t_ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index into t of every t_ref (-1 where none within 1 ms)."""
    j = np.clip(np.searchsorted(t, t_ref), 0, len(t) - 1)
    return np.where(np.abs(t[j] - t_ref) < 1e-3, j, -1)


def truth_lines(res, seconds: float, p_true: np.ndarray, demo5: dict | None) -> list[str]:
    """Both engines against a known position per epoch (N,3) or a point (3,)."""
    t = res.t_gps
    P = np.broadcast_to(p_true, (len(t), 3)) if np.ndim(p_true) == 1 else p_true
    from dgcal.fields.crs import R_ecef_to_enu_at
    R_ecef_to_enu = R_ecef_to_enu_at(P[0])
    f = res.status == 3
    e = (res.p - P) @ R_ecef_to_enu.T
    s = np.sqrt(np.einsum("ij,njk,ik->ni", R_ecef_to_enu, res.P, R_ecef_to_enu))
    ok = res.status >= 2
    z = e[ok] / s[ok]
    n3 = np.linalg.norm(e, axis=1)
    fw, bw = 100 * np.mean(res.forward.status == 3), 100 * np.mean(res.backward.status == 3)
    out = [f"dgcal   {len(t):5d} epochs  fixed {100 * f.mean():5.1f} % (fw {fw:5.1f}, bw {bw:5.1f})  fixed 3D RMS "
           f"{1e3 * np.sqrt(np.mean(n3[f] ** 2)):5.1f} mm  wrong {int(np.sum(n3[f] > 0.1))}  error/sigma RMS "
           f"E/N/U {np.round(np.sqrt(np.mean(z ** 2, 0)), 2)} max {np.max(np.abs(z)):.1f}  "
           f"{1e3 * seconds / len(t):5.1f} ms/epoch"]
    if demo5 is None:
        return out + ["demo5   pyrtklib5 not installed"]
    c = demo5["combined"]
    j = _on(c["t_gps"], t)
    pk = P[j[j >= 0]]
    fk = c["q"][j >= 0] == 1
    ek = np.linalg.norm(c["p_ecef"][j >= 0] - pk, axis=1)
    rate = {k: 100 * np.mean(v["q"] == 1) * len(v["q"]) / len(t) for k, v in demo5.items()}
    out.append(f"demo5   {len(c['q']):5d} epochs  fixed {rate['combined']:5.1f} % (fw {rate['forward']:5.1f}, bw "
               f"{rate['backward']:5.1f})  fixed 3D RMS {1e3 * np.sqrt(np.mean(ek[fk] ** 2)):5.1f} mm  wrong "
               f"{int(np.sum(ek[fk] > 0.1))}  {1e3 * c['run_s'] / len(c['q']):5.1f} ms/epoch (combined run)")
    return out


def agreement_lines(res, seconds: float, demo5: dict | None) -> list[str]:
    """A moving rover without truth: dgcal's fixed epochs against demo5's, epoch by epoch."""
    from dgcal.fields.crs import R_ecef_to_enu_at
    t = res.t_gps
    f = res.status == 3
    fw, bw = 100 * np.mean(res.forward.status == 3), 100 * np.mean(res.backward.status == 3)
    out = [f"dgcal   {len(t):5d} epochs  fixed {100 * f.mean():5.1f} % (fw {fw:5.1f}, bw {bw:5.1f})  "
           f"{1e3 * seconds / len(t):5.1f} ms/epoch"]
    if demo5 is None:
        return out + ["demo5   pyrtklib5 not installed"]
    for name, c in demo5.items():
        j = _on(c["t_gps"], t)
        keep = j >= 0
        both = keep.copy()
        both[keep] = (c["q"][keep] == 1) & (res.status[j[keep]] == 3)
        fk = np.flatnonzero(both)
        R_ecef_to_enu = R_ecef_to_enu_at(res.p[fk[0]] if len(fk) else res.p[0])
        d = (res.p[j[fk]] - c["p_ecef"][fk]) @ R_ecef_to_enu.T
        s = np.sqrt(np.einsum("ij,njk,ik->ni", R_ecef_to_enu, res.P[j[fk]], R_ecef_to_enu))
        z = d / s
        n3 = np.linalg.norm(d, axis=1)
        rate = 100 * np.mean(c["q"] == 1) * len(c["q"]) / len(t)
        out.append(f"demo5 {name:9s} fixed {rate:5.1f} %  both fixed {len(fk):4d}: dgcal - demo5 3D RMS "
                   f"{1e3 * np.sqrt(np.mean(n3 ** 2)):5.1f} mm, mean E/N/U {np.round(1e3 * d.mean(0), 1)} mm, "
                   f"largest {1e3 * n3.max():5.1f} mm, within 2 cm {100 * np.mean(n3 <= 0.02):5.1f} %; dgcal "
                   f"error/sigma RMS E/N/U {np.round(np.sqrt(np.mean(z ** 2, 0)), 2)} max {np.abs(z).max():.1f}")
    fw, bw = demo5["forward"], demo5["backward"]
    jb = _on(fw["t_gps"], bw["t_gps"])
    m = (jb >= 0) & (fw["q"] == 1)
    m[m] &= bw["q"][jb[m]] == 1
    dd = np.linalg.norm(fw["p_ecef"][m] - bw["p_ecef"][jb[m]], axis=1)
    both = (res.forward.status == 3) & (res.backward.status == 3)
    dg = np.linalg.norm(res.forward.p[both] - res.backward.p[both], axis=1)
    out.append(f"forward vs backward (both fixed): dgcal 3D RMS {1e3 * np.sqrt(np.mean(dg ** 2)):5.1f} mm "
               f"(largest {1e3 * dg.max():5.1f}), demo5 {1e3 * np.sqrt(np.mean(dd ** 2)):5.1f} mm "
               f"(largest {1e3 * dd.max():5.1f})")
    return out


def simulated(kind: str, seeds) -> None:
    """Simulated rovers written as RINEX, both engines on the same files, against the truth."""
    from dgcal.sim.rover_motion import simulate_kinematic_rover, write_rover_dataset
    for seed in seeds:
        sim = simulate_kinematic_rover(kind, seed=seed, duration_s=600.0, doppler=seed % 2 == 0)
        with tempfile.TemporaryDirectory() as d:
            out = Path(d) / "rover"
            write_rover_dataset(out, sim)
            files = (str(out / "rover.rnx"), str(out / "nav.rnx"), str(out / "base.rnx"), sim.carrier.base_ecef)
            res, sec = run_dgcal(*files, n_freq=2)
            demo5 = run_demo5(*files, n_freq=2)
        print(f"-- {kind} seed {seed} ({sim.settings['speed_mps']['mean']:.1f} m/s mean, Doppler {seed % 2 == 0}, "
              f"{len(sim.carrier.truth['slips'])} slips)")
        print("\n".join(truth_lines(res, sec, sim.carrier.truth["p_ecef"], demo5)))


PRECISE_SP3 = ROOT / "tests" / "pos" / "gnss" / "data" / "COD0MGXFIN_20210781100_02H_05M_ORB.SP3.gz"


def precise() -> None:
    """The static baseline with CODE's final MGEX SP3 of the day (orbits and its 5-minute clocks) and with broadcast
    orbits, dgcal beside RTKLIB 2.4.3 (pyrtklib, not demo5: one process cannot hold both) with the same products.
    RTKLIB 2.4.3 reads at most 85 satellites of an SP3 file: it gets the file's GPS/Galileo/QZSS records."""
    from dgcal.pos.gnss.carrier import carrier_observations
    from dgcal.pos.gnss.ppk import STATUS, PpkOptions, ppk
    from dgcal.pos.gnss.precise import read_sp3, write_sp3
    from dgcal.pos.gnss.rinex import read_rinex_nav
    from dgcal.pos.gnss.rinex_obs import read_obs_file
    from dgcal.pos.gnss.rtklib import rtklib_ppk
    rover, nav, base, base_pos = (str(v) if not isinstance(v, list) else v for v in STATIC)
    r = carrier_observations(read_obs_file(rover), systems="GEJ")
    b = carrier_observations(read_obs_file(base), systems="GEJ")
    d = read_sp3(PRECISE_SP3)
    keep = [j for j, s in enumerate(d.sats) if s[0] in "GEJ"]
    with tempfile.TemporaryDirectory() as tmp:
        sub = str(Path(tmp) / "gej.sp3")
        write_sp3(sub, d.t, [d.sats[j] for j in keep], d.p[:, keep], d.clk[:, keep])
        print("static 5.3 km baseline (rinex-sept / rinex-3034), GPS + Galileo + QZSS, against the known rover")
        for label, ours, theirs in (("broadcast", [], []), ("CODE SP3", [PRECISE_SP3], [sub])):
            nv = read_rinex_nav(nav, ours)
            t0 = time.perf_counter()
            res = ppk(r, b, nv, base_pos, PpkOptions(systems="GEJ"), p_init=r.p_approx_ecef)
            sec = time.perf_counter() - t0
            rk = rtklib_ppk(rover, nav, base, base_pos, systems="GEJ", precise=theirs, engine="rtklib")
            fx = res.status == STATUS.index("fixed")
            rf = rk["q"] == 1
            e = np.linalg.norm(res.p[fx] - STATIC_REF, axis=1)
            er = np.linalg.norm(rk["p_ecef"][rf] - STATIC_REF, axis=1)
            i = _on(res.t_gps[fx], rk["t_gps"][rf])
            apart = np.linalg.norm(res.p[fx][i >= 0] - rk["p_ecef"][rf][i[i >= 0]], axis=1)
            print(f"  {label:10s} dgcal {100 * fx.mean():5.1f} % fixed, 3D RMS "
                  f"{1e3 * np.sqrt(np.mean(e ** 2)):5.1f} mm, {1e3 * sec / len(res.t_gps):5.2f} ms/epoch | RTKLIB "
                  f"{100 * rf.mean():5.1f} % fixed, 3D RMS "
                  f"{1e3 * np.sqrt(np.mean(er ** 2)):5.1f} mm, {1e3 * rk['run_s'] / max(len(rk['t_gps']), 1):5.2f} "
                  f"ms/epoch | apart: max {1e3 * apart.max():5.1f} mm, RMS {1e3 * np.sqrt(np.mean(apart ** 2)):5.1f} "
                  f"mm over {len(apart)} common fixed epochs")


def main() -> None:
    a = sys.argv[1:]
    if a and a[0] == "precise":
        precise()
        return
    if a and a[0] == "sim":
        simulated(a[1] if len(a) > 1 else "uav", [int(v) for v in a[2:]] or range(3))
        return
    if len(a) >= 6:
        rover, nav, base, base_pos = a[0], a[1], a[2], [float(v) for v in a[3:6]]
        for nf in (2, 3):
            res, sec = run_dgcal(rover, nav, base, base_pos, n_freq=nf)
            print(f"moving rover {rover} against {base}, {nf} frequencies")
            print("\n".join(agreement_lines(res, sec, run_demo5(rover, nav, base, base_pos, n_freq=nf))))
        return
    rover, nav, base, base_pos = (str(v) if not isinstance(v, list) else v for v in STATIC)
    res, sec = run_dgcal(rover, nav, base, base_pos)
    print("static 5.3 km baseline (rinex-sept / rinex-3034) against the known rover position")
    print("\n".join(truth_lines(res, sec, STATIC_REF, run_demo5(rover, nav, base, base_pos))))


if __name__ == "__main__":
    main()
