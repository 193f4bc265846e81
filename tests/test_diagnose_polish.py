"""The final model's polish (``TwoInertiaPlugin.polish``): every unknown refitted from the model's optimum with
finite-difference steps of a tenth of its standard deviations (``search_steps``), as the identifier's windows are.

On 10 s torque-step logs of a strong kinematic error (the independent generator's seed 5102, ten noise draws) the
loop's refits, whose Jacobians take micro-steps, stopped short of the optimum (a refit from the size held 10 % off
stayed there, +12000 noise variances) and the named size scattered 0.41 % against an interval of +-0.17 %; polished,
0.14 %. On this 3 s log the micro-steps come back too; what is held here is the polish's own contract: from a model
held 10 % off along the size, it returns to the optimum; from the optimum, it keeps a model no worse. And the
convergence of a model the loop takes on (``TwoInertiaPlugin.converge``): from another basin of the initial deflection
it comes back to the lowest one."""
from __future__ import annotations

import functools

import numpy as np

from ident.diagnosis import DEFAULT_BUDGET
from ident.fitting.identify import MAX_SEARCH_STEP, SEARCH_STEP
from tests.diagnosis_matrix import Case, searched

NAME = "kinematic_error"


@functools.cache
def _searched() -> tuple:
    return searched(Case("single", 5102, NAME, "strong", "steps"), NAME)


def test_the_polish_brings_a_displaced_model_back_to_its_optimum() -> None:
    plugin, final, _ = _searched()
    assert final.effects == (NAME,)
    steps = plugin.search_steps(final)
    sd = np.sqrt(np.diag(plugin._cov(final)))
    assert np.all(steps > 0) and np.allclose(steps, np.minimum(SEARCH_STEP * sd, MAX_SEARCH_STEP))

    size = plugin.magnitude(final, NAME).value
    held = plugin.probe_size(final, NAME, 0.9, DEFAULT_BUDGET)
    assert abs(plugin.magnitude(held, NAME).value / size - 0.9) < 1e-9
    assert held.train_cost > final.train_cost + 1000.0   # far up the size's profile
    back, said = plugin.polish(held, DEFAULT_BUDGET)
    assert "finite-difference steps of 0.1" in said
    assert abs(plugin.magnitude(back, NAME).value / size - 1.0) < 0.005
    assert back.train_cost < final.train_cost + 1.0   # within a noise variance of the optimum

    kept, _ = plugin.polish(final, DEFAULT_BUDGET)
    assert kept.train_cost <= final.train_cost


def test_a_model_taken_on_leaves_a_basin_of_its_initial_deflection_that_is_not_the_lowest() -> None:
    """Every refit stays in the basin of the initial deflection it starts in, and an accepted effect can move the
    basins (measured on an independent log, seed 7722: the base model's basin stayed the model's, 7,800 noise
    variances above the one the effect made lowest). ``converge`` scans the basins: the model put across the static
    band comes back to the optimum's basin, and says so."""
    plugin, final, _ = _searched()
    st = final.state
    far = st.theta.copy()
    far[3] = -0.8 if st.theta[3] > 0 else 0.8
    held = plugin.evaluate(final.effects, far, st.base, st.scales, sens=st.sens, fixed=st.fixed)
    assert held.train_cost > final.train_cost + 1.0
    back, said = plugin.converge(held, DEFAULT_BUDGET)
    assert "initial deflection across the static band found a lower cost" in said
    assert abs(back.state.theta[3] - st.theta[3]) < 0.05
    assert back.train_cost < final.train_cost + 1.0   # within a noise variance of the optimum
