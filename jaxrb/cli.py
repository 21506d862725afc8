"""The ``jaxrb`` console script: ``jaxrb demo``, ``jaxrb run SCENE_FILE`` and ``jaxrb bench``."""

from __future__ import annotations

import argparse
import sys


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxrb", description="Differentiable rigid-body physics in JAX.")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="simulate small scenes, print a report, write pictures")
    demo.add_argument("--out", default="jaxrb-demo", help="folder for the pictures (default: jaxrb-demo)")
    run = commands.add_parser("run", help="simulate a scene file (.json or MJCF .xml)")
    run.add_argument("scene_file", help="a jaxrb .json scene or a MuJoCo MJCF .xml")
    run.add_argument("--steps", type=int, required=True, help="number of steps to simulate")
    run.add_argument("--out", required=True, help="output folder (trajectory.npz, animation, report.txt)")
    run.add_argument("--every", type=int, default=1, help="keep every k-th state (default 1)")
    run.add_argument("--animation", default="gif", help="gif (default), mp4 (needs ffmpeg), html or none")
    bench = commands.add_parser("bench", help="run the benchmark suite (python -m jaxrb.bench)")
    bench.add_argument("bench_args", nargs=argparse.REMAINDER, help="arguments for jaxrb.bench")
    return parser


def main(argv=None) -> int:
    """Entry point of the ``jaxrb`` command.

    Args:
        argv: command-line arguments without the program name (None: ``sys.argv[1:]``).

    Returns:
        The exit status: 0 on success, 2 for bad input (the message says which field).
    """
    args = _parser().parse_args(argv)
    if args.command == "demo":
        from jaxrb.demo import main as demo_main
        demo_main(args.out)
        return 0
    if args.command == "run":
        from jaxrb.runner import print_progress, run_scene_file
        try:
            print(run_scene_file(args.scene_file, args.steps, args.out, every=args.every,
                                 animation=args.animation, progress=print_progress))
        except (ValueError, FileNotFoundError) as error:
            print(f"jaxrb run: {error}", file=sys.stderr)
            return 2
        return 0
    from jaxrb.bench.__main__ import main as bench_main
    return bench_main(args.bench_args) or 0


if __name__ == "__main__":
    sys.exit(main())
