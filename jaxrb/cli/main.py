"""The ``jaxrb`` console script: ``jaxrb demo``, ``run``, ``fit``, ``evaluate`` and ``bench``."""

from __future__ import annotations

import argparse
import sys


def _seconds(text: str) -> float:
    """A time in seconds, as a number or a fraction such as ``1/148``."""
    try:
        if "/" in text:
            top, bottom = text.split("/")
            return float(top) / float(bottom)
        return float(text)
    except (ValueError, ZeroDivisionError):
        raise argparse.ArgumentTypeError(f"expected seconds as a number or a fraction like 1/148, got {text!r}")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxrb", description="Differentiable rigid-body physics in JAX.")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="simulate small scenes, print a report, write pictures")
    demo.add_argument("--out", default="jaxrb-demo", help="folder for the pictures (default: jaxrb-demo)")
    run = commands.add_parser("run", help="simulate a scene file (.json, MJCF .xml or .urdf)")
    run.add_argument("scene_file", help="a jaxrb .json scene, a MuJoCo MJCF .xml or a .urdf")
    run.add_argument("--steps", type=int, required=True, help="number of steps to simulate")
    run.add_argument("--out", required=True, help="output folder (trajectory.npz, animation, report.txt)")
    run.add_argument("--every", type=int, default=1, help="keep every k-th state (default 1)")
    run.add_argument("--animation", default="gif", help="gif (default), mp4 (needs ffmpeg), html or none")
    for name, text in (("fit", "fit a scene file's parameters to measured trajectories"),
                       ("evaluate", "score a scene file on measured trajectories (published protocol)")):
        command = commands.add_parser(name, help=text)
        command.add_argument("scene_file", help="a jaxrb .json scene, a MuJoCo MJCF .xml or a .urdf")
        command.add_argument("data", help="measured trajectories (.npz; see jaxrb.fit.measured)")
        command.add_argument("--sample-dt", type=_seconds,
                             help="sample spacing (s, e.g. 1/148), for files that do not record it")
        command.add_argument("--angvel-frame", choices=("world", "body"),
                             help="frame of the angular velocity, for files that do not record it")
        command.add_argument("--trajectories", metavar="START:STOP", help="use only these trajectories")
    fit = commands.choices["fit"]
    fit.add_argument("--out", required=True, help="the fitted scene file to write (.json)")
    fit.add_argument("--fields", nargs="+", default=["friction", "restitution"],
                     help="Params fields to fit (default: friction restitution)")
    fit.add_argument("--horizons", type=int, nargs="*", default=[8, 32],
                     help="samples predicted from each measured state, one fitting stage each (default 8 32); "
                          "none (--horizons with no value): full rollouts only, forward search")
    fit.add_argument("--search-width", type=float, default=0.2,
                     help="first step of the forward search on full rollouts, in the fields' unconstrained units "
                          "(default 0.2; 1: a factor e for a log-transformed field)")
    fit.add_argument("--budget", type=float, help="time budget in seconds, compile included")
    fit.add_argument("--resume", metavar="STATE.json", help="save progress here and resume from it")
    evaluate = commands.choices["evaluate"]
    evaluate.add_argument("--plot", metavar="PNG", help="write the error distribution here")
    evaluate.add_argument("--noise-floor", action="store_true", help="also measure the tracker noise's floor")
    # Its options (--quick, --only ..., --out) are python -m jaxrb.bench's, passed on as given:
    # main() reads them with parse_known_args (argparse.REMAINDER refused a leading '--quick').
    commands.add_parser("bench", help="run the benchmark suite (python -m jaxrb.bench; its options pass on, "
                                      "e.g. jaxrb bench --quick)", add_help=False)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``jaxrb`` command.

    Args:
        argv: command-line arguments without the program name (None: ``sys.argv[1:]``).

    Returns:
        The exit status: 0 on success, 2 for bad input (the message says which field).
    """
    parser = _parser()
    args, rest = parser.parse_known_args(argv)
    if args.command != "bench" and rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    if args.command == "demo":
        from jaxrb.cli.demo import main as demo_main
        demo_main(args.out)
        return 0
    if args.command == "run":
        from jaxrb.cli.runner import print_progress, run_scene_file
        try:
            print(run_scene_file(args.scene_file, args.steps, args.out, every=args.every,
                                 animation=args.animation, progress=print_progress))
        except (ValueError, FileNotFoundError) as error:
            print(f"jaxrb run: {error}", file=sys.stderr)
            return 2
        return 0
    if args.command in ("fit", "evaluate"):
        from jaxrb.cli import data_commands
        common = dict(sample_dt=args.sample_dt, angvel_frame=args.angvel_frame, trajectories=args.trajectories)
        try:
            if args.command == "fit":
                print(data_commands.fit_command(args.scene_file, args.data, args.out, fields=args.fields,
                                                horizons=args.horizons, time_budget=args.budget,
                                                search_width=args.search_width,
                                                state_path=args.resume, **common))
            else:
                print(data_commands.evaluate_command(args.scene_file, args.data, plot=args.plot,
                                                     floor=args.noise_floor, **common))
        except (ValueError, FileNotFoundError) as error:
            print(f"jaxrb {args.command}: {error}", file=sys.stderr)
            return 2
        return 0
    from jaxrb.bench.__main__ import main as bench_main
    return bench_main(rest) or 0


if __name__ == "__main__":
    sys.exit(main())
