"""MuJoCo and Bullet on the real elbow tosses, each fitted on training tosses.

The elbow data (``examples/elbow_tosses``, its ``DATA.md``) has no
publishers' fitted simulator parameters, so each peer is fitted here by one
procedure: a coarse grid, then Nelder–Mead from the grid's best point, over
friction and contact softness, 10 substeps a 1/148 s sample, minimising the
protocol's mean position error over the training tosses (:func:`fit_peer`).
Both run the publishers' URDF geometry and inertia (isotropic 6.167e-4 kg m²,
not a solid block's), gravity −9.81, a table plane at z = 0, no link–link
contact, from the same initial states as jaxrb
(:func:`jaxrb.fit.evaluate.prepare_replay`: ``replay.initial.qpos``/``qvel``,
MuJoCo's layout) and return each link's box centre (= centre of mass) and
link-frame orientation at every sample, for
:func:`jaxrb.fit.evaluate.trajectory_errors`. Both engines are optional (the
``peers`` extra): a missing one raises ImportError when its function runs.

Parameters (every value positive; :func:`fit_peer` searches them in log space):

* MuJoCo (:func:`simulate_mujoco`): ``friction``, the sliding friction of
  both the table and the blocks (MuJoCo takes the larger of a pair's, so
  this is the contact's); ``timeconst`` (s) and ``dampratio``, the contacts'
  ``solref`` in MuJoCo's default (time constant, damping ratio) form.
  ``solimp``, ``condim`` 3 and the torsional/rolling coefficients stay
  MuJoCo's defaults. MuJoCo raises a time constant below 2 timesteps
  (1.35 ms here) to that. Defaults (:data:`MUJOCO_DEFAULTS`): friction 1,
  solref (0.02, 1).
* Bullet (:func:`simulate_bullet`): ``friction``, the table's lateral
  friction with the links' set to 1 (pybullet multiplies the two, so this is
  the contact's); ``stiffness`` (N/m) and ``damping`` (N s/m), the table's
  ``contactStiffness``/``contactDamping`` (the links keep theirs unset:
  pybullet puts a pair's stiffnesses in series, the unset one infinite, and
  adds the dampings, an unset one 0.1). A key that is missing (or None) keeps
  pybullet's default: the URDF loader's lateral friction 0.5 on each link
  and 0.5 on the table (0.25 combined), rigid contacts (no stiffness), which
  is :data:`BULLET_DEFAULTS`. In both, pybullet's default linear and angular
  damping of multibodies (0.04, a drag in flight) is set to 0, and the
  hinge's default velocity motor is switched off (force 0).
"""

from __future__ import annotations

import itertools
import os
import time

import numpy as np

from jaxrb.fit.measured import rotate_vectors

#: The data's folder (``elbow_tosses.npz``, ``models/contactnets_elbow.urdf``), or ``JAXRB_ELBOW_TOSSES``.
DEFAULT_FOLDER = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "examples",
                              "elbow_tosses")
SUBSTEPS = 10
#: The URDF's links: mass (kg), isotropic inertia (kg m²), box half extents (m).
LINK_MASS = 0.37
LINK_INERTIA = 6.167e-4
HALF_EXTENTS = (0.05, 0.025, 0.025)
#: Link 2's box centre in its frame, and the hinge's origin in link 1's frame (axis +y).
LINK2_CENTRE = (0.035, 0.0, 0.0)
HINGE_ORIGIN = (-0.035, 0.06, 0.0)
GRAVITY = 9.81
#: MuJoCo's own defaults (geom friction 1, solref 0.02 1).
MUJOCO_DEFAULTS = {"friction": 1.0, "timeconst": 0.02, "dampratio": 1.0}
#: pybullet's defaults: nothing set (links 0.5, table 0.5, multiplied: 0.25; rigid contacts).
BULLET_DEFAULTS: dict = {}
#: Coarse grids for :func:`fit_peer` (values, searched in log space).
MUJOCO_GRID = {"friction": (0.1, 0.2, 0.4, 0.8), "timeconst": (0.002, 0.005, 0.01, 0.02, 0.05),
               "dampratio": (0.5, 1.0, 2.0)}
BULLET_GRID = {"friction": (0.1, 0.2, 0.4, 0.8), "stiffness": (1e3, 3e3, 1e4, 3e4, 1e5),
               "damping": (10.0, 30.0, 100.0, 300.0)}
#: What a failed run (non-finite poses) scores in :func:`fit_peer`.
FAILED_ERROR = 1e3


def data_paths() -> tuple:
    """Where the elbow tosses are: the folder named by ``JAXRB_ELBOW_TOSSES``, else :data:`DEFAULT_FOLDER`.

    Returns:
        (path of ``elbow_tosses.npz``, path of ``models/contactnets_elbow.urdf``).
    """
    folder = os.environ.get("JAXRB_ELBOW_TOSSES", DEFAULT_FOLDER)
    return os.path.join(folder, "elbow_tosses.npz"), os.path.join(folder, "models", "contactnets_elbow.urdf")


def mujoco_xml(sample_dt: float, parameters: dict, table: bool = True) -> str:
    """The elbow as MJCF text: a free joint on link 1, the hinge, and (optionally) the table.

    Args:
        sample_dt: sample spacing (s); the timestep is ``sample_dt / SUBSTEPS``.
        parameters: ``friction``, ``timeconst``, ``dampratio`` (module docstring).
        table: False leaves the table out (free flight).

    Returns:
        The MJCF text.
    """
    contact = (f'friction="{float(parameters["friction"])!r} 0.005 0.0001" '
               f'solref="{float(parameters["timeconst"])!r} {float(parameters["dampratio"])!r}"')
    size = " ".join(repr(h) for h in HALF_EXTENTS)
    inertia = f'mass="{LINK_MASS}" diaginertia="{LINK_INERTIA} {LINK_INERTIA} {LINK_INERTIA}"'
    centre = " ".join(repr(x) for x in LINK2_CENTRE)
    floor = f'<geom name="table" type="plane" size="5 5 0.1" {contact}/>' if table else ""
    return f"""<mujoco model="elbow">
  <option timestep="{sample_dt / SUBSTEPS!r}" gravity="0 0 -{GRAVITY}"/>
  <worldbody>
    {floor}
    <body name="elbow_1" pos="0 0 0">
      <freejoint name="base"/>
      <inertial pos="0 0 0" {inertia}/>
      <geom name="block_1" type="box" size="{size}" {contact}/>
      <body name="elbow_2" pos="{' '.join(repr(x) for x in HINGE_ORIGIN)}">
        <joint name="hinge_1_to_2" type="hinge" axis="0 1 0"/>
        <inertial pos="{centre}" {inertia}/>
        <geom name="block_2" type="box" pos="{centre}" size="{size}" {contact}/>
      </body>
    </body>
  </worldbody>
  <contact><exclude body1="elbow_1" body2="elbow_2"/></contact>
</mujoco>"""


def simulate_mujoco(qpos0, qvel0, num_samples: int, sample_dt: float, parameters: dict, *, table: bool = True):
    """Run every toss in MuJoCo (C, ``mujoco`` package), 10 Euler steps a sample.

    Args:
        qpos0: (K, 8) initial coordinates (link 1's origin, its quaternion w, x, y, z, the hinge angle).
        qvel0: (K, 7) initial velocities (link 1's world-frame linear and body-frame angular
            velocity, the hinge rate): MuJoCo's free-joint layout.
        num_samples: T samples to return per toss (sample 0 the initial state).
        sample_dt: sample spacing (s).
        parameters: ``friction``, ``timeconst``, ``dampratio`` (module docstring).
        table: False simulates free flight.

    Returns:
        (pos (K, T, 2, 3), quat (K, T, 2, 4)): each link's box centre and link-frame orientation
        (w, x, y, z). A toss on which MuJoCo gave up (its bad-acceleration warning, after
        which it resets the state) is NaN from there on.
    """
    import mujoco

    model = mujoco.MjModel.from_xml_string(mujoco_xml(sample_dt, parameters, table))
    data = mujoco.MjData(model)
    bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) for name in ("elbow_1", "elbow_2")]
    qpos0, qvel0 = np.asarray(qpos0, np.float64), np.asarray(qvel0, np.float64)
    count = qpos0.shape[0]
    pos, quat = np.full((count, num_samples, 2, 3), np.nan), np.full((count, num_samples, 2, 4), np.nan)
    bad = int(mujoco.mjtWarning.mjWARN_BADQACC)
    for k in range(count):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = qpos0[k], qvel0[k]
        for t in range(num_samples):
            if t:
                mujoco.mj_step(model, data, nstep=SUBSTEPS)
                if data.warning[bad].number:
                    break
            mujoco.mj_kinematics(model, data)  # mj_step leaves the poses of the step's start
            pos[k, t], quat[k, t] = data.xipos[bodies], data.xquat[bodies]
    return pos, quat


def simulate_bullet(qpos0, qvel0, num_samples: int, sample_dt: float, parameters: dict, urdf_path: str, *,
                    table: bool = True, spacing: float = 20.0):
    """Run every toss in Bullet (``pybullet``, DIRECT) with the publishers' URDF, 10 steps a sample.

    All K tosses run in one world, each elbow shifted by its own horizontal
    offset (``spacing`` apart on a grid, far beyond a toss's 2 m of travel)
    over the one infinite table: separate islands, solved independently, at
    one ``stepSimulation`` call per step for all of them.

    Args:
        qpos0, qvel0, num_samples, sample_dt: as for :func:`simulate_mujoco`.
        parameters: ``friction``, ``stiffness``, ``damping``; missing or None keeps pybullet's
            default (module docstring).
        urdf_path: ``contactnets_elbow.urdf`` (box collision geometry).
        table: False simulates free flight.
        spacing: distance (m) between the tosses' offsets.

    Returns:
        (pos (K, T, 2, 3), quat (K, T, 2, 4)): as for :func:`simulate_mujoco`, quaternions w, x, y, z.
    """
    import pybullet

    qpos0, qvel0 = np.asarray(qpos0, np.float64), np.asarray(qvel0, np.float64)
    count = qpos0.shape[0]
    side = int(np.ceil(np.sqrt(count)))
    offsets = np.zeros((count, 3))
    offsets[:, 0], offsets[:, 1] = spacing * (np.arange(count) % side), spacing * (np.arange(count) // side)
    angvel = rotate_vectors(qpos0[:, 3:7], qvel0[:, 3:6])  # pybullet wants it in the world frame
    get = lambda name: parameters.get(name)  # noqa: E731
    client = pybullet.connect(pybullet.DIRECT)
    try:
        pybullet.setGravity(0, 0, -GRAVITY, physicsClientId=client)
        pybullet.setPhysicsEngineParameter(fixedTimeStep=sample_dt / SUBSTEPS, physicsClientId=client)
        if table:
            plane = pybullet.createMultiBody(0, pybullet.createCollisionShape(pybullet.GEOM_PLANE,
                                                                              physicsClientId=client),
                                             physicsClientId=client)
            if get("friction") is not None:
                pybullet.changeDynamics(plane, -1, lateralFriction=float(get("friction")), physicsClientId=client)
            if get("stiffness") is not None or get("damping") is not None:
                if get("stiffness") is None or get("damping") is None:
                    raise ValueError("simulate_bullet: give both stiffness and damping, or neither")
                pybullet.changeDynamics(plane, -1, contactStiffness=float(get("stiffness")),
                                        contactDamping=float(get("damping")), physicsClientId=client)
        elbows = []
        for k in range(count):
            w, x, y, z = qpos0[k, 3:7]
            elbow = pybullet.loadURDF(urdf_path, (qpos0[k, 0:3] + offsets[k]).tolist(), [x, y, z, w],
                                      flags=pybullet.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
            pybullet.changeDynamics(elbow, -1, linearDamping=0.0, angularDamping=0.0, physicsClientId=client)
            pybullet.setJointMotorControl2(elbow, 0, pybullet.VELOCITY_CONTROL, targetVelocity=0.0, force=0.0,
                                           physicsClientId=client)
            if get("friction") is not None:
                for link in (-1, 0):
                    pybullet.changeDynamics(elbow, link, lateralFriction=1.0, physicsClientId=client)
            pybullet.resetBaseVelocity(elbow, qvel0[k, 0:3].tolist(), angvel[k].tolist(), physicsClientId=client)
            pybullet.resetJointState(elbow, 0, float(qpos0[k, 7]), float(qvel0[k, 6]), physicsClientId=client)
            elbows.append(elbow)
        pos, quat = np.empty((count, num_samples, 2, 3)), np.empty((count, num_samples, 2, 4))
        for t in range(num_samples):
            if t:
                for _ in range(SUBSTEPS):
                    pybullet.stepSimulation(physicsClientId=client)
            for k, elbow in enumerate(elbows):
                # the base is link 1's inertial frame, which is its frame (inertial origin 0)
                p1, q1 = pybullet.getBasePositionAndOrientation(elbow, physicsClientId=client)
                # link 2: linkWorldPosition is its centre of mass, linkWorldOrientation its inertial
                # frame's, unrotated from its link frame in this URDF
                p2, q2 = pybullet.getLinkState(elbow, 0, computeForwardKinematics=True,
                                               physicsClientId=client)[:2]
                pos[k, t] = np.array([p1, p2]) - offsets[k]
                quat[k, t] = [(q1[3], q1[0], q1[1], q1[2]), (q2[3], q2[0], q2[1], q2[2])]
        return pos, quat
    finally:
        pybullet.disconnect(client)


def score_peer(simulate, qpos0, qvel0, trajectories, sizes, parameters: dict) -> tuple:
    """Run a peer on K tosses and score it by the protocol.

    Args:
        simulate: as for :func:`fit_peer`.
        qpos0: (K, 8) initial coordinates.
        qvel0: (K, 7) initial velocities.
        trajectories: the K measured tosses, cut to start at those states.
        sizes: (2,) the links' sizes.
        parameters: the peer's parameters.

    Returns:
        (position (K,) in % of size, rotation (K,) in degrees), NumPy arrays (NaN for a failed run).
    """
    from jaxrb.fit.evaluate import trajectory_errors

    pos, quat = simulate(qpos0, qvel0, trajectories.num_samples, trajectories.sample_dt, parameters)
    position, rotation = trajectory_errors(pos, quat, trajectories, sizes)
    return np.asarray(position, np.float64), np.asarray(rotation, np.float64)


class _Spent(Exception):
    """Nelder–Mead's evaluations are used up."""


def mean_position_error(pos, quat, trajectories, sizes) -> float:
    """The protocol's mean position error over the tosses (% of size); :data:`FAILED_ERROR` if any toss failed.

    Args:
        pos: (K, T, 2, 3) simulated box centres.
        quat: (K, T, 2, 4) simulated orientations.
        trajectories: the K measured tosses (``replay.trajectories`` or a subset).
        sizes: (2,) the links' sizes (``replay.sizes``).

    Returns:
        The mean over tosses of :func:`jaxrb.fit.evaluate.trajectory_errors`' position error.
    """
    from jaxrb.fit.evaluate import trajectory_errors

    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
        return FAILED_ERROR
    position, _ = trajectory_errors(pos, quat, trajectories, sizes)
    value = float(np.mean(np.asarray(position)))
    return value if np.isfinite(value) else FAILED_ERROR


def fit_peer(simulate, qpos0, qvel0, trajectories, sizes, grid: dict, log=print, *, max_evaluations: int = 60,
             tolerance: float = 0.01):
    """Fit a peer's parameters: coarse grid, then Nelder–Mead from its best point, in log space.

    Minimises :func:`mean_position_error` over the given (training) tosses.
    Every parameter with more than one grid value is searched; one with a
    single value is held at it. Nelder–Mead (``scipy.optimize.minimize``)
    works on the logarithms, its first simplex one half grid spacing along
    each axis from the grid's best point.

    Args:
        simulate: ``simulate(qpos0, qvel0, num_samples, sample_dt, parameters) -> (pos, quat)``,
            e.g. :func:`simulate_mujoco` or ``functools.partial(simulate_bullet, urdf_path=...)``.
        qpos0: (K, 8) initial coordinates of the training tosses.
        qvel0: (K, 7) their initial velocities.
        trajectories: the K measured tosses, cut to start at those states (sample 0).
        sizes: (2,) the links' sizes.
        grid: ``{name: values}``, all positive.
        log: called with one line of text per grid's best and per Nelder–Mead improvement (None: silent).
        max_evaluations: Nelder–Mead's limit on simulations after the grid (a hard limit: the
            search stops at it, mid-iteration if need be).
        tolerance: Nelder–Mead's ``xatol`` (log units) and ``fatol`` (% of size).

    Returns:
        (parameters dict, its training error (%), evaluations (grid and Nelder–Mead), seconds).
    """
    from scipy.optimize import minimize

    log = log or (lambda text: None)
    began = time.perf_counter()
    names = list(grid)
    free = [name for name in names if len(grid[name]) > 1]
    history = []

    def error(parameters):
        pos, quat = simulate(qpos0, qvel0, trajectories.num_samples, trajectories.sample_dt, parameters)
        value = mean_position_error(pos, quat, trajectories, sizes)
        history.append((value, dict(parameters)))
        return value

    for values in itertools.product(*(grid[name] for name in names)):
        error(dict(zip(names, map(float, values))))
    grid_size = len(history)
    best_value, best = min(history, key=lambda item: item[0])
    log(f"grid: {len(history)} points, best {best_value:.2f} % at {_text(best)}")
    if free and max_evaluations > 0:
        start = np.log([best[name] for name in free])
        steps = [0.5 * float(np.median(np.diff(np.log(np.sort(grid[name]))))) for name in free]
        simplex = np.vstack([start] + [start + step * np.eye(len(free))[i] for i, step in enumerate(steps)])
        record = [best_value]

        def objective(x):
            if len(history) >= grid_size + max_evaluations:
                raise _Spent
            value = error(dict(best, **{name: float(np.exp(v)) for name, v in zip(free, x)}))
            if value < record[0]:
                record[0] = value
                log(f"  Nelder-Mead {len(history)}: {value:.2f} % at {_text(history[-1][1])}")
            return value

        try:
            minimize(objective, start, method="Nelder-Mead",
                     options={"initial_simplex": simplex, "maxfev": max_evaluations, "xatol": tolerance,
                              "fatol": tolerance})
        except _Spent:
            pass
    best_value, best = min(history, key=lambda item: item[0])
    seconds = time.perf_counter() - began
    log(f"fitted: {best_value:.2f} % at {_text(best)} ({len(history)} evaluations, {seconds:.0f} s)")
    return best, best_value, len(history), seconds


def _text(parameters: dict) -> str:
    """``name=value`` pairs, 4 significant digits."""
    return ", ".join(f"{name}={value:.4g}" for name, value in parameters.items())
