"""The ``jaxrb`` console script: ``jaxrb demo`` and ``jaxrb bench``."""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="jaxrb", description="Differentiable rigid-body physics in JAX.")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("demo", help="simulate two small scenes and print a report")
    bench = commands.add_parser("bench", help="run the benchmark suite (python -m jaxrb.bench)")
    bench.add_argument("bench_args", nargs=argparse.REMAINDER, help="arguments for jaxrb.bench")
    args = parser.parse_args(argv)
    if args.command == "demo":
        from jaxrb.demo import main as demo_main
        demo_main()
        return 0
    from jaxrb.bench.__main__ import main as bench_main
    return bench_main(args.bench_args) or 0


if __name__ == "__main__":
    sys.exit(main())
