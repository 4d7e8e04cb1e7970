"""Double differences of rover and base code and carrier phase for the tightly coupled smoother.

The PPK engine (``dgcal.pos.gnss.ppk``) validates integer fixes epoch by epoch; the smoother needs the integer
ambiguity of every phase arc instead, so that an epoch contributes its carrier phase whatever PPK made of it
(float, or fewer than four satellites). ``arc_integers`` recovers them from PPK's fixed epochs: at a fixed
position the between-receiver single differences of two arcs of one system and frequency, in cycles, differ by
an integer (receiver clocks and phase offsets are common to both); every fixed epoch votes for that integer,
a pair of arcs is tied when its votes agree, and the ties are joined into components (weighted union-find) in
which every arc has an integer offset from the component's root. Any two arcs of a component then have a known
double-difference ambiguity, also in epochs where they were never fixed together.

``dd_epochs`` forms, per rover epoch, the double differences against a reference satellite per system and
frequency (kept from epoch to epoch while it is observed, so that time-correlated errors can be whitened
along a track) as measurements of the rover antenna's range difference (m)::

    z_i = DD(omc)(x0) - lam (N_i - N_ref) + |s_i - x0| - |s_ref - x0|  =  |s_i - p| - |s_ref - p| + e

(phase: with the arcs' integers; code: N = 0), ``s`` the satellite positions at the rover's reception
(Earth rotation applied), ``x0`` any linearisation point within metres, ``p`` the antenna. The covariance is
that of the differencing of zero-difference errors ``sigma0^2 (1/2 + 1/(2 sin^2 el))`` at both receivers.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from dgcal.fields.crs import R_ecef_to_enu_at
from dgcal.pos.gnss.carrier import CarrierObs
from dgcal.pos.gnss.ppk import CarrierPair, PpkOptions, PpkResult, ppk
from dgcal.pos.gnss.ppk_design import zd_var


@dataclass
class DDOptions:
    """Noise model and selection of the double differences (zero-difference zenith sigmas, m; times, s)."""

    phase_sigma_m: float = 0.003
    code_sigma_m: float = 0.3
    phase_corr_s: float = 10.0        # correlation time of the time-correlated share of the phase errors
    code_corr_s: float = 30.0         # the same for the code errors (multipath)
    phase_corr_share: float = 0.64    # share of the variance that is time-correlated (the rest is white)
    code_corr_share: float = 0.75
    elev_mask_deg: float = 10.0
    use_code: bool = True
    use_phase: bool = True
    iono_ppm: float = 0.5             # differential ionosphere (mm per km from the base, slant at 1/sin el)
    tropo_zenith_m: float = 0.0015    # rover zenith troposphere error left by the model
    max_frac_cycles: float = 0.2      # a vote is accepted when within this of its integer
    min_votes: int = 2                # fixed epochs needed to tie two arcs
    min_agree: float = 0.9            # share of the votes of a tie that must agree


@dataclass
class ArcIntegers:
    """Integer offsets of phase arcs: ``root[(i, f, arc)]`` is the arc's component (another arc key) and
    ``offset[(i, f, arc)]`` its SD ambiguity minus the root's (cycles, integer); statistics in ``info``."""

    root: dict
    offset: dict
    info: dict = field(default_factory=dict)
    comp_root: dict = field(default_factory=dict)     # component root -> super-component (systems linked)
    comp_offset_m: dict = field(default_factory=dict)  # component root -> its constant minus the super root's (m)

    def dd(self, a: tuple, b: tuple) -> int | None:
        """N_a - N_b (cycles) if both arcs are in one component, else None."""
        ra, rb = self.root.get(a), self.root.get(b)
        if ra is None or ra != rb:
            return None
        return int(self.offset[a] - self.offset[b])

    def super_root(self, a: tuple):
        """The super-component of an arc (components of several systems linked by their offsets), or None."""
        r = self.root.get(a)
        return None if r is None else self.comp_root.get(r, r)

    def metres(self, a: tuple, lam: float) -> float:
        """The arc's constant relative to its super-component (m): lam * integer offset + component offset."""
        r = self.root[a]
        return lam * self.offset[a] + self.comp_offset_m.get(r, 0.0)


class _UnionFind:
    """Weighted union-find: value(x) - value(root(x)) is kept for every element."""

    def __init__(self):
        self.parent: dict = {}
        self.off: dict = {}

    def find(self, x):
        if x not in self.parent:
            self.parent[x], self.off[x] = x, 0
            return x, 0
        path, o = [], 0
        y = x
        while self.parent[y] != y:
            path.append(y)
            y = self.parent[y]
        root = y
        acc = 0
        for z in reversed(path):        # path compression with accumulated offsets
            acc += self.off[z]
            self.off[z] = acc
            self.parent[z] = root
        o = self.off[x] if x != root else 0
        return root, o

    def union(self, a, b, d, tol: float = 0.0) -> bool:
        """Record value(a) - value(b) = d; False if it contradicts what is known (beyond `tol`)."""
        ra, oa = self.find(a)
        rb, ob = self.find(b)
        if ra == rb:
            return abs(oa - ob - d) <= tol
        # value(ra) - value(rb) = (value(a) - oa) - (value(b) - ob) = d - oa + ob
        self.parent[ra] = rb
        self.off[ra] = d - oa + ob
        return True


def arc_integers(pair: CarrierPair, res: PpkResult, opts: DDOptions | None = None) -> ArcIntegers:
    """Integer SD ambiguity offsets of the phase arcs, from the epochs PPK fixed (see the module docstring)."""
    o = opts or DDOptions()
    arcs = pair.arcs()
    votes: dict = {}
    mask = np.radians(o.elev_mask_deg)
    kept: list = []                                                       # (epoch, sd cycles, usable)
    for k in np.nonzero(res.status == 3)[0]:
        j = int(pair.jb[k])
        if j < 0 or not np.all(np.isfinite(res.p[k])):
            continue
        zr, zb = pair.rover_zd(int(k), res.p[k], reuse_within_m=10.0), pair.base_zd(j)
        # the model of the PPK pass, moved from where it was made to the fixed position (geometry only)
        d_rho = (np.linalg.norm(zr.sat_pos - zr.extra["p_rx"], axis=1) - np.linalg.norm(zr.sat_pos - res.p[k], axis=1))
        sd = (zr.omc_phase - zb.omc_phase + d_rho[:, None]) / pair.lam   # cycles (m, F)
        ok = np.isfinite(sd) & (zr.elev >= mask)[:, None]
        kept.append((int(k), sd, ok))
        for f in range(pair.F):
            for s in np.unique(pair.system):
                mem = np.nonzero(ok[:, f] & (pair.system == s))[0]
                if len(mem) < 2:
                    continue
                ref = int(mem[np.argmax(zr.elev[mem])])
                for i in mem:
                    if i == ref:
                        continue
                    key = ((int(i), f, int(arcs[k, i, f])), (ref, f, int(arcs[k, ref, f])))
                    votes.setdefault(key, []).append(sd[i, f] - sd[ref, f])
    uf = _UnionFind()
    ties = []
    rejected = 0
    for key, v in votes.items():
        v = np.asarray(v)
        n = int(np.round(np.median(v)))
        good = np.abs(v - n) <= o.max_frac_cycles
        if len(v) >= o.min_votes and good.mean() >= o.min_agree:
            ties.append((len(v), key, n))
        else:
            rejected += 1
    conflicts = 0
    for _, (a, b), n in sorted(ties, key=lambda x: -x[0]):
        if not uf.union(a, b, n):
            conflicts += 1
    root, offset = {}, {}
    for x in list(uf.parent):
        r, off = uf.find(x)
        root[x], offset[x] = r, off
    n_comp = len(set(root.values()))
    comp_root, comp_off, n_links = _component_offsets(pair, arcs, kept, root, offset, o)
    return ArcIntegers(root, offset, {"pairs_voted": len(votes), "pairs_tied": len(ties), "pairs_rejected": rejected,
                                      "conflicts": conflicts, "arcs": len(root), "components": n_comp,
                                      "inter_system_links": n_links,
                                      "fixed_epochs_used": int(np.sum(res.status == 3))},
                       comp_root, comp_off)


def _component_offsets(pair: CarrierPair, arcs, kept, root: dict, offset: dict, o: DDOptions):
    """Offsets (m) between integer components of different systems on the same slot, from PPK's fixed epochs.

    Per fixed epoch and component the arcs' single differences less their integer offsets, in metres, all equal
    c dt + lam N_root + receiver phase bias (geometry removed at the fixed position); two components of one slot
    differ by a constant (inter-system phase bias and root ambiguities). Links whose votes scatter by less than
    `max_frac_cycles` (in L1 cycles, ~4 cm) join components into super-components (real-valued union-find).
    """
    votes: dict = {}
    for k, sd, ok in kept:
        for f in range(pair.F):
            q: dict = {}
            for i in np.nonzero(ok[:, f])[0]:
                a = (int(i), f, int(arcs[k, i, f]))
                r = root.get(a)
                if r is not None:
                    q.setdefault(r, []).append((sd[i, f] - offset[a]) * pair.lam[i, f])
            comps = sorted(q, key=lambda r: -len(q[r]))
            med: dict = {}                                                # each component's median, once
            for a_ in range(len(comps)):
                for b_ in range(a_ + 1, len(comps)):
                    ra, rb = comps[a_], comps[b_]
                    if pair.system[ra[0]] == pair.system[rb[0]]:
                        continue                                          # same system: integers or nothing
                    for r in (ra, rb):
                        if r not in med:
                            med[r] = np.median(q[r])
                    votes.setdefault((ra, rb), []).append(med[ra] - med[rb])
    uf = _UnionFind()
    tol = o.max_frac_cycles * 0.19
    links = 0
    for (ra, rb), v in sorted(votes.items(), key=lambda kv: -len(kv[1])):
        v = np.asarray(v)
        med = float(np.median(v))
        good = np.abs(v - med) <= tol
        if len(v) >= o.min_votes and good.mean() >= o.min_agree and uf.union(ra, rb, float(np.mean(v[good])), tol):
            links += 1
    comp_root, comp_off = {}, {}
    for r in set(root.values()):
        sr, off = uf.find(r)
        comp_root[r], comp_off[r] = sr, float(off)
    return comp_root, comp_off, links


@dataclass
class DDEpoch:
    """The double differences of one rover epoch (see the module docstring); per row: ``kind`` 0 phase, 1 code;
    ``mode`` 0 absolute (phase with a known integer, code), 1 float phase (unknown constant ambiguity: usable
    only as a difference between consecutive epochs of its track); ``sat``, ``ref`` satellite indices into the
    pair's list, ``slot``/``ref_slot``; ``z`` (m), ``sat_pos``/``ref_pos`` (ECEF m, at the rover's reception);
    ``var_sat``/``var_ref`` zero-difference variances summed over both receivers (m^2); ``group``: rows that
    share the reference observation (their errors share var_ref); ``track``: a key that is the same at
    consecutive epochs for the same pair of arcs; ``kappa`` (f_L1/f)^2, ``map_sat``/``map_ref`` 1/sin(el) and
    ``base_dist_m`` (horizontal rover-base distance) for the differential-atmosphere budget."""

    k: int
    t_gps: float
    kind: np.ndarray
    mode: np.ndarray
    sat: np.ndarray
    ref: np.ndarray
    slot: np.ndarray
    ref_slot: np.ndarray
    z: np.ndarray
    sat_pos: np.ndarray
    ref_pos: np.ndarray
    var_sat: np.ndarray
    var_ref: np.ndarray
    group: np.ndarray
    track: list
    elev: np.ndarray
    kappa: np.ndarray
    kappa_ref: np.ndarray
    map_sat: np.ndarray
    map_ref: np.ndarray
    base_dist_m: float = 0.0

    @property
    def n(self) -> int:
        """Number of double differences."""
        return len(self.z)

    def covariance(self) -> np.ndarray:
        """Covariance (n,n) m^2 of the rows' noise: shared reference within a group, independent across groups."""
        same = self.group[:, None] == self.group[None, :]
        return np.where(same, self.var_ref[:, None], 0.0) + np.diag(self.var_sat)

    def atmosphere_covariance(self, iono_ppm: float, tropo_zenith_m: float) -> np.ndarray:
        """Covariance (n,n) m^2 of the rows' differential-atmosphere errors: a slant ionosphere error per satellite
        of `iono_ppm` mm per km of distance from the base (times 1/sin el, scaled (f_L1/f)^2, opposite on
        phase and code) and one rover zenith troposphere error `tropo_zenith_m` (times 1/sin el)."""
        if self.n == 0:
            return np.zeros((0, 0))
        used = np.zeros(max(int(self.sat.max()), int(self.ref.max())) + 1, bool)
        used[self.sat] = True
        used[self.ref] = True
        col = np.cumsum(used) - 1                        # the satellites of the rows, ascending: their columns
        n_sat = int(col[-1]) + 1
        col_sat, col_ref = col[self.sat], col[self.ref]
        B = np.zeros((self.n, n_sat + 1))
        sgn = np.where(self.kind == 0, -1.0, 1.0)
        rows = np.arange(self.n)
        B[rows, col_sat] += sgn * self.kappa
        B[rows, col_ref] -= sgn * self.kappa_ref
        B[:, -1] = self.map_sat - self.map_ref
        m = np.empty(n_sat)                              # each satellite's 1/sin(el), the same in all its rows
        m[col_ref] = self.map_ref
        m[col_sat] = self.map_sat
        var = np.append((iono_ppm * 1e-6 * self.base_dist_m * m) ** 2, tropo_zenith_m ** 2)
        return (B * var) @ B.T

    def subset(self, keep: np.ndarray) -> "DDEpoch":
        """The rows selected by a boolean mask."""
        idx = np.nonzero(keep)[0]
        kw = {name: (val[idx] if isinstance(val, np.ndarray) else val) for name, val in self.__dict__.items()}
        kw["track"] = [self.track[i] for i in idx]
        return DDEpoch(**kw)


def _persistent_ref(prev_ref: dict, key, members, elev) -> int:
    """The previous epoch's reference of `key` if still among `members`, else the highest member."""
    ref = prev_ref.get(key)
    if ref is None or ref not in members:
        ref = int(members[np.argmax(elev[members])])
    prev_ref[key] = ref
    return ref


def dd_epochs(pair: CarrierPair, amb: ArcIntegers | None, p_lin: np.ndarray, opts: DDOptions | None = None
              ) -> list[DDEpoch | None]:
    """Double differences of every rover epoch (None without a base epoch or a usable row), modelled at
    ``p_lin`` (N,3) ECEF m (e.g. the PPK or SPP positions).

    Phase, per frequency slot: the arcs of the largest super-component (integers within a system, calibrated
    offsets between systems, `arc_integers`) are absolute rows against a reference kept from epoch to epoch; every
    other arc is a float row (mode 1) against that reference, or, without one, against the highest arc of the
    slot (a time difference cancels the unknown ambiguities and inter-system biases alike). Code: absolute rows
    per system and slot.
    """
    o = opts or DDOptions()
    arcs = pair.arcs()
    mask = np.radians(o.elev_mask_deg)
    kappa_all = (1575.42e6 / pair.freq) ** 2
    out: list[DDEpoch | None] = []
    prev_ref: dict = {}
    systems = list(dict.fromkeys(pair.system))
    R_ecef_to_enu_base = R_ecef_to_enu_at(pair.base_pos)
    for k in range(len(pair.t)):
        j = int(pair.jb[k])
        x0 = p_lin[k]
        if j < 0 or not np.all(np.isfinite(x0)):
            out.append(None)
            continue
        zr, zb = pair.rover_zd(k, x0, reuse_within_m=1.0), pair.base_zd(j)
        x0 = zr.extra["p_rx"]                  # the point it was modelled at (z hardly depends on it)
        rho = np.linalg.norm(zr.sat_pos - x0, axis=1)
        mapping = 1.0 / np.sin(np.maximum(np.nan_to_num(zr.elev), np.radians(3.0)))
        rows: list[tuple] = []          # (kind, mode, sat, ref, slot, ref_slot, z, track)
        for kind, use in ((0, o.use_phase), (1, o.use_code)):
            if not use:
                continue
            sd = (zr.omc_phase - zb.omc_phase) if kind == 0 else (zr.omc_code - zb.omc_code)
            ok = (np.isfinite(sd) & np.isfinite(pair.lam) & (zr.elev >= mask)[:, None]
                  & (zb.elev >= mask)[:, None])
            for f in range(pair.F):
                if kind == 1:
                    for s in systems:
                        mem = np.nonzero(ok[:, f] & (pair.system == s))[0]
                        if len(mem) < 2:
                            continue
                        ref = _persistent_ref(prev_ref, (1, s, f), mem, zr.elev)
                        for i in mem:
                            if i != ref:
                                rows.append((1, 0, int(i), ref, f, f, sd[i, f] - sd[ref, f] + rho[i] - rho[ref],
                                             (1, int(i), ref, f)))
                    continue
                mem = np.nonzero(ok[:, f])[0]
                if len(mem) < 2:
                    continue
                keys = {int(i): (int(i), f, int(arcs[k, i, f])) for i in mem}
                groups: dict = {}
                if amb is not None:
                    for i, a_ in keys.items():
                        sr = amb.super_root(a_)
                        if sr is not None:
                            groups.setdefault(sr, []).append(i)
                fixed = np.array(max(groups.values(), key=len)) if groups else np.array([], int)
                if len(fixed) >= 2:
                    ref = _persistent_ref(prev_ref, (0, f), fixed, zr.elev)
                    q_ref = sd[ref, f] - amb.metres(keys[ref], pair.lam[ref, f])
                    for i in fixed:
                        if i == ref:
                            continue
                        z = sd[i, f] - amb.metres(keys[int(i)], pair.lam[i, f]) - q_ref + rho[i] - rho[ref]
                        rows.append((0, 0, int(i), ref, f, f, z, (0, int(i), ref, f, keys[int(i)][2], keys[ref][2])))
                    in_fixed = set(fixed.tolist())
                    floats = [int(i) for i in mem if int(i) not in in_fixed]
                else:
                    floats = [int(i) for i in mem]
                    ref = _persistent_ref(prev_ref, (2, f), np.array(floats), zr.elev)
                # arcs without a known constant: float rows against the slot's reference (time differences only)
                for i in floats:
                    if i == ref:
                        continue
                    z = sd[i, f] - sd[ref, f] + rho[i] - rho[ref]
                    rows.append((0, 1, i, ref, f, f, z, (2, i, ref, f, keys[i][2], keys[ref][2])))
        if not rows:
            out.append(None)
            continue
        kind, mode, sat, ref, slot, ref_slot, z, track = (list(c) for c in zip(*rows))
        gkey = {}
        group = np.array([gkey.setdefault((kd, r, rf), len(gkey)) for kd, r, rf in zip(kind, ref, ref_slot)])
        sat, ref, slot, ref_slot = np.array(sat), np.array(ref), np.array(slot), np.array(ref_slot)
        kind = np.array(kind)
        s0 = np.where(kind == 0, o.phase_sigma_m, o.code_sigma_m)
        var_sat = zd_var(s0, zr.elev[sat]) + zd_var(s0, zb.elev[sat])
        var_ref = zd_var(s0, zr.elev[ref]) + zd_var(s0, zb.elev[ref])
        d = R_ecef_to_enu_base @ (x0 - pair.base_pos)
        out.append(DDEpoch(k=k, t_gps=float(pair.t[k]), kind=kind, mode=np.array(mode), sat=sat, ref=ref, slot=slot,
                           ref_slot=ref_slot, z=np.array(z, float), sat_pos=zr.sat_pos[sat].copy(),
                           ref_pos=zr.sat_pos[ref].copy(), var_sat=var_sat, var_ref=var_ref, group=group,
                           track=track, elev=zr.elev[sat].copy(), kappa=kappa_all[sat, slot],
                           kappa_ref=kappa_all[ref, ref_slot], map_sat=mapping[sat], map_ref=mapping[ref],
                           base_dist_m=float(np.hypot(d[0], d[1]))))
    return out


@dataclass
class CarrierInput:
    """Double differences for the smoother: one `DDEpoch` (or None) per rover epoch at `t_gps` (GPS s), and
    the time-correlation model of the phase and code errors, (tau s, share) each."""

    t_gps: np.ndarray
    epochs: list
    phase_corr: tuple = (10.0, 0.64)
    code_corr: tuple = (30.0, 0.75)
    atmosphere: tuple = (0.5, 0.0015)  # (iono ppm, tropo zenith m) of the position-covariance budget

    def at(self, t_key: np.ndarray) -> list:
        """The DDEpoch of every keyframe (None where there is none within 1 ms)."""
        if len(self.t_gps) == 0:
            return [None] * len(t_key)
        j = np.clip(np.searchsorted(self.t_gps, t_key - 1e-3), 0, len(self.t_gps) - 1)
        return [self.epochs[i] if abs(self.t_gps[i] - t) < 1e-3 else None for i, t in zip(j, t_key)]


@dataclass
class CarrierFrontEnd:
    """The carrier-phase front end of the TC smoother: the PPK run (forward and/or backward), the arcs' integers
    and the double differences of every rover epoch (`input`)."""

    ppk: PpkResult
    integers: ArcIntegers
    input: CarrierInput
    info: dict = field(default_factory=dict)


def _fixed_phase_epochs(epochs: list) -> int:
    """Rover epochs with at least one double-difference phase row of known integers."""
    return int(sum(e is not None and bool(np.any((e.kind == 0) & (e.mode == 0))) for e in epochs))


def imu_aided_front_end(fe: CarrierFrontEnd, t_gps: np.ndarray, p_ecef: np.ndarray, sigma_3d_m: np.ndarray,
                        dd_opts: DDOptions | None = None, max_sigma_m: float = 0.015) -> CarrierFrontEnd | None:
    """IMU-aided integers: the arcs' integers voted again with the smoother's antenna positions (`t_gps` s, ECEF m,
    3D sigma m) as fixed positions wherever PPK stayed float and the smoother knows the antenna within
    `max_sigma_m` (a tenth of a wavelength: the IMU carries the position through what PPK alone could not fix).
    Returns the front end with the new integers and double differences (modelled at those positions), or None
    when no arc gained an integer."""
    o = dd_opts or DDOptions()
    if fe.integers is None or not o.use_phase:
        return None
    res, pair = fe.ppk, fe.ppk.pair
    j = np.clip(np.searchsorted(t_gps, pair.t - 1e-3), 0, max(len(t_gps) - 1, 0))
    near = (np.abs(t_gps[j] - pair.t) < 1e-3) if len(t_gps) else np.zeros(len(pair.t), bool)
    add = near & (res.status < 3) & (sigma_3d_m[j] < max_sigma_m) & np.all(np.isfinite(p_ecef[j]), axis=1)
    if not add.any():
        return None
    status, p = res.status.copy(), res.p.copy()
    status[add], p[add] = 3, p_ecef[j[add]]
    amb = arc_integers(pair, replace(res, status=status, p=p), o)
    if len(amb.root) <= len(fe.integers.root) or amb.info["conflicts"] > fe.integers.info["conflicts"]:
        return None
    # modelled at the smoother's antenna (PPK's position elsewhere: epochs the smoother does not use)
    p_lin = np.where(near[:, None], p_ecef[j], res.p)
    epochs = dd_epochs(pair, amb, p_lin, o)
    info = {**fe.info, "imu_aided": {"epochs": int(add.sum()), "arcs_before": len(fe.integers.root),
                                     "arcs_after": len(amb.root)}, "integers": amb.info,
            "epochs_with_fixed_phase": _fixed_phase_epochs(epochs)}
    ci = CarrierInput(pair.t.copy(), epochs, fe.input.phase_corr, fe.input.code_corr, fe.input.atmosphere)
    return CarrierFrontEnd(res, amb, ci, info)


def carrier_front_end(rover: CarrierObs, base: CarrierObs, nav, base_ecef, p_approx: tuple[np.ndarray, np.ndarray],
                      ppk_opts: PpkOptions | None = None, dd_opts: DDOptions | None = None,
                      p_init=None) -> CarrierFrontEnd:
    """PPK of the rover against the base (`dgcal.pos.gnss.ppk.ppk`), the integer of every phase arc from its fixed
    epochs (`arc_integers`) and the double differences of every rover epoch modelled at the PPK position (float
    or fixed) or else at `p_approx` = (t GPS s, ECEF m (N,3)) interpolated (e.g. SPP)."""
    o = dd_opts or DDOptions()
    po = ppk_opts or PpkOptions()
    t0 = time.perf_counter()
    res = ppk(rover, base, nav, base_ecef, po, p_init=p_init)
    t_ppk = time.perf_counter() - t0
    pair = res.pair
    amb = arc_integers(pair, res, o) if o.use_phase else None
    t_a, p_a = p_approx
    p_lin = np.column_stack([np.interp(pair.t, t_a, p_a[:, j]) for j in range(3)]) if len(t_a) else \
        np.full((len(pair.t), 3), np.nan)
    # PPK's fixed positions, and its floats when they are good to a metre (with three satellites its kinematic
    # float can be anywhere): the double differences hardly depend on the point they are modelled at
    tr = np.trace(np.nan_to_num(res.P, nan=np.inf), axis1=1, axis2=2)
    good = ((res.status == 3) | ((res.status == 2) & (tr < 1.0))) & np.all(np.isfinite(res.p), axis=1)
    p_lin[good] = res.p[good]
    t1 = time.perf_counter()
    epochs = dd_epochs(pair, amb, p_lin, o)
    info = {"ppk_s": round(t_ppk, 2), "dd_s": round(time.perf_counter() - t1, 2),
            "integers": amb.info if amb is not None else None,
            "epochs_with_dd": int(sum(e is not None for e in epochs)),
            "epochs_with_phase": int(sum(e is not None and bool(np.any(e.kind == 0)) for e in epochs)),
            "epochs_with_fixed_phase": _fixed_phase_epochs(epochs)}
    ci = CarrierInput(pair.t.copy(), epochs, (o.phase_corr_s, o.phase_corr_share), (o.code_corr_s, o.code_corr_share),
                      (o.iono_ppm, o.tropo_zenith_m))
    return CarrierFrontEnd(res, amb, ci, info)
