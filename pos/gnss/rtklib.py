"""RTKLIB as the reference peer (optional): single-point positioning and PPK by RTKLIB 2.4.3 (pyrtklib) or by
rtklibexplorer's demo5 fork (pyrtklib5, ``engine="demo5"``), for side-by-side comparison with dgcal."""
from __future__ import annotations

import os
import tempfile
import time
from typing import Sequence

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK
from dgcal.pos.gnss.gnss_files import CRINEX_MARK, container_of, first_gnss_line, read_gnss_bytes


def rtklib_pntpos(obs_path: str, nav_path: str, elev_mask_deg: float = 10.0,
                  systems: str = "GEJ", sp3: Sequence[str] = (), clk: Sequence[str] = ()
                  ) -> tuple[np.ndarray, np.ndarray]:
    """RTKLIB pntpos per epoch (Klobuchar, Saastamoinen, broadcast orbits, or the `sp3` orbits and `clk` clocks
    given): (t_gps, p_ecef)."""
    t, p, _ = rtklib_pntpos_cov(obs_path, nav_path, elev_mask_deg, systems, sp3, clk)
    return t, p


def _plain_copies(paths: Sequence[str], folder: str) -> list[str]:
    """Plain copies of compressed files (gzip, .Z, bzip2, zip, Hatanaka) in `folder` under names RTKLIB recognises
    (.sp3, .clk: the compression suffix dropped); plain files as given."""
    out = []
    for p in paths:
        p = str(p)
        with open(p, "rb") as fh:
            compressed = container_of(fh.read(4)) != "plain"
        if compressed or first_gnss_line(p).find(CRINEX_MARK) >= 0:
            name = os.path.basename(p)
            stem, suffix = os.path.splitext(name)
            name = stem if suffix.lower() in (".gz", ".z", ".bz2", ".zip") else name
            dst = os.path.join(folder, name)
            with open(dst, "wb") as fh:
                fh.write(read_gnss_bytes(p))
            p = dst
        out.append(p)
    return out


def rtklib_pntpos_cov(obs_path: str, nav_path: str, elev_mask_deg: float = 10.0,
                      systems: str = "GEJ", sp3: Sequence[str] = (), clk: Sequence[str] = ()
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RTKLIB pntpos per epoch with its covariance (sol.qr): t_gps (n,), p_ecef (n,3) m, cov (n,3,3) m^2 ECEF.
    With `sp3` (and `clk`) files RTKLIB's precise ephemeris (EPHOPT_PREC; no satellite antenna offsets without
    an ANTEX file, as dgcal)."""
    import pyrtklib as rk  # why: optional dependency (the `test` extra), needed only for this comparison

    obs, nav, sta = rk.obs_t(), rk.nav_t(), rk.sta_t()
    rk.readrnx(str(obs_path), 1, "", obs, nav, sta)
    for f in ([nav_path] if isinstance(nav_path, (str, os.PathLike)) else nav_path):   # one file or several
        rk.readrnx(str(f), 1, "", obs, nav, sta)
    rk.sortobs(obs)
    rk.uniqnav(nav)
    with tempfile.TemporaryDirectory() as d:
        for f in _plain_copies(sp3, d):
            rk.readsp3(f, nav, 0)
        for f in _plain_copies(clk, d):
            rk.readrnxc(f, nav)
    opt = rk.prcopt_default
    opt.mode = rk.PMODE_SINGLE
    opt.navsys = sum({"G": rk.SYS_GPS, "E": rk.SYS_GAL, "J": rk.SYS_QZS, "C": rk.SYS_CMP, "R": rk.SYS_GLO}[s]
                     for s in systems)
    opt.elmin = np.radians(elev_mask_deg)
    opt.tropopt = rk.TROPOPT_SAAS
    opt.ionoopt = rk.IONOOPT_BRDC
    opt.sateph = rk.EPHOPT_PREC if sp3 else rk.EPHOPT_BRDC
    ts, ps, cs = [], [], []
    i = 0
    while i < obs.n:
        m = 0
        while i + m < obs.n and abs(rk.timediff(obs.data[i + m].time, obs.data[i].time)) < 0.05:
            m += 1
        sub = obs.data[i:i + m]
        sol = rk.sol_t()
        ssat = rk.Arr1Dssat_t(rk.MAXSAT)
        azel = rk.Arr1Ddouble(2 * m)
        msg = rk.Arr1Dchar(100)
        ok = rk.pntpos(sub.ptr, m, nav, opt, sol, azel, ssat.ptr, msg)
        if ok:
            week = rk.Arr1Dint(1)
            tow = rk.time2gpst(sol.time, week)
            ts.append(week[0] * SECONDS_PER_WEEK + tow)
            ps.append([sol.rr[0], sol.rr[1], sol.rr[2]])
            q = [sol.qr[k] for k in range(6)]           # RTKLIB's order: xx yy zz xy yz zx
            cs.append([[q[0], q[3], q[5]], [q[3], q[1], q[4]], [q[5], q[4], q[2]]])
        i += m
    return np.array(ts), np.array(ps), np.array(cs).reshape(-1, 3, 3)


_POSTPOS_FIELDS = ("mode", "soltype", "nf", "navsys", "elmin", "modear", "ionoopt", "tropopt", "refpos", "sateph")


def _module(engine: str):
    """The RTKLIB binding of `engine`: "rtklib" (pyrtklib, RTKLIB 2.4.3) or "demo5" (pyrtklib5)."""
    if engine == "demo5":
        import pyrtklib5 as rk  # why: optional dependency (the `test` extra), needed only for this comparison
    elif engine == "rtklib":
        import pyrtklib as rk  # why: optional dependency (the `test` extra), needed only for this comparison
    else:
        raise ValueError(f"RTKLIB engine {engine!r}: rtklib or demo5")
    return rk


def rtklib_ppk(rover_obs: str, nav_path: str, base_obs: str, base_ecef, elev_mask_deg: float = 10.0,
               systems: str = "GEJ", n_freq: int = 3, static: bool = False, solution: str = "combined",
               fix_and_hold: bool = True, engine: str = "rtklib", precise: Sequence[str] = ()) -> dict:
    """RTKLIB's PPK (postpos, as rnx2rtkp) on RINEX files: per epoch t_gps, p_ecef (m), q (1 fix, 2 float, 5 single),
    ns, ratio, sdx/sdy/sdz (m) and the run time (s), epochs in time order. Broadcast orbits (or the SP3/CLK files
    `precise`), Saastamoinen, broadcast ionosphere, LAMBDA ratio 3; `engine` "demo5" runs rtklibexplorer's fork
    (pyrtklib5) instead."""
    rk = _module(engine)
    settings = {"mode": rk.PMODE_STATIC if static else rk.PMODE_KINEMA,
                "soltype": {"forward": 0, "backward": 1, "combined": 2}[solution], "nf": int(n_freq),
                "modear": 3 if fix_and_hold else 1}
    return _postpos([str(rover_obs), str(nav_path), str(base_obs)], settings, elev_mask_deg, systems, base_ecef,
                    engine, precise)


def rtklib_spp(obs_path: str, nav_path: str, elev_mask_deg: float = 10.0, systems: str = "GEJ",
               precise: Sequence[str] = ()) -> dict:
    """RTKLIB's single-point positioning as rnx2rtkp runs it (postpos, PMODE_SINGLE: Klobuchar, Saastamoinen,
    broadcast orbits) on RINEX files: per epoch t_gps, p_ecef (m), q (5 single), ns, and the run time (s) of
    postpos itself (reading the files included, the process start not)."""
    import pyrtklib as rk  # why: optional dependency (the `test` extra), needed only for this comparison
    return _postpos([str(obs_path), str(nav_path)], {"mode": rk.PMODE_SINGLE, "soltype": 0, "nf": 1},
                    elev_mask_deg, systems, None, precise=precise)


def _postpos(files: list[str], settings: dict, elev_mask_deg: float, systems: str, base_ecef,
             engine: str = "rtklib", precise: Sequence[str] = ()) -> dict:
    """RTKLIB's postpos on `files` (rnx2rtkp's engine) with the prcopt fields `settings` and dgcal's shared
    settings (broadcast orbits, or precise ones from the SP3/CLK files `precise`, broadcast ionosphere,
    Saastamoinen, ratio 3, `base_ecef` when given); prcopt_default is restored afterwards. Returns the solution
    file's epochs as arrays and the run time."""
    rk = _module(engine)
    popt, sopt, fopt = rk.prcopt_default, rk.solopt_default, rk.filopt_t()
    saved = {k: getattr(popt, k) for k in _POSTPOS_FIELDS}
    saved_rb = [popt.rb[i] for i in range(3)]
    saved_thres = popt.thresar[0]
    saved_posf = sopt.posf
    try:
        for k, v in settings.items():
            setattr(popt, k, v)
        popt.navsys = sum({"G": rk.SYS_GPS, "E": rk.SYS_GAL, "J": rk.SYS_QZS, "C": rk.SYS_CMP, "R": rk.SYS_GLO}[s]
                          for s in systems)
        popt.elmin = np.radians(elev_mask_deg)
        popt.ionoopt = rk.IONOOPT_BRDC
        popt.tropopt = rk.TROPOPT_SAAS
        popt.sateph = rk.EPHOPT_PREC if precise else rk.EPHOPT_BRDC
        popt.refpos = 0
        popt.thresar[0] = 3.0
        if base_ecef is not None:
            for i in range(3):
                popt.rb[i] = float(base_ecef[i])
        sopt.posf = rk.SOLF_XYZ
        with tempfile.TemporaryDirectory() as d:
            files = files + _plain_copies(precise, d)
            out_path = os.path.join(d, "rtklib.pos")
            if engine == "demo5":                      # pyrtklib5 takes the output path as a string
                buf = out_path
            else:
                buf = rk.Arr1Dchar(len(out_path) + 1)
                for i, c in enumerate(out_path):
                    buf[i] = c
                buf[len(out_path)] = "\0"
            t0 = time.perf_counter()
            rk.postpos(rk.gtime_t(), rk.gtime_t(), 0.0, 0.0, popt, sopt, fopt, files, len(files), buf, "", "")
            run_s = time.perf_counter() - t0
            rows = []
            with open(out_path) as fh:
                for line in fh:
                    if line.startswith("%") or not line.strip():
                        continue
                    v = line.split()
                    ymd, hms = v[0].split("/"), v[1].split(":")
                    from dgcal.pos.gnss.rinex import gps_seconds_from_calendar
                    t = gps_seconds_from_calendar(int(ymd[0]), int(ymd[1]), int(ymd[2]), int(hms[0]), int(hms[1]),
                                                  float(hms[2]))
                    rows.append([t, float(v[2]), float(v[3]), float(v[4]), int(v[5]), int(v[6]), float(v[14]),
                                 float(v[7]), float(v[8]), float(v[9])])
    finally:
        for k, val in saved.items():
            setattr(popt, k, val)
        for i in range(3):
            popt.rb[i] = saved_rb[i]
        popt.thresar[0] = saved_thres
        sopt.posf = saved_posf
    a = np.array(rows) if rows else np.zeros((0, 10))
    a = a[np.argsort(a[:, 0], kind="stable")]          # a backward solution file runs back in time
    return {"t_gps": a[:, 0], "p_ecef": a[:, 1:4], "q": a[:, 4].astype(int), "ns": a[:, 5].astype(int),
            "ratio": a[:, 6], "sd_ecef": a[:, 7:10], "run_s": run_s}
