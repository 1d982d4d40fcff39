"""Run a study: every (cell, trial) not yet done, in batches, on an executor, streamed to Parquet.

Layout of the output folder ``DIR``:

* ``manifest.json``: the study's content hash (``study_hash``) and settings; a folder whose
  manifest names another study is refused.
* ``results/batch-XXXXXX.parquet``: one file per finished batch, written to a hidden temporary
  name and renamed into place, so a file under its final name is whole. ``--resume`` reads the
  finished (cell, trial) ids from these files and runs the others: a run killed at any moment
  loses at most its batches in flight and never repeats a trial.
* ``report.md`` and ``translation_error.png`` (:mod:`twin.studies.report`).
* ``results.parquet``: the final table, every batch, sorted by (cell, trial); written last, so
  its presence says the study is complete.

``--force`` over a finished study runs the new one in a hidden folder beside it and moves it
into place when it is complete: finished results are never deleted before their replacement
exists. ``--resume`` reads every batch file before anything runs: a damaged one, one of
another table, or a trial in two files is refused in one line, and nothing is deleted. The
study's identity (``study_hash``) covers the study, its scenarios' text and the bytes of the
mesh files they name: a file replaced under the same name is another study.

Columns of the tables (one row per trial):

* ``cell`` (int): the grid cell (row-major over the grid's factors, the last fastest);
  ``trial`` (int): the trial within the cell;
* one column per grid factor, named by its key path (``sensor.sigma_m``), holding the cell's value;
* ``omega_x_urad``, ``omega_y_urad``, ``omega_z_urad`` [urad], ``v_x_um``, ``v_y_um``, ``v_z_um`` [um]:
  the pose error twist ``xi = [omega, v]`` with ``T_est = T_true exp(xi)``, workpiece frame;
* ``rotation_error_deg`` [deg], ``translation_error_um`` [um]: the rotation angle and translation
  distance between the estimate and the truth;
* ``rmse_um`` [um]: RMS point-to-model distance of the inliers at the estimate;
* ``iterations`` (int): pose updates; ``status`` (str): the localization's verdict (``ok``, ...,
  ``error`` where it raised, ``not_installed`` for a missing peer); ``time_s`` [s]: wall time of
  the localization (not reproducible); ``n_points`` (int): points handed to the localization;
* ``crlb_rotation_urad``, ``crlb_translation_um``, ``mahalanobis2``: the Cramer-Rao bound of the
  trial's points at the truth and the pose error's squared Mahalanobis distance under it;
  ``path_error_max_um``: the compensated CAD path's largest error (full trials; NaN otherwise).
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import multiprocessing
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from twin.errors import TwinError
from twin.io.output import new_file_mode, new_folder_mode
from twin.studies.kinds import metric_columns, run_trial
from twin.studies.spec import Study
from twin.studies.trials import TWIST_COLUMNS

MANIFEST = "manifest.json"
RESULTS = "results.parquet"
BATCH_DIR = "results"
BATCH_RE = re.compile(r"^batch-(\d{6})\.parquet$")
#: Seconds to wait for a Dask scheduler named by address before giving up.
CONNECT_TIMEOUT_S = 5
#: Batches in flight per worker (keeps workers busy while finished batches are written).
IN_FLIGHT_PER_WORKER = 2


def batch_size(study: Study, workers: int) -> int:
    """Trials per batch: small enough that a kill loses little and work spreads over workers."""
    return max(1, min(16, study.n_trials // (4 * max(workers, 1)) or 1))


def _worker_setup() -> None:
    """Pool workers leave Ctrl-C to the command, which stops the study and keeps the finished
    batches; and they end with it: on Linux each asks the kernel for SIGKILL when the command
    dies (a SIGKILL of the command would otherwise leave them running for minutes, holding its
    stdout and stderr open, so a ``| tee`` or a CI step waits for them)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        import ctypes

        PR_SET_PDEATHSIG = 1
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)


def pool_size(workers: int, trials: int) -> int:
    """Worker processes for ``workers`` asked: no more than the trials to run nor than the
    machine's cores (more only share the cores and pay their start-up)."""
    return max(1, min(workers, trials, os.cpu_count() or 1))


def run_batch(study: Study, ids: list[tuple[int, int]]) -> list[dict]:
    """The trials ``ids`` ((cell, trial) pairs) of a study, in order (runs in a worker)."""
    return [run_trial(study, c, t) for c, t in ids]


# ------------------------------------------------------------------ the folder
def prepare_folder(out: Path, study: Study, resume: bool, force: bool) -> tuple[Path, set[tuple[int, int]]]:
    """Check the output folder before any work (module docstring); returns the folder to run in
    and the (cell, trial) ids its batch files already hold.

    That is ``out`` itself (created), except with ``force`` over an existing study: then a
    hidden folder beside it, which :func:`run_study` moves into place when the new study is
    complete, so the finished results are never deleted before their replacement exists. With
    ``resume`` every batch file is read first: a damaged one is refused before anything changes.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TwinError(f"--out {out} exists and is not a folder")
    work, done = out, set()
    if out.is_dir() and any(out.iterdir()):
        old = _read_manifest(out)
        same = old is not None and old.get("study_hash") == study.content_hash
        if resume and not same:
            what = "no study manifest" if old is None else f"a different study ({old.get('name')!r})"
            changed = _changed_input(old, study)
            if changed:
                what = f"the same study on another input: {changed} has changed since it began"
            raise TwinError(f"--out {out} holds {what}; --resume continues the same study only "
                            "(--force starts it over)")
        if not resume:
            if not force:
                held = "" if same or old is None else f" (it holds a different study, {old.get('name')!r})"
                raise TwinError(f"--out {out} exists{held}; pass --resume to continue the same study, "
                                "or --force to replace it whole")
            work = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.absolute().parent))
            os.chmod(work, new_folder_mode())
        else:
            done = finished_ids(out, study)  # every batch readable and of this study, no trial twice
    work.mkdir(parents=True, exist_ok=True)
    (work / BATCH_DIR).mkdir(exist_ok=True)
    manifest = {"study_hash": study.content_hash, **study.settings()}
    _write_atomic(work / MANIFEST, json.dumps(manifest, indent=2, default=str).encode())
    return work, done


def _put_in_place(work: Path, out: Path) -> None:
    """Move a finished forced study into place: the old folder aside, the new one in, the old
    one removed (old and new files never mix)."""
    aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.absolute().parent))
    os.replace(out, aside / out.name)
    os.replace(work, out)
    shutil.rmtree(aside, ignore_errors=True)


def _changed_input(old: dict | None, study: Study) -> str | None:
    """The first input file whose content differs from the manifest's record, or None."""
    recorded = (old or {}).get("input_files")
    if not isinstance(recorded, dict):
        return None
    now = dict(study.input_files)
    for path in sorted(set(recorded) | set(now)):
        if recorded.get(path) != now.get(path):
            return path
    return None


def _read_manifest(out: Path) -> dict | None:
    try:
        return json.loads((out / MANIFEST).read_text())
    except (OSError, ValueError):
        return None


def _write_atomic(path: Path, data: bytes) -> None:
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.partial-", dir=path.parent)
    try:
        # mkstemp makes the file private (0600); the result gets a new file's usual permissions
        os.fchmod(fd, new_file_mode())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(name, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(name)
        raise


def _write_table_atomic(path: Path, table: pa.Table) -> None:
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.partial-", dir=path.parent)
    os.close(fd)
    try:
        pq.write_table(table, name)
        with open(name, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(name, new_file_mode())
        os.replace(name, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(name)
        raise


def batch_files(out: Path) -> list[Path]:
    """The finished batch files, by number (temporaries, hidden, are not listed)."""
    d = Path(out) / BATCH_DIR
    return sorted(p for p in d.iterdir() if BATCH_RE.match(p.name)) if d.is_dir() else []


def read_batch(path: Path, study: Study) -> pa.Table:
    """One batch file, refused in one line when it is damaged (truncated, empty, not Parquet)
    or holds another table than this study's."""
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise TwinError(f"{path}: damaged batch file ({' '.join(str(exc).split())[:120]}); delete it and run "
                        "--resume again to redo its trials") from None
    expected = ["cell", "trial", *study.factors, *metric_columns(study.kind)]
    if table.column_names != expected:
        raise TwinError(f"{path}: not a batch of this study (columns {table.column_names[:4]}...); delete it and "
                        "run --resume again to redo its trials")
    return table


def finished_ids(out: Path, study: Study) -> set[tuple[int, int]]:
    """(cell, trial) of every trial in the finished batch files (each read whole and checked)."""
    done: set[tuple[int, int]] = set()
    for p in batch_files(out):
        t = read_batch(p, study)
        ids = list(zip(t.column("cell").to_pylist(), t.column("trial").to_pylist(), strict=True))
        if done & set(ids) or len(set(ids)) != len(ids):
            raise TwinError(f"{p}: holds a trial another batch file holds too; delete the duplicated batch and "
                            "run --resume again")
        done.update(ids)
    return done


def rows_table(study: Study, rows: list[dict]) -> pa.Table:
    """Trial rows as a table with the factor columns added (module docstring)."""
    cells = study.cells
    cols: dict[str, list] = {"cell": [r["cell"] for r in rows], "trial": [r["trial"] for r in rows]}
    for f in study.factors:
        # a table-valued factor (``overrides``) is one JSON text per row
        cols[f] = [_column_value(cells[r["cell"]][f]) for r in rows]
    for m in metric_columns(study.kind):
        cols[m] = [r[m] for r in rows]
    return pa.table(cols)


def _column_value(v):
    return json.dumps(v, sort_keys=True) if isinstance(v, dict) else v


# ------------------------------------------------------------------ executors
def _chunks(ids: list, size: int) -> Iterator[list]:
    for i in range(0, len(ids), size):
        yield ids[i:i + size]


@contextlib.contextmanager
def executor(scheduler: str, workers: int) -> Iterator[tuple[str, object]]:
    """``(mode, executor)``: ``("inline", None)`` (one worker: this process), ``("pool", a process
    pool)`` or ``("dask", a Dask client)`` (a LocalCluster started here, or a running scheduler)."""
    if scheduler == "local" and workers == 1:
        yield "inline", None
        return
    if scheduler == "local":
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_setup)
        try:
            yield "pool", pool
        except BaseException:
            # an interrupt or an error: drop the queued batches instead of running them out
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise TwinError("--scheduler dask needs the 'distributed' package (pip install 'dask[distributed]')") \
            from None
    if scheduler == "dask":
        # the cluster's own log lines would bury the progress and the one-line errors on stderr
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            yield "dask", client
        return
    try:
        client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise TwinError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there "
                        f"({' '.join(str(exc).split())[:160]})") from None
    with client:
        yield "dask", client


def run_study(study: Study, out: Path, workers: int = 1, scheduler: str = "local", resume: bool = False,
              force: bool = False, on_progress: Callable[[int, int], None] = lambda done, total: None) -> dict:
    """Run every trial not yet in ``out``'s batch files, then write the final table and report.

    With ``study.adaptive`` the trials run in rounds of ``adaptive.batch`` per cell until each
    cell's results are stable (:mod:`twin.studies.adaptive`) or it reaches ``study.trials``;
    the rounds depend on the results only, so a resume or another worker count runs the same
    trials.

    Returns a summary: trials run now and before, batches, seconds, the output files.
    """
    out = Path(out)
    if scheduler not in ("local", "dask") and not scheduler.startswith("tcp://"):
        raise TwinError(f"--scheduler must be local, dask or a tcp://HOST:PORT address, got {scheduler!r}")
    if scheduler.startswith("tcp://"):
        _probe(scheduler)
    work, done = prepare_folder(out, study, resume, force)
    try:
        summary = _run_in(work, study, done, workers, scheduler, on_progress)
    except BaseException:
        if work != out:  # a forced study that did not finish: the old one stays as it was
            shutil.rmtree(work, ignore_errors=True)
        raise
    if work != out:
        _put_in_place(work, out)
    summary["out"] = str(out)
    for key in ("results", "report"):
        summary[key] = str(out / Path(summary[key]).name)
    summary["plots"] = [str(out / Path(p).name) for p in summary["plots"]]
    return summary


def _run_in(out: Path, study: Study, done: set[tuple[int, int]], workers: int, scheduler: str,
            on_progress: Callable[[int, int], None]) -> dict:
    """Run the study's missing trials in the prepared folder ``out`` and write its final files."""
    from twin.studies.report import write_report

    resumed = len(done)
    numbers = [_batch_number(p) for p in batch_files(out)]
    state = {"next": max(numbers, default=-1) + 1, "count": len(done)}
    total = study.n_trials
    on_progress(state["count"], total)
    t0 = time.perf_counter()
    if not scheduler.startswith("tcp://"):
        workers = pool_size(workers, total - resumed)
    with executor(scheduler, workers) as (mode, ex):

        def run_ids(ids: list[tuple[int, int]]) -> None:
            batches = list(_chunks(ids, batch_size(study, workers)))
            if mode == "inline":
                results: Iterator[list[dict]] = (run_batch(study, b) for b in batches)
            else:
                results = _stream(mode, ex, study, batches, workers)
            for rows in results:
                _write_table_atomic(out / BATCH_DIR / f"batch-{state['next']:06d}.parquet", rows_table(study, rows))
                state["next"] += 1
                state["count"] += len(rows)
                on_progress(state["count"], total)

        if study.adaptive is None:
            run_ids([(c, t) for c in range(study.n_cells) for t in range(study.trials) if (c, t) not in done])
            rounds = None
        else:
            rounds = _run_adaptive(study, study.adaptive, out, done, run_ids)
    table = final_table(out, [study.trials] * study.n_cells if rounds is None else [r["trials"] for r in rounds])
    expected = total if rounds is None else sum(r["trials"] for r in rounds)
    if table.num_rows != expected:
        raise TwinError(f"{out}: {table.num_rows} trials in the batch files, expected {expected}")
    reused = sum((c, t) in done for c, t in zip(table.column("cell").to_pylist(), table.column("trial").to_pylist(),
                                                 strict=True))
    files = write_report(study, table, out, rounds)
    # the final table last: its presence says the study is complete
    _write_table_atomic(out / RESULTS, table)
    summary = {"study": study.name, "study_hash": study.content_hash, "out": str(out), "cells": study.n_cells,
               "trials_per_cell": study.trials, "trials": table.num_rows, "trials_run": table.num_rows - reused,
               "trials_resumed": reused, "seconds": time.perf_counter() - t0,
               "results": str(out / RESULTS), "report": str(files[0]), "plots": [str(p) for p in files[1:]],
               "success_rate": _success_rate(table),
               "trials_ok": table.column("status").to_pylist().count("ok")}
    if rounds is not None:
        summary["adaptive"] = rounds
    return summary


def _batch_number(path: Path) -> int:
    """The number of a batch file (``batch-NNNNNN.parquet``, as :func:`batch_files` lists them)."""
    match = BATCH_RE.match(path.name)
    if match is None:
        raise TwinError(f"{path}: not a batch file (batch-NNNNNN.parquet)")
    return int(match.group(1))


def _run_adaptive(study: Study, adaptive: dict, out: Path, done: set, run_ids: Callable[[list], None]) -> list[dict]:
    """JCGM 101 7.9's rounds (module docstring of :mod:`twin.studies.adaptive`) under the study's
    adaptive rule ``adaptive``; per cell the trials run and whether the rule was met."""
    from twin.studies.adaptive import is_stable

    h, digits = adaptive["batch"], adaptive["digits"]
    rounds: list[dict[str, Any]] = [{"trials": 0, "stable": False, "unstable": []} for _ in range(study.n_cells)]
    active = list(range(study.n_cells))
    r = 0
    while active:
        hi = min((r + 1) * h, study.trials)
        run_ids([(c, t) for c in active for t in range(r * h, hi) if (c, t) not in done])
        table = final_table(out, [hi] * study.n_cells)  # as an uninterrupted run sees it after this round
        for c in list(active):
            rounds[c]["trials"] = hi
            rounds[c]["unstable"] = _cell_unstable(table, c, h, digits, is_stable)
            rounds[c]["stable"] = not rounds[c]["unstable"]
            if rounds[c]["stable"] or hi >= study.trials:
                active.remove(c)
        r += 1
    return rounds


def _cell_unstable(table: pa.Table, cell: int, h: int, digits: int, is_stable) -> list[str]:
    """The quantities of ``cell`` whose batches do not yet meet the adaptive rule (empty: stable)."""
    from twin.studies.report import MAGNITUDE_COLUMNS, cell_stats

    sel = [i for i, c in enumerate(table.column("cell").to_pylist()) if c == cell]
    sub = table.take(sel)
    ok = [s == "ok" for s in sub.column("status").to_pylist()]
    batch = [t // h for t in sub.column("trial").to_pylist()]
    columns = TWIST_COLUMNS if cell_stats(sub, cell)["determined"] else MAGNITUDE_COLUMNS[:2]
    unstable: list[str] = []
    for name in columns:
        x = sub.column(name).to_pylist()
        groups: dict[int, list] = {}
        for b, v, k in zip(batch, x, ok, strict=True):
            if k:
                groups.setdefault(b, []).append(v)
        if not is_stable([np.asarray(groups[b], dtype=np.float64) for b in sorted(groups)], digits):
            unstable.append(name)
    return unstable


def _success_rate(table: pa.Table) -> float:
    status = table.column("status").to_pylist()
    return sum(s == "ok" for s in status) / max(len(status), 1)


def _stream(mode: str, ex, study: Study, batches: list, workers: int) -> Iterator[list[dict]]:
    """Finished batches as they complete, with a bounded number in flight."""
    limit = max(1, workers * IN_FLIGHT_PER_WORKER)
    queue = iter(batches)
    if mode == "pool":
        pending = set()
        for b in queue:
            pending.add(ex.submit(run_batch, study, b))
            if len(pending) >= limit:
                break
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in finished:
                yield f.result()
                nxt = next(queue, None)
                if nxt is not None:
                    pending.add(ex.submit(run_batch, study, nxt))
        return
    from distributed import as_completed

    first = [ex.submit(run_batch, study, b, pure=False) for b in itertools.islice(queue, limit)]
    ac = as_completed(first)
    for f in ac:
        yield f.result()
        nxt = next(queue, None)
        if nxt is not None:
            ac.add(ex.submit(run_batch, study, nxt, pure=False))


def _probe(address: str) -> None:
    """Refuse an unreachable scheduler address quickly, before the output folder is touched."""
    import socket

    hostport = address[len("tcp://"):]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        raise TwinError(f"--scheduler {address}: expected tcp://HOST:PORT")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        raise TwinError(f"--scheduler {address}: cannot reach a Dask scheduler there ({exc.strerror or exc})") \
            from None
    _handshake(address)


def _handshake(address: str) -> None:
    """Connect a Dask client to ``address`` in a daemon thread and wait at most twice the
    connect timeout: a service that accepts but never answers would otherwise hold the command
    for ever (Dask's own timeout does not cover its handshake), and one that answers in another
    protocol would end in Dask's traceback. A scheduler without workers is refused too: the
    study would wait for one for ever."""
    try:
        from distributed import Client
    except ImportError:
        raise TwinError("--scheduler tcp://... needs the 'distributed' package (pip install 'dask[distributed]')") \
            from None
    found: dict = {}

    def connect() -> None:
        try:
            with Client(address, timeout=f"{CONNECT_TIMEOUT_S}s") as client:
                found["workers"] = len(client.scheduler_info().get("workers", {}))
        except BaseException as exc:  # any failure is reported by the waiting thread
            found["error"] = exc

    quiet = logging.getLogger("distributed")
    was = quiet.disabled
    quiet.disabled = True  # its log of the failed handshake would bury the one-line error
    try:
        thread = threading.Thread(target=connect, name="twin-dask-probe", daemon=True)
        thread.start()
        thread.join(2 * CONNECT_TIMEOUT_S)
    finally:
        quiet.disabled = was
    if thread.is_alive():
        raise TwinError(f"--scheduler {address}: something listens there but gives no Dask scheduler's answer "
                        f"within {2 * CONNECT_TIMEOUT_S} s")
    if "error" in found:
        exc = found["error"]
        raise TwinError(f"--scheduler {address}: not a Dask scheduler ({type(exc).__name__}: "
                        f"{' '.join(str(exc).split())[:120]})")
    if found["workers"] == 0:
        raise TwinError(f"--scheduler {address}: the scheduler has no worker (start one with "
                        f"'dask worker {address}')")


def final_table(out: Path, trials_per_cell: Sequence[int] | None = None) -> pa.Table:
    """Every batch of ``out`` in one table sorted by (cell, trial); a duplicated trial is an error.
    ``trials_per_cell``: keep only the trials below each cell's count (a resumed study may hold
    trials past what its current settings run: they stay in the batch files for a later extension)."""
    files = batch_files(out)
    if not files:
        raise TwinError(f"{out}: no finished batch")
    table = pa.concat_tables([pq.read_table(p) for p in files], promote_options="default")
    table = table.sort_by([("cell", "ascending"), ("trial", "ascending")])
    ids = list(zip(table.column("cell").to_pylist(), table.column("trial").to_pylist(), strict=True))
    if len(set(ids)) != len(ids):
        raise TwinError(f"{out}: a trial appears twice in the batch files")
    if trials_per_cell is not None:
        limit = np.asarray(trials_per_cell)
        cell, trial = np.asarray(table.column("cell").to_pylist()), np.asarray(table.column("trial").to_pylist())
        table = table.filter(pa.array(trial < limit[cell]))
    return table


def progress_printer(quiet: bool, stream: TextIO | None = None) -> Callable[[int, int], None]:
    """A progress callback: a tqdm bar on a terminal, plain lines elsewhere, nothing when quiet."""
    stream = sys.stderr if stream is None else stream
    if quiet:
        return lambda done, total: None
    if stream.isatty():
        from tqdm import tqdm

        bar: dict = {}

        def on_bar(done: int, total: int) -> None:
            if "bar" not in bar:
                bar["bar"] = tqdm(total=total, initial=done, file=stream, unit="trial", desc="[twin study]")
            else:
                bar["bar"].update(done - bar["bar"].n)
            if done >= total:
                bar["bar"].close()
        return on_bar

    start = time.perf_counter()

    def on_line(done: int, total: int) -> None:
        print(f"[twin study] {done}/{total} trials ({time.perf_counter() - start:.1f} s)", file=stream, flush=True)
    return on_line
