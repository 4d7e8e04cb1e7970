"""Satellite position, velocity and clock from broadcast ephemeris (cssrlib's Keplerian model).

Times are continuous GPS seconds; positions/velocities ECEF (m, m/s) at the given time in the
ECEF frame of that time (no Sagnac rotation here, see ``gnss_corrections.sagnac_rotate``).
"""
from __future__ import annotations

import numpy as np
from cssrlib.ephemeris import eph2pos
from cssrlib.gnss import timeadd

from dgcal.fields.constants import C_LIGHT, GM_GPS, OMEGA_EARTH
from dgcal.pos.gnss.corrections import URA_NOMINAL_M
from dgcal.pos.gnss.glonass import glonass_states
from dgcal.pos.gnss.precise import PRECISE_SIGMA_M
from dgcal.pos.gnss.rinex import BroadcastNav, gps_seconds_from_gtime, gtime_from_gps_seconds

MAX_AGE_S = {"G": 7200.0, "J": 7200.0, "E": 10800.0, "C": 3900.0}   # |t - toe| allowed
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
    """Signal-in-space accuracy (m) of an ephemeris, at least 2 m.

    RINEX 3 stores GPS/QZSS/BeiDou "SV accuracy" and Galileo SISA in metres (cssrlib keeps the
    integer part); the synthetic constellation leaves it 0.
    """
    return max(float(eph.sva), 2.0)


def _is_bds_geo(sid: str) -> bool:
    prn = int(sid[1:])
    return sid[0] == "C" and (prn <= 5 or prn >= 59)


# GM (m^3/s^2) and earth rate (rad/s) of each system's interface specification (Galileo's and BeiDou's GM
# happen to equal WGS84's; BeiDou's CGCS2000 earth rate is rounded)
_MU = {"G": GM_GPS, "J": GM_GPS, "E": 3.986004418e14, "C": 3.986004418e14}
_OMGE = {"G": OMEGA_EARTH, "J": OMEGA_EARTH, "E": OMEGA_EARTH, "C": 7.292115e-5}
_SELECT_BUCKET_S = 300.0


def _select_cached(nav: BroadcastNav, sid: str, t_gps: float):
    """``select_ephemeris`` at the middle of a 5-minute bucket, cached (deterministic per bucket)."""
    b = int(np.floor(t_gps / _SELECT_BUCKET_S))
    cache = nav._toe.setdefault("_sel", {})
    key = (sid, b)
    if key not in cache:
        cache[key] = select_ephemeris(nav, sid, (b + 0.5) * _SELECT_BUCKET_S)
    return cache[key]


_PARAM_NAMES = ("A", "e", "M0", "deln", "omg", "cuc", "cus", "crc", "crs", "cic", "cis", "i0",
                "idot", "OMG0", "OMGd", "toes", "af0", "af1", "af2", "tgd", "Adot", "delnd", "mode")


def _params(nav: BroadcastNav, ephs: list) -> dict[str, np.ndarray]:
    """Ephemeris parameters as arrays (one entry per record); rows are cached per record."""
    cache = nav._toe.setdefault("_rows", {})
    rows = []
    for e in ephs:
        r = cache.get(id(e))
        if r is None:
            r = np.array([float(getattr(e, k)) for k in _PARAM_NAMES]
                         + [gps_seconds_from_gtime(e.toe), gps_seconds_from_gtime(e.toc)])
            cache[id(e)] = r
        rows.append(r)
    m = np.array(rows)
    out = {k: m[:, i] for i, k in enumerate(_PARAM_NAMES)}
    out["toe_abs"], out["toc_abs"] = m[:, -2], m[:, -1]
    return out


def kepler_states(prm: dict[str, np.ndarray], sys: np.ndarray, t_gps: np.ndarray):
    """Vectorised broadcast Keplerian orbit and clock (IS-GPS-200 / Galileo / BeiDou MEO-IGSO).

    Same model as cssrlib's ``eph2pos`` (tested against it), for many satellites at once.
    Returns position (n,3), velocity (n,3), clock incl. relativity (s), clock drift (s/s).
    """
    sys = np.asarray(sys)
    mu = np.select([sys == s for s in _MU], list(_MU.values()), np.nan)
    omge = np.select([sys == s for s in _OMGE], list(_OMGE.values()), np.nan)
    dt = t_gps - prm["toe_abs"]
    A = prm["A"]
    Ak = A + np.where(prm["mode"] > 0, dt * prm["Adot"], 0.0)
    n0 = np.sqrt(mu / A ** 3)
    n = n0 + prm["deln"] + np.where(prm["mode"] > 0, 0.5 * dt * prm["delnd"], 0.0)
    M = prm["M0"] + n * dt
    e = prm["e"]
    E = M.copy()
    for _ in range(30):
        dE = (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        E -= dE
        if np.all(np.abs(dE) < 1e-14):
            break
    sE, cE = np.sin(E), np.cos(E)
    nue = 1.0 - e * cE
    nu = np.arctan2(np.sqrt(1.0 - e ** 2) * sE, cE - e)
    phi = nu + prm["omg"]
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    u = phi + prm["cuc"] * c2 + prm["cus"] * s2
    r = Ak * nue + prm["crc"] * c2 + prm["crs"] * s2
    inc = prm["i0"] + prm["idot"] * dt + prm["cic"] * c2 + prm["cis"] * s2
    hu = np.stack([np.cos(u), np.sin(u)])
    xo, yo = r * hu[0], r * hu[1]
    Omg = prm["OMG0"] + prm["OMGd"] * dt - omge * (prm["toes"] + dt)
    sO, cO, si, ci = np.sin(Omg), np.cos(Omg), np.sin(inc), np.cos(inc)
    p = np.stack([xo * cO - yo * ci * sO, xo * sO + yo * ci * cO, yo * si], axis=1)
    # velocity (same formulation as cssrlib)
    Ed = n / nue
    nud = np.sqrt(1.0 - e ** 2) / nue * Ed
    ud = nud + 2.0 * nud * (-prm["cuc"] * s2 + prm["cus"] * c2)
    rd = Ak * e * sE * Ed + 2.0 * nud * (-prm["crc"] * s2 + prm["crs"] * c2)
    incd = prm["idot"] + 2.0 * nud * (-prm["cic"] * s2 + prm["cis"] * c2)
    xod = rd * hu[0] - r * ud * hu[1]
    yod = rd * hu[1] + r * ud * hu[0]
    omegd = prm["OMGd"] - omge
    vx = xod * cO - yod * ci * sO + (-xo * sO - yo * ci * cO) * omegd + yo * si * sO * incd
    vy = xod * sO + yod * ci * cO + (xo * cO - yo * ci * sO) * omegd - yo * si * cO * incd
    vz = yod * si + yo * ci * incd
    v = np.stack([vx, vy, vz], axis=1)
    dtc = t_gps - prm["toc_abs"]
    k_rel = -2.0 * np.sqrt(mu * A) * e / C_LIGHT ** 2
    clk = prm["af0"] + prm["af1"] * dtc + prm["af2"] * dtc ** 2 + k_rel * sE
    drift = prm["af1"] + 2.0 * prm["af2"] * dtc + k_rel * cE * Ed
    return p, v, clk, drift


def satellite_states(nav: BroadcastNav, sats: list[str], t_gps: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Broadcast states of satellites at GPS times ``t_gps`` (s, per satellite).

    Returns ``p_ecef`` (n,3) m, ``v_ecef`` (n,3) m/s, ``clk_s`` (n,) satellite clock offset in s
    for the single-frequency signal (polynomial + relativistic term - TGD/BGD), ``drift`` (n,)
    s/s, ``ura`` (n,) m, and ``ok`` (n,) bool (False: no valid healthy ephemeris, values NaN).
    BeiDou GEO satellites use cssrlib's ``eph2pos`` (their frame rotation), the rest the
    vectorised ``kepler_states``, GLONASS satellites their records' integrated orbits
    (`dgcal.pos.gnss.glonass.glonass_states`; ``ura`` the nominal `URA_NOMINAL_M`, the records state none). With
    precise products (``nav.precise``) every satellite's orbit and clock come from them (`precise_states`), and
    ``ura`` is their accuracy.
    """
    if getattr(nav, "precise", None) is not None:
        return precise_states(nav, sats, t_gps)
    glo = np.array([str(s)[0] == "R" for s in sats], bool)
    if glo.any():
        n = len(sats)
        t_all = np.array(np.broadcast_to(np.asarray(t_gps, float), (n,)))
        out = (np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.full(n, np.nan), np.full(n, np.nan),
               np.full(n, np.nan), np.zeros(n, bool))
        rest = np.flatnonzero(~glo)
        for a, b in zip(out, _broadcast_states(nav, [sats[i] for i in rest], t_all[rest])):
            a[rest] = b
        gi = np.flatnonzero(glo)
        if getattr(nav, "glonass", None) is not None:
            p, v, clk, drift, ok = glonass_states(nav.glonass, [sats[i] for i in gi], t_all[gi])
            for a, b in zip(out, (p, v, clk, drift, np.where(ok, URA_NOMINAL_M["R"], np.nan), ok)):
                a[gi] = b
        return out
    return _broadcast_states(nav, sats, t_gps)


def _broadcast_states(nav: BroadcastNav, sats: list[str], t_gps: np.ndarray) -> tuple:
    """`satellite_states` of GPS, Galileo, BeiDou and QZSS satellites from their Keplerian records."""
    n = len(sats)
    t_gps = np.array(np.broadcast_to(np.asarray(t_gps, float), (n,)))
    p = np.full((n, 3), np.nan)
    v = np.full((n, 3), np.nan)
    clk = np.full(n, np.nan)
    drift = np.full(n, np.nan)
    ura = np.full(n, np.nan)
    if n == 0:
        return p, v, clk, drift, ura, np.zeros(0, bool)
    # the ephemeris is chosen per satellite and 5-minute bucket: select once per distinct pair
    names, sat_i = np.unique(np.asarray(sats, dtype=object).astype(str), return_inverse=True)
    bucket = np.floor(t_gps / _SELECT_BUCKET_S).astype(np.int64)
    pair, pair_i = np.unique(sat_i.astype(np.int64) * (1 << 40) + (bucket - bucket.min()), return_inverse=True)
    first = np.zeros(len(pair), np.int64)
    first[pair_i[::-1]] = np.arange(n)[::-1]
    eph_pair = [_select_cached(nav, str(names[sat_i[j]]), t_gps[j]) for j in first]
    have_pair = np.array([e is not None for e in eph_pair], bool)
    ura_pair = np.array([ura_m(str(names[sat_i[j]]), e) if e is not None else np.nan for j, e in zip(first, eph_pair)])
    geo_sat = np.array([_is_bds_geo(str(name)) for name in names], bool)
    have = have_pair[pair_i]
    geo = geo_sat[sat_i] & have
    kep = have & ~geo
    if kep.any():
        idx = np.nonzero(kep)[0]
        kp = np.nonzero(have_pair & ~geo_sat[sat_i[first]])[0]
        prm_pair = _params(nav, [eph_pair[j] for j in kp])
        where = np.full(len(pair), -1)
        where[kp] = np.arange(len(kp))
        sel = where[pair_i[idx]]
        prm = {k: a[sel] for k, a in prm_pair.items()}
        sysv = np.array([str(x)[0] for x in names])[sat_i[idx]]
        p[idx], v[idx], c, d = kepler_states(prm, sysv, t_gps[idx])
        clk[idx] = c - prm["tgd"]
        drift[idx] = d
    for i in np.nonzero(geo)[0]:
        p[i], v[i], clk[i], drift[i] = _geo_state(eph_pair[pair_i[i]], t_gps[i])
    ura[have] = ura_pair[pair_i[have]]
    ok = have & np.all(np.isfinite(p), axis=1) & np.isfinite(clk)
    return p, v, clk, drift, ura, ok


def group_delay_s(nav: BroadcastNav, sats: list[str], t_gps: np.ndarray) -> np.ndarray:
    """The broadcast group delay (s) that `satellite_states` subtracts for the single-frequency signal (GPS/QZSS
    TGD, Galileo BGD, BeiDou TGD1) of each satellite at `t_gps`; 0 without an ephemeris. Dual-frequency
    ionosphere-free users add it back: the broadcast clock refers to that combination (and so do precise clocks)."""
    t_gps = np.array(np.broadcast_to(np.asarray(t_gps, float), (len(sats),)))
    if getattr(nav, "precise", None) is not None:
        return precise_group_delay_s(nav, sats, t_gps)
    out = np.zeros(len(sats))
    for i, sid in enumerate(sats):
        eph = _select_cached(nav, sid, t_gps[i])
        if eph is not None:
            out[i] = float(getattr(eph, "tgd", 0.0) or 0.0)
    return out


# BeiDou: broadcast clocks refer to B3I and TGD1 is B1I's delay against B3I; precise clocks to the B1I/B3I
# ionosphere-free combination, from which B1I is off by +f3^2/(f1^2-f3^2) TGD1 (a group delay of -1.94 TGD1)
_BDS_B1_IF = -1268.52 ** 2 / (1561.098 ** 2 - 1268.52 ** 2)


def precise_group_delay_s(nav: BroadcastNav, sats: list[str], t_gps: np.ndarray) -> np.ndarray:
    """Delay (s) of the single-frequency signal against the precise clocks' ionosphere-free reference, from each
    satellite's broadcast record nearest in time, healthy or not (a group delay is a hardware constant): GPS/QZSS
    TGD, Galileo BGD(E1,E5a) (IGS clocks refer to E1/E5a), BeiDou ``_BDS_B1_IF`` x TGD1; 0 without any record."""
    out = np.zeros(len(sats))
    for i, sid in enumerate(sats):
        cands = nav.by_sat.get(sid)
        if not cands:
            continue
        toe = nav._toe.get(sid)
        if toe is None:
            toe = np.array([gps_seconds_from_gtime(e.toe) for e in cands])
            nav._toe[sid] = toe
        e = cands[int(np.argmin(np.abs(t_gps[i] - toe)))]
        tgd = float(getattr(e, "tgd", 0.0) or 0.0)
        if sid[0] == "E" and (int(getattr(e, "code", 0)) >> 9) & 1:   # E1/E5b clock: cssrlib keeps BGD(E1,E5a)
            tgd = float(getattr(e, "tgd_b", 0.0) or 0.0)                 # in tgd_b
        elif sid[0] == "C":
            tgd *= _BDS_B1_IF
        out[i] = tgd
    return out


def precise_states(nav: BroadcastNav, sats: list[str], t_gps: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`satellite_states` from the precise products of ``nav.precise`` (`dgcal.pos.gnss.precise`): centre-of-mass
    positions (antenna phase centres with an ANTEX file), clocks with the relativistic term, minus the
    single-frequency signal's delay against the products' ionosphere-free reference (`precise_group_delay_s`, from
    the broadcast group delays); ``ura`` is `PRECISE_SIGMA_M`. A satellite without products at the time is not ok
    (no fallback to the broadcast orbit)."""
    t_gps = np.array(np.broadcast_to(np.asarray(t_gps, float), (len(sats),)))
    p, v, clk, drift, ok = nav.precise.states(list(sats), t_gps)
    clk = clk - precise_group_delay_s(nav, sats, t_gps)
    ura = np.where(ok, PRECISE_SIGMA_M, np.nan)
    return p, v, clk, drift, ura, ok


def _geo_state(eph, t_gps: float):
    """BeiDou GEO state with cssrlib (velocity by central difference of positions)."""
    t = gtime_from_gps_seconds(t_gps)
    rs, dts = eph2pos(t, eph)
    ra, ca = eph2pos(timeadd(t, -0.5), eph)
    rb, cb = eph2pos(timeadd(t, 0.5), eph)
    return rs, rb - ra, dts - eph.tgd, cb - ca


def states_at_transmission(nav: BroadcastNav, sats: list[str], t_rx_gps: float, pr_m: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Satellite states at signal transmission, from the receiver epoch and the pseudoranges.

    ``t_tx = t_rx - pr/c - dt_sat(t_tx)`` (the satellite clock offset found by two iterations);
    this is exact whatever the receiver clock error, because pseudoranges are differences of
    receiver and satellite clock readings. Returns ``(p, v, clk_s, drift, ura, ok)`` as
    ``satellite_states`` (unrotated, ECEF at transmission time).
    """
    t_sv = t_rx_gps - np.asarray(pr_m, float) / C_LIGHT
    p, v, clk, drift, ura, ok = satellite_states(nav, sats, t_sv)
    # re-evaluate at t_sv - clk by a Taylor step: |clk| < 1 ms, so the 2nd-order error is < 1 mm
    clk0 = np.nan_to_num(clk)
    acc = -3.986e14 * p / np.linalg.norm(p, axis=1, keepdims=True) ** 3
    p = p - v * clk0[:, None] + 0.5 * acc * clk0[:, None] ** 2
    v = v - acc * clk0[:, None]
    clk = clk - drift * clk0
    return p, v, clk, drift, ura, ok
