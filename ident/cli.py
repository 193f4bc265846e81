"""``hdrive`` command line: a thin layer over the Python API (parse, call, print JSON or write files)."""
from __future__ import annotations

import argparse
import json
import sys
from typing import Sequence

from .params import DriveParams, ParameterError, parse_assignments


def _params_from(args: argparse.Namespace) -> DriveParams:
    return DriveParams().with_values(**parse_assignments(getattr(args, "param", None)))


def cmd_build_fmu(args: argparse.Namespace) -> dict:
    from fmu_build import build_fmu

    path = build_fmu(fmi_version=args.fmi, out_dir=args.out)
    if not args.json:
        print(path)
    return {"fmu": str(path), "fmi_version": args.fmi}


def cmd_demo(args: argparse.Namespace) -> dict:
    from .demo import write_demo

    summary = write_demo(args.out, params=_params_from(args), amplitude_star=args.amplitude, pulses=args.pulses,
                         progress=not args.json)
    if not args.json:
        print(f"wrote {summary['csv']} and {summary['png']}")
        print("arm increments [um]: " + ", ".join(f"{x:.4f}" for x in summary["increments_um"]))
    return summary


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hdrive", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build-fmu", help="build HarmonicDrive.fmu and print its path")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default 2)")
    p.add_argument("--out", required=True, help="directory to write HarmonicDrive.fmu into")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_build_fmu)

    p = sub.add_parser("demo", help="nominal drive's response to a train of 1 ms torque pulses (CSV + PNG)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--pulses", type=int, default=10, help="number of pulses (default 10)")
    p.add_argument("--amplitude", type=float, default=3.0, help="pulse amplitude tau* = T/f_m (default 3)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="drive parameter in SI (e.g. K_s=2e4) or K_star / J_l_star / f_l_star; repeatable")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        result = args.func(args)
    except (ParameterError, ValueError) as exc:
        print(f"hdrive {args.command}: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
