"""The build cache (``fmu_build/cache.py``) under faults: damaged entries, no compiler, an unwritable cache folder,
signals during a build.

Damaged entries are loaded in a child process: loading a truncated shared library is what used to end in SIGBUS,
which must fail this test, not kill the test session.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from fmu_build import build_fmu
from fmu_build.build import BuildError, build_runner

ROOT = Path(__file__).resolve().parents[1]
# Loads both cached artefacts the way hdrive does: the FMU through fmpy (one short simulation), the stepping loop
# through ctypes. Prints the paths it got.
LOAD = ("import ctypes, fmpy; from fmu_build import build_fmu; from fmu_build.build import build_runner; "
        "p = build_fmu(2); fmpy.simulate_fmu(str(p), stop_time=0.01, step_size=1e-3); "
        "r = build_runner(); ctypes.CDLL(str(r)).hd_run_fmi2; print(p); print(r)")


def child(env_overrides: dict[str, str], code: str = LOAD, timeout_s: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           **env_overrides}
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout_s)


@pytest.fixture
def cache(tmp_path: Path) -> Path:
    """A private cache holding copies of this session's FMI 2 FMU and stepping-loop entries (built once)."""
    root = tmp_path / "cache"
    root.mkdir()
    for path in (build_fmu(fmi_version=2, sanitize=False), build_runner()):
        shutil.copytree(path.parent, root / path.parent.name)
    return root


def entry(cache: Path, prefix: str) -> Path:
    (found,) = [p for p in cache.iterdir() if p.name.startswith(prefix)]
    return found


def truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def replace_binary(fmu: Path) -> None:
    """A well-formed zip whose shared library differs from the one built (one byte flipped)."""
    with zipfile.ZipFile(fmu) as zf:
        items = {i.filename: zf.read(i.filename) for i in zf.infolist()}
    name = next(n for n in items if n.startswith("binaries/"))
    so = bytearray(items[name])
    so[len(so) // 2] ^= 0xFF
    items[name] = bytes(so)
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zf:
        for n, data in items.items():
            zf.writestr(n, data)


def folder_in_place(path: Path) -> None:
    path.unlink()
    path.mkdir()
    (path / "junk").write_text("x")


DAMAGE = {
    "truncated_zip": ("fmi2-", "HarmonicDrive.fmu", truncate),
    "binary_replaced": ("fmi2-", "HarmonicDrive.fmu", replace_binary),
    "folder": ("fmi2-", "HarmonicDrive.fmu", folder_in_place),
    "checksum_missing": ("fmi2-", "HarmonicDrive.fmu.sha256", Path.unlink),
    "truncated_runner": ("runner-", "hd_runner.so", truncate),
}


@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_damaged_entry_is_detected_and_rebuilt_once(cache: Path, damage: str) -> None:
    prefix, name, spoil = DAMAGE[damage]
    spoil(entry(cache, prefix) / name)
    proc = child({"HDRIVE_CACHE": str(cache)})
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "is damaged" in lines[0] and "rebuilding it" in lines[0], proc.stderr
    again = child({"HDRIVE_CACHE": str(cache)})  # rebuilt for good: silent now
    assert again.returncode == 0 and again.stderr == "", again.stderr
    assert not [p for p in cache.rglob("*") if p.name.endswith(".tmp")]


def test_warm_cache_needs_no_compiler(cache: Path, tmp_path: Path) -> None:
    """A warm cache is found without asking for the compiler: no CC on PATH, a CC that does not exist."""
    empty_bin = tmp_path / "bin"
    empty_bin.mkdir()
    (empty_bin / "python3").symlink_to(sys.executable)
    proc = child({"HDRIVE_CACHE": str(cache), "CC": "/nonexistent/cc", "PATH": str(empty_bin)})
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stderr}"
    assert proc.stdout.splitlines()[0].startswith(str(cache)) and proc.stderr == ""


def test_cold_cache_without_compiler_is_a_named_error(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("HDRIVE_CACHE", str(tmp_path / "cold"))
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.raises(BuildError, match="no C compiler"):
        build_fmu(fmi_version=2, sanitize=False)
    assert not list((tmp_path / "cold").iterdir())  # nothing half-built left behind


def test_unwritable_cache_builds_into_a_temporary_folder(cache: Path, tmp_path: Path) -> None:
    """A cache folder that cannot be created or written (here: below a regular file; chmod does not stop root)
    gives one line on stderr and a build into a temporary folder, removed when the process ends."""
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("x")
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    proc = child({"HDRIVE_CACHE": str(blocker / "cache"), "TMPDIR": str(tmpdir)})
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stderr}"
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "is not writable" in lines[0] and "building into" in lines[0], proc.stderr
    assert proc.stdout.splitlines()[0].startswith(str(tmpdir / "hdrive-cache-"))
    assert not list(tmpdir.iterdir())  # the temporary cache went with the process


def _kill_written_pid(path: Path) -> None:
    """Kill the process whose pid ``path`` holds, if it still runs. A SIGINT that reaches the build process while
    ``subprocess.Popen`` is still returning from starting the compiler (measured: KeyboardInterrupt raised in
    ``_fork_exec``) unwinds the build without killing the child, which Popen does not know it owns yet; the
    stand-in would then sleep on. A real compiler finishes in about 0.1 s, into the removed build folder."""
    try:
        os.kill(int(path.read_text()), signal.SIGKILL)
    except (FileNotFoundError, ValueError, ProcessLookupError):
        pass


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_during_a_build_leaves_nothing_behind(tmp_path: Path, signum: int) -> None:
    """Interrupted while the compiler runs: no hdrive-build-* folder, no staging folder, no .tmp file.

    The compiler is a stand-in (``CC``) that says it started and then waits to be killed, so the signal always
    lands while it runs. With the real compiler (about 0.1 s here) the test's own wait could outlast the build on a
    loaded machine: it failed once that way in a full run, the build complete before the signal came."""
    cache, tmpdir, started = tmp_path / "cache", tmp_path / "tmp", tmp_path / "compiler-started"
    tmpdir.mkdir()
    fake_cc = tmp_path / "bin" / "cc"
    fake_cc.parent.mkdir()
    fake_cc.write_text(f"#!/bin/sh\necho $$ > '{started}'\nexec sleep 120\n")  # its pid: the sleep's
    fake_cc.chmod(0o755)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "HDRIVE_CACHE": str(cache), "TMPDIR": str(tmpdir), "CC": str(fake_cc)}
    code = "from fmu_build import build_fmu; build_fmu(2, sanitize=False)"
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120  # test orchestration only: wait for the compiler to be running
        while not started.exists() and proc.poll() is None:
            assert time.monotonic() < deadline, "the build never started"
            time.sleep(0.005)
        assert proc.poll() is None, f"the build ended before the signal: {proc.communicate()}"
        assert list(tmpdir.glob("hdrive-build-*/binaries")), "the compiler ran outside a build folder"
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
        _kill_written_pid(started)
    left = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))  # what a failure reports
    assert proc.returncode != 0, (proc.returncode, err, left)
    assert not list(tmpdir.glob("hdrive-build-*")), (err, left)
    assert not [p for p in cache.rglob("*") if p.name.endswith(".tmp")] if cache.exists() else True, (err, left)
    assert not [p for p in cache.iterdir() if p.name.startswith("fmi2-")] if cache.exists() else True, (err, left)
