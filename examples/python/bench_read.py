"""Time and peak memory of reading one trace with feedloop.read_trace against pandas.read_csv,
each in a fresh Python process (best of --repeat runs; memory is the process's peak resident
set, with the interpreter and the imports counted apart).

    python examples/python/bench_read.py TRACE [--repeat 3]
"""

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
which, path = sys.argv[1], sys.argv[2]
if which == "feedloop":
    import feedloop
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    tr = feedloop.read_trace(path)
    cols = {c: tr[c] for c in tr.columns}  # every column as numpy
    rows = len(tr)
else:
    import pandas as pd
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    df = pd.read_csv(path, comment="#")
    rows = len(df)
dt = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"rows": rows, "seconds": dt, "imports_mib": base / 1024, "peak_mib": peak / 1024}))
"""


def run(which: str, path: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, which, path], check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trace")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    for which in ("feedloop", "pandas"):
        runs = [run(which, a.trace) for _ in range(a.repeat)]
        best = min(runs, key=lambda r: r["seconds"])
        print(f"{which:9} {best['rows']} rows: {best['seconds']:.2f} s (best of {a.repeat}), "
              f"peak {best['peak_mib']:.0f} MiB ({best['peak_mib'] - best['imports_mib']:.0f} MiB "
              f"above the interpreter and imports)")


if __name__ == "__main__":
    main()
