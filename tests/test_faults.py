"""Faults and interrupts end a command with a named error or exit 130 / 143, before the work where they can be
checked then, and leave no staging folder, temporary folder or half-written output behind (issue: reliability)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ident.cli import main
from ident.protocols import batch

ROOT = Path(__file__).resolve().parents[1]


def run_cli(args: list[str], capsys) -> tuple[int, str]:
    code = main(args)
    return code, capsys.readouterr().err


@pytest.mark.parametrize("args, message", [
    (["sweep", "--workers", "-1", "--out", "OUT"], "--workers = -1: must be >= 0"),
    (["study", "--levels", "1", "--out", "OUT"], "--levels = 1: must be >= 2"),
    (["predict", "run.csv", "--draws", "0"], "--draws = 0: must be >= 2"),
    (["diagnose", "run.csv", "--out", "OUT", "--max-effects", "-1"], "--max-effects = -1: must be >= 1"),
    (["resolution", "--controller", "impulse", "--eps1-um", "0"], "--eps1-um = 0.0: must be > 0"),
    (["resolution", "--controller", "impulse", "--eps1-um", "nan"], "--eps1-um = nan: must be a finite number"),
    (["resolution", "--controller", "impulse", "--fl-star", "0", "--pulses", "5"],
     "f_l = 0 N.m (f_l* = 0): a body without friction never comes to rest"),
    (["resolution", "--controller", "linear", "--param", "f_m=0", "--fl-star", "0.2"], "f_m must be > 0"),
])
def test_bad_options_are_named_before_any_work(tmp_path, capsys, args, message) -> None:
    args = [str(tmp_path / a) if a in ("OUT", "run.csv") else a for a in args]
    t0 = time.perf_counter()
    code, err = run_cli(args, capsys)
    assert code == 2 and message in err, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert time.perf_counter() - t0 < 30   # a hang guard, not a speed target
    assert not (tmp_path / "OUT").exists()


def test_out_that_is_a_file_is_refused_before_the_work(tmp_path, capsys) -> None:
    target = tmp_path / "existing"
    target.write_text("keep me")
    for args in (["demo", "--out", str(target)], ["study", "--out", str(target), "--levels", "2"]):
        code, err = run_cli(args, capsys)
        assert code == 2 and f"--out {target}: exists and is not a folder" in err, err
    assert target.read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing"]


def test_emps_report_without_data_is_named(tmp_path, capsys) -> None:
    code, err = run_cli(["emps-report", "--out", str(tmp_path / "e"), "--data", str(tmp_path)], capsys)
    assert code == 2 and "DATA_EMPS.mat: no such EMPS .mat file" in err, err
    assert not (tmp_path / "e").exists()


def test_unreachable_scheduler_is_named(monkeypatch, tmp_path, capsys) -> None:
    monkeypatch.setattr(batch, "CONNECT_TIMEOUT_S", 1.0)
    code, err = run_cli(["sweep", "--levels", "2", "--pulses", "3", "--scheduler", "tcp://127.0.0.1:1",
                         "--out", str(tmp_path / "s")], capsys)
    assert code == 2 and "cannot reach the Dask scheduler at tcp://127.0.0.1:1 within 1 s" in err, err
    assert not (tmp_path / "s").exists()


def _sleep_then_double(x: int) -> int:
    time.sleep(60)
    return 2 * x


def _double(x: int) -> int:
    return 2 * x


def _sleep_then_triple(x: float) -> float:
    time.sleep(x)
    return 3 * x


def test_a_batch_waiting_on_a_long_task_shows_its_progress_alive(monkeypatch, capsys) -> None:
    """A diagnosis step can wait minutes on one refit: its progress bar is redrawn at every liveness poll, so its
    elapsed time moves on stderr (before, it was drawn at the start and when the task ended, nothing between)."""
    monkeypatch.setattr(batch, "LIVENESS_POLL_S", 0.2)
    with batch.WorkerPool(1) as pool:
        assert pool.map(_sleep_then_triple, [3.0], progress=True, desc="long task") == [9.0]
    err = capsys.readouterr().err
    waiting = [line for line in err.replace("\r", "\n").splitlines() if line.startswith("long task") and "0/1" in line]
    # a 3 s task polled every 0.2 s: elapsed 00:00, 00:01 and 00:02 all shown while it runs (2 s would leave the
    # third to a poll landing after 2.0 s)
    assert len({line.split("[")[1].split("<")[0] for line in waiting}) >= 3, err


def _answer(args: tuple, cancelled: object) -> int:
    return 2 * args[0]


def _refuse(args: tuple, cancelled: object) -> int:
    raise ValueError(f"refused {args[0]}")


def _wait_for_cancel(args: tuple, cancelled: object) -> int:
    """Look for the cancel as a fit does (before each simulation); say on disk when it was seen."""
    for i in range(400):
        if cancelled():   # type: ignore[operator]
            Path(args[0]).write_text(str(i))
            return i
        time.sleep(0.025)
    return -1


def test_work_beside_comes_back_stops_when_cancelled_and_says_when_it_could_not_run(tmp_path, monkeypatch) -> None:
    """``WorkerPool.beside`` (the identifier's second start path, run beside its first): the task's result or its
    own exception comes back; a cancel reaches the task on its worker; a pool whose workers did not start says so
    with ``NotRunElsewhere`` (the caller then runs the work itself), not with the pool's error; a serial pool offers
    no such core."""
    from ident.common.elsewhere import NotRunElsewhere

    assert batch.WorkerPool(0).elsewhere is None
    with pytest.raises(batch.BatchError, match="needs local workers: this pool runs serially"):
        batch.WorkerPool(0).beside(_answer, (1,))
    with batch.WorkerPool(1) as pool:
        assert pool.elsewhere is not None
        assert pool.elsewhere(_answer, (21,)).result() == 42
        with pytest.raises(ValueError, match="refused 3"):
            pool.beside(_refuse, (3,)).result()
        seen = tmp_path / "seen"
        waiting = pool.beside(_wait_for_cancel, (str(seen),))
        time.sleep(0.5)
        waiting.cancel()
        for _ in range(200):
            if seen.exists():
                break
            time.sleep(0.05)
        assert seen.exists() and int(seen.read_text()) >= 0

    def no_cluster(n: int, scratch: str) -> None:
        raise OSError("no processes allowed here")

    monkeypatch.setattr(batch, "_new_cluster", no_cluster)
    with batch.WorkerPool(1) as pool:
        with pytest.raises(NotRunElsewhere, match="no processes allowed here"):
            pool.beside(_answer, (1,)).result()


def test_a_second_run_at_once_does_not_warn_about_the_dashboards_port() -> None:
    """Two hdrive runs at once on one machine: the second's local cluster takes a free port for its dashboard
    rather than warning on stderr that Dask's default (8787) is in use (seen in the default test run)."""
    import socket
    import warnings

    with socket.socket() as held:
        try:
            held.bind(("127.0.0.1", 8787))
            held.listen()
        except OSError:
            pass   # already held by something else on this machine: the same situation
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert batch.run_batch(_double, [1, 2], workers=1) == [2, 4]
    assert not [w for w in caught if "already in use" in str(w.message)], [str(w.message) for w in caught]


def _log_closing_heartbeat_and_a_worker_error(x: int) -> int:
    import logging

    log = logging.getLogger("distributed.worker")
    log.error(batch._CLOSING_HEARTBEAT + ".")
    log.error("a worker error the user must see (%d)", x)
    return x


def test_a_workers_closing_heartbeat_is_quiet_and_its_other_errors_are_not(capfd) -> None:
    """A local worker whose heartbeat finds the scheduler gone (this process closing its cluster; Dask's race,
    seen as a traceback on stderr after a diagnosis that ended normally) says nothing; its other errors still
    reach stderr."""
    assert batch.run_batch(_log_closing_heartbeat_and_a_worker_error, [7], workers=1) == [7]
    err = capfd.readouterr().err
    assert "a worker error the user must see (7)" in err
    assert batch._CLOSING_HEARTBEAT not in err


def test_a_cluster_that_loses_its_workers_is_named(monkeypatch) -> None:
    """An external cluster whose last worker goes away while tasks are pending: a named error, not a hang."""
    from dask.distributed import LocalCluster

    monkeypatch.setattr(batch, "LIVENESS_POLL_S", 0.5)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        import threading

        threading.Timer(2.0, lambda: cluster.scale(0)).start()
        t0 = time.perf_counter()
        with pytest.raises(batch.BatchError, match="has no workers left; 2 of 2 runs unfinished"):
            batch.run_batch(_sleep_then_double, [1, 2], scheduler=cluster.scheduler_address)
        assert time.perf_counter() - t0 < 60


def test_workers_at_work_are_not_taken_for_lost(monkeypatch) -> None:
    """The liveness poll asks the scheduler for its workers: the client's cached identity, refreshed in the
    background without the workers' list, made a two-effect diagnosis under load stop with "no workers left" while
    both workers were at work. A refresh every millisecond and a poll every 50 ms make that race (a third of the
    cached reads empty, measured) certain over a 2 s task."""
    import dask

    monkeypatch.setattr(batch, "LIVENESS_POLL_S", 0.05)
    with dask.config.set({"distributed.client.scheduler-info-interval": "1ms"}):
        assert batch.run_batch(_sleep_then_triple, [2.0], workers=1) == [6.0]


@pytest.mark.parametrize("sig, code, line", [
    (signal.SIGTERM, 143, "terminated (SIGTERM)"), (signal.SIGINT, 130, "interrupted (Ctrl-C)")])
def test_a_signal_that_a_c_library_turned_into_its_own_error_still_exits_as_stopped(monkeypatch, capsys, sig, code,
                                                                                     line) -> None:
    """``cli.run``: the signal handler's exception (SIGTERM's ``Terminated``, Ctrl-C's KeyboardInterrupt), swallowed
    by C code that reports a failure of its own instead (here a made-up one, worded as fmpy's schema check words its
    failures), still ends the command as stopped by that signal, with its code and one line. A failure with no
    signal behind it stays a named error (2)."""
    import argparse

    from ident import cli

    def swallowed(args: argparse.Namespace) -> None:
        try:
            cli._on_signal(sig, None)
        except (cli.Terminated, KeyboardInterrupt):
            raise RuntimeError("Document is not valid XML Schema") from None

    def failing(args: argparse.Namespace) -> None:
        raise RuntimeError("Document is not valid XML Schema")

    monkeypatch.setattr(cli, "preflight", lambda args: None)
    monkeypatch.setattr(cli, "_SIGNALS", [])
    assert cli.run(argparse.Namespace(command="sweep", func=failing)) == (2, None)
    assert capsys.readouterr().err.strip() == "hdrive sweep: error: Document is not valid XML Schema"
    assert cli.run(argparse.Namespace(command="sweep", func=swallowed)) == (code, None)
    assert capsys.readouterr().err.strip() == f"hdrive sweep: {line}; no output was left half-written"


def test_the_command_line_leaves_an_ignored_ctrl_c_ignored(monkeypatch) -> None:
    """``cli.main`` takes Ctrl-C over only from Python's own handler: a command started in the background, where the
    shell has SIGINT ignored, must keep ignoring it; and every handler is given back when the command returns."""
    from ident import cli

    seen = []

    def spy(args):
        seen.append((signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)))
        return 0, None

    monkeypatch.setattr(cli, "run", spy)
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        assert cli.main(["build-fmu", "--out", "unused"]) == 0
        signal.signal(signal.SIGINT, signal.default_int_handler)
        assert cli.main(["build-fmu", "--out", "unused"]) == 0
        assert seen == [(signal.SIG_IGN, cli._on_signal), (cli._on_signal, cli._on_signal)]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        for s, h in before.items():
            signal.signal(s, h)


@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
def test_interrupting_a_sweep_leaves_nothing_behind(tmp_path, sig, code, word) -> None:
    """Ctrl-C / SIGTERM during a sweep (compiled protocol loops on Dask threads in the process): exit 130 / 143 with
    one line, no output folder, no staging folder, and no temporary folder (unpacked FMUs) in a private TMPDIR. N =
    20,000 pulses: the compiled sweep at N = 1000 may end before the signal arrives. How fast it stops is measured in
    bench/interrupts.py and bench/protocols.py, not here."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    out = tmp_path / "sweep"
    env = {**os.environ, "TMPDIR": str(tmp), "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "ident", "sweep", "--levels", "25", "--pulses", "20000", "--out",
                             str(out), "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=tmp_path)
    deadline = time.monotonic() + 60
    while not any(tmp.iterdir()) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)   # wait until the work has started (the workers' scratch folder exists)
    time.sleep(1.0)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, stderr
    assert stderr.strip().splitlines()[-1] == f"hdrive sweep: {word} ({'Ctrl-C' if code == 130 else 'SIGTERM'}); " \
                                              "no output was left half-written"
    assert "Traceback" not in stderr and stdout == ""
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tmp"]
    assert list(tmp.iterdir()) == []


def test_unpacked_fmus_are_removed_at_exit_even_unclosed(tmp_path) -> None:
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    code = "from ident import Plant; p = Plant(); p.step(0.02, 1e-3); import os; print(len(os.listdir(os.environ['TMPDIR'])))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "TMPDIR": str(tmp), "PYTHONPATH": str(ROOT)})
    assert out.stdout.strip() == "1"          # the plant's unpacked FMU while it runs
    assert list(tmp.iterdir()) == []          # gone after the interpreter exits, although close() was never called


def test_a_bug_prints_one_line_not_a_traceback(capsys) -> None:
    from ident.cli import build_parser, run

    def broken(args):
        raise KeyError("something internal")

    args = build_parser().parse_args(["resolution", "--controller", "impulse"])
    args.func = broken
    code, result = run(args)
    err = capsys.readouterr().err
    assert (code, result) == (1, None)
    assert err.startswith("hdrive resolution: internal error: KeyError") and err.count("\n") == 1, err


def test_json_output_is_one_document(capsys) -> None:
    assert main(["resolution", "--controller", "impulse", "--pulses", "3", "--json"]) == 0
    json.loads(capsys.readouterr().out)



def _overlapped(monkeypatch, module: object, name: str, call) -> bool:
    """Replace ``module.name`` by a spy that fails, and while it runs lets another thread try to hold the working
    directory (``kept_working_directory``); whether that thread got in while the spy still ran."""
    import threading

    from ident.common.workdir import kept_working_directory

    running, got, threads = [False], [], []

    def other() -> None:
        with kept_working_directory():
            got.append(running[0])

    def spy(*args, **kwargs):
        running[0] = True
        threads.append(threading.Thread(target=other))
        threads[0].start()
        threads[0].join(0.5)   # held: the other thread gets in only once the spy has returned
        running[0] = False
        raise RuntimeError("spy: nothing loaded or started")

    monkeypatch.setattr(module, name, spy)
    with pytest.raises(Exception, match="spy"):
        call()
    threads[0].join()
    return got == [True]


def test_an_fmu_load_and_a_worker_start_never_overlap(monkeypatch) -> None:
    """fmpy loads an FMU's library with the process's working directory switched into the plant's unpacked folder,
    deleted when the plant closes; worker processes inherit the working directory. A worker started inside such a
    load kept a deleted folder, and every FMU it loaded then failed ("[Errno 2] No such file or directory": two
    diagnoses under load had four or five candidates of a step not fitted). Both hold ``kept_working_directory``."""
    import dask.distributed
    import fmpy.fmi2

    from ident.model.plant import Plant

    before = os.getcwd()
    assert not _overlapped(monkeypatch, fmpy.fmi2, "FMU2Slave", Plant)
    assert os.getcwd() == before

    def start() -> None:
        with batch.WorkerPool(2, None) as pool:
            pool.map(abs, [-1])

    assert not _overlapped(monkeypatch, dask.distributed, "LocalCluster", start)


def _started(x: int) -> tuple[int, float]:
    """A task that says when it started (a worker's clock: the same machine's)."""
    start = time.time()
    time.sleep(0.05)
    return x, start


def test_the_costliest_tasks_start_first_and_the_results_keep_their_order() -> None:
    """``WorkerPool.map(cost=...)``: the costliest items are submitted first (on one worker: run first), so a batch
    of uneven tasks does not end waiting on a costly one started last; the results come back in the items' order,
    as without costs and as serially. A cost list of the wrong length is refused before any work."""
    items, cost = [0, 1, 2, 3], [1.0, 3.0, 0.5, 2.0]
    with batch.WorkerPool(1, None) as pool:
        out = pool.map(_started, items, cost=cost)
        plain = pool.map(_started, items)
        with pytest.raises(ValueError, match="cost has 3 entries for 4 items"):
            pool.map(_started, items, cost=cost[:3])
    assert [x for x, _ in out] == items == [x for x, _ in plain]
    assert [x for x, _ in sorted(out, key=lambda r: r[1])] == [1, 3, 0, 2]
    with batch.WorkerPool(0) as serial:
        assert [x for x, _ in serial.map(_started, items, cost=cost)] == items


def test_a_failed_fmu_load_leaves_the_working_directory_where_it_was(monkeypatch) -> None:
    """fmpy does not switch the working directory back when the library does not load; the plant's folder is then
    deleted, and the process would be left in a folder that no longer exists."""
    import fmpy.fmi2

    from ident.model.plant import Plant, PlantError

    def fails(**kwargs):
        os.chdir(kwargs["unzipDirectory"])
        raise OSError("spy: the library does not load")

    monkeypatch.setattr(fmpy.fmi2, "FMU2Slave", fails)
    before = os.getcwd()
    with pytest.raises(PlantError, match="spy"):
        Plant()
    assert os.getcwd() == before


def test_a_script_without_a_main_guard_is_told_what_to_do(tmp_path) -> None:
    """A user's script that starts a diagnosis at import: each worker (a new process importing the script) starts
    workers again, and Dask only says "Nanny failed to start". The error names the cause and the two ways out, in
    the workers (refused at once, where the pool is made: nothing of the script's work runs there) and in the
    script's process (whose workers die of it)."""
    script = tmp_path / "unguarded.py"   # its source must not name __main__ (that counts as a guard): spelled in parts
    script.write_text(f"import sys\nsys.path.insert(0, {str(ROOT)!r})\n"
                      "from ident.protocols.batch import BatchError, WorkerPool\n"
                      "who = 'SCRIPT' if __name__ == '__ma' + 'in__' else 'WORKER'\n"
                      "try:\n"
                      "    with WorkerPool(1) as pool:\n"
                      "        print(who, 'POOL MADE', flush=True)\n"
                      "        pool.share(1)\n"
                      "except BatchError as exc:\n"
                      "    print(who, exc, flush=True)\n"
                      "    raise SystemExit(3)\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    lines = {ln.split(" ", 1)[0]: ln for ln in out.stdout.splitlines()
             if ln.startswith(("SCRIPT", "WORKER")) and "POOL MADE" not in ln}
    assert set(lines) == {"SCRIPT", "WORKER"}, out.stdout + out.stderr[-2000:]
    assert "WORKER POOL MADE" not in out.stdout and "SCRIPT POOL MADE" in out.stdout, out.stdout
    assert "the local Dask workers did not start: this process is a worker importing the main script. The workers " \
           "are new processes that import your main script" in lines["WORKER"]
    assert f"The workers are new processes that import {script}, and it starts" in lines["SCRIPT"]
    for line in lines.values():
        assert 'put that work under `if __name__ == "__main__":`, or pass workers=0' in line


def test_a_killed_processs_unpacked_fmu_is_removed_by_the_next_plant(tmp_path, monkeypatch) -> None:
    """A process killed before ``atexit`` runs (SIGKILL here; a script's default SIGTERM does the same) leaves the
    folder its plant unpacked the FMU into; the next plant on the host removes it (``remove_orphaned_fmus``) and keeps
    those of processes still alive, its own included."""
    import tempfile

    from ident import Plant
    from ident.model.plant import remove_orphaned_fmus

    code = "import time; from ident import Plant; p = Plant(); print('ready', flush=True); time.sleep(120)"
    child = subprocess.Popen([sys.executable, "-c", code], env={**os.environ, "TMPDIR": str(tmp_path)},
                             stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline().strip() == b"ready"
        orphan, = tmp_path.glob("hdrive-fmu-*")
        assert orphan.name.startswith(f"hdrive-fmu-{child.pid}-")
        assert remove_orphaned_fmus(tmp_path) == []   # its process is alive: kept
    finally:
        child.kill()
        child.wait()
    assert orphan.is_dir()   # killed outright: nothing removed it
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with Plant():
        kept, = tmp_path.glob("hdrive-fmu-*")
        assert not orphan.exists() and kept.name.startswith(f"hdrive-fmu-{os.getpid()}-")
        with Plant():   # a second plant of a live process keeps the first one's folder
            assert kept.is_dir() and len(list(tmp_path.glob("hdrive-fmu-*"))) == 2
    assert not list(tmp_path.glob("hdrive-fmu-*"))


def test_a_killed_processs_worker_folder_is_removed_by_the_next_pool(tmp_path, monkeypatch) -> None:
    """A process killed before it removed its local workers' folder (a script calling ``ident.diagnose`` stopped by
    SIGTERM leaves one, its workers' unpacked FMUs inside) has it removed by the next pool that starts local workers
    on the host (``ident.common.scratch``); the folders of live processes, its own included, and those of another
    host stay."""
    import tempfile

    from ident.common.scratch import host_tag
    from ident.protocols.batch import WorkerPool

    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    orphan = tmp_path / f"hdrive-workers-{gone.pid}-{host_tag()}-abc"
    (orphan / "hdrive-fmu-1-x").mkdir(parents=True)
    alive = tmp_path / f"hdrive-workers-{os.getpid()}-{host_tag()}-def"
    elsewhere = tmp_path / f"hdrive-workers-{gone.pid}-{'0' * 8 if host_tag() != '0' * 8 else '1' * 8}-ghi"
    alive.mkdir()
    elsewhere.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with WorkerPool(1) as pool:
        assert pool.map(abs, [-2]) == [2]
        assert not orphan.exists() and alive.is_dir() and elsewhere.is_dir()
        ours = [p for p in tmp_path.glob(f"hdrive-workers-{os.getpid()}-*") if p != alive]
        assert len(ours) == 1 and ours[0].is_dir()
    assert not ours[0].exists()
