"""Writes a folder of simulated traces, each of an X axis with one hidden effect the nominal model
(examples/models/xy-x.toml) lacks: the input of fleet.py when no real fleet is at hand.

    python examples/python/make_fleet.py --out fleet-traces [--count 20]

Each trace is the X-Y circle of examples/jobs/xy-circle.toml; its X axis carries one effect of
five kinds (load-side Coulomb friction, a constant force, cogging, load-side viscous friction,
screw pitch error) at one of four sizes. `hidden.csv` in the folder says which trace has which.
"""

import argparse
import os
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import feedloop

HERE = Path(__file__).resolve().parent
MODELS = HERE.parent / "models"
JOBS = HERE.parent / "jobs"

# (effect id, the model file's TOML for it at size k = 1..4)
EFFECTS = [
    ("coulomb_friction", lambda k: f'[[effects.coulomb_friction]]\nside = "load"\nfc_n = {15.0 * k}\n'),
    ("constant_force", lambda k: f"[effects.constant_force]\nforce_n = {(-1) ** k * 75.0 * k}\n"),
    ("cogging", lambda k: f"[effects.cogging]\namplitude_nm = {0.05 * k}\nperiods_per_rev = 12\n"),
    ("viscous_friction", lambda k: f'[[effects.viscous_friction]]\nside = "load"\nc_ns_per_m = {300.0 * k}\n'),
    ("pitch_error", lambda k: f"[effects.pitch_error]\namplitude_m = {2.0e-6 * k}\n"),
]


def job_text(model: Path) -> str:
    """The circle job with the X axis' model replaced."""
    text = (JOBS / "xy-circle.toml").read_text()
    text = text.replace('model = "../models/xy-x.toml"', f'model = "{model.as_posix()}"')
    return text.replace('model = "../models/xy-y.toml"', f'model = "{(MODELS / "xy-y.toml").as_posix()}"')


def make(i: int, out: Path, work: Path) -> tuple:
    effect, toml = EFFECTS[i % len(EFFECTS)]
    size = i // len(EFFECTS) + 1
    model = work / f"x-{i:02}.toml"
    model.write_text((MODELS / "xy-x.toml").read_text() + "\n" + toml(size))
    job = work / f"job-{i:02}.toml"
    job.write_text(job_text(model))
    name = f"trace-{i:02}.csv"
    feedloop.simulate(job).write(out / name)
    return name, effect, size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="folder for the traces")
    ap.add_argument("--count", type=int, default=20, help="number of traces (default 20)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="simulations run at once (threads; default: the CPU count)")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        with ThreadPoolExecutor(a.workers) as pool:
            rows = list(pool.map(lambda i: make(i, a.out, Path(tmp)), range(a.count)))
    with open(a.out / "hidden.csv", "w") as f:
        f.write("file,hidden_effect,size\n")
        for r in rows:
            f.write(",".join(map(str, r)) + "\n")
    print(f"wrote {len(rows)} traces and hidden.csv to {a.out}")


if __name__ == "__main__":
    main()
