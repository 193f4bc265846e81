"""The discrepancy loop end to end on effects whose shape is not the library's, or whose twin the log may not tell
apart (issue 16), on the independent generator's short logs (3 s at 5 kHz, ``tests.diagnosis_matrix.SHORT``).

Split from ``test_diagnose.py`` so that the default run's two heaviest groups of end-to-end diagnoses run in two test
processes (``--dist loadfile`` keeps a file's tests in one): a kinematic error with its 4/rev over turns of the motor
(both harmonics within 5 %) and over a short motor arc (the size in doubt), a Stribeck decay and a Dahl element of
other shapes than the library's (the shape check: the size in doubt, the interval holding the truth), an exponential
decay the log tells apart (adopted where it is named, its size within 2 %), and viscous friction on either side of
the gear (told apart only where the log rings the spring). The seeds (5102, 5506-5523) appear nowhere in the product.
Slow (marked, stop 63): the shape check on the exponential Stribeck torque-step log (47 s; the Dahl one stays).
"""
from __future__ import annotations

from dataclasses import replace

import pytest

from tests.diagnosis_matrix import SHORT, Case, diagnosed, library_truth, load

KINEMATIC_STEPS = Case("single", 5506, "kinematic_error", "strong", "steps")
EXPONENTIAL_STRIBECK = Case("single", 5515, "stribeck", "strong", "steps", "exponential")
DAHL_2 = Case("single", 5522, "hysteresis", "strong", "default", "dahl")   # the generator drew the exponent 2
EXPONENTIAL_DEFAULT = Case("single", 5523, "stribeck", "strong", "default", "exponential")


def test_a_kinematic_error_over_turns_of_the_motor_is_named_with_both_harmonics():
    """A strong kinematic error (the generator's: a 4/rev at 0.15-0.6 of the 2/rev, phases drawn) in a torque-step
    log whose motor turns through several periods: it is named alone, its 2/rev amplitude within 1 % and its 4/rev
    within 5 % of the truth. Before the 4/rev was in the library the 2/rev alone left the model 8.4x the noise; before
    the simulation started the load where the kinematic error puts it (``DriveParams.load_angle_at``) the fit began
    twisted by e(q_m0), a start outside the static band, and stopped 12 % low at 3.6x the noise. Against the two
    rivals the screen ranks next on this log (all seven: the slow matrix and ``bench/diagnose.py``)."""
    d, truth = diagnosed(KINEMATIC_STEPS, workers=0, candidates=("kinematic_error", "stribeck", "viscous_load"))
    assert [e.name for e in d.effects] == ["kinematic_error"], d.summary
    e, k = d.effects[0], truth["effects"]["kinematic_error"]
    assert abs(e.magnitude - k["amp2"]) <= 0.01 * k["amp2"], (e.magnitude, k)
    assert abs(e.params["kinematic_error_4"] - k["amp4"]) <= 0.05 * k["amp4"], (e.params, k)
    assert any(x.startswith("kinematic error: its 2/rev and 4/rev harmonics fitted") for x in d.derivations)


@pytest.mark.parametrize("case,shape", [pytest.param(EXPONENTIAL_STRIBECK, "exponential", marks=pytest.mark.slow),
                                        (DAHL_2, "exponent 2")], ids=["stribeck-exponential", "dahl-exponent-2"])
def test_an_effect_of_another_shape_leaves_its_size_in_doubt_and_the_interval_holds_the_truth(case, shape):
    """A strong Stribeck friction with an exponential decay in a torque-step log, and a strong Dahl hysteresis of
    exponent 2 in a default-design log (the generator's shapes; the library's are a Gaussian decay and exponent 1).
    The library's shape fits each and is named, its size 16 % and 13 % low with a local interval that misses the
    truth. The shape check refits it through the FMU in the other shape (``stribeck_shape`` = 1,
    ``hysteresis_exponent`` = 2): on these 3 s logs the two fit the training data alike (within the loop's
    threshold), the other shape's size is the truth's within 10 %, and so the name is tentative ("the size depends
    on it") and its interval holds both sizes, the truth among them. Before the check the name was given with the
    library shape's interval alone."""
    d, truth = diagnosed(case, workers=0, candidates=(case.effect,))
    assert [e.name for e in d.effects] == [case.effect], d.summary
    e, size = d.effects[0], truth["magnitudes"][case.effect][0]
    assert abs(e.shape_check["magnitude"] - size) <= 0.10 * size, (e.shape_check, size)
    assert shape in e.shape_check["shape"] and not e.shape_check["unfinished"]
    assert e.ci95[0] <= size <= e.ci95[1], (e.ci95, size)
    assert e.tentative and "the size depends on it" in e.why_tentative, e.why_tentative
    assert any(n.startswith(f"shape check: {case.effect}: ") for n in d.notes)


def test_an_effect_in_the_shape_the_log_prefers_is_named_in_it_with_its_size():
    """A strong Stribeck friction with an exponential decay in a default-design log: here the log tells the shapes
    apart. The Gaussian is accepted, refitted at once with the exponential decay (``stribeck_shape`` = 1), which fits
    the training data better by more than the loop's threshold, and the loop goes on in it: the size named is the
    exponential's, within 2 % of the truth with an interval that holds it, and the final check rejects the
    Gaussian, so the name is confident. Before, the Gaussian's size was named and the shape said to remain."""
    from ident.diagnosis.engine import SEPARABLE

    d, truth = diagnosed(EXPONENTIAL_DEFAULT, workers=0, candidates=("stribeck",))
    assert [e.name for e in d.effects] == ["stribeck"], d.summary
    e, size = d.effects[0], truth["magnitudes"]["stribeck"][0]
    assert "exponential" in e.shape and any("adopted, the loop goes on from it" in n for n in d.notes), d.notes
    assert abs(e.magnitude - size) <= 0.02 * size and e.ci95[0] <= size <= e.ci95[1], (e.magnitude, e.ci95, size)
    assert "Gaussian" in e.shape_check["shape"] and e.shape_check["delta_cost"] >= SEPARABLE, e.shape_check
    assert not e.tentative, e.why_tentative
    assert any(s.startswith("stribeck is named confidently with an exponential") for s in d.summary), d.summary


def test_a_kinematic_error_over_a_short_motor_arc_is_named_with_its_size_in_doubt():
    """The same effect over the default design's short motor arc (a few hundredths of a turn): the 4/rev cannot be
    told from the 2/rev there, so the 2/rev alone is fitted and its amplitude is the one that reproduces the local
    shape (here about half the drive's 2/rev). The name stands; the size is said to be in doubt, with what to
    record, and the name is tentative."""
    d, truth = diagnosed(Case("single", 5507, "kinematic_error", "strong", "default"), workers=0)
    assert [e.name for e in d.effects] == ["kinematic_error"], d.summary
    e = d.effects[0]
    assert e.params["kinematic_error_4"] == 0.0
    assert e.tentative and "its size is the 2/rev alone" in e.why_tentative and "a few turns" in e.why_tentative


def test_viscous_friction_on_either_side_of_the_gear_is_told_apart_only_where_the_log_can() -> None:
    """The twin check (``TwoInertiaPlugin.twin``, ``engine._twin_doubt``): a load-side viscous friction, once
    accepted, is put on the motor side at the size the ratio carries over (b_m = r^2 b_l) and refitted. On a
    torque-step log of a drive whose spring hardly deflects while sliding the two sides fit within ``SEPARABLE``
    noise variances, and the name gets a doubt saying the log cannot tell them apart and what would; on the design's
    log, which rings the spring, the motor side fits far worse and no doubt is added."""
    from ident.diagnosis.engine import SEPARABLE, _twin_doubt
    from ident.diagnosis.models import CandidateFit
    from ident.diagnosis.models.two_inertia import TwoInertiaPlugin

    deltas = {}
    for excitation in ("steps", "default"):
        log, truth = load(Case("single", 5102, "viscous_load", "medium", excitation), **SHORT)
        plugin = TwoInertiaPlugin(log)
        base = plugin.fit_base()
        winner = plugin.refit(base, plugin.screen(base, ("viscous_load",))[0], 300.0)
        b_l = winner.model.state.params.b_l
        assert abs(b_l / library_truth("viscous_load", truth) - 1.0) < 0.5, b_l
        rival, size, _ = plugin.twin_of(winner.model, "viscous_load")
        assert rival == "viscous_motor" and f"{b_l * log.meta.r ** 2:.4g}" in size
        twin = plugin.twin(winner.model, "viscous_load", 300.0)
        assert twin.effects == ("viscous_motor",) and twin.state.params.b_l == 0.0 < twin.state.params.b_m
        deltas[excitation] = twin.train_cost - winner.model.train_cost
        doubts = _twin_doubt(plugin, winner, [winner], 300.0)
        assert bool(doubts) == (deltas[excitation] < SEPARABLE), (excitation, deltas, doubts)
        if doubts:
            assert "cannot tell viscous_load from viscous_motor" in doubts[0] and "deflection" in doubts[0]
            # a rival candidate of the same step that fits far worse does not hide the twin's refit
            worse = CandidateFit("viscous_motor", replace(twin, train_cost=twin.train_cost + 1e6))
            assert _twin_doubt(plugin, winner, [winner, worse], 300.0) == doubts
    assert deltas["steps"] < SEPARABLE < deltas["default"], deltas
    assert plugin.twin_of(winner.model, "hardening") is None and plugin.twin(winner.model, "hardening", 1.0) is None
