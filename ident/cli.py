"""``hdrive`` command line: a thin layer over the Python API (parse, call, print JSON or write files).

Conventions every command follows (the README says the same to users):

- ``--json`` prints one JSON document on stdout whose keys follow ``ident.common.units``: SI, the unit in the key's
  suffix (``resolution_m``, ``elapsed_s``); ``main`` applies ``si_keys`` to every command's result.
- Progress goes to stderr for anything that can take more than a few seconds, with or without ``--json``.
- Help texts are plain text (``DESCRIPTION`` below, not this docstring, is what ``--help`` shows).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import Any, Sequence

from .common.blas import one_blas_thread
from .diagnosis import DEFAULT_BUDGET as DEFAULT_CANDIDATE_BUDGET
from .model.params import DriveParams, ParameterError, parse_assignments
from .protocols.controllers import SettleError
from .protocols.resolution import NoConsistentStep, ThresholdNotFound

DEFAULT_SEARCH_BUDGET = 96   # ident.studies.paper_search.DEFAULT_BUDGET (not imported: keeps `hdrive --help` light)


DESCRIPTION = ("hdrive: resolution of a harmonic-drive joint with exact stick-slip friction, simulated by a real "
               "FMU. Every command takes --json (one JSON document on stdout, SI units named in the keys' suffixes); "
               "progress goes to stderr.")


def _progress(args: argparse.Namespace) -> bool:
    """Progress bars go to stderr, so they are shown with --json too (stdout stays one JSON document)."""
    return True


def _say(args: argparse.Namespace, message: str) -> None:
    print(f"hdrive {args.command}: {message}", file=sys.stderr, flush=True)


def _params_from(args: argparse.Namespace) -> DriveParams:
    values = parse_assignments(getattr(args, "param", None))
    if getattr(args, "fl_star", None) is not None:
        values["f_l_star"] = args.fl_star
    return DriveParams().with_values(**values)


def cmd_build_fmu(args: argparse.Namespace) -> dict:
    from fmu_build import build_fmu

    _say(args, f"building HarmonicDrive.fmu (FMI {args.fmi}; compiled with the C compiler unless cached) ...")
    path = build_fmu(fmi_version=args.fmi, out_dir=args.out)
    if not args.json:
        print(path)
    return {"fmu": str(path), "fmi_version": args.fmi}


def cmd_demo(args: argparse.Namespace) -> dict:
    from .studies.demo import write_demo

    summary = write_demo(args.out, params=_params_from(args), amplitude_star=args.amplitude, pulses=args.pulses,
                         progress=_progress(args))
    if not args.json:
        print(f"wrote {summary['csv']} (a log: read it with ident.read_log), {summary['meta']} and {summary['png']}")
        print("arm increments [µm]: " + ", ".join(f"{x * 1e6:.4f}" for x in summary["increments_m"]))
    return summary


def _resolution_result(args: argparse.Namespace, params: DriveParams) -> tuple[Any, dict]:
    """Run the chosen protocol; (result, the JSON summary without increments)."""
    from .protocols.resolution import impulse_resolution, linear_resolution

    if args.controller == "impulse":
        r = impulse_resolution(params, n_pulses=args.pulses, eps1_m=args.eps1_um * 1e-6, progress=_progress(args))
        return r, {"controller": "impulse", "threshold_amplitude": r.threshold_amplitude,
                   "operating_amplitude": r.operating_amplitude, "n_pulses": r.n_pulses}
    r = linear_resolution(params, n_steps=args.steps, eps1_m=args.eps1_um * 1e-6, progress=_progress(args))
    return r, {"controller": "linear", "counts": r.counts, "n_steps": r.n_steps}


def cmd_resolution(args: argparse.Namespace) -> dict:
    from pathlib import Path

    from .protocols.transient import start_up_transient

    params = _params_from(args)
    r, out = _resolution_result(args, params)
    tr = start_up_transient(r.increments_m)
    out.update(resolution_m=r.resolution_m, median_m=r.median_m, min_m=r.min_m, std_m=r.std_m,
               max_pulse=tr.max_pulse, transient_end_pulse=tr.end_pulse if tr.settled else None,
               steady_max_m=tr.steady_max_m, eps1_m=r.eps1_m, f_l_star=params.f_l_star, elapsed_s=r.elapsed_s,
               params=params.to_dict())
    if args.increments:
        out["increments_m"] = [float(x) for x in r.increments_m]
    if args.out:
        from .common.output import staged_folder

        csv, png = (Path(args.out) / f"{args.controller}{suffix}" for suffix in ("_increments.csv", ".png"))
        with staged_folder(args.out) as stage:
            r.to_frame().to_csv(stage / csv.name, index=False)
            r.plot(stage / png.name)
        out.update(csv=str(csv), png=str(png))
    if not args.json:
        _print_resolution(out)
    return out


def _print_resolution(out: dict) -> None:
    um = {k: out[k] * 1e6 for k in ("resolution_m", "median_m", "min_m", "std_m")}
    extra = (f"A_th = {out['threshold_amplitude']:.4f}, A_op = {out['operating_amplitude']:.4f}"
             if out["controller"] == "impulse" else f"consistent at {out['counts']} counts")
    print(f"{out['controller']} resolution (max increment): {um['resolution_m']:.4f} µm at pulse {out['max_pulse']} "
          f"(median {um['median_m']:.4f}, min {um['min_m']:.4f}, std {um['std_m']:.4f} µm); {extra}")
    if out["transient_end_pulse"] is None:
        print("start-up transient: not settled within the experiment (no steady-state max)")
    else:
        print(f"start-up transient: pulses 1-{out['transient_end_pulse']}; steady-state max after it "
              f"{out['steady_max_m'] * 1e6:.4f} µm")


def cmd_sweep(args: argparse.Namespace) -> dict:
    from pathlib import Path

    from .protocols.sweep import friction_sweep

    sweep = friction_sweep(_params_from(args), args.levels, args.pulses, scheduler=args.scheduler,
                           workers=args.workers, progress=_progress(args))
    from .common.output import staged_folder

    out = Path(args.out)
    df = sweep.to_frame()
    with staged_folder(out, last="sweep.csv") as stage:
        plots = sweep.plot(stage)
        df.to_csv(stage / "sweep.csv", index=False)
    result = {"csv": str(out / "sweep.csv"), "plots": {k: str(out / Path(v).name) for k, v in plots.items()},
              "trend": sweep.trend(), "levels": df.to_dict(orient="records")}
    if not args.json:
        print(df.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        t = result["trend"]
        print(f"resolution vs f_l*: slope {t['slope_um']:.4f} µm per unit f_l*, R² {t['r2']:.3f}; wrote {out}")
    return result


def cmd_study(args: argparse.Namespace) -> dict:
    from .studies.paper import write_study

    study, report = write_study(args.out, _params_from(args), n_pulses=args.pulses, n_steps=args.steps,
                                levels=args.levels, scheduler=args.scheduler, workers=args.workers,
                                progress=_progress(args))
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
    fit = identify(log, model=args.model, progress=True, verbose=getattr(args, "verbose", False))
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
    if not fit.identifiable:
        args.exit_code = EXIT_NOT_IDENTIFIABLE
    return fit, fit.to_dict()


def _digits(value: float, ci95: Sequence[float]) -> int:
    """Significant digits that show an interval's width (at least 6): a tight interval must not print as [x, x]."""
    half = abs(ci95[1] - ci95[0]) / 2
    if not (half > 0 and value and math.isfinite(half) and math.isfinite(value)):
        return 6
    return int(min(15, max(6, math.ceil(math.log10(abs(value) / half)) + 2)))


def _print_fit(out: dict) -> None:
    """The fit as text: values with intervals, the identifiability verdict, the noise, data checks, warnings."""
    for name, v in out.items():
        if isinstance(v, dict) and "ci95" in v:
            if v["value"] is None:
                line = f"{name:10s} no result"
            else:
                d = _digits(v["value"], v["ci95"])
                line = f"{name:10s} {v['value']:.{d}g}  95 % [{v['ci95'][0]:.{d}g}, {v['ci95'][1]:.{d}g}]"
            print(line + ("" if v.get("identifiable", True) else "  NOT IDENTIFIABLE: " + v["reason"]))
    if "identifiable" in out:
        print("identifiable: " + ("yes, all three" if out["identifiable"] else "NO") +
              (f" -- to fix: {out['fix']}" if out.get("fix") else ""))
        print(f"load sensor noise: {out['sigma_load_rad']:.4g} rad; residual "
              f"{out['fit']['residual_over_noise']:.3f}x the noise")
    for c in out.get("data_checks", []):
        if c["status"] != "ok":
            print(f"data check {c['check']}: {c['status']}: {c['detail']}")
    for w in out["warnings"]:
        print(f"warning: {w}")


def _single_log(args: argparse.Namespace) -> bool:
    from pathlib import Path

    return len(args.logs) == 1 and not Path(args.logs[0]).is_dir()


def cmd_identify(args: argparse.Namespace) -> Any:
    if not _single_log(args):
        return _identify_many(args)
    args.log = args.logs[0]
    fit, out = _identified(args)
    if args.out and args.model != "rigid":
        from pathlib import Path

        from .common.output import staged_folder

        with staged_folder(args.out) as stage:
            fit.plot(stage / "identify.png")
        out["png"] = str(Path(args.out) / "identify.png")
    if not args.json:
        _print_fit(out)
    return out


def _identify_many(args: argparse.Namespace) -> Any:
    """Several logs or folders: one row per log on Dask, a table (CSV + JSON) in ``--out``."""
    from .fitting.batch import collect_logs, identify_many, write_table

    if args.model != "two-inertia":
        raise ValueError("several logs at once: only the two-inertia model (--model two-inertia)")
    if not args.out:
        raise ValueError("several logs at once: give --out DIR for the table (identify.csv, identify.json)")
    paths = collect_logs(args.logs)
    table = identify_many(paths, args.meta, scheduler=args.scheduler, workers=args.workers, progress=True)
    files = write_table(table, args.out)
    if not table["identifiable"].all():
        args.exit_code = EXIT_NOT_IDENTIFIABLE
    if not args.json:
        cols = ["log", "status", "identifiable", "K_star", "J_l_star", "f_l_star"]
        print(table[cols].to_string(index=False))
        print(f"wrote {files['csv']} and {files['json']}")
    import json as _json

    return {"logs": _json.loads(table.to_json(orient="records")), **files}


def cmd_predict(args: argparse.Namespace) -> dict:
    from .fitting.predict import predict

    if args.model != "two-inertia":
        raise ValueError("prediction needs the two-inertia model (K*, J_l*, f_l*): a load sensor in the log")
    fit, out = _identified(args)
    if not fit.identifiable:
        out["prediction"] = None
        out["refused"] = ("no prediction: the log does not identify all three parameters (see their reasons); "
                          "a resolution from unidentified parameters would be a guess")
        if not args.json:
            _print_fit(out)
            print(out["refused"])
        return out
    pred = predict(fit, n_draws=args.draws, n_pulses=args.pulses, n_steps=args.steps, workers=args.workers,
                   scheduler=args.scheduler, progress=True)
    out.update(pred.to_dict())
    if not args.json:
        _print_fit(out)
        print(f"impulse resolution {pred.impulse_resolution_um:.4f} µm (95 % {pred.impulse_ci95_um[0]:.4f} - "
              f"{pred.impulse_ci95_um[1]:.4f}); linear {pred.linear_resolution_um:.3f} µm "
              f"(95 % {pred.linear_ci95_um[0]:.3f} - {pred.linear_ci95_um[1]:.3f}; {pred.linear_counts} counts)")
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
    # progress goes to stderr always (also with --json, whose stdout holds only the JSON)
    diag = diagnose(log, model=args.model, holdout=holdout, out_dir=args.out, max_effects=args.max_effects,
                    reference=reference, resolution_pulses=args.pulses, workers=args.workers,
                    scheduler=args.scheduler, progress=True,
                    budget=args.candidate_budget if args.candidate_budget > 0 else None)
    out = diag.to_dict()
    if not args.json:
        steps = diag.to_frame()   # the per-step table; the screens' detail is in the report and the JSON
        print(steps.drop(columns=[c for c in ("screen", "effects") if c in steps], errors="ignore")
              .to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        for line in diag.summary:
            print(line)
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


def cmd_design_experiment(args: argparse.Namespace) -> dict:
    from pathlib import Path

    from .common.output import staged_folder
    from .fitting.design import design_experiment
    from .fitting.logs import read_sidecar

    meta = read_sidecar(args.meta)
    ranges = {name: (float(v[0]), float(v[1])) for name, v in
              (("K_star", args.K_star), ("J_l_star", args.J_l_star), ("f_l_star", args.f_l_star)) if v}
    design = design_experiment(meta, ranges=ranges, max_torque=args.max_torque, max_travel=args.max_travel,
                               duration_s=args.duration, noise_m=args.noise_m,
                               progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    out = design.to_dict()
    with staged_folder(args.out, last="design.json") as stage:
        design.to_frame().to_csv(stage / "schedule.csv", index=False, float_format="%.17g")
        design.bounds.to_csv(stage / "bounds.csv", index=False)
        (stage / "design.json").write_text(json.dumps(out, indent=2) + "\n")
    files = {name: str(Path(args.out) / name) for name in ("schedule.csv", "bounds.csv", "design.json")}
    if not args.json:
        b = design.block
        print(f"block ({b.seconds():.3f} s, repeated): +-{b.pulse_star:g} f_m pulses of {b.width_s * 1e3:g} ms, "
              + (f"+-{b.move_star:g} f_m moves held {b.hold_s * 1e3:g} ms, " if b.move_star else "no moves, ")
              + f"rests of {b.rest_s:g} s")
        print("worst relative bound over the range (1 sigma): "
              + ", ".join(f"{k} {v:.2e}" for k, v in design.worst().items()))
        print(f"wrote {files['schedule.csv']} (time_s, motor_torque_Nm), {files['bounds.csv']}, {files['design.json']}")
    return {**out, "files": files}


def _search_fidelity(args: argparse.Namespace) -> Any:
    """The full protocol that confirms the search's candidates, from --levels / --pulses / --steps."""
    from .protocols.sweep import friction_levels
    from .studies.paper_search import FULL, Fidelity

    levels = args.levels or len(FULL.levels)
    if levels % 2 == 0:
        raise ValueError(f"--levels = {levels}: with --search the levels f_l* = 10^(-2 + 2 i/(n - 1)) must include "
                         "0.1 (the impulse claim's level), which needs an odd number of levels")
    return Fidelity("full", tuple(float(f) for f in friction_levels(levels)), args.pulses or FULL.n_pulses,
                    args.steps or FULL.n_steps)


def _search_effects(args: argparse.Namespace) -> list[str] | None:
    """--effects as a list of distinct library names (None: all of them)."""
    if args.effects is None:
        return None
    from .studies.effect_ranges import effect_ranges

    effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    known = list(effect_ranges())
    bad = [e for e in effects if e not in known]
    if bad or not effects or len(set(effects)) != len(effects):
        raise ValueError(f"--effects {args.effects!r}: give distinct names among {', '.join(known)}"
                         + (f" (unknown: {', '.join(bad)})" if bad else ""))
    return effects


def cmd_paper_search(args: argparse.Namespace) -> dict:
    """``paper-effects --search``: the Pareto search of the effect library for the paper's claims together."""
    from .studies import paper_search as ps
    from .studies.paper_search_report import reach, write_paper_search

    full, effects = _search_fidelity(args), _search_effects(args)
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

    report = emps_report(args.out, args.data, progress=_progress(args))
    if not args.json:
        print(f"wrote {report}")
    return {"report": str(report)}


def _add_log_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="log file: CSV or Parquet with a JSON sidecar (docs/physics.md section 4), or EMPS .mat")
    p.add_argument("--meta", help="JSON sidecar (default: LOG.json or meta.json beside it)")
    _add_model_option(p)
    p.add_argument("--json", action="store_true", help=_JSON_HELP)


def _add_model_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", choices=("two-inertia", "rigid"), default="two-inertia",
                   help="two-inertia: motor, spring and load (needs load_pos_rad); rigid: one body with viscous and "
                        "Coulomb friction (motor-only logs such as EMPS) (default two-inertia)")


def _add_drive_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="drive parameter in SI (e.g. K_s=2e4) or K_star / J_l_star / f_l_star; repeatable "
                        "(default: the nominal drive)")
    p.add_argument("--json", action="store_true", help=_JSON_HELP)


_JSON_HELP = "print one JSON document on stdout (SI units, named in the keys' suffixes); progress stays on stderr"

# What each command runs in parallel (the --scheduler / --workers help names it).
_BATCH_TASKS = {"sweep": "the friction levels", "study": "the friction levels of the sweep",
                "predict": "the resolution runs of the parameter draws (one task per draw)",
                "paper-effects": "the effect cases x friction levels (one task each)"}


def _add_batch_options(p: argparse.ArgumentParser) -> None:
    what = _BATCH_TASKS.get(p.prog.split()[-1], "the batch's tasks")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help=f"run {what} on this dask.distributed cluster "
                   "(default: local workers, see --workers)")
    p.add_argument("--workers", type=int, help=f"local workers for {what}: threads of this process running the "
                   "compiled protocol loops on Dask (default: one per core; 0 = serial in this process, no Dask)")


def _add_build_fmu(sub: Any) -> None:
    p = sub.add_parser("build-fmu", help="build HarmonicDrive.fmu and print its path")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default 2)")
    p.add_argument("--out", required=True, help="directory to write HarmonicDrive.fmu into")
    p.add_argument("--json", action="store_true", help=_JSON_HELP)
    p.set_defaults(func=cmd_build_fmu)


def _add_demo(sub: Any) -> None:
    p = sub.add_parser("demo", help="a drive's response to a train of 1 ms torque pulses: a log (CSV + JSON "
                                    "sidecar, readable by read_log) and a PNG")
    p.add_argument("--out", required=True, help="output directory (pulse_train.csv, pulse_train.json, "
                                                "pulse_train.png, summary.json)")
    p.add_argument("--pulses", type=int, default=10, help="number of pulses (default 10)")
    p.add_argument("--amplitude", type=float, default=3.0, help="pulse amplitude tau* = T_m/f_m (default 3)")
    _add_drive_options(p)
    p.set_defaults(func=cmd_demo)


def _add_resolution(sub: Any) -> None:
    p = sub.add_parser("resolution", help="impulse or linear resolution of one drive (paper sections III-IV)")
    p.add_argument("--controller", choices=("impulse", "linear"), required=True,
                   help="impulse: 1 ms torque pulses at the threshold amplitude (paper section IV); linear: PD "
                        "set-point steps on the motor encoder (paper section III)")
    p.add_argument("--fl-star", type=float, help="load friction level f_l* = f_l/f_m (default: the drive's)")
    p.add_argument("--pulses", type=int, default=1000,
                   help="pulses per impulse experiment N (impulse controller; default 1000)")
    p.add_argument("--steps", type=int, default=1000, help="measured PD steps (linear controller; default 1000)")
    p.add_argument("--eps1-um", type=float, default=0.1, help="motion threshold eps1 [µm] (default 0.1)")
    p.add_argument("--increments", action="store_true",
                   help="also put every increment (increments_m) into the JSON (default: summary figures only)")
    p.add_argument("--out", help="also write every increment (CSV) and a histogram and sequence (PNG) here")
    _add_drive_options(p)
    p.set_defaults(func=cmd_resolution)


def _add_sweep(sub: Any) -> None:
    p = sub.add_parser("sweep", help="impulse resolution at 25 load-friction levels (paper section V)")
    p.add_argument("--levels", type=int, default=25, help="number of levels from f_l* = 0.01 to 1 (default 25)")
    p.add_argument("--pulses", type=int, default=1000, help="pulses per experiment N (default 1000)")
    p.add_argument("--out", required=True, help="output directory (sweep.csv and the PNG plots)")
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
    p = sub.add_parser("identify", help="estimate the drive's parameters from a log (CasADi + IPOPT, exact model); "
                       "several logs or folders: one table, on Dask",
                       epilog="exit codes: 0 identified; 3 a parameter is not identifiable from the log (the JSON "
                              "says which and why); 2 bad input; 130 interrupted")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="log file(s) (CSV or Parquet with a JSON sidecar, docs/physics.md section 4, or EMPS .mat) or "
                        "folders of logs")
    p.add_argument("--meta", help="JSON sidecar (default: LOG.json or meta.json beside it)")
    _add_model_option(p)
    p.add_argument("--json", action="store_true", help=_JSON_HELP)
    p.add_argument("--verbose", action="store_true", help="also show IPOPT's own output")
    p.add_argument("--out", help="one log: also write a plot of measured vs fitted load angle here; several: the "
                                 "table identify.csv / identify.json (required)")
    _add_batch_options(p)
    p.set_defaults(func=cmd_identify)


def _add_predict(sub: Any) -> None:
    p = sub.add_parser("predict", help="identify, then predict impulse and linear resolution with 95 %% intervals",
                       epilog="exit codes: 0 predicted; 3 refused: a parameter is not identifiable from the log; "
                              "2 bad input; 130 interrupted")
    _add_log_options(p)
    p.add_argument("--verbose", action="store_true", help="also show IPOPT's own output")
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
    p.add_argument("--workers", type=int, default=None,
                   help="candidates screened and refitted in parallel on this many local Dask worker processes "
                        "(default: the machine's cores; 0: serially in this process, no Dask)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the candidates on this dask.distributed cluster")
    p.add_argument("--candidate-budget", type=float, default=DEFAULT_CANDIDATE_BUDGET, metavar="LOGS",
                   help="simulations of the training part allowed to each candidate's fit (an evaluation count, so "
                        "the answer does not depend on the machine's speed; a size probe's simulation of a model "
                        "costlier than its search's start counts as often as the FMU's model evaluations say); a "
                        "candidate that needs more is reported as not ruled out and no effect is then named more than "
                        f"tentatively (default {DEFAULT_CANDIDATE_BUDGET:g}; 0: unlimited)")
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
    p.add_argument("--data", help="folder with DATA_EMPS.mat and DATA_EMPS_PULSES.mat (default: "
                                  "$HDRIVE_SHARED/data/emps, else ../shared/data/emps beside the repository)")
    p.add_argument("--json", action="store_true", help=_JSON_HELP)
    p.set_defaults(func=cmd_emps_report)

def _add_design_experiment(sub: Any) -> None:
    p = sub.add_parser("design-experiment", help="a torque schedule that identifies K*, J_l*, f_l* over a range of "
                       "drives (robust prior-averaged D-optimal design), with the bounds it achieves")
    p.add_argument("--meta", required=True, help="JSON sidecar with the known drive data (docs/physics.md section 4)")
    p.add_argument("--max-torque", type=float, required=True, help="largest motor torque allowed [N m]")
    p.add_argument("--max-travel", type=float, required=True, help="largest load (joint) travel allowed [rad]")
    p.add_argument("--duration", type=float, required=True, help="length of the experiment [s]")
    p.add_argument("--noise-m", type=float, default=5e-9,
                   help="load sensor noise at the arm tip [m] for the reported bounds (default 5e-9)")
    for name, (lo, hi) in (("K-star", (1e5, 1e7)), ("J-l-star", (500, 1e4)), ("f-l-star", (0.01, 1))):
        p.add_argument(f"--{name}", type=float, nargs=2, metavar=("LOW", "HIGH"),
                       help=f"range of {name.replace('-', '_').replace('_star', '*')} (default {lo:g} {hi:g})")
    p.add_argument("--out", required=True, help="output folder: schedule.csv, bounds.csv, design.json")
    p.add_argument("--json", action="store_true", help=_JSON_HELP)
    p.set_defaults(func=cmd_design_experiment)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hdrive", description=DESCRIPTION)
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_build_fmu, _add_demo, _add_resolution, _add_sweep, _add_study, _add_identify, _add_predict,
                _add_diagnose, _add_paper_effects, _add_emps_report, _add_design_experiment):
        add(sub)
    return parser


# Smallest value of each numeric option, checked before any work starts (option -> minimum; per command where a
# command allows less, e.g. diagnose --pulses 0 skips the predicted resolution).
_MINIMA: dict[str, float] = {"workers": 0, "draws": 2, "pulses": 1, "steps": 1, "levels": 2, "max_effects": 1,
                             "candidate_budget": 0, "budget": 1, "confirm": 0, "seed": 0}
_MINIMA_BY_COMMAND: dict[tuple[str, str], float] = {("diagnose", "pulses"): 0}
_POSITIVE = ("eps1_um", "amplitude", "max_torque", "max_travel", "duration", "noise_m")


EXIT_BAD_INPUT = 2
EXIT_NOT_IDENTIFIABLE = 3


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that every ``finally`` runs (staging folders, unpacked FMUs, Dask
    workers are cleaned up) before the process exits with 143."""


#: the stopping signals received (``_on_signal``): a C library that runs Python code can swallow the exception the
#: handler raises and report a failure of its own instead; ``run`` then still exits as stopped by the last one. (The
#: CI failure first blamed on this, "Document is not valid XML Schema" in an interrupted sweep, was a libxml2 race
#: at a sweep's start, before any signal: ``ident.model.plant`` serializes those reads now.)
_SIGNALS: list[int] = []


def _on_signal(signum: int, frame: Any) -> None:
    """SIGTERM raises ``Terminated``, Ctrl-C (SIGINT) ``KeyboardInterrupt`` as Python's own handler does; both are
    recorded first (``_SIGNALS``)."""
    import signal

    _SIGNALS.append(signum)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated()


def _stopped(say: Any, signum: int | None = None) -> tuple[int, None]:
    """The exit of a command a signal stopped (``signum``, default the last one recorded): 130 after Ctrl-C, 143
    after SIGTERM, with one line."""
    import signal

    if (signum if signum is not None else _SIGNALS[-1]) == signal.SIGINT:
        say("interrupted (Ctrl-C); no output was left half-written")
        return 130, None
    say("terminated (SIGTERM); no output was left half-written")
    return 143, None


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
    """(exit code, result): 0 with the command's result, 3 with it when a parameter is not identifiable from the
    log (identify, predict), 2 for bad input or a named failure, 130 / 143 when interrupted, 1 for an internal error
    (a bug: its traceback only with HDRIVE_TRACEBACK=1)."""
    import os
    import signal

    from .common.output import OutputDirError
    from .fitting.logs import LogError
    from .protocols.batch import BatchError

    say = lambda msg: print(f"hdrive {args.command}: {msg}", file=sys.stderr)  # noqa: E731
    try:
        preflight(args)
        result = args.func(args)
        return getattr(args, "exit_code", 0), result
    except KeyboardInterrupt:
        return _stopped(say, signal.SIGINT)
    except Terminated:
        return _stopped(say, signal.SIGTERM)
    except (ParameterError, LogError, OutputDirError, BatchError, ValueError, ThresholdNotFound, NoConsistentStep,
            SettleError, RuntimeError, OSError) as exc:
        if _SIGNALS:   # the failure is the signal's, whose exception a C library turned into its own
            return _stopped(say)
        say(f"error: {exc}")
        checks = getattr(exc, "checks", None)  # a failed data check: every check's result, for --json
        return EXIT_BAD_INPUT, ({"error": str(exc), "data_checks": checks} if checks is not None else None)
    except Exception as exc:  # a bug, not bad input
        if _SIGNALS:
            return _stopped(say)
        if os.environ.get("HDRIVE_TRACEBACK"):
            raise
        say(f"internal error: {type(exc).__name__}: {exc} (please report it; HDRIVE_TRACEBACK=1 shows where)")
        return 1, None


def main(argv: Sequence[str] | None = None) -> int:
    import signal

    args = build_parser().parse_args(argv)
    _SIGNALS.clear()   # a signal of an earlier call in this process is not this one's
    # Ctrl-C only where Python's own handler is in place: a SIGINT the process ignores (started in the background)
    # stays ignored
    ours = [signal.SIGTERM] + ([signal.SIGINT] if signal.getsignal(signal.SIGINT) is signal.default_int_handler
                               else [])
    previous = {sig: signal.signal(sig, _on_signal) for sig in ours}
    try:
        with one_blas_thread():
            code, result = run(args)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if result is not None and args.json:
        from .common.units import plain_json, si_keys

        print(json.dumps(plain_json(si_keys(result)), indent=2))
    if code in (130, 143) and argv is None:
        # the command line, interrupted: everything open was closed on the way out (FMU folders, staged files);
        # skip the interpreter's teardown of numpy, pandas, CasADi and Dask (measured 2-3 s on a loaded machine, 11 s
        # with local Dask workers caught in their start-up), after killing those workers
        if "distributed" in sys.modules:
            from .protocols.batch import abandon_local_workers

            abandon_local_workers()
        from .model.plant import remove_unpacked_fmus

        remove_unpacked_fmus()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


if __name__ == "__main__":
    raise SystemExit(main())
