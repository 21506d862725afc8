"""MJCF and URDF through MuJoCo's compiler (jaxrb.files.mjcf), checked against MuJoCo itself.

Gymnasium's MuJoCo models (its ``envs/mujoco/assets`` folder) load with MuJoCo's qpos/qvel
layout, their bodies sit where mj_kinematics puts them, and contact-free steps match MuJoCo's
Euler (and RK4) to rounding; what jaxrb cannot represent is an error naming the element, what
it only approximates a warning; contact filtering is MuJoCo's pair for pair. Everything runs in
float64 (conftest enables x64; scenes are built with ``dtype="float64"``). Compiled functions:
one rollout per stepping test and one for the resting box; the rest builds and converts only.
"""

import copy
import importlib.util
import json
import pathlib

import jax
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.files import mjcf
from jaxrb.files import scenefile as sf
from jaxrb.physics.joints.tree import rotation_matrix
from conftest import assert_same_build

mujoco = pytest.importorskip("mujoco")

EXAMPLE = pathlib.Path(__file__).resolve().parent.parent / "examples" / "box_drop.xml"
_GYM = importlib.util.find_spec("gymnasium")
GYM_ASSETS = pathlib.Path(_GYM.submodule_search_locations[0]) / "envs" / "mujoco" / "assets" if _GYM else None
GYM_MODELS = ("inverted_pendulum", "inverted_double_pendulum", "hopper", "walker2d", "ant", "reacher")
F64 = dict(dtype="float64")
JOINT_TYPES = {0: "free", 1: "ball", 2: "slide", 3: "hinge"}



def mujoco_ids(mj_model, model):
    """MuJoCo body id of each jaxrb body (the importer names an unnamed body '#<id>')."""
    return [int(name[1:]) if name.startswith("#") else mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, name)
            for name in model.names]


def random_coordinates(mj_model, rng):
    """A random qpos (unit quaternions for free and ball joints, hinges and slides about qpos0) and qvel."""
    qpos = mj_model.qpos0.copy()
    for joint in range(mj_model.njnt):
        start, kind = mj_model.jnt_qposadr[joint], mj_model.jnt_type[joint]
        if kind == 0:
            qpos[start:start + 3] += rng.normal(size=3)
        if kind in (0, 1):
            turn = rng.normal(size=4)
            qpos[start + 3 * (kind == 0):start + 3 * (kind == 0) + 4] = turn / np.linalg.norm(turn)
        else:
            qpos[start] += 0.5 * rng.normal()
    return qpos, rng.normal(size=mj_model.nv)


def assert_poses_match(mj_model, mj_data, model, state, atol=1e-9):
    """Centres of mass (xipos), body frames (xquat, up to sign) and velocities (at the centre of mass,
    world frame) of every jaxrb body equal MuJoCo's."""
    ids = mujoco_ids(mj_model, model)
    np.testing.assert_allclose(np.asarray(state.pos), mj_data.xipos[ids], atol=atol, rtol=0)
    quat = np.asarray(state.quat)
    sign = np.sign(np.sum(quat * mj_data.xquat[ids], axis=1, keepdims=True))
    np.testing.assert_allclose(quat * sign, mj_data.xquat[ids], atol=atol, rtol=0)
    velocity = np.zeros(6)
    for index, body in enumerate(ids):
        mujoco.mj_objectVelocity(mj_model, mj_data, mujoco.mjtObj.mjOBJ_BODY, body, velocity, 0)
        np.testing.assert_allclose(np.asarray(state.angvel[index]), velocity[:3], atol=atol, rtol=0)
        np.testing.assert_allclose(np.asarray(state.vel[index]), velocity[3:], atol=atol, rtol=0)


@pytest.fixture(scope="module")
def gym():
    """name -> (MuJoCo model, SceneFile) of gymnasium's models, each read once for the module."""
    cache = {}

    def load(name):
        if GYM_ASSETS is None:
            pytest.skip("gymnasium (its MuJoCo models) is not installed")
        if name not in cache:
            path = GYM_ASSETS / f"{name}.xml"
            cache[name] = (mujoco.MjModel.from_xml_path(str(path)), rb.load_scene(path))
        return cache[name]

    return load


# --------------------------------------------------------------------------- #
# Gymnasium's models against MuJoCo
# --------------------------------------------------------------------------- #

@pytest.mark.parametrize("name", GYM_MODELS)
def test_gym_models_load_with_mujocos_layout_and_poses(gym, name):
    """nq, nv, the joints in MuJoCo's order, masses; then a random qpos/qvel written with
    rb.joints.set_qpos_qvel reads back as written, and puts every body where MuJoCo's
    forward kinematics puts it, moving as MuJoCo's bodies move."""
    mj_model, loaded = gym(name)
    model, params, state = loaded.build(**F64)
    tree = model.joints
    assert (tree.nq, tree.nv, tree.num_actuators) == (mj_model.nq, mj_model.nv, mj_model.nu)
    assert tree.joint_kind == tuple(JOINT_TYPES[int(kind)] for kind in mj_model.jnt_type)
    ids = mujoco_ids(mj_model, model)
    assert ids == list(range(1, mj_model.nbody))  # every body moves, in MuJoCo's order
    np.testing.assert_allclose(params.mass, mj_model.body_mass[ids], rtol=1e-12)
    np.testing.assert_allclose(rb.joints.qpos_qvel(model, params, state)[0], mj_model.qpos0, atol=1e-12)

    qpos, qvel = random_coordinates(mj_model, np.random.default_rng(len(name)))
    moved = rb.joints.set_qpos_qvel(model, params, state, qpos, qvel)
    read_qpos, read_qvel = rb.joints.qpos_qvel(model, params, moved)
    np.testing.assert_allclose(read_qpos, qpos, atol=1e-12)
    np.testing.assert_allclose(read_qvel, qvel, atol=1e-12)
    mj_data = mujoco.MjData(mj_model)
    mj_data.qpos[:], mj_data.qvel[:] = qpos, qvel
    mujoco.mj_forward(mj_model, mj_data)
    assert_poses_match(mj_model, mj_data, model, moved)


def test_gym_build_options_and_warnings(gym):
    """The file's timestep, integrator and substeps; RK4 only where jaxrb's rk4 takes the scene."""
    assert gym("inverted_double_pendulum")[1].build_options == {"dt": 0.01, "integrator": "rk4"}
    hopper = gym("hopper")[1]
    assert hopper.build_options == {"dt": 0.002, "integrator": "midpoint", "substeps": 2}
    text = "\n".join(hopper.warnings)
    assert "integrator RK4: this scene has contact" in text and "max()" in text
    assert len(hopper.warnings) == len(set(hopper.warnings))  # a geom's margin is named once
    assert sum("margin/gap" in warning for warning in hopper.warnings) == 5  # four limbs and the floor


# A free torso with a ball-jointed arm, a hinged hand with a spring, a leg on a slide and a hinge
# (two joints composed on one body), and every actuator kind, the motor's control clamped.
MECHANISM = """<mujoco><option timestep="0.005"/><worldbody>
<body name="torso" pos="0 0 1" euler="10 20 30"><freejoint/><geom type="box" size=".2 .1 .05" mass="3"/>
  <body name="arm" pos=".2 0 0"><joint name="shoulder" type="ball" damping="0.2" armature="0.01"/>
    <geom type="capsule" fromto="0 0 0 .3 0 0" size=".04"/>
    <body name="hand" pos=".3 0 0"><joint name="elbow" axis="0 1 1" stiffness="20" springref="0.3" ref="0.1"
        damping="0.5"/><geom type="sphere" size=".05" pos=".05 0 0"/></body></body>
  <body name="leg" pos="-.2 0 0"><joint name="hip" type="slide" axis="1 0 1" stiffness="10" damping="1"
      armature="0.1"/><joint name="knee" axis="0 1 0" pos="0 0 .05"/><geom type="sphere" size=".06" pos="0 0 -.1"/>
  </body>
</body></worldbody>
<actuator><position joint="elbow" kp="5" kv="0.3"/><velocity joint="hip" kv="2"/>
  <motor joint="knee" gear="3" ctrlrange="-1 1"/></actuator></mujoco>"""


@pytest.mark.parametrize("name, integrator", [("inverted_double_pendulum", "rk4"), ("reacher", "semi_implicit"),
                                              ("mechanism", "semi_implicit")])
def test_contact_free_steps_match_mujoco(name, integrator):
    """Five steps from a random state with random controls (beyond the control ranges) end where
    MuJoCo's Euler (semi_implicit) or RK4 ends, step by step, to 1e-9, limits and contact off."""
    if name == "mechanism":
        mj_model = mujoco.MjModel.from_xml_string(MECHANISM)
    else:
        if GYM_ASSETS is None:
            pytest.skip("gymnasium (its MuJoCo models) is not installed")
        mj_model = mujoco.MjModel.from_xml_path(str(GYM_ASSETS / f"{name}.xml"))
    mj_model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_LIMIT | mujoco.mjtDisableBit.mjDSBL_CONTACT
    mj_model.opt.integrator = (mujoco.mjtIntegrator.mjINT_RK4 if integrator == "rk4"
                               else mujoco.mjtIntegrator.mjINT_EULER)
    loaded = mjcf.scene_from_mjmodel(mj_model, name)
    assert loaded.build_options["contact"] == "none"
    model, params, state = loaded.build(contact="none", substeps=1, integrator=integrator, **F64)
    rng = np.random.default_rng(7)
    qpos, qvel = random_coordinates(mj_model, rng)
    controls = rng.uniform(-2.0, 2.0, size=(5, mj_model.nu))
    state = rb.joints.set_qpos_qvel(model, params, state, qpos, qvel)
    trajectory = rb.rollout(rb.make_step(model), state, params, 5, controls=controls)
    mj_data = mujoco.MjData(mj_model)
    mj_data.qpos[:], mj_data.qvel[:] = qpos, qvel
    for step in range(5):
        mj_data.ctrl[:] = controls[step]
        mujoco.mj_step(mj_model, mj_data)
        np.testing.assert_allclose(trajectory.qpos[step], mj_data.qpos, atol=1e-9, rtol=0, err_msg=f"step {step}")
        np.testing.assert_allclose(trajectory.qvel[step], mj_data.qvel, atol=1e-9, rtol=0, err_msg=f"step {step}")
    mujoco.mj_forward(mj_model, mj_data)
    assert_poses_match(mj_model, mj_data, model, jax.tree_util.tree_map(lambda leaf: leaf[-1], trajectory))


def test_imported_scene_saves_as_json(gym, tmp_path):
    """A scene read from MJCF (joints, actuators, exclusions, geom offsets) and its build options
    (dt, integrator, substeps) go through a jaxrb JSON file unchanged."""
    for name, loaded in (("hopper", gym("hopper")[1]), ("box_drop", rb.load_scene(EXAMPLE))):
        path = tmp_path / f"{name}.json"
        sf.save_scene(path, loaded.scene, **loaded.build_options)
        again = sf.load_scene(path)
        assert again.build_options == loaded.build_options
        assert_same_build(loaded.build(**F64), again.build(**F64))
    data = json.loads((tmp_path / "hopper.json").read_text())
    assert data["build"] == {"dt": 0.002, "integrator": "midpoint", "substeps": 2}
    assert [joint["kind"] for joint in data["joints"]] == ["slide", "slide", "hinge", "hinge", "hinge", "hinge"]
    assert len(data["actuators"]) == 3


# --------------------------------------------------------------------------- #
# The example, poses and conventions
# --------------------------------------------------------------------------- #

def test_example_box_drop_loads():
    loaded = sf.load_scene(EXAMPLE)
    assert loaded.warnings == []
    assert loaded.build_options == {"dt": 0.002, "substeps": 2}
    model, params, state = loaded.build(**F64)
    assert model.shapes == (rb.Box(half_extents=(0.1, 0.1, 0.1)),) and model.names == ("box",)
    assert model.planes == (((0.0, 0.0, 1.0), 0.0),) and model.contact == "impulse"
    assert model.joints is None and model.shape_frames == ()  # one free body, its geom at its frame
    np.testing.assert_allclose(params.mass, [1.0])
    np.testing.assert_allclose(params.inertia[0], np.eye(3) * 0.04 / 6.0, rtol=1e-12)
    np.testing.assert_allclose(params.friction, [0.8])
    np.testing.assert_allclose(params.plane_friction, [0.8])
    np.testing.assert_allclose(params.dt, 0.002)
    np.testing.assert_allclose(state.pos, [[0.0, 0.0, 0.5]])
    half = np.radians(15.0)
    np.testing.assert_allclose(state.quat, [[np.cos(half), 0.0, 0.0, np.sin(half)]], atol=1e-15)


def test_box_and_sphere_rest_like_mujoco():
    """The example box and a sphere, dropped for 1.5 s in MuJoCo and in jaxrb, rest at the
    same height (their centres 0.1 m above the plane) within 5 mm."""
    text = EXAMPLE.read_text().replace(
        "</worldbody>", '<body name="ball" pos="1 0 0.3"><freejoint/>'
        '<geom type="sphere" size="0.1" mass="0.5" friction="0.8"/></body></worldbody>')
    loaded = sf.scene_from_mjcf(text)
    assert loaded.warnings == []
    model, params, state = loaded.build(**F64)
    steps = round(1.5 / 0.002)
    trajectory = rb.rollout(rb.make_step(model), state, params, num_steps=steps)
    heights = np.asarray(trajectory.pos[-1, :, 2])
    np.testing.assert_allclose(heights, [0.1, 0.1], atol=5e-4)
    assert np.max(np.abs(np.asarray(trajectory.vel[-1]))) < 1e-2

    mj_model = mujoco.MjModel.from_xml_string(text)
    mj_data = mujoco.MjData(mj_model)
    for _ in range(steps):
        mujoco.mj_step(mj_model, mj_data)
    mj_heights = mj_data.geom_xpos[1:, 2]
    np.testing.assert_allclose(mj_heights, [0.1, 0.1], atol=5e-3)
    np.testing.assert_allclose(heights, mj_heights, atol=5e-3)


POSES = """<mujoco>{compiler}<worldbody>
<geom type="plane" size="1 1 0.1" euler="5 10 0" pos="0 0 -1" friction="0.6 0.01 0.001"/>
<body pos="0 0 1" euler="30 40 50"><freejoint/><geom type="box" size=".1 .2 .3"/></body>
<body pos="1 0 1" axisangle="1 2 3 0.7"><freejoint/>
  <geom type="capsule" size=".1 .3" pos="0.1 0.2 0.3" euler="10 20 30"/></body>
<body pos="2 0 1" xyaxes="1 1 0 -1 2 0.5"><joint type="free"/>
  <geom type="capsule" fromto="0 0 0 0.3 0.2 0.1" size=".05" mass="2"/></body>
<body pos="3 0 1" zaxis="1 2 3"><freejoint/><geom size=".1" quat="1 2 3 4" pos="0 0 .1" density="300"/></body>
<body pos="4 0 1" quat="2 1 0 0"><freejoint/>
  <inertial pos="0.1 0 0" mass="3" diaginertia="1 2 2.5" euler="20 30 40"/></body>
<body pos="5 0 1" quat="2 1 0 0"><freejoint/><geom type="box" size=".1 .2 .3" pos="0.1 0 0" euler="0 0 90"/>
  <inertial pos="0.1 0 0" mass="3" fullinertia="1 2 2.5 0.1 0.2 0.3"/></body>
</worldbody></mujoco>"""


@pytest.mark.parametrize("compiler", ['', '<compiler angle="radian" eulerseq="XYZ"/>',
                                      '<compiler eulerseq="zyx"/>', '<compiler eulerseq="ZxY"/>'])
def test_poses_inertia_and_geom_offsets_match_mujoco(compiler):
    """Orientation conventions (quat order, euler sequences, axis-angle, xyaxes, zaxis, fromto,
    degrees/radians), geom offsets and inertial frames, against MuJoCo's compiler: the jaxrb body
    frame is MuJoCo's, its centre of mass and inertia MuJoCo's, its shape where MuJoCo's geom is."""
    xml = POSES.format(compiler=compiler)
    mj_model = mujoco.MjModel.from_xml_string(xml)
    mj_data = mujoco.MjData(mj_model)
    mujoco.mj_forward(mj_model, mj_data)
    loaded = sf.scene_from_mjcf(xml)
    assert len(loaded.warnings) == 1 and "max()" in loaded.warnings[0]  # the 0.6 plane against 1.0 bodies
    model, params, state = loaded.build(**F64)
    normal, offset = model.planes[0]
    plane_z = mj_data.geom_xmat[0].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(normal, plane_z, atol=1e-12)
    np.testing.assert_allclose(offset, mj_data.geom_xpos[0] @ plane_z, atol=1e-12)
    assert_poses_match(mj_model, mj_data, model, state, atol=1e-12)
    for index in range(model.num_bodies):
        body = index + 1
        rotation = rotation_matrix(np.asarray(state.quat[index]))
        np.testing.assert_allclose(params.mass[index], mj_model.body_mass[body], rtol=1e-12)
        mj_rotation = mj_data.ximat[body].reshape(3, 3)
        np.testing.assert_allclose(rotation @ np.asarray(params.inertia[index]) @ rotation.T,
                                   mj_rotation @ np.diag(mj_model.body_inertia[body]) @ mj_rotation.T, atol=1e-10)
        if model.shapes[index] is None:
            continue
        geom = mj_model.body_geomadr[body]
        offset, turn = model.shape_frames[index] if model.shape_frames and model.shape_frames[index] \
            else ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
        origin = np.asarray(state.pos[index]) - rotation @ np.asarray(params.com_offset[index])
        np.testing.assert_allclose(origin + rotation @ np.asarray(offset), mj_data.geom_xpos[geom], atol=1e-12)
        np.testing.assert_allclose(rotation @ rotation_matrix(turn), mj_data.geom_xmat[geom].reshape(3, 3),
                                   atol=1e-12)
    assert model.shapes[4] is None
    assert model.shapes[2] == rb.Capsule(radius=0.05, half_length=0.5 * np.sqrt(0.14))


# --------------------------------------------------------------------------- #
# Contact filtering: MuJoCo's pairs
# --------------------------------------------------------------------------- #

def mujoco_pairs(mj_model):
    """The geom pairs MuJoCo's collision filter lets through (bitmasks, <exclude>, a body and its
    parent, bodies welded together), as body-id pairs and (body id, 'plane') pairs: read from the
    contacts MuJoCo finds at qpos0 with every geom's margin so wide that every allowed pair touches
    (not box against box: MuJoCo's box-box collider finds nothing that far apart)."""
    wide = copy.deepcopy(mj_model)
    wide.geom_margin[:] = 100.0
    data = mujoco.MjData(wide)
    mujoco.mj_forward(wide, data)
    pairs = set()
    for contact in data.contact[:data.ncon]:
        bodies = sorted(int(wide.geom_bodyid[g]) for g in contact.geom)
        planes = [g for g in contact.geom if wide.geom_type[g] == 0]
        pairs.add((max(bodies), "plane") if planes else tuple(bodies))
    return pairs


def jaxrb_pairs(mj_model, model):
    """The pairs of model.pair_groups, in MuJoCo's body ids (one plane: the floor)."""
    ids = mujoco_ids(mj_model, model)
    assert len(model.planes) <= 1
    pairs = set()
    for group in model.pair_groups:
        for a, b in zip(group.body_a, group.body_b):
            pairs.add((ids[a], "plane") if group.b_is_plane else tuple(sorted((ids[a], ids[b]))))
    return pairs


FILTERED = """<mujoco><worldbody>
<geom name="floor" type="plane" size="5 5 .1"/>
<geom name="wall" type="box" size=".1 .1 .1" pos="9 0 0" contype="0" conaffinity="0"/>
<body name="a" pos="0 0 1"><freejoint/><geom size=".1"/>
  <geom name="look" type="cylinder" size=".1 .1" contype="0" conaffinity="0"/></body>
<body name="b" pos="1 0 1"><freejoint/><geom size=".1" contype="2" conaffinity="2"/></body>
<body name="c" pos="2 0 1"><freejoint/><geom type="box" size=".1 .1 .1" contype="3" conaffinity="0"/></body>
<body name="d" pos="3 0 1"><joint axis="0 1 0"/><geom type="capsule" size=".05 .2"/>
  <body name="e" pos="0 0 -.5"><joint axis="0 1 0"/><geom size=".1"/>
    <body name="f" pos="0 0 -.3"><geom size=".05"/></body></body></body>
<body name="g" pos="4 0 1"><freejoint/><geom size=".1" contype="4" conaffinity="1"/></body>
</worldbody>
<contact><exclude body1="d" body2="a"/><exclude body1="a" body2="g"/><exclude body1="f" body2="world"/></contact>
</mujoco>"""


@pytest.mark.parametrize("name", ["filtered", "hopper", "walker2d", "ant"])
def test_contact_filtering_is_mujocos(gym, name):
    """contype/conaffinity (either way round), <exclude> (either order, with the world too),
    a body and its parent, a body welded to its parent, visual geoms: jaxrb's pair table holds
    exactly the pairs MuJoCo can collide."""
    if name == "filtered":
        mj_model = mujoco.MjModel.from_xml_string(FILTERED)
        loaded = sf.scene_from_mjcf(FILTERED)
    else:
        mj_model, loaded = gym(name)
    model, _, _ = loaded.build(**F64)
    expected = mujoco_pairs(mj_model)
    assert expected and jaxrb_pairs(mj_model, model) == expected
    if name == "filtered":
        assert model.names == ("a", "b", "c", "d", "e", "f") + ("g",)
        assert (1, "plane") in expected and (2, "plane") not in expected  # b's bits miss the floor's


# --------------------------------------------------------------------------- #
# What jaxrb cannot represent, and what it approximates
# --------------------------------------------------------------------------- #

def arm(body="", world="", after="", top=""):
    """A hinged capsule over a floor, with extra XML in its body, the world, after <worldbody> or before it."""
    return (f"<mujoco>{top}<worldbody><geom name='floor' type='plane' size='1 1 .1'/>{world}"
            f"<body name='arm' pos='0 0 1'><joint name='hinge' axis='0 1 0'/>"
            f"<geom name='rod' type='capsule' fromto='0 0 0 .3 0 0' size='.05'/>{body}</body></worldbody>{after}"
            f"</mujoco>")


HAND = "<body name='hand' pos='.3 0 0'><joint name='wrist' axis='0 1 0'/><geom size='.05'/></body>"

UNSUPPORTED = [
    (arm(after="<tendon><fixed name='t'><joint joint='hinge' coef='1'/></fixed></tendon>"),
     r"tendon: the model has 1 tendon; jaxrb has none"),
    (arm(body="<body name='c' pos='.3 0 0'><joint/><geom name='can' type='cylinder' size='.05 .1'/></body>"),
     r"geom 'can': type 'cylinder' is not a jaxrb shape"),
    (arm(body="<body name='c' pos='.3 0 0'><joint/><geom name='egg' type='ellipsoid' size='.05 .1 .1'/></body>"),
     r"geom 'egg': type 'ellipsoid' is not a jaxrb shape"),
    (arm(body="<geom name='knob' size='.05'/>"),
     r"body 'arm': has 2 geoms that can collide \(geom 'rod', geom 'knob'\); a jaxrb body carries one shape"),
    (arm(after="<actuator><muscle name='flex' joint='hinge' lengthrange='0 1'/></actuator>"),
     r"actuator 'flex': only fixed gains and affine biases are in jaxrb \(no muscles"),
    (arm(after="<actuator><intvelocity name='iv' joint='hinge' kp='1' actrange='-1 1'/></actuator>"),
     r"actuator 'iv': activation dynamics"),
    (arm(body="<site name='s'/>", after="<actuator><general name='push' site='s' gear='1 0 0 0 0 0'/></actuator>"),
     r"actuator 'push': only joint transmissions"),
    (arm(body=HAND, after="<equality><joint name='couple' joint1='hinge' joint2='wrist'/></equality>"),
     r"equality 'couple': only connect and weld equalities"),
    (arm(world="<geom name='wall' type='box' size='.1 .1 .1' pos='2 0 0'/>"),
     r"geom 'wall': a static 'box' that moving geoms can touch"),
    (arm(body="<body name='c' pos='.3 0 0'><joint name='cone' type='ball' range='0 30'/><geom size='.05'/></body>"),
     r"joint 'cone': a ball joint's range \(a cone\)"),
    (arm(world="<body name='m' mocap='true'><geom size='.1' contype='0' conaffinity='0'/></body>"),
     r"body: 1 mocap bodies"),
    (arm(top="<option viscosity='0.1'/>"), r"option: density/viscosity"),
    (arm(body=HAND.replace("<joint", "<joint actuatorfrcrange='-1 1'"),
         after="<actuator><motor joint='wrist'/><motor joint='wrist'/></actuator>"),
     r"joint 'wrist': actuatorfrcrange .* with 2 actuators"),
    ("<mujoco><worldbody><body><geom size='.1'/></body></worldbody></mujoco>", r"worldbody: no body moves"),
    ("<mujoco><worldbody>", r"MuJoCo cannot compile it: XML parse error"),
    (arm(body="<geom size='abc'/>"), r"MuJoCo cannot compile it: .*bad format in attribute 'size'"),
]


@pytest.mark.parametrize("xml, message", UNSUPPORTED, ids=[case[1][:30] for case in UNSUPPORTED])
def test_what_jaxrb_cannot_represent_is_an_error_naming_the_element(xml, message):
    with pytest.raises(ValueError, match=r"^m\.xml: " + message):
        sf.scene_from_mjcf(xml, source="m.xml")


def test_harmless_differences_are_warnings():
    """Solver and contact tuning jaxrb does not map is listed once each, and the scene loads."""
    xml = arm(top="<option integrator='implicitfast'/>", world="<light/><camera/>",
              body=HAND + "<site name='tip'/>",
              after="<equality><connect name='pin' body1='hand' anchor='0 0 0' active='false'/></equality>"
                    "<sensor><jointpos joint='hinge'/></sensor>")
    xml = xml.replace("type='capsule' fromto='0 0 0 .3 0 0' size='.05'",
                                                   "type='capsule' fromto='0 0 0 .3 0 0' size='.05' condim='6' "
                                                   "margin='0.01' solref='0.01 1' friction='0.5'")
    loaded = sf.scene_from_mjcf(xml, source="m.xml")
    text = "\n".join(loaded.warnings)
    for expected in ("geom 'rod': margin/gap", "geom 'rod': condim 6: jaxrb has no torsional or rolling friction",
                     "friction: MuJoCo mixes a pair's friction with max(), jaxrb with sqrt(product): "
                     "geom 'rod'–geom 'floor' 1 against 0.707107",
                     "option: integrator implicitfast", "solref: MuJoCo's contact softness is not mapped",
                     "equality 'pin': inactive at the start"):
        assert expected in text, (expected, text)
    assert len(loaded.warnings) == len(set(loaded.warnings))
    model, params, _ = loaded.build(**F64)
    assert model.names == ("arm", "hand") and model.joints.equality_kind == ()
    np.testing.assert_allclose(params.friction, [0.5, 1.0])  # the geoms' sliding friction, unmixed
    np.testing.assert_allclose(params.plane_friction, [1.0])


def test_loop_closures_actuators_and_force_clamps():
    """Active connect and weld equalities become rb.Connect and rb.Weld; a joint's actuatorfrcrange
    with one actuator joins that actuator's forcerange (divided by its gear)."""
    xml = arm(body=HAND.replace("<joint", "<joint actuatorfrcrange='-3 4'") + "<body name='tip' pos='0 0 -.3'>"
              "<joint name='slide' type='slide' axis='0 0 1'/><geom size='.03' contype='0' conaffinity='0'/></body>",
              after="<equality><connect name='pin' body1='hand' anchor='0.05 0 0'/>"
                    "<weld name='glue' body1='tip' body2='arm'/></equality>"
                    "<actuator><motor name='m' joint='wrist' gear='2' forcerange='-1 10'/>"
                    "<position name='p' joint='slide' kp='3'/></actuator>")
    loaded = sf.scene_from_mjcf(xml, source="m.xml")
    model, _, _ = loaded.build(**F64)
    assert model.joints.equality_kind == ("connect", "weld")
    motor, servo = loaded.scene._actuator_args
    np.testing.assert_allclose(motor["forcerange"], [-1.0, 2.0])  # [-1, 10] and [-3, 4] / 2
    assert "forcerange" not in servo and servo["gain"] == 3.0
    np.testing.assert_allclose(servo["bias"], [0.0, -3.0, 0.0])


# --------------------------------------------------------------------------- #
# URDF
# --------------------------------------------------------------------------- #

URDF = """<robot name="arm">
  <link name="base">
    <inertial><mass value="2"/><inertia ixx="0.02" iyy="0.02" izz="0.02" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision>
  </link>
  <link name="upper">
    <inertial><origin xyz="0 0 -0.2"/><mass value="1"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 -0.4"/><geometry><sphere radius="0.05"/></geometry></collision>
  </link>
  <link name="lower">
    <inertial><origin xyz="0 0 -0.2"/><mass value="0.5"/>
      <inertia ixx="0.005" iyy="0.005" izz="0.0005" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 -0.1"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="5"/><dynamics damping="0.1"/></joint>
  <joint name="elbow" type="continuous"><parent link="upper"/><child link="lower"/><origin xyz="0 0 -0.4"/>
    <axis xyz="1 0 0"/></joint>
</robot>"""


def test_urdf_fixed_and_floating_base(tmp_path):
    """A URDF's root link is fixed to the world (MuJoCo fuses it there: its box would be a static
    shape the arm can touch, an error); with floating_base=True it is a free body whose 7/6
    coordinates lead qpos/qvel, the arm's after them as in the fixed model."""
    path = tmp_path / "arm.urdf"
    path.write_text(URDF)
    with pytest.raises(ValueError, match=r"arm\.urdf: geom '#0': a static 'box' that moving geoms can touch"):
        rb.load_scene(path)
    fixed_path = tmp_path / "fixed.urdf"
    fixed_path.write_text(URDF.replace('<collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision>', ""))
    fixed = rb.load_scene(fixed_path)
    model, params, state = fixed.build(**F64)
    assert model.names == ("upper", "lower") and model.joints.joint_kind == ("hinge", "hinge")
    assert model.joints.limited == (True, False)  # the effort limit (actuatorfrcrange) drives nothing here
    mj_model = mujoco.MjModel.from_xml_path(str(fixed_path))
    qpos, qvel = random_coordinates(mj_model, np.random.default_rng(3))
    mj_data = mujoco.MjData(mj_model)
    mj_data.qpos[:], mj_data.qvel[:] = qpos, qvel
    mujoco.mj_forward(mj_model, mj_data)
    assert_poses_match(mj_model, mj_data, model, rb.joints.set_qpos_qvel(model, params, state, qpos, qvel))

    floating = rb.load_scene(path, floating_base=True)
    model, params, state = floating.build(**F64)
    tree = model.joints
    assert model.names == ("base", "upper", "lower") and model.shapes[0] == rb.Box((0.1, 0.1, 0.05))
    assert tree.joint_kind == ("free", "hinge", "hinge") and (tree.nq, tree.nv) == (9, 8)
    assert (tree.qpos_adr, tree.dof_adr) == ((0, 7, 8), (0, 6, 7))
    qpos, _ = rb.joints.qpos_qvel(model, params, state)
    np.testing.assert_allclose(qpos, [0, 0, 0, 1, 0, 0, 0, 0, 0], atol=1e-15)
    assert not model.pair_groups  # the base and the upper arm are parent and child; the lower arm has no shape
