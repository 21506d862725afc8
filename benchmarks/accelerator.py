"""Throughput on the default JAX device at growing batch: how far vmap scales.

``python -m benchmarks.accelerator [--quick] [--out DIR] [--only ROWS ...]``
runs jaxrb on the benchmark scenes of :mod:`jaxrb.bench.free_body`,
:mod:`benchmarks.jaxrb_runs` (the peers section's scenes) and
:mod:`jaxrb.bench.gradients` on whatever device JAX picks (a GPU when jaxlib
has one, else the CPU) at batches up to 131 072 worlds, and writes
``DIR/accelerator.md``; ``--only`` picks kinds of row (:data:`ROW_KINDS`), so
a short lease can time a few before and after a change. It is separate from
``python -m benchmarks`` because its batches are sized for an accelerator: on
two CPU cores the full run takes hours. It runs no other engine. Nothing in
jaxrb depends on a GPU; this only measures one.

Rows (float32, compile time apart, median of repeated calls with
``block_until_ready``, as :mod:`jaxrb.bench.timing` times everything):

* **free bodies**: 8 boxes, semi-implicit and rk4_body, dt = 1 ms, 1 000 steps.
* **penalty box drop**: the peers section's drop (h = 2 ms, 1 000 steps), with
  its resting error, so a batch that runs fast but wrong would show.
* **penalty column / pyramid**: the peers section's 10-box column (0.5 ms)
  and 55-box 2D pyramid (2 ms), 1 s each, with whether they stand.
* **impulse box drop**: jaxrb's impulse setting (1/60 s × 4), 300 steps.
* **gradient**: the gradients section's scenes, forward and gradient of a
  1 000-step trajectory loss, by autodiff and by the hand-written adjoint
  where the scene has one, at one world and, for scenes with an adjoint, at
  the batches of ``gradient_batches`` (their ratio is the cheap-gradient
  figure; at one world it is set by per-kernel launch cost on a GPU).

Each row is printed as soon as it is measured, so a run cut short still
reports what it finished.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Callable, List, Sequence

import jax

from benchmarks import jaxrb_runs, scenes
from jaxrb.bench import free_body, gradients
from jaxrb.bench.report import Report, bullet_list, fmt_fixed, fmt_si, machine_info, markdown_table

#: Worlds per row. ``quick`` is for checking the module on a CPU in seconds.
SETTINGS = {
    "full": dict(free_batches=(1, 1024, 16384, 131072), drop_batches=(1024, 16384, 131072),
                 column_batches=(16, 1024, 8192), pyramid_batches=(16, 256, 4096),
                 impulse_batches=(1024, 16384), steps=1000, impulse_steps=300, standing_seconds=1.0,
                 gradient_scenes=("tumble", "box_drop_penalty"), gradient_batches=(1024, 16384),
                 gradient_steps=1000, repeats=5),
    "quick": dict(free_batches=(1, 4), drop_batches=(4,), column_batches=(2,), pyramid_batches=(2,),
                  impulse_batches=(2,), steps=20, impulse_steps=5, standing_seconds=0.01,
                  gradient_scenes=("tumble",), gradient_batches=(2,), gradient_steps=20, repeats=2),
}

#: ``--only`` choices: each kind of row and the settings key that lists its batches (or scenes).
ROW_KINDS = {"free": "free_batches", "drop": "drop_batches", "column": "column_batches",
             "pyramid": "pyramid_batches", "impulse": "impulse_batches", "gradients": "gradient_scenes"}

HEADERS = ["scene", "setting", "batch", "bodies", "compile (s)", "run (s)", "body-steps/s", "check"]


def _row(scene: str, setting: str, batch: int, bodies: int, compile_s: float, run_s: float,
         steps: int, check: str) -> list:
    return [scene, setting, batch, bodies, fmt_fixed(compile_s, 2), fmt_fixed(run_s, 4),
            fmt_si(batch * bodies * steps / run_s), check]


def _height_check(row) -> str:
    seconds = row.h * row.num_steps
    return f"{row.metrics['rest_error'] * 1e3:.3f} mm from resting height at {seconds:g} s"


def measurements(settings: dict) -> List[Callable[[], list]]:
    """One thunk per table row, in report order; each returns the row's cells (see :data:`HEADERS`)."""
    steps, repeats = settings["steps"], settings["repeats"]
    peer = dict(peers_repeats=repeats, peers_budget_s=10.0)
    thunks = []

    def free(integrator, batch):
        result = free_body.run_throughput(integrator, batch, steps, repeats=repeats)
        return _row("free bodies", integrator, batch, result.num_bodies, result.compile_s, result.run_s,
                    steps, "finite")

    def drop(batch):
        row = jaxrb_runs.jaxrb_drop("penalty", scenes.PEER_STEP, 1, batch, steps, peer)
        return _row("box drop", row.setting, batch, row.num_bodies, row.compile_s, row.run_s, steps,
                    _height_check(row))

    def standing(run, batch, seconds):
        row = run("penalty", batch, seconds, peer)
        check = ("stands" if row.metrics["stands"] else "FALLS") + f", sink {row.metrics['sink'] * 1e3:.2f} mm"
        return _row(scenes.SCENE_TITLES[row.scene], row.setting, batch, row.num_bodies, row.compile_s,
                    row.run_s, row.num_steps, check)

    def impulse_drop(batch):
        best = scenes.JAXRB_BEST
        row = jaxrb_runs.jaxrb_drop("impulse", best["dt"], best["substeps"], batch, settings["impulse_steps"], peer)
        return _row("box drop", row.setting, batch, row.num_bodies, row.compile_s, row.run_s,
                    settings["impulse_steps"], _height_check(row))

    for integrator in ("semi_implicit", "rk4_body"):
        thunks += [lambda i=integrator, b=batch: free(i, b) for batch in settings["free_batches"]]
    thunks += [lambda b=batch: drop(b) for batch in settings["drop_batches"]]
    thunks += [lambda b=batch: standing(jaxrb_runs.jaxrb_stack, b, settings["standing_seconds"])
               for batch in settings["column_batches"]]
    thunks += [lambda b=batch: standing(jaxrb_runs.jaxrb_pyramid, b, settings["standing_seconds"])
               for batch in settings["pyramid_batches"]]
    thunks += [lambda b=batch: impulse_drop(b) for batch in settings["impulse_batches"]]
    return thunks


GRADIENT_HEADERS = ["scene", "worlds", "method", "steps", "forward (ms)", "gradient (ms)", "ratio",
                    "gradient compile (s)"]


def gradient_rows(settings: dict, log) -> list:
    """Forward and gradient times of each gradient scene (see :mod:`jaxrb.bench.gradients`).

    One world by autodiff and the adjoint; scenes with an adjoint also at each
    of ``gradient_batches`` worlds.
    """
    rows = []
    for name in settings["gradient_scenes"]:
        timed = []
        for batch in (1,) + tuple(settings["gradient_batches"]):
            timed += gradients.gradient_time(name, settings["gradient_steps"], repeats=settings["repeats"],
                                             methods=("autodiff", "adjoint"), batch=batch, log=log)
            if not any(row.get("method") == "adjoint" for row in timed):
                break  # batched rows compare the two methods, as the gradients section's do
        rows += [[name, row["batch"], row["method"], settings["gradient_steps"],
                  fmt_fixed(row["forward_s"] * 1e3, 3), fmt_fixed(row["grad_s"] * 1e3, 3),
                  f"{row['ratio']:.2f}×", fmt_fixed(row["grad_compile_s"], 1)]
                 for row in timed if row["kind"] == "time"]
    return rows


def run(settings: dict, log=None) -> str:
    """Measure every row of ``settings`` (see :data:`SETTINGS`); return the Markdown section.

    A row that raises (out of device memory, say) is reported as such and the
    run goes on, so one failure does not cost the rest.
    """
    log = log or (lambda text: None)
    rows = []
    for thunk in measurements(settings):
        try:
            rows.append(thunk())
        except Exception as error:  # report it and go on: device memory differs between machines
            rows.append(["failed", f"{type(error).__name__}: {str(error).splitlines()[0][:80]}"]
                        + [""] * (len(HEADERS) - 2))
        log(" | ".join(map(str, rows[-1])))
    grads = gradient_rows(settings, log)
    parts = [markdown_table(HEADERS, rows, align=["l", "l", "r", "r", "r", "r", "r", "l"]), ""] if rows else []
    if grads:
        parts += ["Gradient of a trajectory loss over every step, all Params (`jaxrb.bench.gradients`):", "",
                  markdown_table(GRADIENT_HEADERS, grads, align=["l", "r", "l", "r", "r", "r", "r", "r"])]
    return "\n".join(parts)


def main(argv: Sequence[str] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.accelerator", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny batches and horizons, to check the module")
    parser.add_argument("--out", default="bench_out", metavar="DIR", help="where accelerator.md goes")
    parser.add_argument("--only", nargs="+", choices=ROW_KINDS, default=list(ROW_KINDS), metavar="ROWS",
                        help=f"measure only these kinds of row (a short lease): {', '.join(ROW_KINDS)}")
    args = parser.parse_args(argv)
    log = free_body.stderr_log
    settings = dict(SETTINGS["quick" if args.quick else "full"])
    settings.update({key: () for kind, key in ROW_KINDS.items() if kind not in args.only})
    report = Report("jaxrb throughput on " + jax.default_backend().upper())
    info = machine_info()
    info["mode"] = "quick" if args.quick else "full"
    info["rows"] = ", ".join(kind for kind in ROW_KINDS if kind in args.only)
    report.extend(bullet_list(info))
    start = time.perf_counter()
    report.extend(run(settings, log))
    report.paragraph(f"Wall time: {time.perf_counter() - start:.1f} s.")
    os.makedirs(args.out, exist_ok=True)
    report.write(os.path.join(args.out, "accelerator.md"))
    sys.stdout.write(str(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
