"""The paper-effects study (ident.studies.paper_effects): a small sweep runs, its base case equals friction_sweep, an effect
case equals a direct impulse_resolution call, and the verdict logic is right on constructed tables."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ident import DriveParams, impulse_resolution
from ident.model.effects import EFFECTS
from ident.protocols.sweep import friction_sweep
from ident.studies.paper_effects import (
    AVALANCHE_RATIO,
    BASE_CASE,
    EFFECT_CASES,
    LINEAR_GROWTH,
    LINEAR_R2,
    combine,
    effects_sweep,
    summarize,
)

LEVELS = [0.01, 0.1, 1.0]
N = 20


@pytest.fixture(scope="module")
def small_sweep():
    cases = [BASE_CASE, next(c for c in EFFECT_CASES if c.name == "asymmetry_20pct"),
             next(c for c in EFFECT_CASES if c.name == "hysteresis_fl")]
    return effects_sweep(cases, LEVELS, N, workers=0)


def test_cases_cover_the_library() -> None:
    names = [c.name for c in EFFECT_CASES]
    assert len(set(names)) == len(names) and names[0] == "base"
    effects = {c.effect for c in EFFECT_CASES}
    assert effects - {""} <= set(EFFECTS)
    assert set(EFFECTS) - {"flexibility"} <= effects  # every effect of the two-inertia model is tried
    assert all(c.why for c in EFFECT_CASES)


def test_per_f_l_parameters_follow_the_load_friction() -> None:
    case = next(c for c in EFFECT_CASES if c.name == "hysteresis_fl")
    for f in (0.01, 0.5):
        p = case.params(DriveParams(), f)
        assert p.f_l_star == pytest.approx(f)
        assert p.hysteresis_torque == pytest.approx(p.f_l)
    both = combine(case, next(c for c in EFFECT_CASES if c.name == "stribeck_slow")).params(DriveParams(), 0.2)
    assert both.hysteresis_torque == pytest.approx(both.f_l) and both.stribeck_ratio == 0.5


def test_base_case_equals_friction_sweep(small_sweep) -> None:
    ref = friction_sweep(None, LEVELS, N, workers=0)
    df = small_sweep.to_frame()
    base = df[df["case"] == "base"].reset_index(drop=True)
    expect = ref.to_frame()
    for col in ("f_l_star", "threshold_amplitude", "resolution_um", "median_um", "min_um", "first_increment_um"):
        # same simulations; the statistics differ only by the order of scaling to um and taking the median
        np.testing.assert_allclose(base[col].to_numpy(), expect[col].to_numpy(), rtol=1e-12, err_msg=col)
    for got, want in zip(small_sweep.results["base"], ref.results):
        np.testing.assert_array_equal(got.increments_m, want.increments_m)


def test_effect_case_equals_direct_call(small_sweep) -> None:
    case = small_sweep.case("asymmetry_20pct")
    direct = impulse_resolution(DriveParams(f_l=1.0 * 0.01, friction_asymmetry=0.2), n_pulses=N)
    got = small_sweep.results[case.name][2]
    assert got.params == direct.params
    assert got.threshold_amplitude == direct.threshold_amplitude
    np.testing.assert_array_equal(got.increments_m, direct.increments_m)


def test_sweep_table_and_summary(small_sweep, tmp_path) -> None:
    df = small_sweep.to_frame()
    assert len(df) == 3 * len(LEVELS)
    assert (df["resolution_um"] >= df["median_um"]).all() and (df["median_um"] >= df["min_um"]).all()
    assert (df["first_motion_pulse"] >= 1).all()
    s = small_sweep.summary()
    assert list(s["case"]) == ["base", "asymmetry_20pct", "hysteresis_fl"]
    assert small_sweep.plot(tmp_path / "p.png").stat().st_size > 0


def _table(case: str, f, max_um, median_um, first_um) -> pd.DataFrame:
    n = len(f)
    return pd.DataFrame(dict(case=[case] * n, effect=["x"] * n, f_l_star=f, resolution_um=max_um,
                             median_um=median_um, first_motion_um=first_um))


def test_summarize_fit_and_verdicts() -> None:
    f = np.array([0.01, 0.1, 0.5, 1.0])
    lin = _table("lin", f, 0.1 + 0.5 * f, [0.1] * 4, [0.1, 0.1, 0.1, 0.25])        # exact line, x5.7, first motion 2.5x median
    flat = _table("flat", f, [0.12, 0.11, 0.13, 0.12], [0.1] * 4, [0.1, 0.1, 0.1, 0.1])
    ava = _table("ava", f, [0.1, 0.1, 0.1, 0.35], [0.1] * 4, [0.1, 0.1, 0.1, 0.35])  # jump at the end only
    weak = _table("weak", f, 0.1 + 0.05 * f, [0.1] * 4, [0.1] * 4)                  # linear but growth x1.5
    s = summarize(pd.concat([lin, flat, ava, weak])).set_index("case")
    assert s.loc["lin", "slope_um"] == pytest.approx(0.5)
    assert s.loc["lin", "intercept_um"] == pytest.approx(0.1)
    assert s.loc["lin", "r2"] == pytest.approx(1.0)
    assert s.loc["lin", "growth"] == pytest.approx(0.6 / 0.105)
    assert s.loc["lin", "first_over_median_hi"] == pytest.approx(2.5)
    assert s.loc["lin", "linear"] and s.loc["lin", "avalanche"] and s.loc["lin", "reproduces"]
    assert not s.loc["flat", "linear"] and not s.loc["flat", "avalanche"]
    x, y = f, np.array([0.1, 0.1, 0.1, 0.35])
    slope, icpt = np.polyfit(x, y, 1)
    r2 = 1 - np.sum((y - slope * x - icpt) ** 2) / np.sum((y - y.mean()) ** 2)
    assert s.loc["ava", "r2"] == pytest.approx(r2) and r2 < LINEAR_R2
    assert not s.loc["ava", "linear"] and s.loc["ava", "avalanche"] and not s.loc["ava", "reproduces"]
    assert s.loc["weak", "r2"] == pytest.approx(1.0) and s.loc["weak", "growth"] < LINEAR_GROWTH
    assert not s.loc["weak", "linear"]
    # thresholds are inclusive / strict as documented
    edge = _table("edge", np.array([0.01, 1.0]), [0.1, 0.1 * LINEAR_GROWTH], [0.1, 0.1],
                  [0.1, 0.1 * AVALANCHE_RATIO])
    e = summarize(edge).iloc[0]
    assert e["linear"] and not e["avalanche"]
    falling = summarize(_table("down", f, 1.0 - 0.5 * f, [0.1] * 4, [0.1] * 4)).iloc[0]
    assert falling["r2"] == pytest.approx(1.0) and not falling["linear"]
    zero_median = summarize(_table("z", f, [0.1] * 4, [0.0] * 4, [0.0] * 4)).iloc[0]
    assert math.isinf(zero_median["first_over_median_hi"])


def test_write_paper_effects(tmp_path) -> None:
    from ident.studies.paper_effects import write_paper_effects

    cases = [BASE_CASE] + [c for c in EFFECT_CASES if c.name in ("asymmetry_20pct", "hysteresis_fl")]
    sweep, md = write_paper_effects(tmp_path / "pe", cases=cases, levels=[0.1, 1.0], n_pulses=10, workers=0)
    text = md.read_text()
    assert "## Answer" in text and any("+" in c.name for c in sweep.cases)
    assert {"paper_effects.csv", "paper_effects_summary.csv", "paper_effects.json", "paper_effects.png"} <= \
        {p.name for p in md.parent.iterdir()}
    assert len(sweep.cases) == 4
