"""``twin study``: study files refused in one line, results independent of the worker count and
the scheduler, resume after a real SIGKILL without a lost or repeated trial."""

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from tests.helpers import ROOT, SCENARIOS
from twin.cli import main
from twin.cli.common import EXIT_BAD_INPUT
from twin.errors import TwinError
from twin.studies import load_study
from twin.studies.runner import BATCH_DIR, RESULTS, batch_files, run_study

#: A tiny study: two scan lines of the S-surface, two sigma levels, six trials each.
TINY = f"""
name = "tiny"
seed = 7
scenario = "{SCENARIOS / 's_surface.toml'}"
trials = 6
kind = "fast"

[overrides.scan]
max_lines = 2

[grid]
"sensor.sigma_m" = [1e-6, 5e-6]
"""


def write_study(folder, text=TINY, name="tiny.toml"):
    p = folder / name
    p.write_text(text)
    return p


def run_main(capsys, *argv):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def one_line_refusal(rc, err):
    return rc == EXIT_BAD_INPUT and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def assert_same_table(a, b):
    """Equal trial by trial, bit for bit (the wall time aside)."""
    a, b = a.drop_columns(["time_s"]), b.drop_columns(["time_s"])
    assert a.column_names == b.column_names
    for name in a.column_names:
        x, y = a.column(name).to_pylist(), b.column(name).to_pylist()
        if isinstance(x[0], float):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=name)
        else:
            assert x == y, name


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny study run in this process (one worker)."""
    folder = tmp_path_factory.mktemp("study")
    study = write_study(folder)
    run_study(load_study(study), folder / "one", workers=1)
    return study, pq.read_table(folder / "one" / RESULTS)


@pytest.mark.parametrize("text, words", [
    ("bogus = 1\n" + TINY, ["bogus", "allowed"]),
    (TINY.replace("[1e-6, 5e-6]", "[]"), ["empty list"]),
    (TINY.replace("[1e-6, 5e-6]", "[1e-6, -2.0]"), ["sensor.sigma_m", "-2.0"]),
    (TINY + '"sensor.nonsense" = [1]\n', ["sensor.nonsense"]),
    (TINY + '"localize.method" = ["nope"]\n', ["localize.method", "nope"]),
    (TINY.replace('kind = "fast"', 'kind = "slow"'), ["kind", "fast, full"]),
    (TINY + '"localize.points" = [3]\n', ["localize.points", "[6, 10^7]"]),
])
def test_bad_study_refused_in_one_line(tmp_path, capsys, text, words):
    study = write_study(tmp_path, text)
    with pytest.raises(TwinError) as exc:
        load_study(study)
    assert all(w in str(exc.value) for w in words), str(exc.value)
    rc, out, err = run_main(capsys, "study", study, "--out", tmp_path / "out")
    assert one_line_refusal(rc, err), err
    assert out == "" and not (tmp_path / "out").exists()


@pytest.mark.slow  # the default suite's five minutes (issue 31): CI's slow tier runs it
def test_workers_give_identical_tables(reference, tmp_path):
    study, table = reference
    assert table.num_rows == 12 and set(table.column("status").to_pylist()) <= {"ok", "not_converged", "poor_fit"}
    assert table.column("sensor.sigma_m").to_pylist() == [1e-6] * 6 + [5e-6] * 6
    run_study(load_study(study), tmp_path / "two", workers=2)
    assert_same_table(table, pq.read_table(tmp_path / "two" / RESULTS))
    assert (tmp_path / "two" / "report.md").is_file() and (tmp_path / "two" / "translation_error.png").is_file()


@pytest.mark.slow
def test_dask_local_cluster_equals_local_run(reference, tmp_path):
    study, table = reference
    run_study(load_study(study), tmp_path / "dask", workers=2, scheduler="dask")
    assert_same_table(table, pq.read_table(tmp_path / "dask" / RESULTS))


def kill_after_batches(study_file, out, batches: int = 1, *extra: str) -> int:
    """``twin study STUDY --out OUT`` in a subprocess, killed with SIGKILL once ``batches`` batch
    files are written; its return code."""
    cmd = [sys.executable, "-m", "twin.cli", "study", str(study_file), "--out", str(out), "--quiet", *extra]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(batch_files(out)) < batches and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    return proc.returncode


def test_resume_after_sigkill(reference, tmp_path, capsys):
    study, table = reference
    out = tmp_path / "killed"
    assert kill_after_batches(study, out) == -signal.SIGKILL
    assert batch_files(out) and not (out / RESULTS).exists(), "the kill must land between the first batch and the end"
    done_before = sum(pq.read_table(p).num_rows for p in batch_files(out))
    assert 0 < done_before < table.num_rows
    rc, _, err = run_main(capsys, "study", study, "--out", out)   # refused without --resume
    assert one_line_refusal(rc, err) and "--resume" in err
    rc, text, err = run_main(capsys, "study", study, "--out", out, "--resume", "--json", "--quiet")
    assert rc == 0, err
    assert f'"trials_resumed": {done_before}' in text
    final = pq.read_table(out / RESULTS)
    ids = list(zip(final.column("cell").to_pylist(), final.column("trial").to_pylist(), strict=True))
    assert len(ids) == len(set(ids)) == table.num_rows
    assert_same_table(table, final)
    # no temporary batch left under a final name; every row in exactly one batch file
    assert sum(pq.read_table(p).num_rows for p in batch_files(out)) == table.num_rows
    assert all(p.name.startswith("batch-") for p in (out / BATCH_DIR).iterdir() if not p.name.startswith("."))


def test_folder_of_another_study_refused(reference, tmp_path, capsys):
    study, _ = reference
    out = tmp_path / "a"
    other = write_study(tmp_path, TINY.replace("seed = 7", "seed = 8").replace("trials = 6", "trials = 1"),
                        "other.toml")
    rc, _, err = run_main(capsys, "study", other, "--out", out, "--quiet")
    assert rc == 0, err
    for extra in ([], ["--resume"]):
        rc, out_text, err = run_main(capsys, "study", study, "--out", out, *extra)
        assert one_line_refusal(rc, err) and "different study" in err, err
        assert out_text == ""
    assert pq.read_table(out / RESULTS).num_rows == 2   # the other study's results are untouched


def test_unreachable_scheduler(reference, tmp_path, capsys):
    study, _ = reference
    t0 = time.monotonic()
    rc, out, err = run_main(capsys, "study", study, "--out", tmp_path / "x", "--scheduler", "tcp://127.0.0.1:1")
    assert one_line_refusal(rc, err) and "tcp://127.0.0.1:1" in err, err
    assert time.monotonic() - t0 < 10 and out == "" and not (tmp_path / "x").exists()


@pytest.mark.slow
def test_a_random_subset_of_points_per_trial_whatever_the_workers(tmp_path):
    study = write_study(tmp_path, TINY.replace('"sensor.sigma_m" = [1e-6, 5e-6]', '"localize.points" = [150, 0]')
                        .replace("trials = 6", "trials = 3"))
    run_study(load_study(study), tmp_path / "one", workers=1)
    run_study(load_study(study), tmp_path / "two", workers=2)
    a, b = pq.read_table(tmp_path / "one" / RESULTS), pq.read_table(tmp_path / "two" / RESULTS)
    assert_same_table(a, b)
    cells, n = a.column("cell").to_pylist(), a.column("n_points").to_pylist()
    assert all(v == 150 for c, v in zip(cells, n, strict=True) if c == 0)
    assert all(v > 1000 for c, v in zip(cells, n, strict=True) if c == 1)


@pytest.mark.slow  # the default suite's five minutes (issue 31): CI's slow tier runs it
def test_sigkill_leaves_no_worker_behind(tmp_path):
    """SIGKILL of ``twin study --workers 2``: its workers end with it (they would otherwise run
    on for minutes, holding the command's stdout and stderr open: a ``| tee`` or a CI step would
    wait for them). The pipes reach end-of-file as soon as every holder is gone."""
    study = write_study(tmp_path, TINY.replace("trials = 6", "trials = 200"))
    out = tmp_path / "killed"
    argv = [sys.executable, "-m", "twin.cli", "study", str(study), "--out", str(out), "--workers", "2"]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not batch_files(out) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert batch_files(out), "the study must have started its batches"
    os.kill(proc.pid, signal.SIGKILL)
    t0 = time.monotonic()
    proc.communicate(timeout=60)   # returns when the last holder of the pipes is gone
    assert time.monotonic() - t0 < 10.0, "the workers outlived the command"
    assert sum(pq.read_table(p).num_rows for p in batch_files(out)) < 400   # the study was cut short


# ------------------------------------------------------------------ what --resume and --force never lose
def _finished_copy(reference, tmp_path):
    """A copy of the finished tiny study's folder: (study file, folder, its final files' bytes)."""
    import shutil

    study, _ = reference
    src = Path(study).parent / "one"
    out = tmp_path / "done"
    shutil.copytree(src, out)
    finals = {name: (out / name).read_bytes() for name in (RESULTS, "report.md")}
    return study, out, finals


@pytest.mark.parametrize("damage", ["truncated", "random bytes", "empty", "another table", "duplicated"])
def test_a_damaged_batch_is_refused_and_nothing_is_deleted(reference, tmp_path, capsys, damage):
    study, out, finals = _finished_copy(reference, tmp_path)
    first = batch_files(out)[0]
    if damage == "truncated":
        first.write_bytes(first.read_bytes()[:-40])
    elif damage == "random bytes":
        first.write_bytes(np.random.default_rng(3).bytes(2000))
    elif damage == "empty":
        first.write_bytes(b"")
    elif damage == "another table":
        import pyarrow as pa

        pq.write_table(pa.table({"x": [1.0, 2.0]}), first)
    else:
        (out / BATCH_DIR / "batch-999999.parquet").write_bytes(first.read_bytes())
    rc, stdout, err = run_main(capsys, "study", study, "--out", out, "--resume")
    assert one_line_refusal(rc, err) and stdout == "", err
    assert first.name in err or "batch-999999" in err
    assert {name: (out / name).read_bytes() for name in finals} == finals


def test_an_interrupted_force_keeps_the_finished_study(reference, tmp_path):
    study, out, finals = _finished_copy(reference, tmp_path)

    def interrupt(done, total):
        if done > 0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_study(load_study(study), out, force=True, on_progress=interrupt)
    assert {name: (out / name).read_bytes() for name in finals} == finals
    assert [p.name for p in tmp_path.iterdir()] == ["done"]   # no staged folder left behind
    run_study(load_study(study), out, force=True)              # and a whole forced run replaces it
    assert_same_table(pq.read_table(out / RESULTS), pq.read_table(io.BytesIO(finals[RESULTS])))
    assert [p.name for p in tmp_path.iterdir()] == ["done"]


def test_resume_notices_a_replaced_mesh(tmp_path, capsys):
    """The study's identity covers the files its scenario names: the mesh replaced by another
    part's under the same name is refused (it used to mix two parts in one table)."""
    from twin.parts import make_workpiece
    from twin.studies.runner import prepare_folder

    make_workpiece("s_surface").export(tmp_path / "part.stl")
    text = (SCENARIOS / "s_surface.toml").read_text().replace('shape = "s_surface"', 'mesh = "part.stl"')
    (tmp_path / "scenario.toml").write_text(text)
    study = write_study(tmp_path, TINY.replace(str(SCENARIOS / "s_surface.toml"), str(tmp_path / "scenario.toml")))
    out = tmp_path / "out"
    prepare_folder(out, load_study(study), resume=False, force=False)
    assert prepare_folder(out, load_study(study), resume=True, force=False)[0] == out   # same inputs: resumable
    make_workpiece("cube").export(tmp_path / "part.stl")
    rc, _, err = run_main(capsys, "study", study, "--out", out, "--resume")
    assert one_line_refusal(rc, err) and "part.stl has changed" in err, err


@pytest.mark.slow
def test_scheduler_addresses_that_are_not_a_dask_scheduler(reference, tmp_path, capsys):
    """Something that accepts and never answers, an HTTP server, a scheduler without workers:
    each refused in one line within twice the connect timeout, nothing written; a real
    scheduler with a worker runs the study to the same table."""
    import http.server
    import socket
    import threading

    from distributed import LocalCluster

    study, table = reference
    silent = socket.create_server(("127.0.0.1", 0))
    held = []
    threading.Thread(target=lambda: held.append(silent.accept()), daemon=True).start()
    web = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    threading.Thread(target=web.serve_forever, daemon=True).start()
    with LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=None) as empty:
        for address, words in [(f"tcp://127.0.0.1:{silent.getsockname()[1]}", "no Dask scheduler's answer"),
                               (f"tcp://127.0.0.1:{web.server_address[1]}", "Dask scheduler"),
                               (empty.scheduler_address, "no worker")]:
            t0 = time.monotonic()
            rc, out, err = run_main(capsys, "study", study, "--out", tmp_path / "x", "--scheduler", address)
            assert one_line_refusal(rc, err) and words in err, err
            assert time.monotonic() - t0 < 30 and not (tmp_path / "x").exists()
    web.shutdown()
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                      dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        rc, _, err = run_main(capsys, "study", study, "--out", tmp_path / "tcp", "--scheduler", address, "--quiet")
    assert rc == 0, err
    assert_same_table(table, pq.read_table(tmp_path / "tcp" / RESULTS))
