"""The paper-claims search (ident.studies.paper_claims, effect_ranges, paper_search, paper_search_report).

- the claim metrics on hand-made sequences whose R², first-increment ratio, fraction and ratios are known exactly;
- the Pareto front and the ranking on a hand-made misfit matrix;
- the plausible ranges: inside the FMU's parameter table at every corner, the catalogue arithmetic by hand;
- a small search on a coarse grid whose best point the test finds itself, by a separate brute-force evaluation (its
  own calls of the protocols, its own ranking);
- determinism for a seed; the budget split; the CLI's JSON (claims, pareto) and its named errors.
"""
from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from ident import DriveParams, impulse_resolution, linear_resolution
from ident.studies import paper_search as ps
from ident.studies.effect_ranges import ARCMIN, CHA_STIFFNESS, cubic_hardening, drive_knobs, effect_ranges
from ident.studies.paper_claims import (
    BY_NAME,
    CLAIMS,
    ClaimInputs,
    avalanche_ratios,
    claim_values,
    rising_line,
)

TINY = ps.Fidelity("screen", (0.1, 1.0), 10, 10)
TINY_FULL = ps.Fidelity("full", (0.1, 1.0), 10, 10)


# -- claim metrics on known sequences -------------------------------------------------------------------------------
def test_rising_line_r2_known_by_hand() -> None:
    # x = 0..3, y = 0, 1, 1, 3: Sxy = 4.5, Sxx = 5, Syy = 4.75 -> slope 0.9, R² = 4.5² / (5 * 4.75) = 81/95
    r = rising_line(np.array([0.0, 1, 2, 3]), np.array([0.0, 1, 1, 3]))
    assert r["slope_um"] == pytest.approx(0.9) and r["intercept_um"] == pytest.approx(1.25 - 0.9 * 1.5)
    assert r["r2"] == pytest.approx(81 / 95) and r["signed_r2"] == pytest.approx(81 / 95)
    falling = rising_line(np.array([0.0, 1, 2]), np.array([3.0, 2, 1]))
    assert falling["r2"] == pytest.approx(1.0) and falling["signed_r2"] == pytest.approx(-1.0)
    assert rising_line(np.array([0.0, 1]), np.array([2.0, 2.0]))["signed_r2"] == 0.0   # flat: no growth
    with pytest.raises(ValueError, match="two distinct"):
        rising_line(np.array([1.0, 1.0]), np.array([1.0, 2.0]))


def test_avalanche_ratios_known_by_hand() -> None:
    x = np.array([0, 0, 1.0] + [0.2] * 7)          # sorted: 0, 0, 0.2 x 7, 1.0 -> median 0.2
    a = avalanche_ratios(x)
    assert a["first_pulse"] == 3 and a["first_motion_um"] == 1.0 and a["median_um"] == pytest.approx(0.2)
    assert a["first_over_median"] == pytest.approx(5.0) and a["later_over_median"] == pytest.approx(1.0)
    rough = avalanche_ratios(np.array([0, 0, 1.0, 0.5] + [0.2] * 6))
    assert rough["later_over_median"] == pytest.approx(2.5)
    still = avalanche_ratios(np.zeros(4))
    assert still["first_over_median"] == 0.0 and still["first_pulse"] == 5


def _inputs(**kw) -> ClaimInputs:
    d = dict(f_l_star=np.array([0.0, 1, 2, 3]), max_um=np.array([0.0, 1, 1, 3]), impulse_um=np.array([0.1, 0.32]),
             top_um=np.array([0, 0, 1.0] + [0.2] * 7), experiment_um=np.array([0.1] * 19 + [0.4]), linear_um=3.2,
             linear_counts=2)
    d.update(kw)
    return ClaimInputs(**d)


def test_claim_values_verdicts_and_misfits() -> None:
    v = claim_values(_inputs())
    assert v["impulse_resolution"].value == 0.32 and v["impulse_resolution"].met
    assert v["linear_over_impulse"].value == pytest.approx(10.0) and v["linear_over_impulse"].met
    assert v["linear_growth"].value == pytest.approx(81 / 95) and not v["linear_growth"].met
    assert v["linear_growth"].misfit == pytest.approx((0.9 - 81 / 95) / 0.1)
    assert v["avalanche"].value == pytest.approx(5.0) and v["avalanche"].met and v["avalanche"].misfit == 0
    assert v["experimental_histogram"].value == pytest.approx(0.95) and v["experimental_histogram"].met
    worse = claim_values(_inputs(impulse_um=np.array([0.1, 0.4]), linear_counts=3,
                                 top_um=np.array([0, 0, 0.3, 0.5] + [0.2] * 6),
                                 experiment_um=np.array([0.1] * 18 + [0.4] * 2)))
    assert worse["impulse_resolution"].misfit == pytest.approx((0.1 - 0.05) / 0.05)
    # 3.2 / 0.4 = 8 lies 2 from 10, 0.3 beyond the tolerance 1.7; one count off adds 1
    assert worse["linear_over_impulse"].misfit == pytest.approx(0.3 / 1.7 + 1) and not worse["linear_over_impulse"].met
    # first motion 0.3 / 0.2 = 1.5 (0.5 medians short of 2), later 0.5 / 0.2 = 2.5 (0.5 above 2)
    assert worse["avalanche"].misfit == pytest.approx(1.0) and not worse["avalanche"].met
    assert worse["experimental_histogram"].misfit == pytest.approx((0.95 - 0.9) / 0.05)
    for c in CLAIMS:
        assert all(getattr(c, k) for k in ("source", "where", "basis", "quantity"))
        assert (v[c.name].misfit == 0) == v[c.name].met


def test_pareto_front_and_rank() -> None:
    m = np.array([[0, 1, 1], [1, 0, 1], [0, 1, 2], [1, 1, 1], [0, 0, math.inf], [math.inf] * 3])
    assert ps.pareto_front(m) == [0, 1, 4]
    assert ps.pareto_front(np.array([[math.inf, math.inf]] * 2)) == [0, 1]   # all failed: nothing dominates


# -- plausible ranges --------------------------------------------------------------------------------------------
def test_ranges_inside_the_fmu_table_and_catalogue_arithmetic() -> None:
    base = DriveParams()
    ranges = effect_ranges(base)
    space = ps.Space(base, ranges)
    for name, rng in ranges.items():
        for corner in itertools.product((0.0, 1.0), repeat=len(space.knobs((name,)))):
            c = space.candidate((name,), corner)          # DriveParams validates every value against the table
            assert set(c.fmu[name]) and c.params.K_star == pytest.approx(base.K_star * (0.5 + corner[0]))
        assert rng.cited == (rng.source != "none found")
    # CHA-17A, ratio > 50: T1 3.9, T2 12 N.m, K1 1.0e4, K2 1.4e4, K3 1.6e4 N.m/rad
    phi2 = 3.9 / 1.0e4 + (12 - 3.9) / 1.4e4
    assert cubic_hardening(*CHA_STIFFNESS["CHA-17A"]) == pytest.approx(0.6 / (3 * phi2**2))
    assert ranges["hardening"].knobs[0].hi == max(cubic_hardening(*r) for r in CHA_STIFFNESS.values())
    hyst = space.candidate(("hysteresis",), (0.5, 0.5, 1.0, 0.5))
    assert hyst.fmu["hysteresis"]["hysteresis_torque"] == pytest.approx(0.5 * base.K_s * ARCMIN)   # loop 1 arcmin
    assert ranges["stribeck"].knobs[0].hi == 1.5 and ranges["kinematic_error"].knobs[0].hi == 30.0
    with pytest.raises(ValueError, match="span"):
        drive_knobs(1.0)


# -- a small search whose best point the test finds itself -------------------------------------------------------
def _brute_force(base: DriveParams, effects: list[str], fid: ps.Fidelity) -> list[tuple]:
    """Every grid point (ends of each knob; the drive fixed), evaluated by direct protocol calls: (key, label, u)."""
    ranges = effect_ranges(base)
    space = ps.Space(base, {e: ranges[e] for e in effects}, drive_knobs(0.0))
    subsets = [()] + [(e,) for e in effects] + [tuple(effects)]
    out = []
    for s in subsets:
        for u in itertools.product(*[[0.5] if k.lo == k.hi else [0.0, 1.0] for k in space.knobs(s)]):
            p = space.candidate(s, u).params
            runs = {f: impulse_resolution(p.with_values(f_l_star=f), fid.n_pulses).increments_m * 1e6
                    for f in (*fid.levels, 0.176)}
            lin = linear_resolution(p.with_values(f_l_star=0.1), n_steps=fid.n_steps)
            v = claim_values(ClaimInputs(np.array(fid.levels), np.array([runs[f].max() for f in fid.levels]),
                                         runs[0.1], runs[max(fid.levels)], runs[0.176], lin.resolution_m * 1e6,
                                         lin.counts))
            met = sum(x.met for x in v.values())
            out.append(((-met, sum(x.misfit for x in v.values()), len(s)), "+".join(s) or "drive only", u))
    return sorted(out, key=lambda t: t[0])


def test_grid_search_finds_the_brute_force_best() -> None:
    effects = ["asymmetric_friction", "viscous_motor"]
    search = ps.search_paper(grid=2, confirm=2, effects=effects, screen=TINY, full=TINY_FULL, drive_span=0.0,
                             workers=0)
    truth = _brute_force(DriveParams(), effects, TINY)
    assert len(search.screened()) == len(truth) == 1 + 2 + 2 + 4
    best = search.pareto()[0]
    assert (best.candidate.label, best.candidate.u) == truth[0][1:]
    assert (-best.n_met, float(np.sum(best.misfits))) == pytest.approx(truth[0][0][:2])
    # the confirmed set holds the unchanged drive once, and every point once
    points = [(e.candidate.effects, e.candidate.u) for e in search.confirmed()]
    assert [e.candidate.u for e in search.confirmed() if not e.candidate.effects] == [(0.5, 0.5)]
    assert len(set(points)) == len(points) == 3


def test_search_is_deterministic_for_a_seed_and_spends_its_budget() -> None:
    kw = dict(budget=8, confirm=1, effects=["asymmetric_friction", "viscous_load"], screen=TINY, full=TINY_FULL,
              workers=0)
    a, b, c = (ps.search_paper(seed=s, **kw) for s in (7, 7, 8))
    ua = [(e.candidate.label, e.candidate.u, tuple(e.misfits)) for e in a.evaluations]
    assert ua == [(e.candidate.label, e.candidate.u, tuple(e.misfits)) for e in b.evaluations]
    assert [e.candidate.u for e in a.screened()] != [e.candidate.u for e in c.screened()]
    assert len(a.screened()) == 8 and a.plan == ps.plan(8, 2)
    stages = [e.stage for e in a.evaluations]
    assert stages.count("screen-single") == 6 and stages.count("screen-pair") == 2
    assert stages.count("recheck") == ps.RECHECK_FACTOR * 1 and stages.count("confirm") == 2
    # the rechecked and confirmed points are screened points (the shortlists pick, they do not invent)
    screened = {(e.candidate.effects, e.candidate.u) for e in a.screened()}
    assert all((e.candidate.effects, e.candidate.u) in screened for e in a.rechecked())


def test_plan_splits_the_budget() -> None:
    p = ps.plan(96, 7)
    assert (p.n1, p.n2, p.n_pairs, p.refine) == (4, 2, 14, 36)
    assert 8 * p.n1 + p.n_pairs * p.n2 + p.refine == 96
    assert ps.plan(500, 7).n_pairs == 21
    with pytest.raises(ValueError, match="at least 18"):
        ps.plan(17, 7)


def test_batch_session_reuses_one_cluster() -> None:
    from ident.protocols.batch import batch_session

    with batch_session(workers=1) as run:
        assert run(abs, [-1, -2, 3]) == [1, 2, 3]
        assert run(str, []) == []
        assert run(math.sqrt, [4.0, 9.0], desc="second batch") == [2.0, 3.0]


# -- the command line ------------------------------------------------------------------------------------------
def test_cli_search_json(tmp_path, monkeypatch, capsys) -> None:
    from ident.cli import DEFAULT_SEARCH_BUDGET, main

    assert DEFAULT_SEARCH_BUDGET == ps.DEFAULT_BUDGET
    monkeypatch.setattr(ps, "SCREEN", TINY)
    code = main(["paper-effects", "--search", "--out", str(tmp_path / "s"), "--json", "--workers", "0",
                 "--effects", "asymmetric_friction,viscous_load", "--budget", "8", "--confirm", "1", "--levels", "3",
                 "--pulses", "10", "--steps", "10"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert [c["name"] for c in out["claims"]] == [c.name for c in CLAIMS]
    assert all({"target", "tolerance", "source"} <= set(c) for c in out["claims"])
    assert out["pareto"] and all({"effects", "drive", "claims"} <= set(p) for p in out["pareto"])
    first = out["pareto"][0]
    assert set(first["claims"]) == set(BY_NAME) and all({"value", "met"} <= set(v) for v in first["claims"].values())
    files = {p.name for p in (tmp_path / "s").iterdir()}
    assert {"paper_search.md", "paper_search.json", "paper_search_evaluations.csv", "paper_search_sweep.png",
            "paper_search_increments.png"} <= files
    text = (tmp_path / "s" / "paper_search.md").read_text()
    assert "## Answer" in text and "EMPS" in text and "no cited source" in text


@pytest.mark.parametrize("argv, message", [
    (["--effects", "nope"], "--effects"), (["--budget", "3"], "at least"), (["--levels", "4"], "odd"),
    (["--budget", "0"], "--budget"), (["--confirm", "-1"], "--confirm")])
def test_cli_search_errors_named_before_work(tmp_path, capsys, argv, message) -> None:
    from ident.cli import main

    code = main(["paper-effects", "--search", "--out", str(tmp_path / "s"), "--workers", "0", *argv])
    assert code == 2 and message in capsys.readouterr().err and not (tmp_path / "s").exists()
