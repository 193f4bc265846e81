"""Shared fixtures: the FMUs are built (or taken from the cache) once per test session."""
from __future__ import annotations

import signal
import threading
from pathlib import Path

import pytest

from fmu_build import build_fmu


def pytest_configure(config: pytest.Config) -> None:
    """SIGINT handled as in a terminal, for the Ctrl-C tests (SIGINT sent to a subprocess, or
    ``_thread.interrupt_main``, which does nothing where Python does not handle SIGINT). A test run started in the
    background by a non-interactive shell (``cmd &``) has SIGINT ignored, and an ignored signal stays ignored across
    ``exec``, so every process the tests start ignored the Ctrl-C they were sent: five tests failed that way. Python's
    own handler is installed instead (a handled signal is reset to its default at ``exec``); in pytest-xdist's
    workers as well, which run this hook too."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)


#: the test files that take longest, longest first (their test time in the default run on the 2-core machine of
#: bench/README.md, stop 69; test_resolution.py and test_fmu_vs_generator.py make the most independent references on
#: a fresh machine, bench/README.md stop 66)
HEAVIEST_FIRST = ("test_identify_reference.py", "test_diagnose.py", "test_diagnose_shapes.py", "test_identify.py",
                  "test_resolution.py", "test_fmu_vs_generator.py", "test_diagnose_rigid.py", "test_faults.py",
                  "test_diagnose_polish.py", "test_diagnose_intervals.py", "test_reference_logs.py", "test_memo.py")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The heaviest files first (``HEAVIEST_FIRST``), the others after them in their own order: pytest-xdist hands a
    file's tests to one process (``--dist loadfile``) in this order (``--no-loadscope-reorder``; its own order is by
    the count of tests, which put the longest file last). Longest first, no process is left with a long file while
    the others are done (the run's tail). A name that is no longer a file here is an error, not a silent no-op."""
    here = Path(__file__).resolve().parent
    gone = [name for name in HEAVIEST_FIRST if not (here / name).is_file()]
    if gone:
        raise pytest.UsageError(f"tests/conftest.py HEAVIEST_FIRST names files that do not exist: {gone}")
    rank = {name: i for i, name in enumerate(HEAVIEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))   # stable: the rest keep their order


@pytest.fixture(scope="session")
def fmu2() -> Path:
    """Path of the FMI 2.0 co-simulation HarmonicDrive.fmu."""
    return build_fmu(fmi_version=2)


@pytest.fixture(scope="session")
def fmu3() -> Path:
    """Path of the FMI 3.0 co-simulation HarmonicDrive.fmu."""
    return build_fmu(fmi_version=3)


@pytest.fixture(scope="session", params=[2, 3], ids=["fmi2", "fmi3"])
def fmu_any(request) -> Path:
    return build_fmu(fmi_version=request.param)
