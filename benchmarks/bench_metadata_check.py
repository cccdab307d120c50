"""How long the metadata check of a finished store takes (every run and ``box status`` make
it before touching anything): each document read once, those of the layout concurrently,
against reading every document wherever it is compared (as before), side by side.

The store is the tests' small planar one (24 × 15 entries, ``stage=generate``), made on
local disk and, where moto is installed (``pip install -e ".[test]"``), in a real
S3-compatible server process on 127.0.0.1 (moto's, one request at a time: on real object
storage a round trip costs more, and concurrent reads overlap more).  The two variants
alternate, ``--repeats`` times each, on one opened store; printed: medians and the ratio.

Run: python benchmarks/bench_metadata_check.py [--repeats 9]
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def measure(url: str, cwd: Path, repeats: int) -> dict[str, float]:
    from pipeline.domains import load_domain
    from pipeline.store import metadata
    from pipeline.store.score_store import ScoreStore
    from tests import pipeline_runs as pr

    made = pr.run(url, "stage=generate", cwd=cwd)
    if made.returncode:
        raise RuntimeError(made.stderr[-2000:])
    # opened for writing (nothing is written): a read-only store reads each document once
    # for its whole life, which would hide the difference measured here
    store, domain = ScoreStore(url, read_only=False), load_domain("planar")
    once = ScoreStore.documents_read_once
    every_time = contextlib.contextmanager(lambda self: (yield))
    times: dict[str, list[float]] = {"read once": [], "read every time": []}
    try:
        for _ in range(repeats):
            for name, variant in (("read once", once), ("read every time", every_time)):
                ScoreStore.documents_read_once = variant
                start = time.perf_counter()
                found = metadata.check(store, domain)
                times[name].append(time.perf_counter() - start)
                assert not found, found
    finally:
        ScoreStore.documents_read_once = once
    return {name: statistics.median(v) for name, v in times.items()}


def report(where: str, medians: dict[str, float]) -> None:
    once, every = medians["read once"], medians["read every time"]
    print(f"{where:28s} {once * 1e3:10.1f} {every * 1e3:16.1f} {every / once:8.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    print(f"{'store':28s} {'once ms':>10s} {'every time ms':>16s} {'ratio':>9s}   "
          f"(medians of {args.repeats})")
    with tempfile.TemporaryDirectory(prefix="bench-metadata-") as tmp:
        tmp = Path(tmp)
        report("local disk", measure(str(tmp / "a.zarr"), tmp, args.repeats))
        if shutil.which("moto_server") is None:
            print("S3 (moto): skipped, moto_server is not installed")
            return
        from tests.s3_server import BUCKET, serve

        with serve():
            report("S3 (moto on 127.0.0.1)", measure(f"s3://{BUCKET}/a.zarr", tmp,
                                                      args.repeats))


if __name__ == "__main__":
    main()
