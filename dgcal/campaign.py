"""`dgcal run CAMPAIGN.toml`: the calibration chain camera -> triangulation -> POS -> mounting -> DG check.

Each step is a dgcal verb run with arguments built from the campaign file (docs/campaign.md). A step is
skipped when its fingerprint (its arguments and the contents of its input files) matches its last
successful run, its outputs are still there and no step before it that it depends on ran again; so an
interrupted or edited campaign resumes where it must. The run ends with the calibration report
(DIR/report.html, DIR/report.json).

Campaign file (TOML, paths relative to it)::

    crs = "EPSG:32651"
    truth = "truth.json"   # optional: a simulation's truth, compared in the report
    [camera]          # field, measurements + image_size | images, model; or camera_json (no step)
    [triangulation]   # gcp, measurements and/or images; or eop (no step)
    [pos]             # mode lc|tc, imu, events, gnss | rinex_obs + rinex_nav, imu_grade, lever_arm_gnss, set;
                      # or trajectory + events (an external POS, no step)
    [mount]           # method (proposed), compare = [more methods], measurements (for iso),
                      # pos_common_fraction (proposed, iso: share of the POS error common to the flight)
    [check]           # gcp, measurements, events, trajectory (a DG check flight; default: the calibration flight)
Every section may add `args = [...]`: extra arguments of its verb.
"""
from __future__ import annotations

import hashlib
import json
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from dgcal.fields.errors import InputError

STATE = ".dgcal-state.json"


@dataclass
class Step:
    """One verb of the chain: its argv, the files it reads, the files it must leave behind, the steps it follows."""

    name: str
    argv: list[str]
    inputs: list[Path]
    outputs: list[Path]
    after: list[str] = field(default_factory=list)

    def fingerprint(self) -> str:
        """SHA-256 of the argv and of the contents of every input file (folders: every file in them)."""
        h = hashlib.sha256(json.dumps(self.argv).encode())
        for p in self.inputs:
            p = Path(p)
            if p.is_dir():
                for q in sorted(p.rglob("*")):
                    if q.is_file():
                        h.update(str(q.relative_to(p)).encode())
                        _hash_file(h, q)
            elif p.is_file():
                h.update(p.name.encode())
                _hash_file(h, p)
            else:
                raise InputError(f"input of step {self.name} not found", p)
        return h.hexdigest()


def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)


def load_campaign(path: Path) -> dict:
    """The campaign TOML with paths made absolute; InputError naming the file on syntax errors."""
    path = Path(path)
    if not path.is_file():
        raise InputError("campaign file not found", path)
    try:
        cfg = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", path) from None
    cfg["_base"] = path.parent.resolve()
    cfg["_path"] = path.resolve()
    return cfg


def _p(cfg: dict, section: str, key: str, required: bool = True) -> Path | None:
    val = cfg.get(section, {}).get(key)
    if val is None:
        if required:
            raise InputError(f"[{section}] needs '{key}'", cfg["_path"], field=f"{section}.{key}")
        return None
    p = Path(val)
    return p if p.is_absolute() else cfg["_base"] / p


def plan(cfg: dict, out: Path) -> list[Step]:
    """The steps of a campaign, in order, with their dgcal arguments, input files and expected outputs."""
    out = Path(out)
    crs = cfg.get("crs")
    if not crs:
        raise InputError("the campaign needs a top-level 'crs'", cfg["_path"], field="crs")
    for sec in ("camera", "triangulation", "pos", "mount", "check"):
        if sec in cfg and not isinstance(cfg[sec], dict):
            raise InputError(f"'{sec}' must be a [{sec}] table", cfg["_path"], field=sec)
    steps: list[Step] = []
    cam, tri, pos, mnt, chk = (cfg.get(k) for k in ("camera", "triangulation", "pos", "mount", "check"))
    cam_json = _p(cfg, "camera", "camera_json", required=False) if cam else None
    if cam and cam_json is None:
        field_csv = _p(cfg, "camera", "field")
        a = ["camera", "--field", str(field_csv), "--model", str(cam.get("model", "fraser7")),
             "--out", str(out / "camera")]
        ins = [field_csv]
        if "images" in cam:
            a += ["--images", str(_p(cfg, "camera", "images"))]
            ins.append(_p(cfg, "camera", "images"))
        else:
            a += ["--measurements", str(_p(cfg, "camera", "measurements")), "--image-size",
                  *map(str, _size(cfg, "camera"))]
            ins.append(_p(cfg, "camera", "measurements"))
        a += [str(v) for v in cam.get("args", [])]
        steps.append(Step("camera", a, ins, [out / "camera" / "camera.json"]))
        cam_json = out / "camera" / "camera.json"
    eop = _p(cfg, "triangulation", "eop", required=False) if tri else None
    gcp = _p(cfg, "triangulation", "gcp", required=False) if tri else None
    tri_meas = _p(cfg, "triangulation", "measurements", required=False) if tri else None
    if tri and eop is None:
        if cam_json is None:
            raise InputError("[triangulation] needs a [camera] section or camera_json", cfg["_path"], field="camera")
        gcp = _p(cfg, "triangulation", "gcp")
        a = ["triangulate", "--camera", str(cam_json), "--gcp", str(gcp), "--crs", crs,
             "--out", str(out / "triangulation")]
        ins = [cam_json, gcp]
        if "images" in tri:
            a += ["--images", str(_p(cfg, "triangulation", "images"))]
            ins.append(_p(cfg, "triangulation", "images"))
        if tri_meas is not None:
            a += ["--measurements", str(tri_meas)]
            ins.append(tri_meas)
        if "images" not in tri and tri_meas is None:
            raise InputError("[triangulation] needs 'measurements' or 'images'", cfg["_path"],
                             field="triangulation.measurements")
        a += [str(v) for v in tri.get("args", [])]
        steps.append(Step("triangulate", a, ins, [out / "triangulation" / "eop.csv"], after=_names(steps)))
        eop = out / "triangulation" / "eop.csv"
    events = _p(cfg, "pos", "events", required=False) if pos else None
    traj = _p(cfg, "pos", "trajectory", required=False) if pos else None
    if pos and traj is None:
        mode = str(pos.get("mode", "lc"))
        if mode not in ("lc", "tc"):
            raise InputError(f"[pos] mode must be lc or tc, not {mode!r}", cfg["_path"], field="pos.mode")
        imu, events = _p(cfg, "pos", "imu"), _p(cfg, "pos", "events")
        a = ["pos", "--mode", mode, "--imu", str(imu), "--events", str(events), "--out", str(out / "pos"),
             "--no-progress"]
        ins = [imu, events]
        if mode == "lc" and "gnss" in pos:
            a += ["--gnss", str(_p(cfg, "pos", "gnss"))]
            ins.append(_p(cfg, "pos", "gnss"))
        elif "rinex_obs" in pos or mode == "tc":
            obs, nav = _p(cfg, "pos", "rinex_obs"), _p(cfg, "pos", "rinex_nav")
            a += ["--rinex-obs", str(obs), "--rinex-nav", str(nav)]
            ins += [obs, nav]
        else:
            raise InputError("[pos] mode lc needs 'gnss' (or rinex_obs and rinex_nav)", cfg["_path"], field="pos.gnss")
        if "imu_grade" in pos:
            a += ["--imu-grade", str(pos["imu_grade"])]
        if "lever_arm_gnss" in pos:
            a += ["--lever-arm", *map(str, _vec3(cfg, "pos", "lever_arm_gnss"))]
        for kv in pos.get("set", []):
            a += ["--set", str(kv)]
        steps.append(Step("pos", a, ins, [out / "pos" / "trajectory.csv", out / "pos" / "events.csv"]))
        traj = out / "pos" / "trajectory.csv"
    if mnt is not None:
        if eop is None or traj is None or events is None:
            raise InputError("[mount] needs [triangulation] (or its eop) and [pos] (or its trajectory and events)",
                             cfg["_path"], field="mount")
        method = str(mnt.get("method", "proposed"))
        methods = [method] + [str(m) for m in mnt.get("compare", []) if m != method]
        for m in methods:
            if m not in ("traditional", "proposed", "iso"):
                raise InputError(f"unknown mounting method {m!r} (traditional, proposed, iso)", cfg["_path"],
                                 field="mount.method")
        dep = _names(steps)
        for m in methods:
            a = ["mount", "--eop", str(eop), "--crs", crs, "--trajectory", str(traj), "--events", str(events),
                 "--method", m, "--out", str(out / f"mount_{m}")]
            ins = [eop, traj, events]
            if m == "iso":
                meas = _p(cfg, "mount", "measurements", required=False) or tri_meas
                if meas is None or gcp is None or cam_json is None:
                    raise InputError("mount method iso needs the triangulation's gcp and measurements and a camera",
                                     cfg["_path"], field="mount.compare")
                a += ["--camera", str(cam_json), "--gcp", str(gcp), "--measurements", str(meas)]
                ins += [cam_json, gcp, meas]
            if m in ("proposed", "iso") and "pos_common_fraction" in mnt:
                a += ["--pos-common-fraction", str(float(mnt["pos_common_fraction"]))]
            a += [str(v) for v in mnt.get("args", [])]
            steps.append(Step(f"mount_{m}", a, ins, [out / f"mount_{m}" / "mounting.json"], after=dep))
        if chk is not None:
            if cam_json is None:
                raise InputError("[check] needs a camera", cfg["_path"], field="camera")
            order = (["traditional"] if "traditional" in methods else []) + [m for m in methods if m != "traditional"]
            c_gcp = _p(cfg, "check", "gcp", required=False) or gcp
            c_meas = _p(cfg, "check", "measurements", required=False) or tri_meas
            c_events = _p(cfg, "check", "events", required=False) or events
            c_traj = _p(cfg, "check", "trajectory", required=False) or traj
            if c_gcp is None or c_meas is None:
                raise InputError("[check] needs gcp and measurements", cfg["_path"], field="check.gcp")
            mounts = [out / f"mount_{m}" / "mounting.json" for m in order]
            a = ["check", "--mounting", *map(str, mounts), "--camera", str(cam_json), "--trajectory", str(c_traj),
                 "--events", str(c_events), "--gcp", str(c_gcp), "--measurements", str(c_meas), "--crs", crs,
                 "--out", str(out / "check")]
            a += [str(v) for v in chk.get("args", [])]
            steps.append(Step("check", a, [*mounts, cam_json, c_traj, c_events, c_gcp, c_meas],
                              [out / "check" / "check.json"], after=_names(steps)))
    if not steps:
        raise InputError("the campaign has no step to run", cfg["_path"])
    return steps


def _names(steps: list[Step]) -> list[str]:
    return [s.name for s in steps]


def _size(cfg: dict, section: str) -> list[int]:
    v = cfg[section].get("image_size")
    if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and x > 0 for x in v)):
        raise InputError("needs image_size = [width, height] (px)", cfg["_path"], field=f"{section}.image_size")
    return v


def _vec3(cfg: dict, section: str, key: str) -> list[float]:
    v = cfg[section][key]
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)):
        raise InputError("needs three numbers [x, y, z]", cfg["_path"], field=f"{section}.{key}")
    return [float(x) for x in v]


def run_campaign(path: Path, out: Path, force: bool = False, runner: Callable[[list[str]], int] | None = None,
                 log=sys.stderr, report: bool = True) -> dict:
    """Run (or resume) a campaign into `out`; returns {"steps": {name: "ran"|"skipped"}, "timings_s": {...},
    "report": path or None}. A step is skipped when its fingerprint matches the last successful run, its
    outputs exist and no step it follows ran; a failing step raises InputError (earlier results are kept)."""
    from dgcal.cli import main as dgcal_main

    runner = runner or dgcal_main
    cfg = load_campaign(path)
    out = Path(out)
    steps = plan(cfg, out)
    out_abs = out.resolve()
    for step in steps:  # every campaign file must be there before anything runs
        for p in step.inputs:
            if not Path(p).exists() and out_abs not in Path(p).resolve().parents:
                raise InputError(f"input of step {step.name} not found", p)
    out.mkdir(parents=True, exist_ok=True)
    state_path = out / STATE
    state = {}
    if state_path.is_file() and not force:
        try:
            state = json.loads(state_path.read_text())
        except (OSError, json.JSONDecodeError):
            state = {}  # a damaged state file only costs a full rerun
    done: dict[str, str] = {}
    timings: dict[str, float] = {}
    for step in steps:
        fp = step.fingerprint()
        upstream_ran = any(done.get(n) == "ran" for n in step.after)
        if state.get(step.name) == fp and not upstream_ran and all(p.exists() for p in step.outputs):
            done[step.name] = "skipped"
            print(f"[{step.name}] up to date, skipped", file=log)
            continue
        print(f"[{step.name}] dgcal {' '.join(step.argv)}", file=log, flush=True)
        state.pop(step.name, None)
        _save_state(state_path, state)
        t0 = time.perf_counter()
        try:
            rc = runner(step.argv)
        except InputError:
            raise
        except Exception as exc:  # a crash inside a verb: one line naming the step; earlier steps stay done
            raise InputError(f"step {step.name} crashed ({type(exc).__name__}: {exc}); rerun it alone with "
                             f"`dgcal --debug {' '.join(step.argv[:1])} ...` to see where", cfg["_path"]) from exc
        timings[step.name] = time.perf_counter() - t0
        if rc != 0:
            raise InputError(f"step {step.name} failed (exit {rc}); fix it and run again to resume", cfg["_path"])
        missing = [str(p) for p in step.outputs if not p.exists()]
        if missing:
            raise InputError(f"step {step.name} did not write {', '.join(missing)}", cfg["_path"])
        state[step.name] = fp
        _save_state(state_path, state)
        done[step.name] = "ran"
        print(f"[{step.name}] done in {timings[step.name]:.1f} s", file=log, flush=True)
    result = {"steps": done, "timings_s": timings, "report": None}
    if report:
        from dgcal.reports.campaign import write_campaign_report
        t0 = time.perf_counter()
        paths = write_campaign_report(cfg, out, steps=done, timings=timings)
        timings["report"] = time.perf_counter() - t0
        result["report"] = str(Path(paths["html"]).resolve())
    return result


def _save_state(path: Path, state: dict) -> None:
    tmp = path.with_suffix(".part")
    tmp.write_text(json.dumps(state, indent=1))
    tmp.replace(path)
