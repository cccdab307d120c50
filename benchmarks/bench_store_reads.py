"""What checking a finished store costs: ``box status`` (every document, every chunk's
digest) and a re-run that finds nothing to do (the same checks, then each stage's to-do),
this checkout against another revision, side by side, with the store reads each makes.

The store is the tests' small planar one (24 × 15 entries in 4 × 3 blocks, generated and
evaluated), on local disk and, where moto is installed (``pip install -e ".[test]"``), in a
real S3-compatible server process on 127.0.0.1 (moto's: one request at a time, each a
round trip).  Each variant runs in its own process (its code first on the path) that
times ``status.collect`` and an in-process ``run_pipeline`` of ``stage=generate`` and of
``stage=evaluate`` on the finished store, and of ``stage=generate`` after the consolidated
copy in the root document was made stale (a "repair re-run": the copy is written again,
then every stage has nothing to do), ``--repeats`` times each after one warm-up, and
counts the reads (``get``) and listings (``list*``) Zarr makes of the store, and in S3 the
requests s3fs sends for them.  The variants
alternate ``--rounds`` times; printed: medians over all repeats, and the ratio.

Run: python benchmarks/bench_store_reads.py [--rounds 3] [--repeats 5] [--baseline-rev e205980]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from child_runs import export_revision, run_child  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: the code before the consolidated copy was written only after a document changed and a
#: store opened for reading read the documents its check read (2026-11-25)
BASELINE_REV = "e205980"

TIMED = ("status", "re-run generate", "re-run evaluate", "repair re-run")


def child(job: dict) -> None:
    """Time the checks of the store at ``job["url"]`` with the code on this process's path;
    print one JSON line: the times per kind, and the reads per kind (one call's)."""
    import time

    import zarr.storage
    from hydra import compose, initialize_config_dir
    from rich.console import Console

    from pipeline.configs import CONF_DIR, register_configs
    from pipeline.stages import run_pipeline
    from pipeline.store import status
    from tests import pipeline_runs as pr

    calls = {"get": 0, "list": 0}
    sent = []  # the S3 requests, for the child's whole life
    if job["url"].startswith("s3://"):
        recording = _this_checkouts_s3_server().requests_sent()  # kept: its exit undoes it
        sent = recording.__enter__()
    for cls in (zarr.storage.LocalStore, zarr.storage.FsspecStore):
        for name, kind in (("get", "get"), ("list", "list"), ("list_prefix", "list"),
                           ("list_dir", "list")):
            original = getattr(cls, name)

            def counted(*args, _original=original, _kind=kind, **kwargs):
                calls[_kind] += 1
                return _original(*args, **kwargs)

            setattr(cls, name, counted)
    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*pr.SMALL, f"store.path={job['url']}"])
    quiet = Console(file=open("/dev/null", "w"))  # noqa: SIM115, PTH123

    def rerun(stage: str):
        def once():
            cfg.stage = stage
            run_pipeline(cfg, quiet)
        return once

    kinds = {"status": lambda: status.damaged(status.collect(job["url"])),
             "re-run generate": rerun("generate"), "re-run evaluate": rerun("evaluate"),
             "repair re-run": rerun("generate")}
    before_each = {"repair re-run": _stale_copy(job["url"])}
    times, reads = {}, {}
    for kind, call in kinds.items():
        before_each.get(kind, lambda: None)()
        said = call()  # warm-up (the expected layout, Hydra, imports)
        assert not said, said
        times[kind] = []
        for r in range(job["repeats"]):
            before_each.get(kind, lambda: None)()
            before = {**calls, "requests": len(sent)}
            start = time.perf_counter()
            call()
            times[kind].append(time.perf_counter() - start)
            if r == 0:
                reads[kind] = {k: v - before[k] for k, v in
                               {**calls, "requests": len(sent)}.items()}
    print(json.dumps({"times": times, "reads": reads}))


def _this_checkouts_s3_server():
    """This checkout's ``tests/s3_server.py`` (the variant's own ``tests`` is first on the
    path, and an older one may lack what is used here)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("s3_server_here", ROOT / "tests" /
                                                  "s3_server.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _stale_copy(url: str):
    """A function that makes the consolidated copy of ``scores/score`` in the root document
    of the store at ``url`` differ from the array's own document: the next run repairs it
    (writes the root attributes' record and the copy again), then finds nothing to do."""
    from zarr.core.buffer import default_buffer_prototype
    from zarr.core.sync import sync

    from pipeline.store.location import locate

    zstore = locate(url).zarr_store(read_only=False)

    def edit() -> None:
        doc = json.loads(sync(zstore.get("zarr.json", default_buffer_prototype())).to_bytes())
        doc["consolidated_metadata"]["metadata"]["scores/score"]["attributes"]["long_name"] = "?"
        data = default_buffer_prototype().buffer.from_bytes(json.dumps(doc).encode())
        sync(zstore.set("zarr.json", data))
    return edit


def measure(where: str, url: str, variants: dict[str, Path], args) -> None:
    found = {label: {kind: [] for kind in TIMED} for label in variants}
    reads = {}
    for _ in range(args.rounds):
        for label, root in variants.items():
            out = run_child(__file__, {"url": url, "repeats": args.repeats}, root, label)
            for kind in TIMED:
                found[label][kind] += out["times"][kind]
            reads[label] = out["reads"]
    (this, new), (base, old) = list(found.items())[:2] if len(found) > 1 else \
        (next(iter(found.items())), (None, None))
    for kind in TIMED:
        a = statistics.median(new[kind])
        line = f"{where:22s} {kind:16s} {a * 1e3:9.1f} ms {_counts(reads[this][kind])}"
        if base is not None:
            b = statistics.median(old[kind])
            line += f" | {b * 1e3:9.1f} ms {_counts(reads[base][kind])} | {b / a:5.2f}x"
        print(line)


def _counts(one: dict) -> str:
    """Zarr's reads and listings, and where the store is in S3 the requests they took."""
    s3 = f" {one['requests']:5d} S3 requests" if one.get("requests") else ""
    return f"{one['get']:5d} reads {one['list']:3d} lists{s3}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline-rev", default=BASELINE_REV)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(json.loads(args.child))  # this variant's code: first on the path
        return
    sys.path.insert(1, str(ROOT))
    from tests import pipeline_runs as pr

    with tempfile.TemporaryDirectory(prefix="bench-store-reads-") as tmp:
        tmp = Path(tmp)
        variants = {"this checkout": ROOT}
        base = export_revision(args.baseline_rev, tmp / "base",
                               parts=("pipeline", "conf", "box_core", "tests"))
        if base is not None:
            variants[args.baseline_rev] = base
        print(f"{'store':22s} {'what':16s} {'this checkout':>30s} | "
              f"{args.baseline_rev:>30s} | ratio   (medians of {args.rounds * args.repeats})")
        stores = [("local disk", str(tmp / "a.zarr"))]
        server = None
        if shutil.which("moto_server") is not None:
            from tests.s3_server import BUCKET, serve

            server = serve()
            server.__enter__()
            stores.append(("S3 (moto, 127.0.0.1)", f"s3://{BUCKET}/a.zarr"))
        else:
            print("S3 (moto): skipped, moto_server is not installed")
        try:
            for where, url in stores:
                made = pr.run(url, "stage=generate", cwd=tmp)
                made = made if made.returncode else pr.run(url, "stage=evaluate", cwd=tmp)
                if made.returncode:
                    raise RuntimeError(made.stderr[-2000:])
                measure(where, url, variants, args)
        finally:
            if server is not None:
                server.__exit__(None, None, None)


if __name__ == "__main__":
    main()
