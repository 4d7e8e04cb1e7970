"""What a verb declares to become a step of a campaign (`dgcal run`, dgcal.campaign).

A verb that can run in a campaign has, in its command module (dgcal.commands.<verb>), module-level
`SECTION` (its campaign-file table), `OUTPUTS` (role -> file name of what it writes into --out) and
`campaign_steps(c: Campaign)`, which reads its section and what earlier steps provide and adds its
`Step`s: the argv (the reproducible record of what runs), the input files (fingerprinted) and the output
files. dgcal.campaign.plan() is a loop over those verbs; the campaign report reads the same files.
"""
from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from dgcal.fields.errors import InputError
from dgcal.fields.io.atomic import file_sha256


@dataclass
class Step:
    """One verb of the chain: its argv, the files it reads, the files it must leave behind, the steps it follows.

    `files` holds every output the verb declares (role -> path), `label` what tells steps of one verb apart
    (the mounting method as the campaign names it), `out_dir` the folder the verb writes (its --out), `weight`
    its rough run time relative to other steps (steps run side by side start the heaviest ready one first).
    """

    name: str
    argv: list[str]
    inputs: list[Path]
    outputs: list[Path]
    after: list[str] = field(default_factory=list)
    label: str = ""
    files: dict[str, Path] = field(default_factory=dict)
    out_dir: Path | None = None
    weight: float = 1.0

    @property
    def verb(self) -> str:
        """The dgcal verb the step runs (argv[0])."""
        return self.argv[0]

    def input_files(self) -> list[tuple[str, Path]]:
        """Every input file with the name it is hashed under (folders: every file in them, by relative path);
        InputError when an input is missing."""
        files = []
        for p in self.inputs:
            p = Path(p)
            if p.is_dir():
                files += [(q.relative_to(p).as_posix(), q) for q in sorted(p.rglob("*")) if q.is_file()]
            elif p.is_file():
                files.append((p.name, p))
            else:
                raise InputError(f"input of step {self.name} not found", p)
        return files

    def fingerprint(self, cache: dict | None = None) -> str:
        """SHA-256 of the argv and of the contents of every input file (folders: every file in them).

        `cache` (resolved path -> [size, mtime_ns, inode, sha256]) saves reading a file again whose size,
        modification time and inode are those recorded; it is updated with every file read."""
        h = hashlib.sha256(json.dumps(self.argv).encode())
        for name, q in self.input_files():
            h.update(name.encode())
            h.update(file_digest(q, cache).encode())
        return h.hexdigest()


_RACY_NS = 3_000_000_000  # files modified less than 3 s ago are hashed again next time


def file_digest(path: Path, cache: dict | None = None) -> str:
    """SHA-256 of a file, from `cache` (resolved path -> [size, mtime_ns, inode, sha256]) when its size,
    modification time and inode are the recorded ones; a file read is entered in `cache`, unless it changed in
    the last seconds (a change within the file system's timestamp resolution would go unseen)."""
    st = path.stat()
    key, stamp = str(path.resolve()), [st.st_size, st.st_mtime_ns, st.st_ino]
    if cache is not None:
        hit = cache.get(key)
        if isinstance(hit, list) and len(hit) == 4 and hit[:3] == stamp:
            return str(hit[3])
    digest = file_sha256(path)
    if cache is not None and time.time_ns() - st.st_mtime_ns > _RACY_NS:
        cache[key] = [*stamp, digest]
    return digest


class Campaign:
    """A campaign file being planned into `out`: its sections (paths made absolute), the steps so far, and
    the files the campaign provides to later steps (`provided`: camera, eop, gcp, measurements, trajectory,
    events), either made by a step or given in the campaign file."""

    def __init__(self, cfg: dict, out: Path) -> None:
        self.cfg = cfg
        self.out = Path(out)
        self.file = cfg["_path"]
        self.steps: list[Step] = []
        self.provided: dict[str, Path] = {}
        crs = cfg.get("crs")
        if not crs:
            raise InputError("the campaign needs a top-level 'crs'", self.file, field="crs")
        self.crs = str(crs)

    def error(self, message: str, field_name: str) -> InputError:
        """An input error naming the campaign file and the field (`section.key`)."""
        return InputError(message, self.file, field=field_name)

    def section(self, name: str) -> dict | None:
        """The [name] table, or None when the campaign has none."""
        val = self.cfg.get(name)
        if val is None:
            return None
        if not isinstance(val, dict):
            raise self.error(f"'{name}' must be a [{name}] table", name)
        return val

    def path(self, section: str, key: str, required: bool = True) -> Path | None:
        """The path `key` of [section], relative to the campaign file; None (or an error) when absent."""
        val = (self.section(section) or {}).get(key)
        if val is None:
            if required:
                raise self.error(f"[{section}] needs '{key}'", f"{section}.{key}")
            return None
        p = Path(val)
        return p if p.is_absolute() else self.cfg["_base"] / p

    def image_size(self, section: str) -> list[int]:
        """`image_size = [width, height]` (px) of [section]."""
        v = (self.section(section) or {}).get("image_size")
        if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and x > 0 for x in v)):
            raise self.error("needs image_size = [width, height] (px)", f"{section}.image_size")
        return v

    def vec3(self, section: str, key: str) -> list[float]:
        """A vector of three numbers `key = [x, y, z]` of [section]."""
        v = (self.section(section) or {}).get(key)
        if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)):
            raise self.error("needs three numbers [x, y, z]", f"{section}.{key}")
        return [float(x) for x in v]

    def extra_args(self, section: str) -> list[str]:
        """`args = [...]` of [section]: further arguments of its verb, appended to the step's argv; never `--out`
        (a step's outputs stay inside the campaign folder, where later steps and the report find them)."""
        args = [str(v) for v in (self.section(section) or {}).get("args", [])]
        for a in args:
            if a == "--out" or a.startswith("--out="):
                raise self.error("args cannot move a step's outputs (--out): they stay in the campaign folder",
                                 f"{section}.args")
        return args

    def step_names(self) -> list[str]:
        """Names of the steps planned so far (what a new step follows)."""
        return [s.name for s in self.steps]

    def steps_of(self, verb: str) -> list[Step]:
        """The planned steps running `verb`, in order."""
        return [s for s in self.steps if s.verb == verb]

    def add(self, name: str, argv: list[str], inputs: Sequence[Path], out_dir: Path, outputs: Mapping[str, str],
            required: Sequence[str], after: Sequence[str] = (), label: str = "", weight: float = 1.0) -> Step:
        """Append a step whose verb writes `outputs` (role -> file name) into `out_dir`; `required` roles must
        exist after it ran (and for it to count as up to date)."""
        files = {role: Path(out_dir) / fname for role, fname in outputs.items()}
        step = Step(name, list(argv), list(inputs), [files[r] for r in required], list(after), label, files,
                    Path(out_dir), weight)
        self.steps.append(step)
        return step

    def provide(self, kind: str, path: Path) -> None:
        """Record a file later steps use (camera, eop, gcp, measurements, trajectory, events)."""
        self.provided[kind] = Path(path)
