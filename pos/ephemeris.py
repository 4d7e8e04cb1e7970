"""Satellite position, velocity and clock from broadcast ephemeris (cssrlib's Keplerian model).

Times are continuous GPS seconds; positions/velocities ECEF (m, m/s) at the given time in the
ECEF frame of that time (no Sagnac rotation here, see ``gnss_corrections.sagnac_rotate``).
"""
from __future__ import annotations

import numpy as np

from pos.gnss_types import C_LIGHT
from pos.rinex import BroadcastNav, gps_seconds_from_gtime, gtime_from_gps_seconds

MAX_AGE_S = {"G": 7200.0, "J": 7200.0, "E": 10800.0, "C": 3900.0}   # |t - toe| allowed
URA_M = np.array([2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0,
                  1536.0, 3072.0, 6144.0])


def _healthy(sid: str, eph) -> bool:
    if sid[0] == "E":
        return (int(eph.svh) & 0x7) == 0          # E1-B data validity and signal health bits
    return int(eph.svh) == 0


def select_ephemeris(nav: BroadcastNav, sid: str, t_gps: float):
    """The healthy ephemeris of satellite ``sid`` with the nearest toe within the validity span, or None.

    Galileo: I/NAV records (E1/E5b clock, matching single-frequency E1 use) are preferred,
    F/NAV ones are used only when no I/NAV record is valid.
    """
    cands = nav.by_sat.get(sid)
    if not cands:
        return None
    toe = nav._toe.get(sid)
    if toe is None:
        toe = np.array([gps_seconds_from_gtime(e.toe) for e in cands])
        nav._toe[sid] = toe
    age = np.abs(t_gps - toe)
    ok = age <= MAX_AGE_S.get(sid[0], 7200.0)
    if sid[0] == "E":
        inav = ok & np.array([e.mode == 0 for e in cands])
        if inav.any():
            ok = inav
    best = None
    for i in np.argsort(age):
        if ok[i] and _healthy(sid, cands[i]):
            best = cands[i]
            break
    return best


def ura_m(sid: str, eph) -> float:
    """User range accuracy (m) of an ephemeris (GPS/QZSS URA index; 3 m for other systems)."""
    if sid[0] in "GJ":
        k = int(eph.sva)
        return float(URA_M[k]) if 0 <= k < len(URA_M) else 6144.0
    return 3.0


def _is_bds_geo(sid: str) -> bool:
    prn = int(sid[1:])
    return sid[0] == "C" and (prn <= 5 or prn >= 59)


def satellite_states(nav: BroadcastNav, sats: list[str], t_gps: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Broadcast states of satellites at GPS times ``t_gps`` (s, per satellite).

    Returns ``p_ecef`` (n,3) m, ``v_ecef`` (n,3) m/s, ``clk_s`` (n,) satellite clock offset in s
    for the single-frequency signal (polynomial + relativistic term - TGD/BGD), ``drift`` (n,)
    s/s, ``ura`` (n,) m, and ``ok`` (n,) bool (False: no valid healthy ephemeris, values NaN).
    """
    from cssrlib.ephemeris import eph2pos, eph2rel
    from cssrlib.gnss import timeadd

    n = len(sats)
    t_gps = np.broadcast_to(np.asarray(t_gps, float), (n,))
    p = np.full((n, 3), np.nan)
    v = np.full((n, 3), np.nan)
    clk = np.full(n, np.nan)
    drift = np.full(n, np.nan)
    ura = np.full(n, np.nan)
    ok = np.zeros(n, dtype=bool)
    for i, sid in enumerate(sats):
        eph = select_ephemeris(nav, sid, t_gps[i])
        if eph is None:
            continue
        t = gtime_from_gps_seconds(t_gps[i])
        rs, vs, dts = eph2pos(t, eph, flg_v=True)
        if _is_bds_geo(sid):
            # cssrlib's analytic velocity does not apply the GEO frame rotation: difference positions
            ra, _ = eph2pos(timeadd(t, -0.5), eph)
            rb, _ = eph2pos(timeadd(t, 0.5), eph)
            vs = rb - ra
        dtc = t_gps[i] - gps_seconds_from_gtime(eph.toc)
        rel_rate = eph2rel(timeadd(t, 0.5), eph) - eph2rel(timeadd(t, -0.5), eph)
        p[i], v[i] = rs, vs
        clk[i] = dts - eph.tgd
        drift[i] = eph.af1 + 2.0 * eph.af2 * dtc + rel_rate
        ura[i] = ura_m(sid, eph)
        ok[i] = np.all(np.isfinite(rs)) and np.isfinite(dts)
    return p, v, clk, drift, ura, ok


def states_at_transmission(nav: BroadcastNav, sats: list[str], t_rx_gps: float, pr_m: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Satellite states at signal transmission, from the receiver epoch and the pseudoranges.

    ``t_tx = t_rx - pr/c - dt_sat(t_tx)`` (the satellite clock offset found by two iterations);
    this is exact whatever the receiver clock error, because pseudoranges are differences of
    receiver and satellite clock readings. Returns ``(p, v, clk_s, drift, ura, ok)`` as
    ``satellite_states`` (unrotated, ECEF at transmission time).
    """
    t_sv = t_rx_gps - np.asarray(pr_m, float) / C_LIGHT
    _, _, clk, _, _, _ = satellite_states(nav, sats, t_sv)
    clk = np.nan_to_num(clk)
    # second pass uses the clock of the first; the clock changes < 1e-12 s over that difference
    return satellite_states(nav, sats, t_sv - clk)
