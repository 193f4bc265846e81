"""``hdrive`` command line: a thin layer over the Python API (parse, call, print JSON or write files)."""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Sequence

from .model.params import DriveParams, ParameterError, parse_assignments
from .protocols.controllers import SettleError
from .protocols.resolution import NoConsistentStep, ThresholdNotFound

DEFAULT_SEARCH_BUDGET = 96   # ident.studies.paper_search.DEFAULT_BUDGET (not imported: keeps `hdrive --help` light)


def _params_from(args: argparse.Namespace) -> DriveParams:
    values = parse_assignments(getattr(args, "param", None))
    if getattr(args, "fl_star", None) is not None:
        values["f_l_star"] = args.fl_star
    return DriveParams().with_values(**values)


def cmd_build_fmu(args: argparse.Namespace) -> dict:
    from fmu_build import build_fmu

    path = build_fmu(fmi_version=args.fmi, out_dir=args.out)
    if not args.json:
        print(path)
    return {"fmu": str(path), "fmi_version": args.fmi}


def cmd_demo(args: argparse.Namespace) -> dict:
    from .studies.demo import write_demo

    summary = write_demo(args.out, params=_params_from(args), amplitude_star=args.amplitude, pulses=args.pulses,
                         progress=not args.json)
    if not args.json:
        print(f"wrote {summary['csv']} and {summary['png']}")
        print("arm increments [um]: " + ", ".join(f"{x:.4f}" for x in summary["increments_um"]))
    return summary


def _um(x) -> float | list[float]:
    import numpy as np

    arr = np.asarray(x, dtype=float) * 1e6
    return arr.tolist() if arr.ndim else float(arr)


def cmd_resolution(args: argparse.Namespace) -> dict:
    from .protocols.resolution import impulse_resolution, linear_resolution

    params = _params_from(args)
    if args.controller == "impulse":
        r = impulse_resolution(params, n_pulses=args.pulses, eps1_m=args.eps1_um * 1e-6)
        out = {"controller": "impulse", "threshold_amplitude": r.threshold_amplitude,
               "operating_amplitude": r.operating_amplitude, "n_pulses": r.n_pulses}
    else:
        r = linear_resolution(params, n_steps=args.steps, eps1_m=args.eps1_um * 1e-6)
        out = {"controller": "linear", "counts": r.counts, "n_steps": r.n_steps}
    out.update(resolution_um=_um(r.resolution_m), median_um=_um(r.median_m), min_um=_um(r.min_m),
               std_um=_um(r.std_m), f_l_star=params.f_l_star, elapsed_s=r.elapsed_s,
               increments_um=_um(r.increments_m), params=params.to_dict())
    if args.out:
        from pathlib import Path

        Path(args.out).mkdir(parents=True, exist_ok=True)
        r.to_frame().to_csv(Path(args.out) / f"{args.controller}_increments.csv", index=False)
        out["png"] = str(r.plot(Path(args.out) / f"{args.controller}.png"))
    if not args.json:
        extra = (f"A_th = {out['threshold_amplitude']:.4f}, A_op = {out['operating_amplitude']:.4f}"
                 if args.controller == "impulse" else f"consistent at {out['counts']} counts")
        print(f"{args.controller} resolution (max increment): {out['resolution_um']:.4f} um "
              f"(median {out['median_um']:.4f}, min {out['min_um']:.4f}, std {out['std_um']:.4f} um); {extra}")
    return out


def cmd_sweep(args: argparse.Namespace) -> dict:
    from pathlib import Path

    from .protocols.sweep import friction_sweep

    sweep = friction_sweep(_params_from(args), args.levels, args.pulses, scheduler=args.scheduler,
                           workers=args.workers, progress=not args.json)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    df = sweep.to_frame()
    df.to_csv(out / "sweep.csv", index=False)
    plots = sweep.plot(out)
    result = {"csv": str(out / "sweep.csv"), "plots": {k: str(v) for k, v in plots.items()},
              "trend": sweep.trend(), "levels": df.to_dict(orient="records")}
    if not args.json:
        print(df.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        t = result["trend"]
        print(f"resolution vs f_l*: slope {t['slope_um']:.4f} um, R^2 {t['r2']:.3f}; wrote {out}")
    return result


def cmd_study(args: argparse.Namespace) -> dict:
    from .studies.paper import write_study

    study, report = write_study(args.out, _params_from(args), n_pulses=args.pulses, n_steps=args.steps,
                                levels=args.levels, scheduler=args.scheduler, workers=args.workers,
                                progress=not args.json)
    if not args.json:
        print(study.comparison().to_string(index=False))
        print(f"wrote {report}")
    return {"report": str(report), **study.summary(),
            "comparison": study.comparison().to_dict(orient="records")}


def _read(args: argparse.Namespace):
    from pathlib import Path

    from .fitting.logs import read_log

    if str(args.log).endswith(".mat"):
        from .studies.emps import load_emps

        return load_emps(args.log)
    return read_log(Path(args.log), args.meta)


def _identified(args: argparse.Namespace) -> tuple[object, dict]:
    from .fitting.identify import identify

    log = _read(args)
    fit = identify(log, model=args.model, progress=not args.json)
    if args.model == "rigid":
        from .fitting.rigid import rigid_warnings

        d = fit.to_dict()
        out = {name: {"value": d[name]["value"], "ci95": d[name]["ci95_hac"], "ci95_ls": d[name]["ci95_ls"]}
               for name in ("M", "Fv", "Fc", "offset")}
        out.update(si={name: d[name]["value"] for name in ("M", "Fv", "Fc", "offset")},
                   fit={"relative_error_pct": fit.relative_error_pct, "nrmse_motor": None, "nrmse_load": None},
                   warnings=rigid_warnings(fit),
                   covariance="ci95: residual-based (Newey-West) sandwich; ci95_ls: noise-only LS")
        return fit, out
    return fit, fit.to_dict()


def cmd_identify(args: argparse.Namespace) -> dict:
    fit, out = _identified(args)
    if args.out and args.model != "rigid":
        from pathlib import Path

        Path(args.out).mkdir(parents=True, exist_ok=True)
        out["png"] = str(fit.plot(Path(args.out) / "identify.png"))
    if not args.json:
        for name, v in out.items():
            if isinstance(v, dict) and "ci95" in v:
                print(f"{name:10s} {v['value']:.6g}  95 % [{v['ci95'][0]:.6g}, {v['ci95'][1]:.6g}]")
        print(f"fit: {out['fit']}")
        for w in out["warnings"]:
            print(f"warning: {w}")
    return out


def cmd_predict(args: argparse.Namespace) -> dict:
    from .fitting.predict import predict

    if args.model != "two-inertia":
        raise ValueError("prediction needs the two-inertia model (K*, J_l*, f_l*): a load sensor in the log")
    fit, out = _identified(args)
    pred = predict(fit, n_draws=args.draws, n_pulses=args.pulses, n_steps=args.steps, workers=args.workers,
                   scheduler=args.scheduler, progress=not args.json)
    out.update(pred.to_dict())
    if not args.json:
        print(f"impulse resolution {pred.impulse_resolution_um:.4f} um (95 % {pred.impulse_ci95_um[0]:.4f} - "
              f"{pred.impulse_ci95_um[1]:.4f}); linear {pred.linear_resolution_um:.3f} um "
              f"({pred.linear_counts} counts)")
    return out


def cmd_diagnose(args: argparse.Namespace) -> dict:
    from .diagnosis.engine import diagnose

    log = _read(args)
    holdout = None
    if args.holdout:
        holdout = _read(argparse.Namespace(log=args.holdout, meta=args.meta))
    reference = None
    if str(args.log).endswith(".mat"):
        from .studies.emps import emps_reference

        reference = emps_reference(log, holdout)
    diag = diagnose(log, model=args.model, holdout=holdout, out_dir=args.out, max_effects=args.max_effects,
                    reference=reference,
                    resolution_pulses=args.pulses, workers=args.workers, progress=not args.json,
                    candidate_budget_s=args.candidate_budget if args.candidate_budget > 0 else None)
    out = diag.to_dict()
    if not args.json:
        print(diag.to_frame().to_string(index=False))
        for e in diag.effects:
            print(f"named: {e.name} = {e.magnitude:.4g} {e.unit} (95 % {e.ci95[0]:.4g} .. {e.ci95[1]:.4g})")
        for u in diag.unexplained:
            print(f"unexplained: {u['regime']}: {u['detail']}")
        if diag.files.get("report"):
            print(f"wrote {diag.files['report']}" + (f" and {diag.fmu}" if diag.fmu else ""))
    return out


def cmd_paper_effects(args: argparse.Namespace) -> dict:
    if args.search:
        return cmd_paper_search(args)
    from .studies.paper_effects import write_paper_effects

    levels, pulses = args.levels or 13, args.pulses or 300
    sweep, report = write_paper_effects(args.out, levels=levels, n_pulses=pulses, workers=args.workers,
                                        scheduler=args.scheduler, base=_params_from(args), progress=not args.json)
    summary = sweep.summary()
    if not args.json:
        cols = ["case", "slope_um", "r2", "growth", "first_over_median_hi", "linear", "avalanche"]
        print(summary[cols].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
        print(f"wrote {report}")
    return {"report": str(report), "summary": json.loads(summary.to_json(orient="records"))}


def cmd_paper_search(args: argparse.Namespace) -> dict:
    """``paper-effects --search``: the Pareto search of the effect library for the paper's claims together."""
    from .protocols.sweep import friction_levels
    from .studies import paper_search as ps
    from .studies.paper_search import FULL, Fidelity
    from .studies.paper_search_report import reach, write_paper_search

    levels = args.levels or len(FULL.levels)
    if levels % 2 == 0:
        raise ValueError(f"--levels = {levels}: with --search the levels f_l* = 10^(-2 + 2 i/(n - 1)) must include "
                         "0.1 (the impulse claim's level), which needs an odd number of levels")
    full = Fidelity("full", tuple(float(f) for f in friction_levels(levels)), args.pulses or FULL.n_pulses,
                    args.steps or FULL.n_steps)
    effects = [e.strip() for e in args.effects.split(",") if e.strip()] if args.effects is not None else None
    if effects is not None:
        from .studies.effect_ranges import effect_ranges

        known = list(effect_ranges())
        bad = [e for e in effects if e not in known]
        if bad or not effects or len(set(effects)) != len(effects):
            raise ValueError(f"--effects {args.effects!r}: give distinct names among {', '.join(known)}"
                             + (f" (unknown: {', '.join(bad)})" if bad else ""))
    search, report = write_paper_search(args.out, base=_params_from(args), budget=args.budget, confirm=args.confirm,
                                        seed=args.seed, effects=effects, screen=ps.SCREEN, full=full,
                                        workers=args.workers, scheduler=args.scheduler, progress=True)
    out = {"report": str(report), **search.to_dict(), "reach": reach(search)}
    if not args.json:
        for i, e in enumerate(search.pareto(), 1):
            verdicts = ", ".join(f"{k} {v.value:.3g} {'met' if v.met else 'not met'}" for k, v in e.claims.items())
            print(f"{i}. {e.candidate.label}: {verdicts}")
        print(f"wrote {report}")
    return out


def cmd_emps_report(args: argparse.Namespace) -> dict:
    from .studies.emps import emps_report

    report = emps_report(args.out, args.data)
    if not args.json:
        print(f"wrote {report}")
    return {"report": str(report)}


def _add_log_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="log file: CSV or Parquet with a JSON sidecar (physics.md section 4), or EMPS .mat")
    p.add_argument("--meta", help="JSON sidecar (default: LOG.json or meta.json beside it)")
    p.add_argument("--model", choices=("two-inertia", "rigid"), default="two-inertia")
    p.add_argument("--json", action="store_true", help="print JSON")


def _add_drive_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="drive parameter in SI (e.g. K_s=2e4) or K_star / J_l_star / f_l_star; repeatable")
    p.add_argument("--json", action="store_true", help="print JSON")


def _add_batch_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the levels on this dask.distributed cluster")
    p.add_argument("--workers", type=int, help="local worker processes (default: cores; 0 = serial, no Dask)")


def _add_build_fmu(sub: Any) -> None:
    p = sub.add_parser("build-fmu", help="build HarmonicDrive.fmu and print its path")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default 2)")
    p.add_argument("--out", required=True, help="directory to write HarmonicDrive.fmu into")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_build_fmu)


def _add_demo(sub: Any) -> None:
    p = sub.add_parser("demo", help="nominal drive's response to a train of 1 ms torque pulses (CSV + PNG)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--pulses", type=int, default=10, help="number of pulses (default 10)")
    p.add_argument("--amplitude", type=float, default=3.0, help="pulse amplitude tau* = T/f_m (default 3)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="drive parameter in SI (e.g. K_s=2e4) or K_star / J_l_star / f_l_star; repeatable")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_demo)


def _add_resolution(sub: Any) -> None:
    p = sub.add_parser("resolution", help="impulse or linear resolution of one drive (paper sections III-IV)")
    p.add_argument("--controller", choices=("impulse", "linear"), required=True)
    p.add_argument("--fl-star", type=float, help="load friction level f_l* = f_l/f_m (default: the drive's)")
    p.add_argument("--pulses", type=int, default=1000, help="pulses per impulse experiment N (default 1000)")
    p.add_argument("--steps", type=int, default=1000, help="measured PD steps (default 1000)")
    p.add_argument("--eps1-um", type=float, default=0.1, help="motion threshold eps1 [um] (default 0.1)")
    p.add_argument("--out", help="also write the increments (CSV) and a histogram (PNG) here")
    _add_drive_options(p)
    p.set_defaults(func=cmd_resolution)


def _add_sweep(sub: Any) -> None:
    p = sub.add_parser("sweep", help="impulse resolution at 25 load-friction levels (paper section V)")
    p.add_argument("--levels", type=int, default=25, help="number of levels from f_l* = 0.01 to 1 (default 25)")
    p.add_argument("--pulses", type=int, default=1000, help="pulses per experiment N (default 1000)")
    p.add_argument("--out", required=True, help="output directory (CSV + PNG)")
    _add_batch_options(p)
    _add_drive_options(p)
    p.set_defaults(func=cmd_sweep)


def _add_study(sub: Any) -> None:
    p = sub.add_parser("study", help="the paper's whole study (sections III-V) with a markdown report")
    p.add_argument("--out", required=True, help="output directory for report.md and its plots")
    p.add_argument("--pulses", type=int, default=1000, help="pulses per impulse experiment N (default 1000)")
    p.add_argument("--steps", type=int, default=1000, help="measured PD steps (default 1000)")
    p.add_argument("--levels", type=int, default=25, help="friction levels (default 25)")
    _add_batch_options(p)
    _add_drive_options(p)
    p.set_defaults(func=cmd_study)


def _add_identify(sub: Any) -> None:
    p = sub.add_parser("identify", help="estimate the drive's parameters from a log (CasADi + IPOPT, exact model)")
    _add_log_options(p)
    p.add_argument("--out", help="also write a plot of measured vs fitted load angle here")
    p.set_defaults(func=cmd_identify)


def _add_predict(sub: Any) -> None:
    p = sub.add_parser("predict", help="identify, then predict impulse and linear resolution with 95 %% intervals")
    _add_log_options(p)
    p.add_argument("--draws", type=int, default=20, help="parameter draws for the interval (default 20)")
    p.add_argument("--pulses", type=int, default=1000, help="pulses per impulse experiment (default 1000)")
    p.add_argument("--steps", type=int, default=1000, help="measured PD steps (default 1000)")
    _add_batch_options(p)
    p.set_defaults(func=cmd_predict)


def _add_diagnose(sub: Any) -> None:
    p = sub.add_parser("diagnose", help="find where the model and the log disagree, name the missing effects, refit "
                       "(report, plots and the fitted FMU)")
    _add_log_options(p)
    p.add_argument("--out", required=True, help="output directory (diagnosis.md, diagnosis.json, PNGs, fitted FMU)")
    p.add_argument("--holdout", help="a second log to hold back for scoring (default: the last 30 %% of LOG)")
    p.add_argument("--max-effects", type=int, default=3, help="stop after naming this many effects (default 3)")
    p.add_argument("--pulses", type=int, default=200,
                   help="pulses per impulse experiment for each model's predicted resolution (0: skip; default 200)")
    p.add_argument("--workers", type=int, default=0,
                   help="candidates refitted in parallel on this many local Dask workers (default 0: serial)")
    p.add_argument("--candidate-budget", type=float, default=300.0, metavar="SECONDS",
                   help="wall time allowed to each candidate's fit; one not fitted in time is reported as such "
                        "(default 300; 0: unlimited)")
    p.set_defaults(func=cmd_diagnose)


def _add_paper_effects(sub: Any) -> None:
    p = sub.add_parser("paper-effects", help="the friction sweep with and without each effect of the library: which "
                                             "effects reproduce the paper's linear trend and avalanche")
    p.add_argument("--out", required=True, help="output directory for paper_effects.md (paper_search.md with "
                                                "--search), CSVs and plots")
    p.add_argument("--levels", type=int, help="friction levels from f_l* = 0.01 to 1 (default 13; with --search: "
                                              "of the full protocol that confirms the candidates, default 25)")
    p.add_argument("--pulses", type=int, help="pulses per impulse experiment N (default 300; with --search: of the "
                                              "full protocol, default 1000)")
    p.add_argument("--search", action="store_true",
                   help="search one and two effects at cited plausible magnitudes (and K*, J_l* within +-50 %%) for "
                        "drives that reproduce the paper's claims together; Pareto set over the claims' misfits")
    p.add_argument("--budget", type=int, default=DEFAULT_SEARCH_BUDGET,
                   help=f"with --search: screening evaluations (default {DEFAULT_SEARCH_BUDGET}; more is finer)")
    p.add_argument("--confirm", type=int, default=3,
                   help="with --search: candidates confirmed with the full protocol (default 3)")
    p.add_argument("--steps", type=int, help="with --search: measured PD steps of the full protocol (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="with --search: seed of the search design (default 0)")
    p.add_argument("--effects", metavar="NAME,NAME", help="with --search: only these effects of the library "
                                                          "(default: every effect with a plausible range)")
    _add_drive_options(p)
    _add_batch_options(p)
    p.set_defaults(func=cmd_paper_effects)


def _add_emps_report(sub: Any) -> None:
    p = sub.add_parser("emps-report", help="the EMPS benchmark (real drive): rigid IDIM-LS side by side with the paper")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--data", help="folder with DATA_EMPS.mat and DATA_EMPS_PULSES.mat (default: ../shared/data/emps)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_emps_report)

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hdrive", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_build_fmu, _add_demo, _add_resolution, _add_sweep, _add_study, _add_identify, _add_predict,
                _add_diagnose, _add_paper_effects, _add_emps_report):
        add(sub)
    return parser


# Smallest value of each numeric option, checked before any work starts (option -> minimum; per command where a
# command allows less, e.g. diagnose --pulses 0 skips the predicted resolution).
_MINIMA: dict[str, float] = {"workers": 0, "draws": 2, "pulses": 1, "steps": 1, "levels": 2, "max_effects": 1,
                             "candidate_budget": 0, "budget": 1, "confirm": 0, "seed": 0}
_MINIMA_BY_COMMAND: dict[tuple[str, str], float] = {("diagnose", "pulses"): 0}
_POSITIVE = ("eps1_um", "amplitude")


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that every ``finally`` runs (staging folders, unpacked FMUs, Dask
    workers are cleaned up) before the process exits with 143."""


def _on_sigterm(signum: int, frame: Any) -> None:
    raise Terminated()


def preflight(args: argparse.Namespace) -> None:
    """Everything about the command line that can be checked before the work starts: numeric options in range, the
    output folder writable, the Dask scheduler reachable. ValueError naming the option and the allowed range."""
    import math

    for name, value in vars(args).items():
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            continue
        flag = "--" + name.replace("_", "-")
        if not math.isfinite(value):
            raise ValueError(f"{flag} = {value!r}: must be a finite number")
        low = _MINIMA_BY_COMMAND.get((args.command, name), _MINIMA.get(name))
        if low is not None and value < low:
            raise ValueError(f"{flag} = {value!r}: must be >= {low:g}")
        if name in _POSITIVE and value <= 0:
            raise ValueError(f"{flag} = {value!r}: must be > 0")
    if getattr(args, "out", None):
        from .common.output import check_output_dir

        check_output_dir(args.out)
    if getattr(args, "scheduler", None):
        from .protocols.batch import connect

        connect(args.scheduler).close()


def run(args: argparse.Namespace) -> tuple[int, Any]:
    """(exit code, result): 0 with the command's result, 2 for bad input or a named failure, 130 / 143 when
    interrupted, 1 for an internal error (a bug: its traceback only with HDRIVE_TRACEBACK=1)."""
    import os

    from .common.output import OutputDirError
    from .fitting.logs import LogError
    from .protocols.batch import BatchError

    say = lambda msg: print(f"hdrive {args.command}: {msg}", file=sys.stderr)  # noqa: E731
    try:
        preflight(args)
        return 0, args.func(args)
    except KeyboardInterrupt:
        say("interrupted (Ctrl-C); no output was left half-written")
        return 130, None
    except Terminated:
        say("terminated (SIGTERM); no output was left half-written")
        return 143, None
    except (ParameterError, LogError, OutputDirError, BatchError, ValueError, ThresholdNotFound, NoConsistentStep,
            SettleError, RuntimeError, OSError) as exc:
        say(f"error: {exc}")
        return 2, None
    except Exception as exc:  # a bug, not bad input
        if os.environ.get("HDRIVE_TRACEBACK"):
            raise
        say(f"internal error: {type(exc).__name__}: {exc} (please report it; HDRIVE_TRACEBACK=1 shows where)")
        return 1, None


def main(argv: Sequence[str] | None = None) -> int:
    import signal

    args = build_parser().parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        code, result = run(args)
    finally:
        signal.signal(signal.SIGTERM, previous)
    if code == 0 and args.json:
        print(json.dumps(result, indent=2))
    return code


if __name__ == "__main__":
    raise SystemExit(main())
