"""A friction ripple: the effect outside the library that every named effect of a two-inertia diagnosis is compared
with.

A harmonic drive's friction is not one level: it varies along the travel with the wave generator's angle (its cam
deforms the flexspline in two lobes, so what rubs repeats twice per motor revolution, the kinematic error's 2/rev
and its 4/rev harmonic, and a shaft's eccentricity repeats once). The library has no such effect, and a log can
mistake one for a library effect. The default design shows how: its forward impulses start at one end of the motor's
travel and its backward ones at the other, so a level that changes along the travel reads as a level that changes
with the direction. Measured on an independent log (a 2/rev ripple of 5.3e-5 of the motor friction, over 0.089 rad
of motor travel): asymmetric friction was named, confidently, and fitted the log to 1.011x the sensor noise.

**The comparison** (``stand_in_costs``), linearized at the final model: the named effect's contribution (its size
coordinates' Jacobian columns times their values) is taken out of the residual, and a ripple of the motor friction
at ``HARMONICS`` per motor revolution (a sine and a cosine each, any amplitude and phase) is fitted in its place
together with every other unknown, by linear least squares. Its training cost against the named model's (the same
least squares with the effect's own columns) is the number the loop judges, as it judges a twin (``engine``).

**The ripple's columns** (``torques``, ``columns``): a change of the motor's friction level acts on the motor as a
torque against its motion while it slides. The FMU is simulated with the logged torque plus
``-f_m sgn(v_m) h(q_m)`` over the samples where the model's own simulation has the motor sliding (``h`` one
harmonic of the motor angle), and the difference from the model's residual is the column. The breakaway's static
level is left out: a change of it moves a breakaway by a sample or less where the torque rises steeply (the
impulses), and the sliding part is what sets how far a slide goes. Measured on the log above: the column of the
FMU's own friction asymmetry and the one made this way from a constant torque -f_m over the slides share all but
0.08 % of their square norm (the FMU's parameter also changes the load's friction and the breakaway
levels).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..screening import partial_out
from .problem import one_sided_column

#: the ripple's harmonics per motor revolution: the wave generator's 2/rev and 4/rev (the kinematic error's own,
#: ``coordinates.KINEMATIC_COORDS``) and a shaft's eccentricity, 1/rev
HARMONICS = (1, 2, 4)


def torques(q_m: np.ndarray, v_m: np.ndarray, f_m: float) -> np.ndarray:
    """The ripple's torques on the motor per unit relative amplitude, one column per sine and cosine of
    ``HARMONICS`` [N.m]: ``-f_m sgn(v_m) h(q_m)`` where the motor slides (``v_m`` != 0), zero where it sticks."""
    sliding = -f_m * np.sign(v_m)
    return np.column_stack([sliding * fn(k * q_m) for k in HARMONICS for fn in (np.sin, np.cos)])


def columns(residuals_with: Callable[[np.ndarray], np.ndarray], r: np.ndarray, tau: np.ndarray,
            target: float) -> np.ndarray:
    """d(residual)/d(amplitude) of each column of ``tau`` (``torques``) by a one-sided difference
    (``problem.one_sided_column``: the load moves by about ``target`` noise sigmas): ``residuals_with(extra
    torque)`` is the model's residual with that torque added to the logged one, ``r`` its residual without."""
    def column(t: np.ndarray) -> np.ndarray:
        return one_sided_column(lambda h: residuals_with(h * t), r, 1.0, target)
    return np.column_stack([column(tau[:, j]) for j in range(tau.shape[1])])


def stand_in_costs(r: np.ndarray, J: np.ndarray, theta: np.ndarray, effects: dict[str, tuple[list[int], list[int]]],
                   H: np.ndarray) -> dict[str, float]:
    """The training cost (in noise variances: ``r`` is weighed by the noise) of the ripple ``H`` in place of each
    effect, minus the named model's, both linearized at ``theta``. ``effects``: name -> (its size coordinates,
    indices into ``theta`` and the columns of ``J``: zero is the effect off, so their columns times their values
    are its contribution; all its coordinates, a Stribeck velocity too, none of which the ripple's model keeps).
    An effect that contributes nothing there (its columns are zero: a bound holds it) is left out."""
    named = _left(r, partial_out(J))
    out = {}
    for name, (own, effect) in effects.items():
        own_signal = J[:, own] @ theta[own]
        if not np.any(own_signal):
            continue
        others = [i for i in range(J.shape[1]) if i not in effect]
        ripple = _left(r - own_signal, partial_out(np.column_stack([J[:, others], H])))
        out[name] = float(ripple @ ripple - named @ named)
    return out


def _left(r: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``r`` with the span of the orthonormal ``Q`` taken out (the least-squares fit's residual)."""
    return r - Q @ (Q.T @ r)
