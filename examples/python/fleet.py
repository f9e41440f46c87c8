"""Diagnoses every trace of a folder on a Dask cluster (one task per trace) and writes one row per
trace: the file, the top candidate effect with its class and cut, the verdict, the error figures
and the time the diagnosis took.

    python examples/python/fleet.py --traces DIR --model M --out results.parquet [--workers N]

Without --scheduler a local cluster of N worker processes (default: the CPU count, one thread
each) runs on this machine; with --scheduler tcp://HOST:8786 the same tasks go to an existing
Dask cluster (its workers need the feedloop package and the traces' folder at the same path).
--serial diagnoses the traces one after another in this process, for comparison.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import feedloop


def diagnose_one(path: str, model: str, axis) -> dict:
    """One row of the results: the diagnosis of trace `path` (never raises: an error is a row)."""
    start = time.perf_counter()
    row = {
        "file": os.path.basename(path),
        "top_effect": None,
        "top_class": None,
        "top_cut_pct": None,
        "top_significant": None,
        "second_effect": None,
        "verdict": None,
        "model_cv_rms": None,
        "base_refit_cv_rms": None,
        "samples": None,
        "error": None,
        "seconds": None,
    }
    try:
        tr = feedloop.read_trace(path)
        row["samples"] = len(tr)
        d = feedloop.diagnose(tr, model, axis=axis)
        c = d.candidates
        if c:
            row.update(
                top_effect=c[0]["effect"],
                top_class=c[0]["class"],
                top_cut_pct=c[0]["error_reduction_pct"],
                top_significant=c[0]["significant"],
            )
        if len(c) > 1:
            row["second_effect"] = c[1]["effect"]
        row.update(
            verdict=d.verdict,
            model_cv_rms=d.json.get("model_cv_rms"),
            base_refit_cv_rms=d.json.get("base_refit_cv_rms"),
        )
    except feedloop.FeedloopError as e:
        row["error"] = str(e)
    row["seconds"] = time.perf_counter() - start
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--traces", required=True, type=Path, help="folder of traces (*.csv)")
    ap.add_argument("--model", required=True, help="nominal model file (TOML)")
    ap.add_argument("--out", required=True, type=Path, help="results file (Parquet)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="worker processes of the local cluster (default: the CPU count)")
    ap.add_argument("--axis", default=None, help="axis the model describes (default: the only one)")
    ap.add_argument("--scheduler", default=None,
                    help="address of an existing Dask scheduler instead of a local cluster")
    ap.add_argument("--serial", action="store_true",
                    help="no cluster: one trace after another in this process")
    a = ap.parse_args()

    files = sorted(str(p.resolve()) for p in a.traces.glob("*.csv") if p.name != "hidden.csv")
    if not files:
        print(f"fleet.py: no *.csv trace in {a.traces}", file=sys.stderr)
        return 2
    if not Path(a.model).exists():
        print(f"fleet.py: {a.model}: no such model file", file=sys.stderr)
        return 2
    model = str(Path(a.model).resolve())
    if a.workers < 1:
        print(f"fleet.py: --workers {a.workers}: must be 1 or more", file=sys.stderr)
        return 2

    start = time.perf_counter()
    if a.serial:
        rows = [diagnose_one(f, model, a.axis) for f in files]
        how = "serial, one process"
    else:
        from dask.distributed import Client, LocalCluster

        if a.scheduler:
            client = Client(a.scheduler)
            cluster = None
            how = f"Dask cluster at {a.scheduler}"
        else:
            cluster = LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
            how = f"Dask local cluster, {a.workers} worker processes"
        try:
            futures = client.map(diagnose_one, files, model=model, axis=a.axis, pure=False)
            rows = client.gather(futures)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    wall = time.perf_counter() - start

    import pandas as pd

    df = pd.DataFrame(rows)
    df.to_parquet(a.out, index=False)
    with pd.option_context("display.width", 200, "display.max_colwidth", 40):
        print(df.drop(columns=["verdict", "error"]).to_string(index=False))
    failed = int(df["error"].notna().sum())
    print(f"{len(df)} traces in {wall:.2f} s wall ({how}); sum of per-trace times "
          f"{df['seconds'].sum():.2f} s; {failed} failed; wrote {a.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
