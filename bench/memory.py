"""Peak memory of reading a 5 M-row image measurements CSV (issue 16: the readers stream their files).

    .venv/bin/python bench/memory.py [--rows 5000000] [--keep DIR]

Writes `measurements.csv` (image,id,x,y,sx,sy: 10 000 images of 500 tie points each, 500 000 point ids, the
shape of a large aerial block) into a temporary folder, then reads it in a fresh subprocess with
`dgcal.fields.io.gcp_files.read_any_measurements` (what `dgcal.api.read_any_measurements` is) and prints the file
size, the subprocess's peak RSS (resource.getrusage ru_maxrss) after importing the reader and after reading, and
the ratios to the file size. Target: the memory the read adds is at most 3x the file size.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from dgcal.fields.io.gcp_files import read_any_measurements
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
t0 = time.perf_counter()
meas, crs, pts = read_any_measurements(sys.argv[1])
dt = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"rows": len(meas), "base_rss": base, "peak_rss": peak, "seconds": dt}))
"""


def write_measurements_csv(path: Path, rows: int, per_image: int = 500, n_points: int = 500_000) -> None:
    """`rows` measurements: image k holds points (53 k + j) mod n_points, j < per_image (no point twice)."""
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("image,id,x,y,sx,sy\n")
        k = 0
        written = 0
        while written < rows:
            n = min(per_image, rows - written)
            img = f"IMG_{k:05d}.JPG"
            base = 53 * k
            fh.write("".join(f"{img},P{(base + j) % n_points:06d},{(j * 37.113) % 6000:.4f},"
                             f"{(j * 21.457 + k) % 4000:.4f},0.5000,0.5000\n" for j in range(n)))
            written += n
            k += 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=5_000_000)
    ap.add_argument("--keep", type=Path, default=None, help="write the CSV here (kept) instead of a temp folder")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        csv = folder / "measurements.csv"
        t0 = time.perf_counter()
        write_measurements_csv(csv, args.rows)
        size = csv.stat().st_size
        print(f"wrote {args.rows:,} rows, {size / 2**20:.1f} MiB in {time.perf_counter() - t0:.1f} s: {csv}")
        out = subprocess.run([sys.executable, "-c", CHILD, str(csv)], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
    added = r["peak_rss"] - r["base_rss"]
    print(f"read {r['rows']:,} rows in {r['seconds']:.1f} s")
    print(f"file size                 {size / 2**20:9.1f} MiB")
    print(f"peak RSS after import     {r['base_rss'] / 2**20:9.1f} MiB")
    print(f"peak RSS after reading    {r['peak_rss'] / 2**20:9.1f} MiB   ({r['peak_rss'] / size:.2f} x the file)")
    print(f"added by reading          {added / 2**20:9.1f} MiB   ({added / size:.2f} x the file; target <= 3)")
    return 0 if added / size <= 3.0 else 1


if __name__ == "__main__":
    sys.exit(main())
