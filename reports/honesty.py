"""The honesty table of every report: where a reference exists (a known position, withheld fixes, check points, a
simulation's truth), each quantity's errors against the sigmas the run claimed — n, RMS error, median sigma, RMS
and maximum of |error|/sigma and a verdict — and a line saying so where no reference exists.

The rows are plain dictionaries (the JSON summaries' `honesty` key: `{"rows": [...], "notes": [...]}`); this module
imports NumPy only, so a process that writes a summary without a report (`dgcal pos --mode spp --no-report`) never
imports matplotlib. `add_honesty` writes the section into a dgcal.reports.html.HtmlReport (duck-typed: heading,
table, text), `honesty_html` as an HTML fragment for the pages built as strings."""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

HONEST_RMS = (0.7, 1.4)   # error/sigma RMS of honest sigmas (1 expected)
HONEST_MAX = 5.0          # no |error|/sigma at or beyond this
FEW_VALUES = 10           # below this many values a verdict is weak (the RMS of n honest ratios scatters widely)

VERDICTS = ("honest", "sigmas too small", "sigmas too large")
TITLE = "Honesty: errors against their sigmas"
HEADER = ("reference", "quantity", "n", "RMS error", "median sigma", "error/sigma RMS", "max |error|/sigma",
          "verdict")   # the RMS error and median sigma carry their unit in each cell (rows of different units)
LEGEND = (f"error/sigma is each error divided by the sigma the run claimed for it: honest sigmas give an RMS near 1 "
          f"({HONEST_RMS[0]}–{HONEST_RMS[1]} is taken as honest) and no value beyond {HONEST_MAX:g}; above "
          f"{HONEST_RMS[1]} (or a value beyond {HONEST_MAX:g}) the sigmas are too small, below {HONEST_RMS[0]} too "
          f"large. With fewer than {FEW_VALUES} values a verdict is weak.")


def verdict(z_rms: float, z_max: float) -> str:
    """'honest' when the RMS of error/sigma is within HONEST_RMS and its largest magnitude below HONEST_MAX,
    'sigmas too small' when the RMS is above the band or a value reaches HONEST_MAX, else 'sigmas too large'."""
    if z_rms > HONEST_RMS[1] or z_max >= HONEST_MAX:
        return "sigmas too small"
    if z_rms < HONEST_RMS[0]:
        return "sigmas too large"
    return "honest"


def honesty_rows(errors, sigmas, names: Sequence[str], reference: str = "", unit: str = "m") -> list[dict]:
    """One row per column of `errors` (n,k) against `sigmas` (n,k) (or (k,): the same for every value), named by
    `names`: n, RMS error, median sigma, RMS and max of |error|/sigma, verdict. Values whose error or sigma is not
    finite, or whose sigma is not positive, are left out; a column with none left gives no row. `reference` names
    what the errors are measured against, `unit` the unit of errors and sigmas. 1-D errors and sigmas (n,) are one
    quantity."""
    e, s = np.asarray(errors, float), np.asarray(sigmas, float)
    if e.ndim == 1:                      # one quantity: errors and sigmas are its values
        e, s = e[:, None], (s[:, None] if s.ndim == 1 else s)
    s = np.broadcast_to(s, e.shape)
    if len(names) != e.shape[1]:
        raise ValueError(f"{len(names)} names for {e.shape[1]} columns of errors")
    rows = []
    for j, name in enumerate(names):
        ok = np.isfinite(e[:, j]) & np.isfinite(s[:, j]) & (s[:, j] > 0)
        if not ok.any():
            continue
        ej, sj = e[ok, j], s[ok, j]
        z = np.abs(ej / sj)
        z_rms, z_max = float(np.sqrt(np.mean(z ** 2))), float(np.max(z))
        rows.append({"reference": reference, "quantity": str(name), "unit": unit, "n": int(ok.sum()),
                     "rms_error": float(np.sqrt(np.mean(ej ** 2))), "median_sigma": float(np.median(sj)),
                     "error_over_sigma_rms": z_rms, "max_abs_error_over_sigma": z_max,
                     "verdict": verdict(z_rms, z_max)})
    return rows


def combined_sigma(*sigmas) -> np.ndarray:
    """The root sum of squares of independent sigmas (broadcast; a missing one, None, counts as 0)."""
    return np.sqrt(sum(np.square(np.asarray(s, float)) for s in sigmas if s is not None))


def honesty_section(rows: Iterable[dict], notes: Iterable[str] = ()) -> dict:
    """The `honesty` record of a JSON summary: its rows and the lines that go with them (what each reference is,
    what the sigmas include)."""
    return {"rows": list(rows), "notes": [n for n in notes if n]}


def no_reference(why: str) -> dict:
    """The `honesty` record of a run with nothing to compare with: no rows, the line saying so."""
    return honesty_section([], [why])


def merge_sections(sections: Iterable[dict | None], prefixes: Iterable[str] | None = None) -> dict:
    """Several `honesty` records as one (the campaign's): rows and notes in order; with `prefixes`, each record's
    references and notes start with its prefix (e.g. the step's name)."""
    rows, notes = [], []
    sections = list(sections)
    prefixes = list(prefixes) if prefixes is not None else [""] * len(sections)
    for sec, pre in zip(sections, prefixes):
        if not sec:
            continue
        lead = f"{pre}: " if pre else ""
        rows += [{**r, "reference": f"{lead}{r['reference']}" if r.get("reference") else pre} for r in sec["rows"]]
        notes += [f"{lead}{n}" for n in sec.get("notes", [])]
    return honesty_section(rows, notes)


def _num(v: float, unit: str = "") -> str:
    """A number with its unit at the unit's resolution (dgcal.reports.units; NumPy only, like this module)."""
    from dgcal.reports.units import with_unit
    return "–" if v is None or not np.isfinite(v) else with_unit(v, unit)


def table_rows(section: dict) -> list[list[str]]:
    """The rows of the honesty table as text (the HEADER's columns); a verdict on few values says so."""
    out = []
    for r in section["rows"]:
        v = r["verdict"] + (f" (only {r['n']} value{'s' if r['n'] != 1 else ''})" if r["n"] < FEW_VALUES else "")
        out.append([r.get("reference", ""), r["quantity"], str(r["n"]), _num(r["rms_error"], r["unit"]),
                    _num(r["median_sigma"], r["unit"]), f"{r['error_over_sigma_rms']:.2f}",
                    f"{r['max_abs_error_over_sigma']:.2f}", v])
    return out


def add_honesty(rep, section: dict | None, heading: str | None = TITLE, level: int = 2):
    """Write the honesty section into a report `rep` (dgcal.reports.html.HtmlReport): a heading (None: none), the
    table and its legend when there are rows, then the section's notes (the line that no reference exists, when
    none does). A missing section (None) reads as no reference. Returns `rep`."""
    if section is None:
        section = no_reference("No reference: nothing to compare the results with.")
    if heading:
        rep.heading(heading, level)
    if section["rows"]:
        rep.table(HEADER, table_rows(section))
        rep.text(LEGEND, cls="small")
    for note in section.get("notes", []):
        rep.text(note, cls="small" if section["rows"] else None)
    return rep


def honesty_html(section: dict | None, heading: str | None = TITLE, level: int = 2) -> str:
    """The honesty section as an HTML fragment: what `add_honesty` writes into an HtmlReport, for a page built
    as a string."""
    from dgcal.reports.html import HtmlReport   # why: matplotlib only for pages (this module stays NumPy only)
    rep = add_honesty(HtmlReport(""), section, heading, level)
    return "\n".join(p for p in rep.parts if isinstance(p, str))   # as HtmlReport.render joins them
