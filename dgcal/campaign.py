"""`dgcal run CAMPAIGN.toml`: the calibration chain camera -> triangulation -> POS -> mounting -> DG check.

Each step is a dgcal verb run with arguments built from the campaign file (docs/campaign.md): every verb
of `CHAIN` declares, in its command module, its section, its output files and `campaign_steps` (how its
section becomes its argv; dgcal.steps), and `plan()` is a loop over them. A step is
skipped when its fingerprint (its arguments and the contents of its input files) matches its last
successful run (DIR/.dgcal-state.json, written after the step), its output folder is still the complete one it
wrote (its manifest, dgcal.fields.io.atomic) and no step before it that it depends on ran again; so an
interrupted (even killed) or edited campaign resumes where it must, after the leftovers of the interrupted
run are cleaned up. The run ends with the calibration report
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

import importlib
import json
import re
import sys
import time
import tomllib
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable, Sequence

from dgcal.commands import camera, check, mount, pos, triangulate
from dgcal.fields.errors import InputError
from dgcal.fields.io import validate
from dgcal.fields.io.atomic import (MANIFEST, atomic_write, clean_stale, file_sha256, manifest_problems, output_lock,
                                    staged_dir)
from dgcal.fields.io.text_files import read_text
from dgcal.fields.processes import cpus, fork_map
from dgcal.precompile import load_cached_kernels
from dgcal.fields import progress
from dgcal.step_pool import Outcome, StepPool, log_notes, output_to_log
from dgcal.steps import Campaign, Step, file_digest

__all__ = ["CHAIN", "STATE", "Campaign", "DemoOptions", "Step", "load_campaign", "load_state", "plan", "run_campaign",
           "run_demo"]

STATE = ".dgcal-state.json"
STATE_VERSION = 2   # {"version", "steps": {name: record}} (dgcal.campaign._record)
CHAIN = (camera, triangulate, pos, mount, check)  # the verbs of a campaign, in order (dgcal.steps)
LIGHTER_STEP_NICE = 5   # niceness of a step started while a heavier one runs or waits (`--jobs` > 1)
# imported by the runner before it forks the steps (--jobs > 1): modules most verbs load (0.5-1 s each time) and
# the POS verb's (gtsam starts its TBB pool on first use, not on import); none that starts threads on import
# (OpenCV does: no module that imports cv2) or holds state a fork would break
PRELOAD = ("numpy", "scipy.linalg", "scipy.sparse", "scipy.optimize", "scipy.spatial.transform", "pyproj",
           "dgcal.reports.html", "dgcal.fields.io.formats", "dgcal.fields.crs", "dgcal.pos.pipeline",
           "dgcal.reports.pos")
# modules whose cached numba kernels the runner loads before it forks (dgcal.precompile.load_cached_kernels); none
# of them imports OpenCV
PRELOAD_KERNELS = ("dgcal.bundle.solver.kernels", "dgcal.pos.smoother.recursions", "dgcal.pos.gnss.ambiguity",
                   "dgcal.pos.gnss.carrier", "dgcal.pos.gnss.carrier_model", "dgcal.pos.gnss.ppk_design")


def preload_for_steps() -> None:
    """Import `PRELOAD` and load the cached kernels of `PRELOAD_KERNELS`: what the runner's forked steps share."""
    for module in PRELOAD:
        importlib.import_module(module)
    load_cached_kernels(PRELOAD_KERNELS)


def load_campaign(path: Path) -> dict:
    """The campaign TOML with paths made absolute; InputError naming the file (and the key, `section.key`) on
    syntax errors and on values of the wrong type or out of range (`check_campaign`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("campaign file not found", path)
    text = read_text(path)
    try:
        cfg = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {' '.join(str(exc).split())}", path) from None
    except RecursionError:
        raise InputError("not valid TOML: nested too deeply", path) from None
    check_campaign(cfg, path, text)
    validate.toml_numbers_in_range(cfg, path, text)   # what the keys' own checks leave
    cfg["_base"] = path.parent.resolve()
    cfg["_path"] = path.resolve()
    return cfg


# the keys of a campaign file and their kinds: path (text), text, list of texts, image size, 3-vector, ...
_CAMPAIGN_KEYS: dict[str | None, dict[str, tuple]] = {
    None: {"crs": ("text",), "name": ("text",), "truth": ("path",)},
    "camera": {"camera_json": ("path",), "field": ("path",), "measurements": ("path",), "images": ("path",),
               "image_size": ("image_size",), "model": ("text",)},
    "triangulation": {"eop": ("path",), "gcp": ("path",), "measurements": ("path",), "images": ("path",)},
    "pos": {"trajectory": ("path",), "events": ("path",), "imu": ("path",), "gnss": ("path",),
            "rinex_obs": ("path",), "rinex_nav": ("path",), "rinex_base": ("path",), "mode": ("text",),
            "imu_grade": ("text",), "base_position": ("vec3", 1e8), "lever_arm_gnss": ("vec3", 1000.0),
            "frequencies": ("int", 1, 3), "set": ("texts",)},
    "mount": {"method": ("text",), "compare": ("texts",), "measurements": ("path",),
              "pos_common_fraction": ("number", 0.0, 1.0)},
    "check": {"gcp": ("path",), "measurements": ("path",), "events": ("path",), "trajectory": ("path",)},
}


def _toml_line(text: str, section: str | None, key: str) -> int | None:
    """The line of `key = ...` in [section] (top level for None), for error messages."""
    start = 0
    if section is not None:
        m = re.search(rf"^\s*\[\s*{re.escape(section)}\s*\]", text, re.M)
        if m is None:
            return None
        start = m.end()
    m = re.compile(rf"^\s*{re.escape(key)}\s*=", re.M).search(text, start)
    return None if m is None else text.count("\n", 0, m.start()) + 1


def check_campaign(cfg: dict, path: Path, text: str = "") -> None:
    """Every known key of a campaign file of the right type: paths and names are texts, `args`/`set`/`compare`
    lists of texts, `image_size` two whole pixel counts, vectors three finite numbers, fractions in [0, 1];
    an InputError names the file, line and key (`section.key`)."""
    for section, keys in _CAMPAIGN_KEYS.items():
        table = cfg if section is None else cfg.get(section)
        if table is None:
            continue
        if not isinstance(table, dict):
            raise InputError(f"'{section}' must be a [{section}] table", path, _toml_line(text, None, section),
                             section)
        for key, kind in {**keys, **({} if section is None else {"args": ("texts",)})}.items():
            if key not in table:
                continue
            v, name, line = table[key], key if section is None else f"{section}.{key}", _toml_line(text, section, key)
            what = kind[0]
            if what in ("path", "text"):
                if not isinstance(v, str) or (what == "path" and not v.strip()):
                    raise InputError(f"must be a {'file name' if what == 'path' else 'text'} in quotes, not "
                                     f"{_short(v)}", path, line, name)
            elif what == "texts":
                if not isinstance(v, list) or not all(isinstance(x, (str, int, float)) and not isinstance(x, bool)
                                                      for x in v):
                    raise InputError(f"must be a list of texts [\"...\", ...], not {_short(v)}", path, line, name)
            elif what == "image_size":
                if not isinstance(v, list) or len(v) != 2:
                    raise InputError(f"must be [width, height] (px), not {_short(v)}", path, line, name)
                validate.image_size(v[0], v[1], path, line, name)
            elif what == "vec3":
                validate.vector(v, 3, path, line, name, -kind[1], kind[1])
            elif what == "int":
                validate.integer(v, kind[1], kind[2], path, line, name)
            elif what == "number":
                validate.in_range(v, kind[1], kind[2], path, line, name)


def _short(v) -> str:
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


def plan_campaign(cfg: dict, out: Path) -> Campaign:
    """The planned campaign: every verb of `CHAIN` adds its steps (`campaign_steps`) in order."""
    c = Campaign(cfg, out)
    for verb in CHAIN:  # every section a table before anything is read
        c.section(verb.SECTION)
    for verb in CHAIN:
        verb.campaign_steps(c)
    if not c.steps:
        raise InputError("the campaign has no step to run", cfg["_path"])
    for step in c.steps:
        check_step_argv(step, cfg["_path"])
    return c


def check_step_argv(step: Step, path: Path) -> None:
    """The command line a step will run parses (a misspelt `model` or an unknown option in `args` is an
    InputError naming the campaign file now, not an argparse exit in the middle of the run)."""
    import contextlib
    import io

    from dgcal.cli import build_parser
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser(step.argv).parse_args(step.argv)
    except SystemExit:
        msg = next((ln for ln in reversed(err.getvalue().splitlines()) if "error:" in ln), "invalid arguments")
        raise InputError(f"step {step.name}: {msg.split('error:', 1)[-1].strip()} (dgcal {' '.join(step.argv)[:200]})",
                         path) from None


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
                 log=sys.stderr, report: bool = True, rerun: Sequence[str] = (), jobs: int = 1) -> dict:
    """Run (or resume) a campaign into `out`; returns {"steps": {name: "ran"|"skipped"}, "timings_s": {...},
    "report": path or None}. First what an interrupted run left is cleaned up (`clean_stale` on every output
    folder of the plan and on `out`). A step is skipped when its record in DIR/.dgcal-state.json (written
    after it finished) still holds: same argv and input contents, its output folder complete per its manifest
    and the very one it wrote, no step it follows ran, and it is not named in `rerun` (step names such as
    `mount_iso`, or verbs: `mount` is every mounting step); `force` reruns everything. `jobs` > 1 runs up to
    that many steps at once, each in a child process, as soon as the steps it follows are done (POS beside
    the camera and triangulation, the mounting methods side by side); 1 runs them in order in this process.
    A failing step raises InputError once the steps running beside it have ended (their results are kept,
    as are earlier ones). The campaign folder is locked for the whole run (a second run on it is refused)."""
    with output_lock(out):
        return _run_campaign(path, Path(out), force, runner, log, report, rerun, jobs)


def _run_campaign(path: Path, out: Path, force: bool, runner: Callable[[list[str]], int] | None, log, report: bool,
                  rerun: Sequence[str], jobs: int) -> dict:
    from dgcal.cli import main as dgcal_main

    runner = runner or dgcal_main
    cfg = load_campaign(path)
    out = Path(out)
    planned = plan_campaign(cfg, out)
    steps = planned.steps
    forced = _rerun_steps(steps, rerun, cfg["_path"])
    out_abs = out.resolve()
    for step in steps:  # every campaign file must be there before anything runs
        for p in step.inputs:
            if not Path(p).exists() and out_abs not in Path(p).resolve().parents:
                raise InputError(f"input of step {step.name} not found", p)
    out.mkdir(parents=True, exist_ok=True)
    clean_stale(out)                      # the report's staging, killed writes of the state file
    for step in steps:                    # staging and set-aside folders of killed steps (old outputs put back)
        clean_stale(step.out_dir)
    state_path = out / STATE
    records = {} if force else load_state(state_path)
    cache = {k: v for r in records.values() for k, v in r.get("inputs", {}).items()}
    done: dict[str, str] = {}
    timings: dict[str, float] = {}
    fingerprints: dict[str, str] = {}
    by_name = {s.name: s for s in steps}
    pending = list(steps)
    pool = None
    if jobs > 1:
        preload_for_steps()
        pool = StepPool(runner, blas_threads=max(1, cpus() // jobs))
    failure: InputError | None = None

    def waiting(step: Step) -> bool:
        """A step it follows has not ended well (yet)."""
        return any(done.get(n) in (None, "failed") for n in step.after if n in by_name)

    def finish(o: Outcome) -> None:
        """Record a step that ended (the record last: only a finished step is done), or keep its failure."""
        nonlocal failure
        step = by_name[o.name]
        step_log_path = step_log(out, step)
        warnings, error_line = log_notes(step_log_path)
        err = _step_failure(step, o, cfg["_path"], error_line, step_log_path)
        if err is not None:
            failure = failure or err
            done[step.name] = "failed"
            return
        timings[step.name] = o.seconds
        records[step.name] = _record(step, fingerprints[step.name], cache)
        _save_state(state_path, records)
        done[step.name] = "ran"
        for w in warnings:
            print(f"[{step.name}] {w}", file=log)
        print(f"[{step.name}] done in {o.seconds:.1f} s" + (f" ({len(warnings)} warning(s); log {step_log_path})"
                                                            if warnings else ""), file=log, flush=True)

    with progress.stage("campaign steps") as beat:
        try:
            while pending or (pool and len(pool)):
                # side by side the heaviest ready step first (iso before the quick mountings); in turn, plan order
                for step in (sorted(pending, key=lambda s: -s.weight) if pool is not None else list(pending)):
                    if failure is not None or (pool is not None and len(pool) >= jobs):
                        break
                    if waiting(step):
                        continue
                    pending.remove(step)
                    fp = fingerprints[step.name] = step.fingerprint(cache)
                    why = ("--force" if force else "--rerun" if step.name in forced
                           else _why_rerun(step, records.get(step.name), fp,
                                           [n for n in step.after if done.get(n) == "ran"]))
                    if why is None:
                        done[step.name] = "skipped"
                        print(f"[{step.name}] up to date, skipped", file=log)
                        continue
                    print(f"[{step.name}] ({why}) dgcal {' '.join(step.argv)}", file=log, flush=True)
                    records.pop(step.name, None)
                    _save_state(state_path, records)
                    if pool is None:
                        beat.set_text(f"step {step.name}")
                        finish(_run_here(step, runner, step_log(out, step)))
                    else:
                        # a step lighter than one running or waiting yields the CPU to it (the longer chain)
                        heavier = any(s.weight > step.weight for s in [*pending, *(by_name[n] for n in pool.running)])
                        pool.start(step.name, step.argv, nice=LIGHTER_STEP_NICE if heavier else 0,
                                   log=step_log(out, step))
                        beat.set_text("steps " + ", ".join(pool.running))
                if failure is not None and not (pool and len(pool)):
                    raise failure
                if pool is not None and len(pool):
                    finish(pool.wait())
                    beat.set_text("steps " + ", ".join(pool.running))
                elif pending and all(waiting(s) for s in pending):
                    break                         # nothing can start (cannot happen with a well-formed plan)
        except BaseException:
            if pool is not None:
                pool.stop()
            raise
    if failure is not None:
        raise failure
    result = {"steps": {s.name: done[s.name] for s in steps if s.name in done},
              "timings_s": {s.name: timings[s.name] for s in steps if s.name in timings}, "report": None}
    timings = result["timings_s"]
    if report:
        from dgcal.reports.campaign import write_campaign_report
        t0 = time.perf_counter()
        with staged_dir(out, merge=True) as tmp:   # report.json and report.html together, the manifest last
            write_campaign_report(cfg, out, report_files(planned), steps=result["steps"], timings=timings, into=tmp)
        timings["report"] = time.perf_counter() - t0
        result["report"] = str((out / "report.html").resolve())
    return result


def step_log(out: Path, step: Step) -> Path:
    """The log file of a step's own output (its progress, warnings, the libraries' messages)."""
    return Path(out) / LOGS / (re.sub(r"[^A-Za-z0-9_.-]+", "_", step.name) + ".log")


LOGS = "logs"   # the campaign's folder of step logs


def _run_here(step: Step, runner: Callable[[list[str]], int], log: Path | None = None) -> Outcome:
    """Run a step in this process (its output into `log`): its outcome (exit status or exception) and wall time."""
    t0 = time.perf_counter()
    try:
        with output_to_log(log):
            rc = runner(step.argv)
    except Exception as exc:
        return Outcome(step.name, error=exc, seconds=time.perf_counter() - t0)
    return Outcome(step.name, rc=int(rc or 0), seconds=time.perf_counter() - t0)


def _step_failure(step: Step, o: Outcome, campaign: Path, error_line: str | None = None,
                  log: Path | None = None) -> InputError | None:
    """The InputError a step's outcome makes (crash, non-zero exit, missing output; its log's error line), None
    when it is done."""
    if isinstance(o.error, InputError):
        return o.error
    if o.error is not None:   # a crash inside a verb: one line naming the step; earlier steps stay done
        err = InputError(f"step {step.name} crashed ({type(o.error).__name__}: {o.error}); rerun it alone with "
                         f"`dgcal --debug {' '.join(step.argv[:1])} ...` to see where", campaign)
        err.__cause__ = o.error
        return err
    if o.rc != 0:
        said = f": {error_line}" if error_line else ""
        where = f" (log {log})" if log is not None and log.is_file() else ""
        return InputError(f"step {step.name} failed (exit {o.rc}){said}{where}; fix it and run again to resume",
                          campaign)
    missing = [str(p) for p in step.outputs if not p.exists()]
    if missing:
        return InputError(f"step {step.name} did not write {', '.join(missing)}", campaign)
    return None


def _rerun_steps(steps: list[Step], names: Sequence[str], campaign: Path) -> set[str]:
    """The steps `--rerun` names: step names (mount_iso) or verbs (mount: every mounting step)."""
    chosen: set[str] = set()
    for n in names:
        hit = {s.name for s in steps if n in (s.name, s.verb)}
        if not hit:
            raise InputError(f"--rerun {n}: no such step in this campaign (steps: "
                             f"{', '.join(s.name for s in steps)})", campaign)
        chosen |= hit
    return chosen


def _why_rerun(step: Step, rec: dict | None, fp: str, upstream: list[str]) -> str | None:
    """Why a step must run again, or None when its record shows it up to date."""
    if rec is None:
        return "not run yet"
    if rec.get("fingerprint") != fp:
        if rec.get("argv") != step.argv:
            return "arguments changed"
        changed = [Path(k).name for k, v in rec.get("input_sha256", {}).items()
                   if not Path(k).is_file() or file_digest(Path(k)) != v]
        return f"input changed: {', '.join(changed[:3])}" if changed else "inputs changed"
    if upstream:
        return f"after {', '.join(upstream)}"
    problems = [] if step.out_dir is None else manifest_problems(step.out_dir)
    missing = [p.name for p in step.outputs if not p.exists()]
    if problems or missing:
        return f"outputs incomplete: {(problems or missing)[0]}"
    if step.out_dir is not None and _manifest_digest(step.out_dir) != rec.get("outputs"):
        return "outputs replaced since it ran"
    return None


def _manifest_digest(folder: Path) -> str | None:
    p = Path(folder) / MANIFEST
    return file_sha256(p) if p.is_file() else None


def _record(step: Step, fp: str, cache: dict) -> dict:
    """What the state file keeps of a finished step: fingerprint, argv, the stamps and SHA-256 of its input
    files, the digest of its output folder's manifest."""
    keys = [str(q.resolve()) for _, q in step.input_files()]
    return {"fingerprint": fp, "argv": step.argv, "finished_unix": time.time(),
            "input_sha256": {k: file_digest(Path(k), cache) for k in keys},
            "inputs": {k: cache[k] for k in keys if k in cache},
            "outputs": None if step.out_dir is None else _manifest_digest(step.out_dir)}


def load_state(path: Path) -> dict:
    """The finished steps' records of DIR/.dgcal-state.json (step name -> record); {} when there is none or
    it is damaged or of an earlier version (which only costs a full rerun)."""
    try:
        state = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(state, dict) or state.get("version") != STATE_VERSION or not isinstance(state.get("steps"), dict):
        return {}
    return {k: v for k, v in state["steps"].items() if isinstance(v, dict)}


def _save_state(path: Path, records: dict) -> None:
    with atomic_write(path) as fh:
        json.dump({"version": STATE_VERSION, "steps": records}, fh, indent=1)


@dataclass
class DemoOptions:
    """`dgcal demo`: the output folder (data/ and results/), the simulation's seed, rerun everything, steps at once."""

    out: Path
    seed: int = 3
    force: bool = False
    jobs: int = 1


def _simulate(data: Path, seed: int) -> dict:
    """`dgcal.sim.campaign.simulate_campaign`, imported here: in the demo's child process, not the runner."""
    from dgcal.sim.campaign import simulate_campaign
    return simulate_campaign(data, seed)


def run_demo(opts: DemoOptions, log=None) -> dict:
    """Simulate the seed-003-like campaign into out/data (unless it is there for this seed) and run it into
    out/results; returns `run_campaign`'s record plus the time taken (s)."""
    t0 = time.perf_counter()
    log = log or sys.stderr
    data, results = Path(opts.out) / "data", Path(opts.out) / "results"
    stamp = data / "truth.json"
    if opts.force or not stamp.is_file() or json.loads(stamp.read_text()).get("seed") != opts.seed:
        print(f"[simulate] campaign (seed {opts.seed}) -> {data}", file=log, flush=True)
        if opts.jobs > 1:   # the simulation (its imports too) in a child while this process loads what the steps share
            fork_map([preload_for_steps, partial(_simulate, data, opts.seed)])
        else:
            _simulate(data, opts.seed)
        simulated = time.perf_counter() - t0
        print(f"[simulate] done in {simulated:.1f} s", file=log, flush=True)
    else:
        simulated = None
        print(f"[simulate] {data} already there, kept", file=log)
    res = run_campaign(data / "campaign.toml", results, force=opts.force, log=log, jobs=opts.jobs)
    if simulated is not None:
        res["timings_s"] = {"simulate": simulated, **res["timings_s"]}
    res["elapsed_s"] = time.perf_counter() - t0
    return res
