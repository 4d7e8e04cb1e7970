"""RTKLIB's single-point positioning (pyrtklib, optional) for side-by-side comparison with dgcal's SPP."""
from __future__ import annotations

import numpy as np

from dgcal.fields.constants import SECONDS_PER_WEEK


def rtklib_pntpos(obs_path: str, nav_path: str, elev_mask_deg: float = 10.0,
                  systems: str = "GEJ") -> tuple[np.ndarray, np.ndarray]:
    """RTKLIB pntpos per epoch (Klobuchar, Saastamoinen, broadcast orbits): (t_gps, p_ecef)."""
    import pyrtklib as rk  # why: optional dependency (the `test` extra), needed only for this comparison

    obs, nav, sta = rk.obs_t(), rk.nav_t(), rk.sta_t()
    rk.readrnx(obs_path, 1, "", obs, nav, sta)
    rk.readrnx(nav_path, 1, "", obs, nav, sta)
    rk.sortobs(obs)
    rk.uniqnav(nav)
    opt = rk.prcopt_default
    opt.mode = rk.PMODE_SINGLE
    opt.navsys = sum({"G": rk.SYS_GPS, "E": rk.SYS_GAL, "J": rk.SYS_QZS, "C": rk.SYS_CMP}[s]
                     for s in systems)
    opt.elmin = np.radians(elev_mask_deg)
    opt.tropopt = rk.TROPOPT_SAAS
    opt.ionoopt = rk.IONOOPT_BRDC
    opt.sateph = rk.EPHOPT_BRDC
    ts, ps = [], []
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
        i += m
    return np.array(ts), np.array(ps)
