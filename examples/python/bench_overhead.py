"""The package's overhead on `diagnose` against the CLI: the same trace and model diagnosed by
`feedloop diagnose --json` (a process per run), by `feedloop.diagnose` in a fresh Python process
(interpreter start and import counted), and by `feedloop.diagnose` in a running interpreter.
Best of --repeat runs each.

    python examples/python/bench_overhead.py --cli target/release/feedloop \\
        --trace examples/data/emps/emps_estimation.csv --model examples/models/emps-nominal.toml
"""

import argparse
import subprocess
import sys
import time

import feedloop


def best(f, n):
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        out.append(time.perf_counter() - t0)
    return min(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cli", required=True, help="the feedloop binary")
    ap.add_argument("--trace", required=True)
    ap.add_argument("--model", required=True)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    cli = best(lambda: subprocess.run(
        [a.cli, "diagnose", "--trace", a.trace, "--model", a.model, "--json"],
        check=True, capture_output=True), a.repeat)
    code = f"import feedloop; feedloop.diagnose({a.trace!r}, {a.model!r})"
    fresh = best(lambda: subprocess.run([sys.executable, "-c", code], check=True,
                                        capture_output=True), a.repeat)
    warm = best(lambda: feedloop.diagnose(a.trace, a.model), a.repeat)
    print(f"CLI diagnose --json:                 {cli:.3f} s")
    print(f"python -c 'feedloop.diagnose(...)':  {fresh:.3f} s ({fresh - cli:+.3f} s against the CLI)")
    print(f"feedloop.diagnose in a running interpreter: {warm:.3f} s ({warm - cli:+.3f} s)")


if __name__ == "__main__":
    main()
