"""Tests of the Python package against the CLI it binds: the same traces, the same workbench
figures, the same messages."""

import json
import os
import shutil
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

import feedloop

REPO = Path(__file__).resolve().parents[2]
JOB = REPO / "examples" / "jobs" / "xy-circle.toml"
EMPS = REPO / "examples" / "data" / "emps" / "emps_estimation.csv"
EMPS_MODEL = REPO / "examples" / "models" / "emps-nominal.toml"


@pytest.fixture(scope="session")
def cli():
    """The `feedloop` binary: $FEEDLOOP_BIN, the workspace's release build (built when absent and
    cargo is there), or one on PATH."""
    env = os.environ.get("FEEDLOOP_BIN")
    if env:
        return env
    built = REPO / "target" / "release" / "feedloop"
    if not built.exists() and shutil.which("cargo"):
        subprocess.run(
            ["cargo", "build", "--release", "-p", "feedloop-cli"], cwd=REPO, check=True
        )
    if built.exists():
        return str(built)
    found = shutil.which("feedloop")
    if found:
        return found
    pytest.fail("no feedloop binary: set FEEDLOOP_BIN or build it with cargo build --release")


@pytest.fixture(scope="session")
def cli_trace(cli, tmp_path_factory):
    """The trace `feedloop sim` writes for the circle job."""
    out = tmp_path_factory.mktemp("sim")
    subprocess.run([cli, "sim", str(JOB), "--out", str(out), "--quiet", "--json"], check=True,
                   stdout=subprocess.DEVNULL)
    return out / "trace.csv"


def csv_columns(path):
    """The CSV's columns parsed by Python itself (float() reads the shortest round-trip text)."""
    lines = [l for l in Path(path).read_text().splitlines() if not l.startswith("#")]
    names = lines[0].split(",")
    rows = [[float(c) for c in l.split(",")] for l in lines[1:]]
    cols = np.array(rows, dtype=np.float64).T
    return dict(zip(names, cols))


def test_simulate_equals_the_cli_trace_to_the_bit(cli_trace):
    sim = feedloop.simulate(JOB)
    read = feedloop.read_trace(cli_trace)
    want = csv_columns(cli_trace)
    assert sim.columns == list(want) == read.columns
    assert "x.load" in sim.columns and len(sim) == len(want["t"]) > 1000
    for c in sim.columns:
        a = sim[c]
        assert a.dtype == np.float64
        # bit for bit: the same float64 values, compared as integers
        assert np.array_equal(a.view(np.uint64), want[c].view(np.uint64)), c
        assert np.array_equal(read[c].view(np.uint64), want[c].view(np.uint64)), c
    dt = np.median(np.diff(want["t"]))
    assert sim.period_s == pytest.approx(dt, rel=1e-9)


def test_to_pandas_holds_every_column(cli_trace):
    pd = pytest.importorskip("pandas")
    tr = feedloop.read_trace(cli_trace)
    df = tr.to_pandas()
    assert isinstance(df, pd.DataFrame)
    assert list(df.columns) == tr.columns and len(df) == len(tr)
    assert np.array_equal(df["y.torque"].to_numpy(), tr["y.torque"])


def test_emps_diagnose_names_coulomb_friction_first():
    d = feedloop.diagnose(EMPS, EMPS_MODEL)
    top = d.candidates[0]
    assert top["effect"] == "coulomb_friction" and top["significant"] is True
    assert isinstance(d.verdict, str) and "coulomb_friction" in d.verdict
    assert "coulomb_friction" in d._repr_html_()


def test_emps_fit_brings_the_equation_error_under_5_percent():
    f = feedloop.fit(EMPS, EMPS_MODEL, add=["coulomb_friction", "constant_force"])
    before = f.error_before["equation_nrmse_pct"]
    after = f.error_after["equation_nrmse_pct"]
    assert before > 10.0 and after < 5.0
    # the published EMPS figures: Fc about 20 N, an offset of about 3 N
    assert 18.0 < f.params["fc_n"] < 23.0
    assert "[effects.coulomb_friction]" in f.model_text
    # the fitted model, given as text, compares as well as fit said
    c = feedloop.compare(EMPS, f.model_text)
    assert c.equation_nrmse_pct == pytest.approx(after, rel=1e-6)


def test_results_equal_the_cli_json(cli, tmp_path):
    out = subprocess.run(
        [cli, "diagnose", "--trace", str(EMPS), "--model", str(EMPS_MODEL), "--json"],
        check=True, capture_output=True, text=True,
    ).stdout
    want = json.loads(out)
    got = feedloop.diagnose(feedloop.read_trace(EMPS), EMPS_MODEL).json
    assert [c["effect"] for c in got["candidates"]] == [c["effect"] for c in want["candidates"]]
    assert got["verdict"] == want["verdict"]


def test_errors_are_the_cli_messages(cli, tmp_path):
    missing = tmp_path / "nothing.csv"
    with pytest.raises(feedloop.FeedloopError) as e:
        feedloop.read_trace(missing)
    assert str(missing) in str(e.value) and "cannot read trace" in str(e.value)
    r = subprocess.run([cli, "diagnose", "--trace", str(EMPS), "--model", str(EMPS_MODEL),
                        "--axis", "q"], capture_output=True, text=True)
    assert r.returncode == 2
    with pytest.raises(feedloop.FeedloopError) as e:
        feedloop.diagnose(EMPS, EMPS_MODEL, axis="q")
    assert r.stderr.strip() == f"feedloop: error: {e.value}"
    with pytest.raises(feedloop.FeedloopError, match="coulomb_frikshun"):
        feedloop.fit(EMPS, EMPS_MODEL, add=["coulomb_frikshun"])
    with pytest.raises(KeyError, match="q.load"):
        feedloop.read_trace(EMPS)["q.load"]


def test_threads_run_the_workbench_together():
    # the work runs without the interpreter lock: four threads finish with the serial answers
    tr = feedloop.read_trace(EMPS)
    results = [None] * 4

    def work(i):
        results[i] = feedloop.diagnose(tr, EMPS_MODEL).candidates[0]["effect"]

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == ["coulomb_friction"] * 4


def test_mcap_export_reads_back_every_column_and_sample(cli, cli_trace, tmp_path):
    reader = pytest.importorskip("mcap.reader")
    out = tmp_path / "trace.mcap"
    subprocess.run([cli, "trace", "export", str(cli_trace), "--format", "mcap", "--out",
                    str(out)], check=True, stdout=subprocess.DEVNULL)
    want = csv_columns(cli_trace)
    got = {}
    times = {}
    with open(out, "rb") as f:
        r = reader.make_reader(f)
        for schema, channel, message in r.iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            props = json.loads(schema.data)["properties"]
            m = json.loads(message.data)
            assert set(m) == set(props)
            axis = channel.topic.lstrip("/")
            for k, v in m.items():
                # every channel carries t: each axis' copy is checked
                name = f"{axis}:t" if k == "t" else f"{axis}.{k}"
                got.setdefault(name, []).append(v)
            times.setdefault(axis, []).append(message.log_time)
    assert set(times) == {"x", "y"}
    assert {c for c in got if ":" not in c} == set(want) - {"t"}
    for c, v in got.items():
        ref = want["t"] if c.endswith(":t") else want[c]
        assert np.array_equal(np.array(v, dtype=np.float64), ref), c
    for axis, ts in times.items():
        assert ts == [round(t * 1e9) for t in want["t"]], axis


def test_parquet_export_reads_back_every_column_and_sample(cli, cli_trace, tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    out = tmp_path / "trace.parquet"
    subprocess.run([cli, "trace", "export", str(cli_trace), "--format", "parquet", "--out",
                    str(out)], check=True, stdout=subprocess.DEVNULL)
    want = csv_columns(cli_trace)
    table = pq.read_table(out)
    assert table.column_names == list(want)
    for c in want:
        col = table.column(c)
        assert str(col.type) == "double"
        assert np.array_equal(col.to_numpy(), want[c]), c
    meta = table.schema.metadata
    assert float(meta[b"period_s"]) == pytest.approx(feedloop.read_trace(cli_trace).period_s)


def test_columns_view_the_trace_read_only_and_outlive_it(cli_trace):
    import gc

    tr = feedloop.read_trace(cli_trace)
    a = tr["x.load"]
    want = csv_columns(cli_trace)["x.load"]
    assert not a.flags.writeable
    with pytest.raises(ValueError):
        a[0] = 1.0
    del tr
    gc.collect()
    # the array keeps the trace's memory alive
    assert np.array_equal(a, want)
    b = a.copy()
    b[0] = 1.0
    assert b.flags.writeable and a[0] == want[0]
