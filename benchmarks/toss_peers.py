"""MuJoCo and Bullet on the real cube tosses, with the publishers' fitted parameters.

Acosta et al. (RA-L 2022) fitted each simulator to the DAIR Lab cube tosses;
their values are in ``examples/cube_tosses/DATA.md``. Each peer here
runs every toss from the same free-flight initial state that jaxrb gets
(estimated from the raw data, as the publishers did: no length calibration),
10 substeps per 1/148 s sample, and returns poses at the samples, scored by
the same metric (:mod:`jaxrb.fit.evaluate`). Both are optional (the ``peers``
extra): a missing one is reported as such.
"""

from __future__ import annotations

import os

import numpy as np

SUBSTEPS = 10
CUBE_HALF_WIDTH = 0.0524
CUBE_MASS = 0.37
CUBE_INERTIA = 8.1e-4
#: MuJoCo: stiffness and damping x3 at evaluation, as the publishers scored it.
MUJOCO = {"stiffness": 3294.16 * 3, "damping": 45.105 * 3, "friction": 0.21807}
#: Bullet: set on the plane; the cube keeps lateral friction 0.5 and pybullet multiplies the two.
BULLET = {"stiffness": 1783.77, "damping": 27.222, "plane_friction": 0.35804, "cube_friction": 0.5}


def _mujoco_xml(sample_dt: float) -> str:
    p = MUJOCO
    size = CUBE_HALF_WIDTH
    return f"""<mujoco model="cube_toss">
  <option timestep="{sample_dt / SUBSTEPS!r}" gravity="0 0 -9.81"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1" solref="-{p['stiffness']!r} -{p['damping']!r}"
          friction="{p['friction']!r} .001 .001"/>
    <body name="cube" pos="0 0 0.5">
      <freejoint/>
      <inertial pos="0 0 0" mass="{CUBE_MASS}" diaginertia="{CUBE_INERTIA} {CUBE_INERTIA} {CUBE_INERTIA}"/>
      <geom type="box" size="{size} {size} {size}" friction="{p['friction']!r} .001 .001"/>
    </body>
  </worldbody>
</mujoco>"""


def _rotate_inverse(quat, vector):
    w, axis = quat[0], -quat[1:]
    twice = 2.0 * np.cross(axis, vector)
    return vector + w * twice + np.cross(axis, twice)


def simulate_mujoco(initial: dict, num_samples: int, sample_dt: float):
    """Run every toss in MuJoCo (C, ``mujoco`` package).

    Args:
        initial: ``pos``, ``vel``, ``angvel`` (K, 1, 3) world frame and ``quat`` (K, 1, 4).
        num_samples: T samples to return per toss (sample 0 the initial state).
        sample_dt: sample spacing (s).

    Returns:
        (pos (K, T, 1, 3), quat (K, T, 1, 4)).
    """
    import mujoco

    model = mujoco.MjModel.from_xml_string(_mujoco_xml(sample_dt))
    data = mujoco.MjData(model)
    count = initial["pos"].shape[0]
    pos, quat = np.empty((count, num_samples, 1, 3)), np.empty((count, num_samples, 1, 4))
    for k in range(count):
        mujoco.mj_resetData(model, data)
        q = initial["quat"][k, 0]
        data.qpos[:3], data.qpos[3:7] = initial["pos"][k, 0], q
        # a free joint's angular velocity is in the body frame
        data.qvel[:3], data.qvel[3:6] = initial["vel"][k, 0], _rotate_inverse(q, initial["angvel"][k, 0])
        for t in range(num_samples):
            if t:
                mujoco.mj_step(model, data, nstep=SUBSTEPS)
            pos[k, t, 0], quat[k, t, 0] = data.qpos[:3], data.qpos[3:7]
    return pos, quat


def simulate_bullet(initial: dict, num_samples: int, sample_dt: float, urdf_folder: str):
    """Run every toss in Bullet (``pybullet``) with the publishers' URDF files.

    Args:
        initial, num_samples, sample_dt: as for :func:`simulate_mujoco`.
        urdf_folder: the folder holding ``cube.urdf`` and ``plane.urdf``.

    Returns:
        (pos (K, T, 1, 3), quat (K, T, 1, 4)), quaternions (w, x, y, z).
    """
    import pybullet

    client = pybullet.connect(pybullet.DIRECT)
    try:
        pybullet.setGravity(0, 0, -9.81, physicsClientId=client)
        pybullet.setTimeStep(sample_dt / SUBSTEPS, physicsClientId=client)
        plane = pybullet.loadURDF(os.path.join(urdf_folder, "plane.urdf"), physicsClientId=client)
        cube = pybullet.loadURDF(os.path.join(urdf_folder, "cube.urdf"), physicsClientId=client)
        pybullet.changeDynamics(plane, -1, contactStiffness=BULLET["stiffness"], contactDamping=BULLET["damping"],
                                lateralFriction=BULLET["plane_friction"], physicsClientId=client)
        pybullet.changeDynamics(cube, -1, lateralFriction=BULLET["cube_friction"], physicsClientId=client)
        count = initial["pos"].shape[0]
        pos, quat = np.empty((count, num_samples, 1, 3)), np.empty((count, num_samples, 1, 4))
        for k in range(count):
            w, x, y, z = initial["quat"][k, 0]
            pybullet.resetBasePositionAndOrientation(cube, initial["pos"][k, 0].tolist(), [x, y, z, w],
                                                     physicsClientId=client)
            pybullet.resetBaseVelocity(cube, initial["vel"][k, 0].tolist(), initial["angvel"][k, 0].tolist(),
                                       physicsClientId=client)
            for t in range(num_samples):
                if t:
                    for _ in range(SUBSTEPS):
                        pybullet.stepSimulation(physicsClientId=client)
                p, (x, y, z, w) = pybullet.getBasePositionAndOrientation(cube, physicsClientId=client)
                pos[k, t, 0], quat[k, t, 0] = p, (w, x, y, z)
        return pos, quat
    finally:
        pybullet.disconnect(client)
