"""The store of the independent references' results (``tests/reference/stored.py``): a stored result is the one the
reference makes, it is read rather than made again, any other argument is another entry, a damaged entry is made
again, an unwritable folder is no error, ``HDRIVE_REFERENCE_CACHE=0`` bypasses the store, and the store stays below its
bound by dropping the entries used least recently."""
from __future__ import annotations

import os

import numpy as np
import pytest

from tests.reference import stored as store_module
from tests.reference.event_driven import DriveSI, pulse_increments
from tests.reference.generator.logs import identification_case

CALLS: list[tuple] = []


@store_module.stored
def _counted(x: float, scale: np.ndarray, *, label: str = "a") -> dict:
    CALLS.append((x, label))
    return {"x": x * scale, "label": label}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("HDRIVE_CACHE", str(tmp_path))
    monkeypatch.delenv("HDRIVE_REFERENCE_CACHE", raising=False)
    CALLS.clear()
    return tmp_path / "reference-results"


def test_a_result_is_made_once_then_read(cache) -> None:
    a = _counted(0.1, np.arange(3.0))
    b = _counted(0.1, np.arange(3.0))
    assert CALLS == [(0.1, "a")] and len(list(cache.glob("_counted-*.pkl"))) == 1
    np.testing.assert_array_equal(a["x"], b["x"])
    _counted(np.nextafter(0.1, 1.0), np.arange(3.0))  # another float (one ulp up): another entry
    _counted(0.1, np.arange(3.0), label="b")          # another keyword: another entry
    _counted(0.1, np.arange(4.0))                     # another array: another entry
    assert len(CALLS) == 4 and len(list(cache.glob("_counted-*.pkl"))) == 4


def test_a_damaged_entry_is_made_again_and_no_partial_file_is_left(cache) -> None:
    _counted(2.0, np.ones(2))
    (entry,) = cache.glob("_counted-*.pkl")
    entry.write_bytes(entry.read_bytes()[:10])
    assert _counted(2.0, np.ones(2))["x"].tolist() == [2.0, 2.0] and len(CALLS) == 2
    assert _counted(2.0, np.ones(2))["x"].tolist() == [2.0, 2.0] and len(CALLS) == 2  # kept whole again
    assert sorted(p.name for p in cache.iterdir()) == [entry.name]


def test_an_unwritable_folder_is_no_error_and_the_switch_bypasses_the_store(cache, tmp_path, monkeypatch,
                                                                                capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("HDRIVE_CACHE", str(blocker))
    assert _counted(3.0, np.ones(1))["x"].tolist() == [3.0]
    assert "not kept" in capsys.readouterr().err
    monkeypatch.setenv("HDRIVE_CACHE", str(tmp_path))
    monkeypatch.setenv("HDRIVE_REFERENCE_CACHE", "0")
    _counted(3.0, np.ones(1))
    _counted(3.0, np.ones(1))
    assert len(CALLS) == 3 and not cache.exists()


def test_stored_references_equal_fresh_ones(cache, monkeypatch) -> None:
    """The generator's log and the event-driven integrator's increments, read from the store, are bit for bit those
    the references make with the store off."""
    drive = DriveSI.from_nondim(K_star=1e6, J_l_star=2500, f_l_star=0.1)
    kept = [identification_case(4133, "pulse_train", duration_s=0.3) for _ in range(2)]
    incs = [pulse_increments(drive, 1.5, 2.0, 3)[0], pulse_increments(drive, 1.5, 2.0, 3)[0]]
    assert len(list(cache.glob("*.pkl"))) == 2
    monkeypatch.setenv("HDRIVE_REFERENCE_CACHE", "0")
    fresh = identification_case(4133, "pulse_train", duration_s=0.3)
    fresh_incs = pulse_increments(drive, 1.5, 2.0, 3)[0]
    for g in kept:
        for name, column in fresh.columns().items():
            assert np.array_equal(getattr(g, name), column), name
        assert g.truth.to_dict() == fresh.truth.to_dict()
    assert incs[0] == incs[1] == fresh_incs


@pytest.mark.parametrize("env", [{"HDRIVE_CACHE": "/x/h"}, {"XDG_CACHE_HOME": "/x/xdg"}, {"HOME": "/x/home"}])
def test_the_store_sits_where_the_fmu_builds_do(monkeypatch, env) -> None:
    """``stored.cache_root`` repeats ``fmu_build.cache.cache_dir``'s rule (the references may import nothing of the
    product); the two give the same folder under each of the rule's three cases."""
    from fmu_build.cache import cache_dir

    for name in ("HDRIVE_CACHE", "XDG_CACHE_HOME"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert store_module.cache_root() == cache_dir()


def test_the_store_stays_below_its_bound_and_drops_the_entries_used_least_recently(cache, monkeypatch) -> None:
    """Five equal entries against a bound of four: the new entry drops the two used least recently (their
    modification times set apart here, a read renewing the first's), and the store keeps three quarters of it."""
    names = []
    for i in range(4):
        before = set(cache.glob("*.pkl")) if cache.exists() else set()
        _counted(float(i), np.ones(1000))
        (new,) = set(cache.glob("*.pkl")) - before
        names.append(new)
    for i, path in enumerate(names):
        os.utime(path, (1_000_000 + i, 1_000_000 + i))
    _counted(0.0, np.ones(1000))                  # read: the first entry is now the one used last
    assert len(CALLS) == 4
    size = names[0].stat().st_size
    writing = cache / f".tmp123.tmp-{names[1].name}"   # another process's entry being written: not the store's yet
    writing.write_bytes(names[1].read_bytes())
    os.utime(writing, (1, 1))
    monkeypatch.setattr(store_module, "STORE_BYTES", 4 * size + 100)
    _counted(4.0, np.ones(1000))                  # a fifth entry: over the bound
    assert writing.is_file()                      # the oldest file, yet left to its writer
    writing.unlink()
    left = set(cache.glob("*.pkl"))
    assert names[0] in left and names[3] in left and names[1] not in left and names[2] not in left
    assert len(left) == 3
    _counted(1.0, np.ones(1000))                  # a dropped entry is made again
    assert CALLS[-1] == (1.0, "a") and len(CALLS) == 6
