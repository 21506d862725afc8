"""Command line: ``python -m benchmarks [--quick] [--out DIR] [--only SECTION ...]``.

The report committed as docs/benchmarks.md: every section of
``python -m jaxrb.bench`` and the two that run other engines, ``peers``
(:mod:`benchmarks.peers`), ``real_data`` (:mod:`benchmarks.real_data`) and
``double_pendulum`` (:mod:`benchmarks.double_pendulum`), ``joints_accuracy``
and ``joints_speed`` (:mod:`benchmarks.joints_accuracy`, :mod:`benchmarks.joints_speed`), in
the order of :data:`SECTIONS`. Run it from the repository's root with the
``peers`` extra installed (``pip install -e ".[peers]"``); an engine that is
missing is a note in the report, not a failure. ``--only peers real_data``
runs the side-by-side sections alone. The options are
``python -m jaxrb.bench``'s (:func:`jaxrb.bench.__main__.main` runs the
report, with this module's two sections added); the report goes to stdout
and to ``DIR/report.md`` (default ``bench_out``), progress to stderr.

The GPU runs are a command of their own: ``python -m benchmarks.accelerator``.
"""

from __future__ import annotations

import sys

from jaxrb.bench import __main__ as package_report

#: Every section, in report order: jaxrb's own (jaxrb.bench.__main__.SECTIONS) and the peers'.
SECTIONS = ("real_data", "double_pendulum", "joints_accuracy", "joints_speed", "speed_error", "hard_cases", "peers",
            "tumbling", "throughput", "contact", "gradients", "smoothing")


def _run_peers(quick: bool, out_dir: str, log):
    from benchmarks import peers

    return peers.peers_section(peers.QUICK if quick else peers.FULL, log)


def _run_real_data(quick: bool, out_dir: str, log):
    from benchmarks import elbow_tosses, real_data

    cube, cube_results = real_data.real_data_section(real_data.QUICK if quick else real_data.FULL, log)
    elbow, elbow_results = elbow_tosses.elbow_section(elbow_tosses.QUICK if quick else elbow_tosses.FULL, log)
    return (f"**Cube tosses.** {cube}\n\n**Elbow tosses: two hinged blocks, joints and contact.** {elbow}",
            {"cube": cube_results, "elbow": elbow_results})


def _run_double_pendulum(quick: bool, out_dir: str, log):
    from benchmarks import double_pendulum

    return double_pendulum.double_pendulum_section(double_pendulum.QUICK if quick else double_pendulum.FULL, log)


def _run_joints_accuracy(quick: bool, out_dir: str, log):
    from benchmarks import joints_accuracy

    return joints_accuracy.joints_accuracy_section(joints_accuracy.QUICK if quick else joints_accuracy.FULL, log)


def _run_joints_speed(quick: bool, out_dir: str, log):
    from benchmarks import joints_speed

    return joints_speed.joints_speed_section(joints_speed.QUICK if quick else joints_speed.FULL, log)


#: The sections this folder adds to jaxrb's report.
EXTRA = {
    "peers": package_report.Section(
        "Peers side by side: MuJoCo, MJX, Brax, Jax2D, pymunk",
        "the same scenes in each installed peer (pip install -e \".[peers]\"), same run, ratios jaxrb / peer "
        "and the issue's targets",
        _run_peers),
    "real_data": package_report.Section(
        "Real data: measured cube and elbow tosses beside MuJoCo and Bullet",
        "400 measured cube tosses and 400 tosses of two hinged blocks, half fitted, half scored; MuJoCo and "
        "Bullet with the publishers' parameters (cubes, examples/cube_tosses) and fitted on the same half "
        "(elbow, examples/elbow_tosses)",
        _run_real_data),
    "double_pendulum": package_report.Section(
        "Real data: a double pendulum beside its publishers' model",
        "6 measured records of the DFKI double pendulum, predicted 0.05, 0.2 and 0.5 s ahead from the measured "
        "state and torques (examples/double_pendulum): jaxrb's fitted scene against the publishers' identified "
        "plant, leave-one-record-out, and the noise floor",
        _run_double_pendulum),
    "joints_accuracy": package_report.Section(
        "Joints beside MuJoCo: each integrator's distance to MuJoCo's RK4",
        "gymnasium's inverted pendulums, hopper and ant and a double pendulum from random states, contact and "
        "limits off, h = 1e-4 s: jaxrb's integrators and MuJoCo's Euler against MuJoCo's RK4",
        _run_joints_accuracy),
    "joints_speed": package_report.Section(
        "Joints speed beside Brax and MJX, at two vector widths",
        "a 10-link hinge chain and gymnasium's ant in the air at 1 and 1 024 worlds, the ant on its floor: jaxrb's "
        "integrators beside Brax's pipelines and MJX, natively and under --xla_cpu_max_isa=AVX2",
        _run_joints_speed),
}


def main(argv=None) -> int:
    """Run the report's sections (all of them, or those of ``--only``) and write ``DIR/report.md``.

    Args:
        argv: arguments without the program name (None: ``sys.argv[1:]``).

    Returns:
        0 (bad arguments exit with status 2 before anything runs).
    """
    return package_report.main(
        argv, sections=SECTIONS, extra=EXTRA, prog="python -m benchmarks",
        description="The committed benchmark report (docs/benchmarks.md): jaxrb's sections (python -m "
                    "jaxrb.bench) and, side by side, other engines (peers: MuJoCo, MJX, Brax, Jax2D, pymunk; "
                    "real_data: measured cube tosses beside MuJoCo and Bullet; double_pendulum: a real double pendulum beside "
                    "its publishers' model). Needs the peers extra for "
                    "the other engines. Prints Markdown and writes DIR/report.md.")


if __name__ == "__main__":
    sys.exit(main())
