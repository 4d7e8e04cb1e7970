"""`dgcal run CAMPAIGN.toml`: the calibration chain camera -> triangulation -> POS -> mounting -> DG check.

Each step is a dgcal verb run with arguments built from the campaign file (docs/campaign.md): every verb
of `CHAIN` declares, in its command module, its section, its output files and `campaign_steps` (how its
section becomes its argv; dgcal.steps), and `plan()` is a loop over them. A step is
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
    [mount]           # method (joint), compare = [more methods], measurements (for iso),
                      # pos_common_fraction (joint, iso: share of the POS error common to the flight);
                      # methods two-step, joint, iso (the seed's traditional = two-step, proposed = joint)
    [check]           # gcp, measurements, events, trajectory (a DG check flight; default: the calibration flight)
Every section may add `args = [...]`: extra arguments of its verb.
"""
from __future__ import annotations

import json
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from dgcal.commands import camera, check, mount, pos, triangulate
from dgcal.fields.errors import InputError
from dgcal.steps import Campaign, Step

__all__ = ["CHAIN", "STATE", "Campaign", "DemoOptions", "Step", "load_campaign", "plan", "run_campaign", "run_demo"]

STATE = ".dgcal-state.json"
CHAIN = (camera, triangulate, pos, mount, check)  # the verbs of a campaign, in order (dgcal.steps)


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


def plan_campaign(cfg: dict, out: Path) -> Campaign:
    """The planned campaign: every verb of `CHAIN` adds its steps (`campaign_steps`) in order."""
    c = Campaign(cfg, out)
    for verb in CHAIN:  # every section a table before anything is read
        c.section(verb.SECTION)
    for verb in CHAIN:
        verb.campaign_steps(c)
    if not c.steps:
        raise InputError("the campaign has no step to run", cfg["_path"])
    return c


def plan(cfg: dict, out: Path) -> list[Step]:
    """The steps of a campaign, in order, with their dgcal arguments, input files and expected outputs."""
    return plan_campaign(cfg, out).steps


def report_files(c: Campaign) -> dict:
    """The files of the planned steps the campaign report reads, by section (as the verbs declare them):
    camera, triangulation, pos, check (role -> path) and mounts (method as named -> role -> path)."""
    def first(verb) -> dict:
        return next((dict(s.files) for s in c.steps_of(verb.NAME)), {})
    cam = first(camera) or ({"camera": c.provided["camera"]} if "camera" in c.provided else {})
    return {"camera": cam, "triangulation": first(triangulate), "pos": first(pos), "check": first(check),
            "mounts": {s.label: dict(s.files) for s in c.steps_of(mount.NAME)}}


def run_campaign(path: Path, out: Path, force: bool = False, runner: Callable[[list[str]], int] | None = None,
                 log=sys.stderr, report: bool = True) -> dict:
    """Run (or resume) a campaign into `out`; returns {"steps": {name: "ran"|"skipped"}, "timings_s": {...},
    "report": path or None}. A step is skipped when its fingerprint matches the last successful run, its
    outputs exist and no step it follows ran; a failing step raises InputError (earlier results are kept)."""
    from dgcal.cli import main as dgcal_main

    runner = runner or dgcal_main
    cfg = load_campaign(path)
    out = Path(out)
    planned = plan_campaign(cfg, out)
    steps = planned.steps
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
        paths = write_campaign_report(cfg, out, report_files(planned), steps=done, timings=timings)
        timings["report"] = time.perf_counter() - t0
        result["report"] = str(Path(paths["html"]).resolve())
    return result


def _save_state(path: Path, state: dict) -> None:
    tmp = path.with_suffix(".part")
    tmp.write_text(json.dumps(state, indent=1))
    tmp.replace(path)


@dataclass
class DemoOptions:
    """`dgcal demo`: the output folder (data/ and results/), the simulation's seed, rerun everything."""

    out: Path
    seed: int = 3
    force: bool = False


def run_demo(opts: DemoOptions, log=None) -> dict:
    """Simulate the seed-003-like campaign into out/data (unless it is there for this seed) and run it into
    out/results; returns `run_campaign`'s record plus the time taken (s)."""
    from dgcal.sim.campaign import simulate_campaign
    log = log or sys.stderr
    data, results = Path(opts.out) / "data", Path(opts.out) / "results"
    t0 = time.perf_counter()
    stamp = data / "truth.json"
    if opts.force or not stamp.is_file() or json.loads(stamp.read_text()).get("seed") != opts.seed:
        print(f"[simulate] campaign (seed {opts.seed}) -> {data}", file=log, flush=True)
        simulate_campaign(data, opts.seed)
    else:
        print(f"[simulate] {data} already there, kept", file=log)
    res = run_campaign(data / "campaign.toml", results, force=opts.force, log=log)
    res["elapsed_s"] = time.perf_counter() - t0
    return res
