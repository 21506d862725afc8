"""Gradient cost: reverse-mode memory of long rollouts, and gradient time against forward time.

Both figures are for ``jax.grad`` of a trajectory loss with respect to every
field of ``Params`` (:func:`trajectory_loss`: mean squares of position,
velocity, angular velocity and the quaternion's vector part over every step,
the shape of a system-identification loss, so the reverse pass needs every
step). Scenes (float32 by default, like the other throughput benchmarks):

* **box_bounce**: box (half 0.1 m, 1 kg) dropped from 0.5 m with a tumble,
  restitution 0.5, onto a plane; impulse contact, dt = 1/60 s, 4 substeps.
* **box_bounce_jacobi**: the same, with the Jacobi impulse solver (all rows
  of a pass at once on split masses; ``jaxrb.physics.contact.impulse``), whose
  passes have no row loop to reverse.
* **box_drop_penalty**: the same box and drop with penalty contact at the
  box-drop benchmark's step, dt = 2 ms, one substep (the rollout's
  plane-penalty path, :mod:`jaxrb.physics.plane_penalty`), so that both contact
  models' gradients are timed.
* **tumble**: torque-free body, principal inertia (0.3, 0.35, 0.4) kg m²,
  ω0 = (0.1, 15, 0.1) rad/s, no gravity; semi-implicit Euler, dt = 1/240 s.

**Memory** is XLA's own account of the compiled gradient program,
``jax.jit(grad).lower(...).compile().memory_analysis()``: ``temp_size_in_bytes``
is the scratch the program allocates besides its arguments and outputs, and
for reverse mode it is dominated by what is saved for the backward pass.
Nothing is run, so T = 10 000 costs one compile, not 10 000 steps. It is
measured without checkpointing and with ``rb.rollout(..., checkpoint=True)``
(segments of about √T steps, each recomputed in the backward pass). Since
``rb.rollout`` rematerialises every step, reverse mode saves one State a
step, not the step's intermediates; this loss reads every state, so both
grow as T, about two States a step without segments (the trajectory and
each step's input) and one with them.

**Time**: compile time apart; run = median of repeated calls with
``block_until_ready`` (:mod:`jaxrb.bench.timing`) of the forward loss and of
its gradient, both over the same T steps, called in turn. The ratio grad /
forward is the "cheap gradient" figure (target ≤ 3×; checkpointing adds about one more
forward pass). Timed at one world, and for scenes with a hand-written
adjoint or in :data:`BATCHED_AUTODIFF` also at ``gradient_batch`` worlds
(``vmap`` over the initial states, Params shared, the loss their mean).

**Methods** (:data:`METHODS`): ``autodiff`` (``rb.rollout``'s reverse
mode), ``checkpoint`` (the same with ``checkpoint=True``) and ``adjoint``
(``rb.rollout(..., adjoint=True)``, :mod:`jaxrb.physics.adjoint`; only where the
scene's model has one: tumble and box_drop_penalty, not the impulse scenes).
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import jax
import jax.numpy as jnp

import jaxrb as rb
from jaxrb.physics import adjoint
from jaxrb.bench.report import fmt_fixed, markdown_table
from jaxrb.bench.timing import compile_jitted, time_alternated
from jaxrb.physics.step import _segment_length
from jaxrb.model.options import grouped


def box_bounce_scene():
    scene = rb.Scene(dim=3)
    scene.add_plane(restitution=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.5), angvel=(1.0, 2.0, 0.5),
                   restitution=0.5)
    return scene


def tumble_scene():
    scene = rb.Scene(dim=3, gravity=(0.0, 0.0, 0.0))
    scene.add_body(None, mass=1.0, inertia=(0.3, 0.35, 0.4), angvel=(0.1, 15.0, 0.1))
    return scene


#: name -> (scene factory, description, build settings)
SCENES = {
    "box_bounce": (box_bounce_scene, "box half 0.1 m dropped from 0.5 m with a tumble, e=0.5, impulse",
                   dict(dt=1 / 60, substeps=4, contact="impulse")),
    "box_bounce_jacobi": (box_bounce_scene, "the same bounce, impulse with the Jacobi solver",
                          dict(dt=1 / 60, substeps=4, contact="impulse", solver="jacobi")),
    "box_drop_penalty": (box_bounce_scene, "the same box and drop, penalty contact, dt = 2 ms",
                         dict(dt=2e-3, substeps=1, contact="penalty")),
    "tumble": (tumble_scene, "torque-free tumbling body, semi-implicit",
               dict(dt=1 / 240, integrator="semi_implicit")),
}

#: How reverse mode is taken: method -> rollout keywords (see the module docs).
METHODS = {"autodiff": dict(), "checkpoint": dict(checkpoint=True), "adjoint": dict(adjoint=True)}

#: Scenes without an adjoint whose autodiff gradient is timed at
#: ``gradient_batch`` worlds too: the Jacobi solver, the impulse scheme meant
#: for batches. The sequential solver's gradient at 1 024 worlds would take
#: minutes of the report a call, so box_bounce is timed at one world only.
BATCHED_AUTODIFF = ("box_bounce_jacobi",)

#: What :func:`run` does by default: the full run of ``python -m jaxrb.bench``
#: (its quick mode overrides some).
#: ``gradient_methods``: keys of :data:`METHODS` to time and size (``adjoint``
#: only where the scene has one). ``gradient_batch``: worlds of the batched time
#: rows (None: none), autodiff and adjoint only (see :data:`BATCHED_AUTODIFF`).
#: ``gradient_rounds``: timed rounds of forward and gradient at most, fewer
#: (at least 3) once :data:`TIME_BUDGET_S` is spent. A one-world round takes
#: milliseconds, and on a noisy host the median of 5 of them was no figure:
#: ten medians of 5 in one process spread over 2.3-3.8x for the penalty box
#: drop's adjoint, whose medians of 201 read 3.2-3.8x in three processes
#: (docs/design.md, 'Reverse mode').
DEFAULT_SETTINGS = dict(gradient_scenes=("tumble", "box_bounce", "box_bounce_jacobi", "box_drop_penalty"),
                        gradient_methods=tuple(METHODS), gradient_memory_steps=(1000, 10000),
                        gradient_time_steps=1000, gradient_batch=1024,
                        gradient_rounds=201, gradient_dtype="float32")

#: Seconds of timed calls after which :func:`gradient_time` stops adding rounds.
TIME_BUDGET_S = 5.0

#: The issue's target for grad / forward.
TARGET_RATIO = 3.0


def all_finite(tree) -> bool:
    """Whether every entry of every array in ``tree`` (a gradient) is finite."""
    return all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in jax.tree_util.tree_leaves(tree))


def trajectory_loss(trajectory) -> jax.Array:
    """Mean squares of pos, vel, angvel (and quat's vector part in 3D) over a trajectory.

    Args:
        trajectory: State with a leading time axis (T, n, ...).

    Returns:
        () scalar.
    """
    loss = jnp.mean(trajectory.pos ** 2) + jnp.mean(trajectory.vel ** 2) + jnp.mean(trajectory.angvel ** 2)
    if trajectory.quat is not None:
        loss = loss + jnp.mean(trajectory.quat[..., 1:] ** 2)
    return loss


def make_loss(step: Callable, num_steps: int, method: str = "autodiff", batch: int = 1) -> Callable:
    """``loss(params, state)`` of a ``num_steps`` rollout (see :func:`trajectory_loss`).

    Args:
        step: from ``rb.make_step``.
        num_steps: T.
        method: a key of :data:`METHODS`.
        batch: 1, or the number of worlds ``state`` holds (leading axis): the
            loss is then the mean of theirs.
    """
    options = METHODS[method]

    def loss(params, state):
        return trajectory_loss(rb.rollout(step, state, params, num_steps, **options))

    if batch == 1:
        return loss
    return lambda params, states: jnp.mean(jax.vmap(loss, in_axes=(None, 0))(params, states))


def build(name: str, dtype="float32", batch: int = 1):
    """``(step, params, state)`` of scene ``name`` from :data:`SCENES`.

    ``batch`` > 1 stacks that many copies of the state (leading axis).
    """
    if name not in SCENES:
        raise ValueError(f"gradients: unknown scene {name!r}; valid scenes are: {', '.join(SCENES)}")
    factory, _, settings = SCENES[name]
    model, params, state = factory().build(**grouped(dict(settings, dtype=jnp.dtype(dtype))))
    if batch > 1:
        state = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), state)
    return rb.make_step(model), params, state


def methods_for(step, methods: Sequence[str]) -> list:
    """``methods`` less ``"adjoint"`` where ``step``'s model has no hand-written adjoint."""
    return [m for m in methods if m != "adjoint" or adjoint.supports(step.model)]


def _memory_row(name, num_steps, method, compiled, compile_s) -> dict:
    stats = compiled.memory_analysis()
    checkpoint = method == "checkpoint"
    return dict(kind="memory", scene=name, num_steps=num_steps, method=method, checkpoint=checkpoint,
                segment=_segment_length(num_steps, True) if checkpoint else None,
                temp_bytes=int(stats.temp_size_in_bytes),
                argument_bytes=int(stats.argument_size_in_bytes),
                output_bytes=int(stats.output_size_in_bytes),
                bytes_per_step=stats.temp_size_in_bytes / num_steps, compile_s=compile_s)


def gradient_memory(name: str, num_steps: int, method: str = "autodiff", dtype="float32") -> dict:
    """Compile the gradient of a ``num_steps`` rollout loss and read XLA's memory account.

    Returns:
        A row: ``kind="memory"``, ``scene``, ``num_steps``, ``method``,
        ``checkpoint`` (method == "checkpoint"), ``segment`` (checkpoint
        segment length in steps, or None), ``temp_bytes``,
        ``argument_bytes``, ``output_bytes``, ``bytes_per_step`` (temp / T)
        and ``compile_s``.
    """
    step, params, state = build(name, dtype)
    compiled, compile_s = compile_jitted(jax.grad(make_loss(step, num_steps, method)), params, state)
    return _memory_row(name, num_steps, method, compiled, compile_s)


def gradient_time(name: str, num_steps: int, repeats: int = 5, dtype="float32",
                  methods: Sequence[str] = ("autodiff", "checkpoint", "adjoint"), batch: int = 1,
                  budget_s: float = TIME_BUDGET_S, log=None) -> list:
    """Time the forward loss and its gradient over ``num_steps`` steps.

    For each method the forward and the gradient are timed in turn, call by
    call (:func:`jaxrb.bench.timing.time_alternated`): one warm-up round and
    up to ``repeats`` timed rounds, fewer (but at least 3) once ``budget_s``
    seconds of timed calls are spent. So each row's forward time is its own.
    Methods the scene has no adjoint for are skipped (:func:`methods_for`).

    Every gradient compiled here at one world also yields its memory row, so
    a caller that times T steps need not compile the same programs again.

    Returns:
        Rows: one ``kind="time"`` per method (``scene``, ``batch``,
        ``num_steps``, ``method``, ``checkpoint``, ``forward_compile_s``,
        ``forward_s``, ``grad_compile_s``, ``grad_s``, ``ratio`` =
        grad_s / forward_s, ``forward_temp_bytes``), then at one world the
        matching ``kind="memory"`` rows.
    """
    log = log or (lambda text: None)
    step, params, state = build(name, dtype, batch)
    forward, forward_compile_s = compile_jitted(make_loss(step, num_steps, batch=batch), params, state)
    forward_temp = int(forward.memory_analysis().temp_size_in_bytes)
    times, memories = [], []
    for method in methods_for(step, methods):
        grad, grad_compile_s = compile_jitted(jax.grad(make_loss(step, num_steps, method, batch)), params, state)
        (forward_s, _, value), (grad_s, _, gradient) = time_alternated(
            (forward, grad), params, state, repeats=repeats, budget_s=budget_s)
        if not bool(jnp.isfinite(value)):
            raise FloatingPointError(f"gradients bench {name}: non-finite loss {value}")
        if not all_finite(gradient):
            raise FloatingPointError(f"gradients bench {name}: non-finite gradient ({method})")
        times.append(dict(kind="time", scene=name, batch=batch, num_steps=num_steps, method=method,
                          checkpoint=method == "checkpoint", forward_compile_s=forward_compile_s,
                          forward_s=forward_s, grad_compile_s=grad_compile_s, grad_s=grad_s,
                          ratio=grad_s / forward_s, forward_temp_bytes=forward_temp))
        if batch == 1:
            memories.append(_memory_row(name, num_steps, method, grad, grad_compile_s))
        log(f"gradients {name:>10} batch {batch} T={num_steps} {method:>10}: forward {forward_s * 1e3:.2f} ms, "
            f"grad {grad_s * 1e3:.2f} ms (x{grad_s / forward_s:.2f}), grad compile {grad_compile_s:.1f} s")
    return times + memories


def run(settings: Optional[dict] = None, log=None) -> list:
    """Run the gradient benchmark; return its rows (dicts, see the functions above).

    Args:
        settings: keys of :data:`DEFAULT_SETTINGS` (missing ones take the
            default): ``gradient_scenes``, ``gradient_methods``, ``gradient_memory_steps`` (T
            values for memory), ``gradient_time_steps`` (T for timing, whose
            memory comes from the same compiled programs),
            ``gradient_batch``, ``gradient_rounds``, ``gradient_dtype``. Other keys
            are ignored, so the command line's whole settings dict can be
            passed.
        log: optional ``log(text)`` for progress.

    Returns:
        The ``"time"`` rows (one world, then ``gradient_batch`` worlds for
        scenes with an adjoint, autodiff and adjoint, and for
        :data:`BATCHED_AUTODIFF`, autodiff), then the ``"memory"``
        rows ordered by scene, T, method.
    """
    settings = {**DEFAULT_SETTINGS, **(settings or {})}
    unknown = sorted(set(settings["gradient_methods"]) - set(METHODS))
    if unknown:
        raise ValueError(f"gradients: unknown 'gradient_methods' {unknown}; valid: {', '.join(METHODS)}")
    log = log or (lambda text: None)
    time_steps, dtype = settings["gradient_time_steps"], settings["gradient_dtype"]
    times, memories = [], []
    for name in settings["gradient_scenes"]:
        timed = gradient_time(name, time_steps, repeats=settings["gradient_rounds"], dtype=dtype,
                              methods=settings["gradient_methods"], log=log)
        times += [row for row in timed if row["kind"] == "time"]
        memories += [row for row in timed if row["kind"] == "memory"]
        methods = [row["method"] for row in timed if row["kind"] == "time"]
        if settings["gradient_batch"] and ("adjoint" in methods or name in BATCHED_AUTODIFF):
            times += gradient_time(name, time_steps, repeats=settings["gradient_rounds"], dtype=dtype,
                                   methods=[m for m in methods if m in ("autodiff", "adjoint")],
                                   batch=settings["gradient_batch"], log=log)
        for num_steps in settings["gradient_memory_steps"]:
            if num_steps == time_steps:
                continue  # measured above from the timed programs
            for method in methods:
                row = gradient_memory(name, num_steps, method, dtype)
                log(f"gradients {name:>10} T={num_steps} {method:>10}: temp "
                    f"{row['temp_bytes'] / 1e6:.2f} MB, compile {row['compile_s']:.1f} s")
                memories.append(row)
    memories.sort(key=lambda row: (settings["gradient_scenes"].index(row["scene"]), row["num_steps"],
                                   list(METHODS).index(row["method"])))
    return times + memories


def target_rows(rows: Sequence[dict]) -> list:
    """Per scene and batch, the cheapest gradient against :data:`TARGET_RATIO`.

    Returns:
        Dicts: ``scene``, ``batch``, ``method`` (the cheapest), ``ratio``,
        ``passed`` (ratio ≤ the target).
    """
    best = {}
    for row in rows:
        if row["kind"] == "time":
            key = (row["scene"], row["batch"])
            if key not in best or row["ratio"] < best[key]["ratio"]:
                best[key] = row
    return [dict(scene=row["scene"], batch=row["batch"], method=row["method"], ratio=row["ratio"],
                 passed=row["ratio"] <= TARGET_RATIO) for row in best.values()]


def fmt_bytes(value) -> str:
    """Bytes in binary units: ``fmt_bytes(3.3e6) -> '3.15 MiB'``."""
    value = float(value)
    for factor, unit in ((2 ** 30, "GiB"), (2 ** 20, "MiB"), (2 ** 10, "KiB")):
        if abs(value) >= factor:
            return f"{value / factor:.2f} {unit}"
    return f"{value:.0f} B"


def markdown(rows: Sequence[dict]) -> str:
    """Markdown tables (time, target, memory) from the rows of :func:`run`."""
    times = [row for row in rows if row["kind"] == "time"]
    memories = [row for row in rows if row["kind"] == "memory"]
    autodiff = {(row["scene"], row["num_steps"]): row["temp_bytes"] for row in memories
                if row["method"] == "autodiff"}
    parts = []
    if times:
        parts.append(markdown_table(
            ["scene", "batch", "T", "method", "forward compile (s)", "forward run (ms)", "grad compile (s)",
             "grad run (ms)", "grad / forward"],
            [[row["scene"], row["batch"], row["num_steps"], row["method"],
              fmt_fixed(row["forward_compile_s"], 2), fmt_fixed(1e3 * row["forward_s"], 2),
              fmt_fixed(row["grad_compile_s"], 2), fmt_fixed(1e3 * row["grad_s"], 2),
              fmt_fixed(row["ratio"], 2) + "×"] for row in times]))
        parts.append(markdown_table(
            ["scene", "batch", f"target: grad / forward ≤ {TARGET_RATIO:g}×", "status"],
            [[row["scene"], row["batch"], f"{row['ratio']:.2f}× ({row['method']})",
              "**PASS**" if row["passed"] else "**MISSED**"] for row in target_rows(rows)]))
    if memories:
        parts.append(markdown_table(
            ["scene", "T", "method", "segment", "temp memory", "bytes / step", "vs autodiff", "compile (s)"],
            [[row["scene"], row["num_steps"], row["method"],
              row["segment"] if row["segment"] else "—", fmt_bytes(row["temp_bytes"]),
              fmt_fixed(row["bytes_per_step"], 0),
              fmt_fixed(row["temp_bytes"] / autodiff[(row["scene"], row["num_steps"])], 3)
              if (row["scene"], row["num_steps"]) in autodiff else "—",
              fmt_fixed(row["compile_s"], 1)] for row in memories]))
    return "\n\n".join(parts)


def gradients_section(settings: Optional[dict] = None, log=None):
    """Run the benchmark; return ``(markdown, rows)`` like the other sections."""
    settings = {**DEFAULT_SETTINGS, **(settings or {})}
    rows = run(settings, log)
    text = [
        "Scenes: " + "; ".join(f"**{n}**: {SCENES[n][1]}" for n in settings["gradient_scenes"]) + ". "
        f"{settings['gradient_dtype']}; `jax.grad` with respect to all Params of the mean squared state over "
        "the whole rollout (`rb.rollout`, every step kept). *grad / forward*: median run time of the "
        f"jitted gradient over that of the jitted forward loss, T = {settings['gradient_time_steps']} "
        "(target ≤ 3×), the two called in turn so they share the host's fast and slow spells (each "
        f"row times its own forward), up to {settings['gradient_rounds']} rounds after a warm-up, fewer "
        f"(at least 3) once {TIME_BUDGET_S:g} s of calls are spent. *method*: `autodiff` is `rb.rollout`'s "
        "reverse mode, `checkpoint` the same with `checkpoint=True`, `adjoint` is "
        "`rb.rollout(..., adjoint=True)`, the hand-written adjoint of 3D semi-implicit free bodies and of "
        "penalty contact against planes (`jaxrb.physics.adjoint`, "
        "`jaxrb.physics.plane_penalty_adjoint`; none for impulse contact). *batch*: worlds "
        "(`vmap` over the initial state, Params shared, the loss their mean). *temp memory*: "
        "`temp_size_in_bytes` of XLA's `memory_analysis()` of the compiled gradient (scratch besides "
        "arguments and outputs, mostly what is kept for the backward pass: `rb.rollout` "
        "rematerialises each step, so about a State a step); *segment*: steps per `jax.checkpoint` "
        "segment (`checkpoint=True`, about √T).",
        "",
        markdown(rows),
    ]
    return "\n".join(text), rows
