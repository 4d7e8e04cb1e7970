"""The double-difference measurement model of one PPK epoch, compiled (numba): rows, design matrix, covariance.

`dgcal.pos.gnss.ppk` forms, every epoch and every relinearisation, double differences per system and frequency
slot against a reference satellite; built row by row from Python (or from ~50 small NumPy calls) that was a
large share of an epoch's time. `dd_rows` picks the groups and rows, `dd_system` fills y, H, R; their order and
arithmetic are those of the filter's docstring (`dgcal.pos.gnss.ppk`): per group of two satellites or more its
phase rows, then its code rows. Satellites, slots and states are indices as in `ppk._Pass` (state ``amb0 + i*F + f``
is the SD ambiguity of satellite i, slot f, cycles); metres, seconds, radians.
"""
from __future__ import annotations

import numpy as np
from numba import njit

NK = 6          # the kinematic states before the ambiguities: position, velocity (ECEF m, m/s)


@njit(cache=True)
def dd_rows(valid: np.ndarray, sys_id: np.ndarray, n_sys: int, score: np.ndarray, drop_code: np.ndarray):
    """Groups and rows of the double differences of one epoch.

    Groups: per system (`sys_id` 0..n_sys-1, in that order) and slot, the `valid` (m,F) satellites when two or
    more; the reference is the first with the highest `score` (m,F). Rows, group by group: phase of every other
    member (ascending), then code of those not in `drop_code` (m,F). Returns per row (phase, sat, ref, slot,
    block: rows sharing their reference observation) and per group (system, slot, reference).
    """
    m, F = valid.shape
    cap = 2 * m * F
    phase = np.zeros(cap, np.bool_)
    sat = np.zeros(cap, np.int64)
    ref = np.zeros(cap, np.int64)
    slot = np.zeros(cap, np.int64)
    block = np.zeros(cap, np.int64)
    g_sys = np.zeros(n_sys * F, np.int64)
    g_slot = np.zeros(n_sys * F, np.int64)
    g_ref = np.zeros(n_sys * F, np.int64)
    nr, ng, nb = 0, 0, 0
    for s in range(n_sys):
        for f in range(F):
            count, best = 0, -1
            for i in range(m):
                if valid[i, f] and sys_id[i] == s:
                    count += 1
                    if best < 0 or score[i, f] > score[best, f]:
                        best = i
            if count < 2:
                continue
            g_sys[ng], g_slot[ng], g_ref[ng] = s, f, best
            ng += 1
            for is_phase in (True, False):
                start = nr
                for i in range(m):
                    if valid[i, f] and sys_id[i] == s and i != best and (is_phase or not drop_code[i, f]):
                        phase[nr], sat[nr], ref[nr], slot[nr], block[nr] = is_phase, i, best, f, nb
                        nr += 1
                if nr > start:
                    nb += 1
    return phase[:nr], sat[:nr], ref[:nr], slot[:nr], block[:nr], g_sys[:ng], g_slot[:ng], g_ref[:ng]


def zd_var(sigma0, elev):
    """Zero-difference variance (m^2) at elevation `elev` (rad) for the zenith sigma `sigma0` (m),
    ``sigma0^2 (1/2 + 1/(2 sin^2 el))`` with the elevation floored at 2 degrees: numbers or NumPy arrays (the
    smoother's double differences, `dgcal.pos.gnss.dd`); the kernels below call its compiled form `_zd_var`."""
    s = np.sin(np.maximum(elev, np.radians(2.0)))
    return sigma0 ** 2 * (0.5 + 0.5 / (s * s))


_zd_var = njit(cache=True)(zd_var)


@njit(cache=True)
def dd_system(phase, sat, ref, slot, block, los, sd_phase, sd_code, lam, elev_rover, elev_base, sigma_phase,
              sigma_code, code_factor, x0, n_state, amb0, iono0, kappa):
    """y (m), H and R of the rows of `dd_rows`: ``y = DD(omc) + (e_r - e_i).x0`` (the state-independent part, the
    model is H x), H rows ``[e_r - e_i, lam (N_i - N_r) if phase, -+kappa (I_i - I_r)]`` (ambiguities from state
    `amb0`, ``amb0 + i*F + f``; the slant single-difference ionosphere at L1 of satellite i at state ``iono0 + i``,
    scaled by ``kappa[i, f] = (f_L1/f)^2``, - on phase, + on code; iono0 < 0: none) and R the covariance of the
    differencing of zero-difference errors at both receivers (`zd_var` of the zenith sigmas, rover and base
    elevations), shared by the rows of a block; the code variance of satellite i, slot f times
    ``code_factor[i, f]``."""
    nr = len(sat)
    F = lam.shape[1]
    y = np.empty(nr)
    H = np.zeros((nr, n_state))
    v_ref = np.empty(nr)
    v_sat = np.empty(nr)
    for q in range(nr):
        i, r, f = sat[q], ref[q], slot[q]
        g0, g1, g2 = los[r, 0] - los[i, 0], los[r, 1] - los[i, 1], los[r, 2] - los[i, 2]
        H[q, 0], H[q, 1], H[q, 2] = g0, g1, g2
        sign = -1.0 if phase[q] else 1.0
        if iono0 >= 0:
            H[q, iono0 + i] = sign * kappa[i, f]
            H[q, iono0 + r] = -sign * kappa[r, f]
        if phase[q]:
            d = sd_phase[i, f] - sd_phase[r, f]
            H[q, amb0 + i * F + f] = lam[i, f]
            H[q, amb0 + r * F + f] = -lam[r, f]
            v_ref[q] = _zd_var(sigma_phase, elev_rover[r]) + _zd_var(sigma_phase, elev_base[r])
            v_sat[q] = _zd_var(sigma_phase, elev_rover[i]) + _zd_var(sigma_phase, elev_base[i])
        else:
            d = sd_code[i, f] - sd_code[r, f]
            v_ref[q] = _zd_var(sigma_code, elev_rover[r]) + _zd_var(sigma_code, elev_base[r])
            v_sat[q] = (_zd_var(sigma_code, elev_rover[i]) + _zd_var(sigma_code, elev_base[i])) * code_factor[i, f]
        y[q] = d + (g0 * x0[0] + g1 * x0[1] + g2 * x0[2])
    R = np.zeros((nr, nr))
    for a in range(nr):
        for b in range(nr):
            if block[a] == block[b]:
                R[a, b] = v_ref[a]
        R[a, a] += v_sat[a]
    return y, H, R
