"""Command line: ``python -m jaxrb.bench [--quick] [--out DIR] [--only SECTION ...]``.

Prints a Markdown report to stdout (progress goes to stderr) and writes it to
``DIR/report.md`` (default ``bench_out``). The sections (:data:`SECTIONS`) are
jaxrb's own: speed against error on scenes with closed forms, the hard cases,
integrator accuracy on a tumbling body, free-body and contact throughput,
gradient memory and time, and the smoothing knobs. None of them imports
another engine.

The side-by-side runs with other engines (``peers``: MuJoCo, MJX, Brax, Jax2D,
pymunk; ``real_data``: the measured cube tosses beside MuJoCo and Bullet), the
generator of the committed report (docs/benchmarks.md) and the GPU runs live
outside the package, in the repository's ``benchmarks/`` folder:
``python -m benchmarks`` from a source checkout, with the ``peers`` extra
(``pip install -e ".[peers]"``), runs every section of this report and theirs.
Asked for one of those sections (:data:`MOVED`), this command stops with an
error that names ``python -m benchmarks``; it does not run them itself: a
wheel of jaxrb has no ``benchmarks/`` folder, and the package imports nothing
from it (``benchmarks`` builds on this module through :func:`main`'s
``extra`` sections).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from typing import Callable, Dict, Optional, Sequence

SECTIONS = ("speed_error", "hard_cases", "tumbling", "throughput", "contact", "gradients", "smoothing")
#: Sections that moved to ``benchmarks/`` (they import other engines); ``--only`` names them in its error.
MOVED = ("peers", "real_data", "double_pendulum", "joints_accuracy", "joints_speed")
MOVED_TO = "python -m benchmarks"

#: What each mode runs. ``quick`` shows every section at one or two settings
#: of each kind (the sections' own QUICK settings say which): on the 2-core host
#: of docs/benchmarks.md it took 2.7-2.8 minutes with the peers installed (0.7 of
#: them the peers section) and about 2 without, measured when this command still
#: ran the peers section (python -m benchmarks runs it now); compiling its
#: programs is most of it. ``full``
#: took about 45 minutes with the peers (docs/benchmarks.md's section wall
#: times); what it does not set comes from the sections' own defaults
#: (free_body.TUMBLE_CONFIGS, gradients.DEFAULT_SETTINGS).
SETTINGS = {
    "quick": dict(tumble_steps=(1 / 60,), tumble_horizon=6.0, repeats=3,
                  tumble_configs=(("semi_implicit", "exp_map"), ("implicit_gyro", "exp_map"), ("rk4", None),
                                  ("rk4_body", None)),
                  throughput_integrators=("semi_implicit",), batches=(1, 64),
                  throughput_steps=1000, num_bodies=8,
                  contact_scenes=("bounce",), contact_batches=(64, 16),
                  contact_steps=100, gradient_scenes=("tumble",), gradient_methods=("autodiff", "adjoint"),
                  gradient_memory_steps=(1000,), gradient_batch=None, gradient_rounds=21),
    "full": dict(tumble_steps=(1 / 60, 1 / 240, 1 / 1000), tumble_horizon=20.0, repeats=5,
                 throughput_integrators=("euler", "semi_implicit", "implicit_gyro", "rk4", "rk4_body"),
                 batches=(1, 1024), throughput_steps=1000, num_bodies=8,
                 contact_scenes=("bounce", "slide", "drop", "stack3d", "pyramid2d"),
                 contact_batches=(1024, 16), contact_steps=100),
}


@dataclasses.dataclass(frozen=True)
class Section:
    """A report section that :func:`main` runs beside its own (``benchmarks/`` adds the peers' this way).

    Attributes:
        title: the section's heading, without its number.
        info: its line in the report's "Machine and settings" list.
        run: ``run(quick, out_dir, log) -> (markdown, results)``: ``quick`` is
            True for ``--quick``, ``out_dir`` is ``--out`` and ``log(text)``
            writes a progress line.
    """

    title: str
    info: str
    run: Callable


def parse_args(argv=None, sections: Sequence[str] = SECTIONS, prog: str = "python -m jaxrb.bench",
               description: Optional[str] = None):
    """Read the command line.

    Args:
        argv: arguments without the program name (None: ``sys.argv[1:]``).
        sections: the section names ``--only`` accepts, in report order.
        prog: the program name that help and errors show.
        description: the help's description (None: this command's).

    Returns:
        The parsed ``argparse.Namespace`` (``quick``, ``out``, ``only``). A
        section of :data:`MOVED` that ``sections`` lacks, or any other unknown
        name, exits with status 2 and a message (the moved ones name
        ``python -m benchmarks``).
    """
    parser = argparse.ArgumentParser(
        prog=prog,
        description=description or (
            "jaxrb benchmarks: speed against error on scenes with closed forms, the hard cases, "
            "integrator accuracy on a tumbling body, free-body and contact throughput, gradient memory and "
            "time, and the smoothing knobs' gradient bias and spread. Prints Markdown and writes "
            f"DIR/report.md. Other engines side by side (peers, real_data): {MOVED_TO}, from a source "
            "checkout with the peers extra."))
    parser.add_argument("--quick", action="store_true",
                        help="one or two configurations of each kind and shorter horizons (under 3 minutes on 2 "
                             "cores, mostly compiling)")
    parser.add_argument("--out", default="bench_out", metavar="DIR",
                        help="directory for report.md (default: bench_out)")
    parser.add_argument("--only", nargs="+", default=list(sections), metavar="SECTION",
                        help=f"run only these sections: {', '.join(sections)}")
    args = parser.parse_args(argv)
    moved = [name for name in args.only if name in MOVED and name not in sections]
    if moved:
        parser.error(f"{', '.join(moved)}: the sections that run other engines moved out of the jaxrb "
                     f"package; from a jaxrb source checkout with the peers extra "
                     f"(pip install -e \".[peers]\") run: {MOVED_TO} --only {' '.join(moved)}")
    unknown = [name for name in args.only if name not in sections]
    if unknown:
        parser.error(f"argument --only: invalid choice: {', '.join(map(repr, unknown))} "
                     f"(choose from {', '.join(sections)})")
    return args


def main(argv=None, *, sections: Sequence[str] = SECTIONS, extra: Optional[Dict[str, Section]] = None,
         prog: str = "python -m jaxrb.bench", description: Optional[str] = None) -> int:
    """Run the sections, print the report and write ``DIR/report.md``.

    Args:
        argv: arguments without the program name (None: ``sys.argv[1:]``).
        sections: every section's name in report order: :data:`SECTIONS` and
            the keys of ``extra``.
        extra: sections from outside this module by name (``benchmarks/``'s
            peers and real data); their ``info`` lines go after this module's.
        prog, description: for the help and errors (see :func:`parse_args`).

    Returns:
        0 (bad arguments exit with status 2 before anything runs).
    """
    extra = dict(extra or {})
    missing = [name for name in sections if name not in SECTIONS and name not in extra]
    if missing:
        raise ValueError(f"sections {missing} are neither jaxrb's own nor in extra")
    args = parse_args(argv, sections, prog, description)
    import jax

    # float64 for the accuracy runs; float32 runs ask for their dtype explicitly.
    jax.config.update("jax_enable_x64", True)

    from jaxrb.bench import free_body, gradients, smoothing
    from jaxrb.bench.report import Report, bullet_list, fmt_step, machine_info
    from jaxrb.bench.timing import Stopwatch

    mode = "quick" if args.quick else "full"
    settings = {"tumble_configs": free_body.TUMBLE_CONFIGS, **gradients.DEFAULT_SETTINGS, **SETTINGS[mode],
                **smoothing.SETTINGS[mode]}
    from jaxrb.bench import speed_error

    speed_error_settings = speed_error.QUICK if args.quick else speed_error.FULL
    speed_error_count = sum(len(speed_error_settings["speed_error_configs"][name])
                            for name in speed_error_settings["speed_error_scenes"])
    log = free_body.stderr_log
    report = Report("jaxrb benchmark report")
    report.heading("Machine and settings")
    info = machine_info()
    info.update({
        "mode": mode + (" (--quick)" if args.quick else ""),
        "sections": ", ".join(args.only),
        "tumbling": ("integrators " + ", ".join(f"{i}/{o}" if o else i for i, o in settings["tumble_configs"])
                     + f", h ∈ {{{', '.join(fmt_step(h) for h in settings['tumble_steps'])}}} s, "
                     f"horizon {settings['tumble_horizon']:g} s, float64 and float32"),
        "throughput": (f"{settings['num_bodies']} bodies, batches {list(settings['batches'])}, "
                       f"{settings['throughput_steps']} steps per jitted scan, float32, "
                       f"integrators {', '.join(settings['throughput_integrators'])}"),
        "contact": (f"scenes {', '.join(settings['contact_scenes'])}, batches 1 and "
                    f"{settings['contact_batches'][0]}"
                    + (f" (stacks: 1 and {settings['contact_batches'][1]})"
                       if {"stack3d", "pyramid2d"} & set(settings["contact_scenes"]) else "")
                    + f", {settings['contact_steps']} steps per jitted scan, float32"),
        "gradients": (f"scenes {', '.join(settings['gradient_scenes'])}, memory at T = "
                      f"{', '.join(map(str, settings['gradient_memory_steps']))} and time at T = "
                      f"{settings['gradient_time_steps']} at "
                      + (f"1 and {settings['gradient_batch']} worlds" if settings["gradient_batch"] else "one world")
                      + f", methods {', '.join(settings['gradient_methods'])}, float32"),
        "smoothing": (f"K = {settings['smoothing_worlds']} worlds, sweeps "
                      f"{', '.join(settings['smoothing_sweeps'])}, float64"),
        "speed_error": (f"scenes {', '.join(speed_error_settings['speed_error_scenes'])}: "
                        f"{speed_error_count} configurations "
                        "(integrator / contact model / step / substeps / iterations), error against the "
                        "closed form, cost at batch 1 and body-steps/s at batch "
                        f"{speed_error_settings['speed_error_batch']}"),
        "hard_cases": ("tallest 3D stack, 2D pyramid, mass ratios, fastest impact, fast spin, "
                       "overlap recovery, long rest (small sizes with --quick)"),
        **{name: section.info for name, section in extra.items()},
        "timing": (f"compile = trace + lower + compile; run = median of up to "
                   f"{settings['repeats']} calls after one warm-up, block_until_ready"),
    })
    report.extend(bullet_list(info))

    def section(title, run):
        """Run one section, add its text and its wall time to the report."""
        report.heading(title)
        with Stopwatch() as watch:
            text, _ = run()
        report.extend(text)
        report.paragraph(f"Section wall time: {watch.seconds:.1f} s.")

    def run_speed_error():
        return speed_error.speed_error_section({**settings, **speed_error_settings, "out_dir": args.out}, log)

    def run_hard_cases():
        from jaxrb.bench import hard_cases

        case_settings = hard_cases.QUICK if args.quick else hard_cases.FULL
        return hard_cases.hard_cases_section({**case_settings, "out_dir": args.out}, log)

    def run_contact():
        from jaxrb.bench import contact

        return contact.contact_section(settings["contact_scenes"], settings["contact_batches"][0],
                                       settings["contact_batches"][1], settings["contact_steps"],
                                       repeats=settings["repeats"], log=log)

    def run_gradients():
        return gradients.gradients_section(settings, log)

    runners = {
        "speed_error": ("Speed against error", run_speed_error),
        "hard_cases": ("Hard cases: stability, pass or fail", run_hard_cases),
        "tumbling": ("Torque-free tumbling in detail (intermediate-axis flip)", lambda: free_body.tumbling_section(
            settings["tumble_steps"], settings["tumble_horizon"], repeats=settings["repeats"], log=log,
            configs=settings["tumble_configs"])),
        "throughput": ("Free-body throughput", lambda: free_body.throughput_section(
            settings["throughput_integrators"], settings["batches"], settings["throughput_steps"],
            settings["num_bodies"], repeats=settings["repeats"], log=log)),
        "contact": ("Contact throughput", run_contact),
        "gradients": ("Gradient memory and time", run_gradients),
        "smoothing": ("Smoothing knobs: gradient bias and spread",
                      lambda: smoothing.smoothing_section(settings, log=log, out_dir=args.out)),
        **{name: (section.title, lambda run=section.run: run(args.quick, args.out, log))
           for name, section in extra.items()},
    }
    with Stopwatch() as total:
        for number, name in enumerate([name for name in sections if name in args.only], start=1):
            title, run = runners[name]
            section(f"{number}. {title}", run)
    try:
        load = "{:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    except (AttributeError, OSError):  # pragma: no cover
        load = "?"
    report.paragraph(
        f"Total benchmark wall time: {total.seconds:.1f} s. Load average (1, 5, 15 min) at the "
        f"end: {load} on {os.cpu_count()} CPUs; other processes competing for the cores make "
        "the run times (not the errors) unreliable, most of all for the larger fusions "
        "(rk4, batched runs).")

    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "report.md")
    report.write(path)
    sys.stdout.write(str(report))
    sys.stdout.flush()
    log(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
