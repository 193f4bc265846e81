"""Reading and writing logs (ident.fitting.logs): exact round trips, and a clear LogError for every kind of bad input."""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident.fitting.logs import DriveLog, LogError, LogMeta, read_log, write_log

RATE = 1000.0
META = {"r": 0.01, "J_m_kgm2": 2e-5, "f_m_Nm": 0.01, "arm_length_m": 0.3, "encoder_counts_per_rev": 12566,
        "sample_rate_hz": RATE}
HEADER = "time_s,motor_torque_Nm,motor_pos_rad,load_pos_rad"


def make_log(n: int = 40, load: bool = True, t0: float = 12.5) -> DriveLog:
    rng = np.random.default_rng(1)
    return DriveLog(t0 + np.arange(n) / RATE, rng.normal(size=n) * 1e-2, rng.normal(size=n) * 1e3,
                    rng.normal(size=n) * 1e-7 if load else None, LogMeta(**META))


def rows(n: int = 12) -> list[list[str]]:
    """Data rows (as text) of a good log: time, torque, motor, load."""
    return [[repr(k / RATE), "0.01", repr(k * 1e-3), repr(k * 1e-5)] for k in range(n)]


def write_csv(folder: Path, data: list[list[str]], header: str = HEADER, name: str = "run.csv",
              meta: dict | None = META, meta_name: str = "run.json") -> Path:
    """A CSV log (and its sidecar unless ``meta`` is None) written as raw text."""
    path = folder / name
    path.write_text("\n".join([header, *(",".join(r) for r in data)]) + "\n")
    if meta is not None:
        (folder / meta_name).write_text(json.dumps(meta))
    return path


def read_error(path: Path, meta=None) -> str:
    with pytest.raises(LogError) as info:
        read_log(path, meta)
    return str(info.value)


def assert_same(a: DriveLog, b: DriveLog) -> None:
    for name in ("time_s", "motor_torque_Nm", "motor_pos_rad"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), strict=True)
    if a.load_pos_rad is None:
        assert b.load_pos_rad is None
    else:
        np.testing.assert_array_equal(a.load_pos_rad, b.load_pos_rad, strict=True)
    assert (a.meta, a.kind, a.meta_extra) == (b.meta, b.kind, b.meta_extra)


# ------------------------------------------------------------------------------------------------- round trips

@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
@pytest.mark.parametrize("load", [True, False], ids=["load", "motor-only"])
def test_round_trip_is_exact(tmp_path, suffix, load):
    log = make_log(load=load)
    data, sidecar = write_log(log, tmp_path / f"drive{suffix}")
    assert (data, sidecar) == (tmp_path / f"drive{suffix}", tmp_path / "drive.json")
    back = read_log(data)
    assert_same(log, back)
    assert back.source == str(data)
    assert back.time_s[0] == 12.5                       # time is kept as is, not shifted to zero
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([data.name, sidecar.name])   # no temp files left


def test_numpy_meta_values_are_written_as_plain_numbers(tmp_path):
    log = make_log()
    log.meta = LogMeta(np.float64(0.01), None, np.float64(0.02), 0.3, np.int64(4096), np.float64(RATE))
    assert read_log(write_log(log, tmp_path / "np.csv")[0]).meta == LogMeta(0.01, None, 0.02, 0.3, 4096, RATE)


def test_round_trip_linear_kind_meta_extra_and_unknown_meta(tmp_path):
    log = make_log()
    log.kind, log.meta_extra = "linear", {"Kp": 160.18, "Kv": 243.9}
    log.meta = LogMeta(1.0, None, None, 1.0, 1, 1000.0)
    log.extra = {"qg": np.arange(log.n) * 0.5}
    data, sidecar = write_log(log, tmp_path / "emps.csv")
    assert json.loads(sidecar.read_text())["units"]["motor_pos_rad"] == "m"
    assert "qg" in pd.read_csv(data).columns            # extra signals are written ...
    back = read_log(data)
    assert_same(log, back)
    assert back.extra == {}                             # ... and ignored on reading, like any extra column


def test_write_replaces_existing_files(tmp_path):
    write_log(make_log(n=20), tmp_path / "a.csv")
    log = make_log(n=30)
    assert read_log(write_log(log, tmp_path / "a.csv")[0]).n == 30


def test_write_checks_the_log_before_writing_anything(tmp_path):
    log = make_log()
    log.motor_pos_rad[7] = np.nan
    with pytest.raises(LogError, match=r"motor_pos_rad, row 8: NaN"):
        write_log(log, tmp_path / "bad.csv")
    log = make_log()
    log.meta = LogMeta(0.01, None, None, 0.3, 0, RATE)
    with pytest.raises(LogError, match="encoder_counts_per_rev"):
        write_log(log, tmp_path / "bad.csv")
    log = make_log()
    log.meta = LogMeta(0.01, None, None, 0.3, 100, 0.0)
    with pytest.raises(LogError, match=r"'sample_rate_hz' = 0.0 is unphysical"):
        write_log(log, tmp_path / "bad.csv")
    log = make_log()
    log.time_s = log.time_s[:-1]
    with pytest.raises(LogError, match="different lengths"):
        write_log(log, tmp_path / "bad.csv")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="sidecar"):
        write_log(make_log(), tmp_path / "log.json")


def test_failed_write_leaves_old_file_and_no_temp(tmp_path, monkeypatch):
    data, _ = write_log(make_log(n=20), tmp_path / "a.csv")
    before = data.read_bytes()

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(pd.DataFrame, "to_csv", broken)
    with pytest.raises(OSError, match="disk full"):
        write_log(make_log(n=30), data)
    assert data.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json"]


def test_extra_columns_whitespace_and_extra_keys_are_fine(tmp_path):
    data = [[*r, "junk"] for r in rows()]
    meta = {k: v for k, v in META.items() if k != "f_m_Nm"} | {"J_m_kgm2": None, "operator": "x"}   # None, absent
    path = write_csv(tmp_path, data, header="time_s, motor_torque_Nm, motor_pos_rad, load_pos_rad, comment", meta=meta)
    log = read_log(path)
    assert (log.n, log.meta.J_m_kgm2, log.meta.f_m_Nm, log.has_load) == (12, None, None, True)
    assert log.motor_pos_rad[11] == 11e-3


# ------------------------------------------------------------------------------------------------- the data file

def test_missing_and_empty_files(tmp_path):
    assert re.search(r"nowhere\.csv: log file not found", read_error(tmp_path / "nowhere.csv"))
    (tmp_path / "empty.csv").write_text("")
    assert "empty.csv: empty file" in read_error(tmp_path / "empty.csv", META)
    (tmp_path / "blank.csv").write_text("\n\n")
    assert "blank.csv: empty file" in read_error(tmp_path / "blank.csv", META)
    path = write_csv(tmp_path, [], name="header.csv")
    assert "header.csv: too few samples: 0 data row(s), need at least 10" in read_error(path, META)


def test_too_few_samples(tmp_path):
    path = write_csv(tmp_path, rows(9))
    assert "run.csv: too few samples: 9 data row(s)" in read_error(path)
    assert read_log(write_csv(tmp_path, rows(10))).n == 10


def test_missing_columns_are_listed_with_what_was_found(tmp_path):
    path = write_csv(tmp_path, [[r[0], r[2]] for r in rows()], header="time_s,motor_position")
    msg = read_error(path)
    assert "run.csv: missing required column(s) motor_torque_Nm, motor_pos_rad" in msg
    assert "found: time_s, motor_position" in msg


@pytest.mark.parametrize("cell, problem", [
    ("abc", "'abc' is not a number"),
    ("1,5", "row 5 (file line 6) has 5 fields, the header has 4"),    # a decimal comma adds a field
    ("", "empty cell"),
    ("nan", "NaN ('nan')"),
    ("-inf", "infinite value '-inf'"),
    ("1e400", "infinite value '1e400'"),
])
def test_bad_cells_name_column_row_and_text(tmp_path, cell, problem):
    data = rows()
    data[4][2] = cell                          # data row 5, column motor_pos_rad
    msg = read_error(write_csv(tmp_path, data))
    assert "run.csv" in msg and problem in msg
    assert "column motor_pos_rad, row 5:" in msg or cell == "1,5"


def test_short_row_is_an_empty_cell(tmp_path):
    data = rows()
    data[6] = data[6][:3]
    assert "column load_pos_rad, row 7: empty cell" in read_error(write_csv(tmp_path, data))


def test_non_monotonic_time(tmp_path):
    data = rows()
    data[8][0] = data[7][0]
    msg = read_error(write_csv(tmp_path, data))
    assert "run.csv: column time_s, row 9: time is not strictly increasing (0.007 s after 0.007 s at row 8)" in msg


def test_irregular_time_against_the_median(tmp_path):
    data = rows(20)
    data[12][0] = repr(12.05 / RATE)           # 1.05 ms then 0.95 ms instead of 1 ms
    msg = read_error(write_csv(tmp_path, data))
    assert "run.csv: column time_s, row 13: irregular time: interval 0.00105 s from row 12" in msg
    assert "expected 0.001 s (the median interval)" in msg
    data[12][0] = repr(12.005 / RATE)          # 0.5 % off: accepted
    assert read_log(write_csv(tmp_path, data)).n == 20


def test_time_against_the_sample_rate(tmp_path):
    path = write_csv(tmp_path, rows(), meta={**META, "sample_rate_hz": 500.0})
    msg = read_error(path)
    assert "run.csv: sample rate: the sidecar says sample_rate_hz = 500 Hz, the column time_s runs at 1000 Hz" in msg


@pytest.mark.parametrize("rel, ok", [(0.008, False), (2e-4, False), (5e-5, True)])
def test_sample_rate_against_the_time_column(tmp_path, rel, ok):
    """Issue 21: a sidecar rate 0.8 % off the time column is an error naming both numbers; any mismatch above 1e-4
    relative is; below it is accepted."""
    path = write_csv(tmp_path, rows(), meta={**META, "sample_rate_hz": RATE * (1 + rel)})
    if ok:
        assert read_log(path).n == 12
        return
    msg = read_error(path)
    assert f"sample_rate_hz = {RATE * (1 + rel):.10g} Hz, the column time_s runs at 1000 Hz" in msg
    assert f"relative difference {rel / (1 + rel):.3g} > 0.0001" in msg


def test_parquet_bad_cells_and_columns(tmp_path):
    log = make_log()
    frame = log.to_frame()
    frame.loc[3, "load_pos_rad"] = np.nan
    path = tmp_path / "run.parquet"
    frame.to_parquet(path)
    (tmp_path / "run.json").write_text(json.dumps(META))
    assert "run.parquet: column load_pos_rad, row 4: NaN" in read_error(path)
    frame = log.to_frame().astype({"motor_torque_Nm": str})
    frame.loc[5, "motor_torque_Nm"] = "12 mNm"
    frame.to_parquet(path)
    assert "run.parquet: column motor_torque_Nm, row 6: '12 mNm' is not a number" in read_error(path)
    log.to_frame().drop(columns="time_s").to_parquet(path)
    assert "run.parquet: missing required column(s) time_s" in read_error(path)
    path.write_text("not parquet")
    assert "run.parquet: cannot read the table" in read_error(path)


# ------------------------------------------------------------------------------------------------- the sidecar

def test_sidecar_lookup_order(tmp_path):
    path = write_csv(tmp_path, rows(), meta={**META, "r": 0.5}, meta_name="meta.json")
    assert read_log(path).meta.r == 0.5                                  # meta.json when there is no run.json
    (tmp_path / "run.json").write_text(json.dumps({**META, "r": 0.25}))
    assert read_log(path).meta.r == 0.25                                 # same stem first
    (tmp_path / "other.json").write_text(json.dumps({**META, "r": 0.125}))
    assert read_log(path, tmp_path / "other.json").meta.r == 0.125      # an explicit path wins
    assert read_log(path, str(tmp_path / "other.json")).meta.r == 0.125
    assert read_log(path, {**META, "r": 0.0625}).meta.r == 0.0625       # and so does a dict


def test_no_sidecar_names_the_places_looked_at(tmp_path):
    path = write_csv(tmp_path, rows(), meta=None)
    msg = read_error(path)
    assert f"{path}: no JSON sidecar found (looked for: {tmp_path / 'run.json'}, {tmp_path / 'meta.json'})" in msg
    msg = read_error(path, tmp_path / "gone.json")
    assert f"looked for: {tmp_path / 'gone.json'}" in msg


@pytest.mark.parametrize("key", ["r", "arm_length_m", "sample_rate_hz"])
def test_missing_required_key(tmp_path, key):
    """encoder_counts_per_rev, J_m_kgm2 and f_m_Nm may be absent (a linear axis, an unknown motor); these may not."""
    meta = dict(META)
    del meta[key]
    msg = read_error(write_csv(tmp_path, rows(), meta=meta))
    assert f"sidecar {tmp_path / 'run.json'}" in msg and f"missing key '{key}'" in msg
    assert f"looked for: {tmp_path / 'run.json'}, {tmp_path / 'meta.json'}" in msg
    assert f"key '{key}' is null" in read_error(tmp_path / "run.csv", {**META, key: None})


@pytest.mark.parametrize("key, value, problem", [
    ("r", 0, "is unphysical: must be > 0"),
    ("r", -0.01, "is unphysical: must be > 0"),
    ("J_m_kgm2", 0.0, "is unphysical: must be > 0"),
    ("f_m_Nm", -0.001, "is unphysical: must be > 0"),
    ("f_m_Nm", 0, "is unphysical: must be > 0"),
    ("r", 100, "is outside the range the plant accepts [1e-06, 1]"),
    ("J_m_kgm2", 1e-300, "kg.m2 is outside the range the plant accepts [1e-12, 1000] kg.m2"),
    ("encoder_counts_per_rev", 2**40, "is outside the range the plant accepts [1, 2147483647]"),
    ("arm_length_m", 0, "is unphysical: must be > 0"),
    ("encoder_counts_per_rev", 0, "is unphysical: must be >= 1"),
    ("encoder_counts_per_rev", 100.5, "is not an integer"),
    ("sample_rate_hz", -1000, "is unphysical: must be > 0"),
    ("sample_rate_hz", "1000", "is not a finite number"),
    ("r", True, "is not a finite number"),
])
def test_invalid_meta_values(tmp_path, key, value, problem):
    msg = read_error(write_csv(tmp_path, rows(), meta={**META, key: value}))
    assert f"sidecar {tmp_path / 'run.json'}" in msg and f"key '{key}' = {value!r} {problem}" in msg


def test_a_repeated_column_is_refused(tmp_path):
    path = write_csv(tmp_path, [r + ["1"] for r in rows()], header=HEADER + ",motor_torque_Nm")
    assert "column motor_torque_Nm appears more than once in the header" in read_error(path)


@pytest.mark.parametrize("column, value", [("motor_torque_Nm", 1e300), ("load_pos_rad", -2e6)])
def test_a_value_the_plant_cannot_take_names_its_row(tmp_path, column, value):
    data = rows()
    data[4][HEADER.split(",").index(column)] = repr(value)
    msg = read_error(write_csv(tmp_path, data))
    assert f"column {column}, row 5: {value:g} is outside the range the plant accepts [-1e+06, 1e+06]" in msg, msg


def test_meta_values_are_typed(tmp_path):
    meta = read_log(write_csv(tmp_path, rows()), {**META, "encoder_counts_per_rev": 4096.0, "r": 1}).meta
    assert meta.encoder_counts_per_rev == 4096 and isinstance(meta.encoder_counts_per_rev, int)
    assert isinstance(meta.r, float)
    msg = read_error(tmp_path / "run.csv", {**META, "f_m_Nm": float("nan")})
    assert "meta dict given to read_log" in msg and "key 'f_m_Nm' = nan is not a finite number" in msg


def test_broken_sidecar_files(tmp_path):
    path = write_csv(tmp_path, rows(), meta=None)
    (tmp_path / "run.json").write_text("{'r': 0.01}")
    assert f"{tmp_path / 'run.json'}: cannot read the JSON sidecar" in read_error(path)
    (tmp_path / "run.json").write_text("[1, 2]")
    assert "the sidecar must be a JSON object, got list" in read_error(path)
    (tmp_path / "run.json").write_text(json.dumps({**META, "kind": "planar"}))
    assert "key 'kind' = 'planar'" in read_error(path)


# ------------------------------------------------------------------------------------------------- units

@pytest.mark.parametrize("torque_unit", ["N.m", "N m", "Nm", "N*m", "N·m"])
def test_si_units_are_accepted(tmp_path, torque_unit):
    units = {"time_s": "s", "motor_torque_Nm": torque_unit, "motor_pos_rad": "rad", "load_pos_rad": "rad",
             "comment": "whatever"}                   # units of ignored columns are ignored too
    assert read_log(write_csv(tmp_path, rows(), meta={**META, "units": units})).n == 12


@pytest.mark.parametrize("column, unit", [
    ("time_s", "ms"), ("motor_torque_Nm", "mNm"), ("motor_pos_rad", "deg"), ("load_pos_rad", "counts"),
    ("motor_pos_rad", None), ("motor_pos_rad", "m"),
])
def test_other_units_are_refused(tmp_path, column, unit):
    msg = read_error(write_csv(tmp_path, rows(), meta={**META, "units": {column: unit}}))
    assert f"sidecar {tmp_path / 'run.json'}" in msg
    assert f"column {column} has unit {unit!r}" in msg and "convert the data to SI" in msg


def test_units_follow_the_kind_and_must_be_a_mapping(tmp_path):
    path = write_csv(tmp_path, rows())
    linear = {**META, "kind": "linear", "units": {"motor_pos_rad": "m", "motor_torque_Nm": "N"}}
    assert read_log(path, linear).kind == "linear"
    assert "column motor_torque_Nm has unit 'N.m'" in read_error(path, {**linear, "units": {"motor_torque_Nm": "N.m"}})
    assert "key 'units' must map column -> unit" in read_error(path, {**META, "units": "SI"})


def test_no_temp_files_are_left_in_a_folder_of_logs(tmp_path):
    for k in range(3):
        write_log(make_log(), tmp_path / f"log{k}.parquet")
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]


def test_optional_keys_may_be_absent(tmp_path):
    meta = {k: v for k, v in META.items() if k not in ("encoder_counts_per_rev", "J_m_kgm2", "f_m_Nm")}
    log = read_log(write_csv(tmp_path, rows(), meta=meta))
    assert log.meta.encoder_counts_per_rev is None and log.meta.J_m_kgm2 is None and log.meta.f_m_Nm is None
