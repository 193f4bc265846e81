"""Search the effect library for a plausible drive that reproduces the paper's claims together.

Every candidate is the given drive (nominal by default) with its K* and J_l* within +-50 % and zero, one or two
effects of the library at magnitudes inside the ranges of ``ident.studies.effect_ranges`` (each bounded by a cited
source). A candidate is *evaluated* by the paper's protocols on the FMU: the impulse protocol at every friction level
of a fidelity, at f_l* = 0.176, and the linear (PD) protocol at f_l* = 0.1; ``ident.studies.paper_claims`` turns
that into the claims' values, verdicts and misfits. The search minimises the five misfits together and returns the
Pareto set.

Design (few protocol runs; deterministic for a seed; the budget counts evaluations, never time):

1. **screen, single effects**: the drive alone and each effect alone, ``n1`` points each of a Latin hypercube over
   the unit cube of its knobs (drive knobs first), at the cheap *screening* fidelity (6 of the 25 levels, 0.0215 ...
   1, N = 100 pulses, 100 PD steps);
2. **screen, pairs**: pairs of effects, in order of how much their two members moved the claims' best misfits
   beyond what the drive alone reached (``promise``), ``n2`` points each, as many pairs as the budget allows;
3. **refine** (coarse to fine): Latin hypercubes in boxes around the best screened Pareto points, the box halving
   every round, until the screening budget is spent;
4. **recheck**: a shortlist (``shortlist``: the best screened point, the best on each claim, then the rest of the
   ranked Pareto set; ``2 x confirm`` long) at every level of the full protocol with the screening's N;
5. **confirm**: the shortlist of the rechecked points (``confirm`` long) and the unchanged drive with the full
   protocol (25 levels, N = 1000, 1000 PD steps). The answer is the Pareto set of the confirmed candidates.

Everything runs on Dask (``ident.protocols.batch.batch_session``; one task per candidate and level): locally on
threads of this process (the protocols' compiled loops release the GIL), or on the cluster at ``scheduler``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from ..common.checks import whole
from ..model.params import DriveParams
from ..model.plant import PlantError
from ..protocols.resolution import NoConsistentStep, ThresholdNotFound, impulse_resolution, linear_resolution
from ..protocols.sweep import friction_levels
from .effect_ranges import DRIVE_KNOBS, EffectRange, Knob, drive_knobs, effect_ranges
from .paper_claims import CLAIMS, F_L_EXPERIMENT, F_L_IMPULSE, ClaimInputs, ClaimValue, claim_values

DEFAULT_BUDGET = 96      # screening evaluations (see bench/paper_effects.py for what fits in 10 min on 2 cores)
DEFAULT_CONFIRM = 3      # candidates confirmed with the full protocol (besides the unchanged drive)
RECHECK_FACTOR = 2       # the shortlist re-evaluated at every level (screening N) is this times ``confirm`` long
SINGLE_SHARE, PAIR_SHARE = 0.4, 0.3  # of the budget; the rest refines
REFINE_CENTERS, REFINE_POINTS, REFINE_HALF_WIDTH = 3, 4, 0.25


# -- fidelities and candidates ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Fidelity:
    """How a candidate is evaluated: the impulse protocol (``n_pulses``) at ``levels`` and at f_l* = 0.176, the
    linear protocol (``n_steps`` measured steps) at f_l* = 0.1. ``levels`` must contain 0.1."""

    name: str
    levels: tuple[float, ...]
    n_pulses: int
    n_steps: int

    def __post_init__(self) -> None:
        if not any(math.isclose(f, F_L_IMPULSE, rel_tol=1e-9) for f in self.levels) or len(self.levels) < 2:
            raise ValueError(f"fidelity {self.name!r}: levels must include f_l* = {F_L_IMPULSE:g} and at least "
                             f"one other level, got {self.levels}")
        whole("n_pulses", self.n_pulses, 1)
        whole("n_steps", self.n_steps, 1)


# every 4th of the paper's levels from 0.0215 (f_l* = 0.01 is left to the full protocol: its slowly decaying ringing
# makes it the most expensive level, and the line's R² is set by the spread of the higher levels)
SCREEN = Fidelity("screen", tuple(float(f) for f in friction_levels(25)[4::4]), 100, 100)
FULL = Fidelity("full", tuple(float(f) for f in friction_levels(25)), 1000, 1000)


def recheck_fidelity(screen: Fidelity, full: Fidelity) -> Fidelity:
    """Every level of the full protocol with the screening's N and PD steps. Why: the max increment is set by the
    first pulses (the start-up transient), so N = 100 gives nearly the max of N = 1000, but the max is jagged in
    f_l*, so the R² of its line depends on which levels are sampled: a few levels can show a line that 25 do not."""
    return Fidelity("recheck", full.levels, screen.n_pulses, screen.n_steps)


@dataclass(frozen=True)
class Candidate:
    """A drive to evaluate: ``effects`` (library names), the unit-cube point ``u`` (drive knobs, then each effect's
    knobs), the knob values it maps to (``knobs``: ``{"drive": {...}, effect: {...}}``), the FMU parameters the
    effects set (``fmu``) and the drive itself (``params``, load friction still the given drive's)."""

    effects: tuple[str, ...]
    u: tuple[float, ...]
    knobs: Mapping[str, Mapping[str, float]]
    fmu: Mapping[str, Mapping[str, float]]
    params: DriveParams

    @property
    def label(self) -> str:
        return "+".join(self.effects) or "drive only"

    def at(self, f_l_star: float) -> DriveParams:
        return self.params.with_values(f_l_star=float(f_l_star))


@dataclass(frozen=True)
class Space:
    """Where the search looks: the given drive ``base``, the effects' plausible ``ranges`` and the drive's own knobs
    (K*, J_l* factors). A candidate is a set of effects and a point of the unit cube of their knobs."""

    base: DriveParams
    ranges: Mapping[str, EffectRange]
    drive: tuple[Knob, ...] = DRIVE_KNOBS

    def knobs(self, effects: Sequence[str]) -> list[Knob]:
        """The knobs of a candidate with ``effects``, in the order of its point: the drive's, then each effect's."""
        return [*self.drive, *(k for e in effects for k in self.ranges[e].knobs)]

    def candidate(self, effects: Sequence[str], u: Sequence[float]) -> Candidate:
        """The candidate of ``effects`` at unit-cube point ``u``."""
        dims = len(self.knobs(effects))
        if len(u) != dims:
            raise ValueError(f"{'+'.join(effects) or 'drive'}: expected a point with {dims} coordinates, got {len(u)}")
        drive_k = {k.name: k.value(x) for k, x in zip(self.drive, u)}
        b = self.base
        p = b.with_values(K_star=b.K_star * drive_k["K_star_rel"], J_l_star=b.J_l_star * drive_k["J_l_star_rel"])
        knobs: dict[str, dict[str, float]] = {"drive": {"K_star": p.K_star, "J_l_star": p.J_l_star, **drive_k}}
        fmu: dict[str, dict[str, float]] = {}
        i = len(self.drive)
        for e in effects:
            rng = self.ranges[e]
            knobs[e] = {k.name: k.value(x) for k, x in zip(rng.knobs, u[i:i + len(rng.knobs)])}
            fmu[e] = rng.to_fmu(knobs[e], p)
            i += len(rng.knobs)
        p = p.with_values(**{k: v for values in fmu.values() for k, v in values.items()})
        return Candidate(tuple(effects), tuple(float(x) for x in u), knobs, fmu, p)

    def unchanged(self) -> Candidate:
        """The given drive itself: no effect, the middle of the (symmetric) drive knobs."""
        return self.candidate((), (0.5,) * len(self.drive))


# -- evaluation --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Task:
    kind: str            # "impulse" or "linear"
    params: DriveParams
    n: int


def _run_task(task: _Task) -> tuple[Any, ...]:
    """(increments µm, A_th, CPU s) of an impulse protocol, or (resolution µm, counts, CPU s) of a linear one, or
    ("error", text, 0): a drive the protocol cannot measure (no threshold, no consistent step, the FMU refusing)
    scores as failed. The CPU time (of the thread running the task) is reported, never used."""
    cpu0 = time.thread_time()
    try:
        if task.kind == "impulse":
            r = impulse_resolution(task.params, task.n)
            return r.increments_m * 1e6, r.threshold_amplitude, time.thread_time() - cpu0
        lin = linear_resolution(task.params, n_steps=task.n)
        return lin.resolution_m * 1e6, lin.counts, time.thread_time() - cpu0
    except (ThresholdNotFound, NoConsistentStep, PlantError) as exc:
        return "error", f"{task.kind} protocol at f_l* = {task.params.f_l_star:.4g}: {type(exc).__name__}: {exc}", 0.0


@dataclass
class Evaluation:
    """One candidate evaluated at one fidelity (µm at the arm). ``increments_um[i]`` belongs to ``f_l_star[i]``;
    ``error`` names the protocol that failed (then every misfit is inf)."""

    candidate: Candidate
    fidelity: Fidelity
    stage: str
    f_l_star: np.ndarray
    increments_um: list[np.ndarray]
    thresholds: np.ndarray
    experiment_um: np.ndarray
    linear_um: float
    linear_counts: int
    error: str | None = None
    claims: dict[str, ClaimValue] = field(default_factory=dict)
    task_s: float = 0.0      # CPU time of its protocol runs, summed (reported by the bench, used by nothing)

    @property
    def misfits(self) -> np.ndarray:
        if self.error:
            return np.full(len(CLAIMS), math.inf)
        return np.array([self.claims[c.name].misfit for c in CLAIMS])

    @property
    def n_met(self) -> int:
        return 0 if self.error else sum(bool(self.claims[c.name].met) for c in CLAIMS)

    def at(self, f_l_star: float) -> np.ndarray:
        """The increments at the level nearest to ``f_l_star`` (log scale)."""
        return self.increments_um[int(np.argmin(abs(np.log(self.f_l_star / f_l_star))))]

    def row(self) -> dict[str, Any]:
        """One table row: the candidate's knobs, its FMU parameters and every claim's value, verdict and misfit."""
        c = self.candidate
        out: dict[str, Any] = dict(stage=self.stage, fidelity=self.fidelity.name, effects=c.label,
                                   n_met=self.n_met, total_misfit=float(np.sum(self.misfits)), error=self.error or "",
                                   task_s=self.task_s)
        out.update({f"{g}.{k}": v for g, kv in c.knobs.items() for k, v in kv.items()})
        out.update({f"fmu.{k}": v for kv in c.fmu.values() for k, v in kv.items()})
        for claim in CLAIMS:
            cv = self.claims.get(claim.name)
            out.update({f"{claim.name}.value": cv.value if cv else math.nan,
                        f"{claim.name}.met": bool(cv.met) if cv else False,
                        f"{claim.name}.misfit": cv.misfit if cv else math.inf})
        return out


def _tasks(cands: Sequence[Candidate], fid: Fidelity) -> list[tuple[int, int, _Task]]:
    """(candidate, slot, task): slot i < len(levels) is sweep level i, slot len(levels) the experiment level, the
    last slot the linear protocol. Low friction first: those levels run longest."""
    levels = [*fid.levels, F_L_EXPERIMENT]
    out = [(j, i, _Task("impulse", c.at(f), fid.n_pulses)) for j, c in enumerate(cands) for i, f in enumerate(levels)]
    out += [(j, len(levels), _Task("linear", c.at(F_L_IMPULSE), fid.n_steps)) for j, c in enumerate(cands)]
    return sorted(out, key=lambda t: (t[2].params.f_l_star, t[0], t[1]))


def evaluate(cands: Sequence[Candidate], fid: Fidelity, run: Any, *, stage: str = "",
             progress: bool = False) -> list[Evaluation]:
    """Evaluate ``cands`` at fidelity ``fid`` with the batch runner ``run`` (``batch_session``)."""
    tasks = _tasks(cands, fid)
    results = run(_run_task, [t for _, _, t in tasks], progress=progress,
                  desc=f"{stage or fid.name}: {len(cands)} drives x {len(fid.levels) + 2} runs")
    slots: list[dict[int, tuple]] = [{} for _ in cands]
    for (j, i, _), r in zip(tasks, results):
        slots[j][i] = r
    return [_evaluation(c, fid, stage, s) for c, s in zip(cands, slots)]


def _evaluation(c: Candidate, fid: Fidelity, stage: str, slot: dict[int, tuple]) -> Evaluation:
    n = len(fid.levels)
    errors = [r[1] for r in slot.values() if isinstance(r[0], str)]
    f = np.array(fid.levels)
    task_s = float(sum(r[2] for r in slot.values()))
    if errors:
        return Evaluation(c, fid, stage, f, [], np.array([]), np.array([]), math.nan, 0, errors[0], task_s=task_s)
    incs = [np.asarray(slot[i][0]) for i in range(n)]
    ev = Evaluation(c, fid, stage, f, incs, np.array([slot[i][1] for i in range(n)]), np.asarray(slot[n][0]),
                    float(slot[n + 1][0]), int(slot[n + 1][1]), task_s=task_s)
    ev.claims = claim_values(ClaimInputs(f, np.array([x.max() for x in incs]), ev.at(F_L_IMPULSE),
                                         incs[int(np.argmax(f))], ev.experiment_um, ev.linear_um, ev.linear_counts))
    return ev


# -- Pareto set and ranking ---------------------------------------------------------------------------------------
def pareto_front(misfits: np.ndarray) -> list[int]:
    """Indices of the rows not dominated by any other (all misfits <= and one <), in row order. Rows with an inf
    everywhere (failed evaluations) are never on the front unless every row failed."""
    m = np.asarray(misfits, float)
    keep = []
    for i in range(m.shape[0]):
        dominated = np.any(np.all(m <= m[i], axis=1) & np.any(m < m[i], axis=1))
        if not dominated and (np.isfinite(m[i]).any() or not np.isfinite(m).any()):
            keep.append(i)
    return keep


def rank_key(ev: Evaluation) -> tuple:
    """Best first: more claims met, then a smaller sum of misfits (each in its claim's tolerance), then fewer
    effects."""
    total = float(np.sum(ev.misfits))
    return (-ev.n_met, total if math.isfinite(total) else math.inf, len(ev.candidate.effects))


def ranked_pareto(evals: Sequence[Evaluation]) -> list[Evaluation]:
    """The Pareto set of ``evals`` over the claims' misfits, best first (``rank_key``, ties in input order)."""
    front = pareto_front(np.array([e.misfits for e in evals])) if evals else []
    return sorted((evals[i] for i in front), key=rank_key)


# -- the search ------------------------------------------------------------------------------------------------------
def _lhs(n: int, dim: int, seed: Sequence[int], lo: np.ndarray | None = None,
         hi: np.ndarray | None = None) -> np.ndarray:
    """``n`` Latin-hypercube points in the box [lo, hi] of the unit cube (seeded: the same points every run)."""
    from scipy.stats import qmc

    u = qmc.LatinHypercube(d=dim, seed=np.random.default_rng(list(seed))).random(n)
    lo = np.zeros(dim) if lo is None else lo
    hi = np.ones(dim) if hi is None else hi
    return lo + u * (hi - lo)


def promise(evals: Sequence[Evaluation], effect: str) -> float:
    """How much an effect alone moved the claims: the sum over claims of how far its best misfit lies below the best
    misfit of the drive alone (0 when it never did better); failed evaluations count as misfit 1e6."""
    def best(effects: tuple[str, ...]) -> np.ndarray:
        m = np.array([e.misfits for e in evals if e.candidate.effects == effects])
        return np.nan_to_num(m, posinf=1e6).min(axis=0) if m.size else np.full(len(CLAIMS), 1e6)
    return float(np.sum(np.clip(best(()) - best((effect,)), 0.0, None)))


@dataclass(frozen=True)
class SearchPlan:
    """How the screening budget is spent: ``n1`` points for the drive alone and each effect, ``n2`` for each of
    ``n_pairs`` pairs, the rest (``refine``) in refinement rounds."""

    budget: int
    n1: int
    n2: int
    n_pairs: int
    refine: int
    grid: int = 0        # > 0: a full grid of this many values per knob replaced stages 1-3


def plan(budget: int, n_effects: int) -> SearchPlan:
    """Split ``budget`` screening evaluations: about 40 % on the drive alone and the single effects (``n1`` points
    each, at least 2), about 30 % on pairs (as many pairs as fit with two points each, then more points per pair up
    to ``n1``), the rest refines. ValueError naming the minimum when the budget cannot hold two points per single and one pair."""
    budget = whole("budget", budget, 1)
    singles, pairs = 1 + n_effects, n_effects * (n_effects - 1) // 2
    minimum = 2 * singles + (2 if pairs else 0)
    if budget < minimum:
        raise ValueError(f"--budget = {budget}: the search needs at least {minimum} evaluations (two points for the "
                         f"drive alone and for each of the {n_effects} effects, and two for one pair)")
    n1 = max(2, int(SINGLE_SHARE * budget) // singles)
    rest = budget - singles * n1
    pair_budget = min(rest, max(2, int(PAIR_SHARE * budget)))
    n_pairs = min(pairs, pair_budget // 2)
    n2 = min(n1, pair_budget // n_pairs) if n_pairs else 0
    return SearchPlan(budget, n1, n2, n_pairs, rest - n_pairs * n2)


@dataclass
class PaperSearch:
    """The search's result: every evaluation (``stage``: screen-single, screen-pair, refine-k, confirm), the ranges
    and fidelities used, the plan and the seed. ``pareto()``: the confirmed Pareto set, best first."""

    space: Space
    screen: Fidelity
    full: Fidelity
    plan: SearchPlan
    confirm: int
    seed: int
    evaluations: list[Evaluation]
    elapsed_s: float = math.nan
    stage_s: dict[str, float] = field(default_factory=dict)   # wall time per stage (reported, used by nothing)

    @property
    def base(self) -> DriveParams:
        return self.space.base

    @property
    def ranges(self) -> Mapping[str, EffectRange]:
        return self.space.ranges

    def screened(self) -> list[Evaluation]:
        """The screening stages' evaluations (screening fidelity)."""
        return [e for e in self.evaluations if e.stage not in ("recheck", "confirm")]

    def rechecked(self) -> list[Evaluation]:
        """The shortlist re-evaluated at every level with the screening's N."""
        return [e for e in self.evaluations if e.stage == "recheck"]

    def confirmed(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.stage == "confirm"]

    def reference(self) -> Evaluation:
        """The given drive unchanged (no effect, nominal K*, J_l*) with the full protocol."""
        u = self.space.unchanged().u
        return next(e for e in self.confirmed() if not e.candidate.effects and e.candidate.u == u)

    def pareto(self) -> list[Evaluation]:
        """The Pareto set of the confirmed candidates (the unchanged drive included), best first."""
        return ranked_pareto(self.confirmed())

    def to_frame(self) -> pd.DataFrame:
        """One row per evaluation: stage, fidelity, effects, knobs, FMU parameters, each claim's value / met /
        misfit."""
        return pd.DataFrame([e.row() for e in self.evaluations])

    def to_dict(self) -> dict[str, Any]:
        """``claims`` (name, target, tolerance, source sentence, ...) and ``pareto`` (best first: effects with their
        FMU parameters, the drive, every claim's value and verdict), plus the search's counts."""
        from .paper_claims import claims_table

        return {"claims": claims_table(), "pareto": [pareto_entry(e) for e in self.pareto()],
                "evaluations": {"screen": len(self.screened()), "recheck": len(self.rechecked()),
                                "confirm": len(self.confirmed()),
                                "plan": vars(self.plan), "seed": self.seed},
                "fidelities": {f.name: dict(levels=list(f.levels), n_pulses=f.n_pulses, n_steps=f.n_steps,
                                            experiment_level=F_L_EXPERIMENT)
                               for f in (self.screen, recheck_fidelity(self.screen, self.full), self.full)}}


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def pareto_entry(e: Evaluation) -> dict[str, Any]:
    """One Pareto point as JSON: ``effects`` {name: {FMU parameter: value}}, ``drive`` (K*, J_l*, K_s, J_l),
    ``knobs`` (the magnitudes in the sources' units), ``claims`` {name: {value, met, misfit}}."""
    c = e.candidate
    return {"effects": {k: dict(v) for k, v in c.fmu.items()},
            "drive": {"K_star": c.params.K_star, "J_l_star": c.params.J_l_star, "K_s": c.params.K_s,
                      "J_l": c.params.J_l},
            "knobs": {k: dict(v) for k, v in c.knobs.items() if k != "drive"},
            "claims": {k: {"value": _finite(v.value), "met": bool(v.met), "misfit": _finite(v.misfit)}
                       for k, v in e.claims.items()},
            "error": e.error}


def _points(space: Space, effects: tuple[str, ...], n: int, seed: Sequence[int],
            center: Sequence[float] | None = None, half: float = 0.5) -> list[Candidate]:
    dim = len(space.knobs(effects))
    lo = hi = None
    if center is not None:
        c = np.asarray(center)
        lo, hi = np.clip(c - half, 0.0, 1.0), np.clip(c + half, 0.0, 1.0)
    return [space.candidate(effects, u) for u in _lhs(n, dim, seed, lo, hi)]


def _pairs_by_promise(evals: Sequence[Evaluation], effects: Sequence[str]) -> list[tuple[str, str]]:
    score = {e: promise(evals, e) for e in effects}
    pairs = [(a, b) for i, a in enumerate(effects) for b in effects[i + 1:]]
    return sorted(pairs, key=lambda ab: -(score[ab[0]] + score[ab[1]]))  # stable: library order on ties


def _refine(evals: list[Evaluation], n: int, rnd: int, seed: int, space: Space) -> list[Candidate]:
    """Up to ``n`` points around the best ``REFINE_CENTERS`` screened Pareto points, in boxes of half-width
    ``REFINE_HALF_WIDTH / 2^(rnd - 1)``."""
    centers = ranked_pareto(evals)[:REFINE_CENTERS]
    per = [n // len(centers) + (1 if i < n % len(centers) else 0) for i in range(len(centers))]
    out = []
    for i, (ev, k) in enumerate(zip(centers, per)):
        if k:
            out += _points(space, ev.candidate.effects, k, (seed, 3, rnd, i), ev.candidate.u,
                           REFINE_HALF_WIDTH / 2 ** (rnd - 1))
    return out


def shortlist(evals: Sequence[Evaluation], k: int, exclude: Sequence[Candidate] = ()) -> list[Candidate]:
    """Up to ``k`` candidates worth a closer look: the best of the ranked Pareto set, then the best on each claim in
    turn (smallest misfit, ties by rank), then the rest of the ranked Pareto set; each point once, failed
    evaluations and the ``exclude``d points never."""
    ok = [e for e in evals if not e.error]
    if not ok or k <= 0:
        return []
    ranked = ranked_pareto(ok)
    per_claim = [min(ok, key=lambda e, c=c: (e.claims[c.name].misfit, rank_key(e))) for c in CLAIMS]
    out, seen = [], {(c.effects, c.u) for c in exclude}
    for e in ranked[:1] + per_claim + ranked[1:]:
        key = (e.candidate.effects, e.candidate.u)
        if key not in seen:
            seen.add(key)
            out.append(e.candidate)
        if len(out) == k:
            break
    return out


def search_paper(base: DriveParams | None = None, *, budget: int = DEFAULT_BUDGET, confirm: int = DEFAULT_CONFIRM,
                 seed: int = 0, effects: Sequence[str] | None = None, screen: Fidelity = SCREEN,
                 full: Fidelity = FULL, grid: int = 0, drive_span: float = 0.5, workers: int | None = None,
                 scheduler: str | None = None, progress: bool = False) -> PaperSearch:
    """Search the effect library (``effects``: a subset of its names, all by default) for drives that reproduce the
    paper's claims; ``budget`` screening evaluations, then ``confirm`` candidates and the unchanged drive with the
    full protocol; K* and J_l* vary within +-``drive_span`` of ``base``'s. Deterministic for a given ``seed``; on
    Dask (``workers=0``: serially in this process).

    ``grid`` > 0 replaces the screening stages by an exhaustive grid (``grid`` values per knob, ends included; one
    value for a knob whose range is a point) over the drive alone, every single effect and every pair (``budget``
    and ``seed`` are then unused): a coarse, checkable search for small studies and tests."""
    from ..protocols.batch import batch_session

    space = _space(base or DriveParams(), effects, drive_span, min(min(screen.levels), min(full.levels)))
    names = list(space.ranges)
    grid = whole("grid", grid, 0)
    grid_cands = _grid(space, names, grid) if grid else []
    the_plan = SearchPlan(len(grid_cands), 0, 0, len(names) * (len(names) - 1) // 2, 0, grid) if grid else \
        plan(budget, len(names))
    confirm = whole("confirm", confirm, 0)
    t0 = time.perf_counter()
    stage_s: dict[str, float] = {}
    # the protocols' compiled loops release the GIL: locally the batches run on threads of this process
    with batch_session(scheduler=scheduler, workers=workers, threads=True) as run:
        def ev(cands: list[Candidate], fid: Fidelity, stage: str) -> list[Evaluation]:
            t = time.perf_counter()
            out = evaluate(cands, fid, run, stage=stage, progress=progress)
            stage_s[stage] = time.perf_counter() - t   # reported, used by nothing
            return out

        evals = ev(grid_cands, screen, "grid") if grid else _screen(space, the_plan, seed, ev, screen)
        unchanged = space.unchanged()
        rechecked = ev(shortlist(evals, RECHECK_FACTOR * confirm, [unchanged]), recheck_fidelity(screen, full),
                       "recheck")
        evals += rechecked + ev([unchanged] + shortlist(rechecked, confirm, [unchanged]), full, "confirm")
    return PaperSearch(space, screen, full, the_plan, confirm, seed, evals, time.perf_counter() - t0, stage_s)


def _space(base: DriveParams, effects: Sequence[str] | None, span: float, f_l_star_min: float) -> Space:
    ranges = effect_ranges(base, f_l_star_min)
    names = list(ranges) if effects is None else list(effects)
    unknown = [e for e in names if e not in ranges]
    if unknown or len(set(names)) != len(names):
        raise ValueError(f"effects {unknown or names}: use distinct names among {', '.join(ranges)}")
    return Space(base, {e: ranges[e] for e in names}, drive_knobs(span))


def _grid(space: Space, names: list[str], n: int) -> list[Candidate]:
    """Every point of an ``n``-value grid per knob for the drive alone, each effect and each pair of effects."""
    import itertools

    if n < 2:
        raise ValueError(f"grid = {n}: a grid needs at least 2 values per knob (the ends of each range)")
    subsets = [()] + [(e,) for e in names] + [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    axis = lambda k: [0.5] if k.lo == k.hi else np.linspace(0.0, 1.0, n)  # noqa: E731
    return [space.candidate(s, u) for s in subsets for u in itertools.product(*map(axis, space.knobs(s)))]


def _screen(space: Space, p: SearchPlan, seed: int, ev: Any, screen: Fidelity) -> list[Evaluation]:
    """Stages 1-3 at the screening fidelity (``ev(candidates, fidelity, stage)`` evaluates): singles, pairs in
    order of promise, refinement rounds."""
    names = list(space.ranges)
    singles = [()] + [(e,) for e in names]
    evals = ev([c for i, s in enumerate(singles) for c in _points(space, s, p.n1, (seed, 1, i))], screen,
               "screen-single")
    pairs = _pairs_by_promise(evals, names)[:p.n_pairs]
    evals += ev([c for i, s in enumerate(pairs) for c in _points(space, s, p.n2, (seed, 2, i))], screen,
                "screen-pair")
    left, rnd = p.refine, 1
    while left > 0:
        cands = _refine(evals, min(left, REFINE_CENTERS * REFINE_POINTS), rnd, seed, space)
        if not cands:
            break
        evals += ev(cands, screen, f"refine-{rnd}")
        left, rnd = left - len(cands), rnd + 1
    return evals


__all__ = ["DEFAULT_BUDGET", "DEFAULT_CONFIRM", "FULL", "RECHECK_FACTOR", "SCREEN", "Candidate", "Evaluation", "Fidelity",
           "PaperSearch", "SearchPlan", "Space", "evaluate", "pareto_entry", "pareto_front", "plan",
           "promise", "rank_key", "ranked_pareto", "recheck_fidelity", "search_paper", "shortlist"]
