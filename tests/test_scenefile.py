"""jaxrb's JSON scene files: round trips (joints included), version 1 files, malformed files.

MJCF and URDF import (through MuJoCo's compiler) is tested in tests/test_mjcf.py.
"""

import ast
import copy
import inspect
import json
import pathlib
import warnings

import jax
import numpy as np
import pytest

import jaxrb as rb
from jaxrb.files import mjcf
from jaxrb.files import scenefile as sf
from jaxrb.files import common as scenefile_common
from conftest import assert_same_build



def scene_3d():
    """Every 3D shape kind, a mass-only body, most add_body options, two planes."""
    scene = rb.Scene(dim=3, gravity=(0.1, 0.0, -9.7))
    scene.add_plane(friction=0.7)
    scene.add_plane(normal=(0.0, 0.2, 1.0), offset=-0.5, restitution=0.2, collision_category=2,
                    collision_mask=3)
    scene.add_body(rb.Box(half_extents=(0.1, 0.2, 0.3)), mass=2.0, pos=(0.0, 0.0, 1.0),
                   quat=np.array([1.0, 0.1, 0.2, 0.0]), vel=(1.0, 0.0, 0.0), name="crate")
    scene.add_body(rb.Sphere(radius=0.1), density=500.0, pos=(1.0, 0.0, 1.0), angvel=(0.0, 3.0, 0.0),
                   friction=0.9, restitution=0.3, linear_damping=0.1, angular_damping=0.2)
    scene.add_body(rb.Capsule(radius=0.05, half_length=0.2), mass=1.5, pos=(2.0, 0.0, 1.0),
                   inertia=[[0.03, 0.001, 0.0], [0.001, 0.03, 0.0], [0.0, 0.0, 0.002]],
                   collision_category=1, collision_mask=5)
    scene.add_body(rb.PointMasses(points=[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.2, 0.0],
                                          [0.0, 0.0, 0.1]], masses=[1.0, 2.0, 3.0, 4.0]),
                   pos=(3.0, 0.0, 1.0), quat=(0.0, 0.0, 0.0, 1.0))
    scene.add_body(None, mass=1.0, inertia=(0.1, 0.2, 0.25), pos=(4.0, 0.0, 1.0))
    return scene


def scene_2d():
    """Every 2D shape kind and a half-plane."""
    scene = rb.Scene(dim=2)
    scene.add_plane(normal=(0.1, 1.0), offset=0.05, friction=0.4)
    scene.add_body(rb.Circle(radius=0.2), pos=(0.0, 1.0), angvel=2.0, name="wheel")
    scene.add_body(rb.Box(half_extents=(0.3, 0.1)), mass=3.0, pos=(1.0, 1.0), angle=0.4, vel=(0.5, 0.0))
    scene.add_body(rb.Polygon(vertices=[[0.0, 0.0], [0.4, 0.0], [0.1, 0.3]]), density=20.0,
                   pos=(2.0, 1.0), restitution=0.5)
    scene.add_body(rb.PointMasses(points=[[0.0, 0.0], [0.2, 0.0], [0.0, 0.3]], masses=[1.0, 1.0, 2.0]),
                   pos=(3.0, 1.0), angle=-0.3)
    return scene


def scene_joints():
    """Every joint kind, both loop closures, every actuator kind, both exclusions, the add_body
    keywords of articulated bodies (com, shape_pos, shape_quat), joint options with their defaults and not."""
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.7)
    base = scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=2.0, pos=(0.0, 0.0, 1.0), name="base")
    arm = scene.add_body(rb.Capsule(0.05, 0.2), mass=1.0, inertia=(0.01, 0.01, 0.002), pos=(0.0, 0.0, 0.7),
                         com=(0.0, 0.0, -0.05), shape_pos=(0.0, 0.0, -0.1), shape_quat=(1.0, 0.1, 0.0, 0.0))
    ball = scene.add_body(rb.Sphere(0.05), pos=(0.3, 0.0, 0.5))
    weight = scene.add_body(None, mass=0.5, inertia=(1e-3, 1e-3, 1e-3), pos=(0.3, 0.0, 0.3))
    loose = scene.add_body(rb.Sphere(0.05), pos=(1.0, 0.0, 0.5))
    rail = scene.add_joint(rb.Slider(axis=(1, 0, 0)), base, None, range=(-1, 1), damping=0.5, name="rail")
    elbow = scene.add_joint(rb.Hinge(axis=np.array([0.0, 1.0, 0.0]), anchor=(0.0, 0.0, 0.9)), arm, base,
                            stiffness=3.0, springref=0.2, ref=0.1, armature=0.01, frictionloss=0.05)
    scene.add_joint(rb.Ball(anchor=(0.3, 0.0, 0.55)), ball, arm)
    scene.add_joint(rb.Fixed(), weight, ball)
    scene.add_joint(rb.Free(), loose)
    scene.add_equality(rb.Connect(anchor=(0.3, 0.0, 0.3)), weight, None, name="pin")
    scene.add_equality(rb.Weld(), loose, base)
    scene.add_actuator(elbow, "position", kp=20.0, kv=1.0, ctrlrange=(-1, 1))
    scene.add_actuator(rail, "general", gain=2.0, bias=(0.1, -1.0, -0.2), forcerange=(-5, 5), gear=2.0)
    scene.add_actuator(rail, "velocity", kv=0.5)
    scene.add_actuator(elbow)
    scene.exclude_collision(base, ball)
    scene.exclude_collision(weight, plane=0)
    return scene


@pytest.mark.parametrize("make_scene, options", [
    (scene_3d, dict(dt=0.004, substeps=2)), (scene_2d, dict(dt=0.004, substeps=2)),
    (scene_joints, dict(dt=0.004, substeps=2, joint_friction="smooth", integrator="semi_implicit"))],
    ids=["3d", "2d", "joints"])
def test_json_round_trip_rebuilds_identical_model_params_state(make_scene, options, tmp_path):
    scene = make_scene()
    path = tmp_path / "scene.json"
    sf.save_scene(path, scene, **options)
    loaded = sf.load_scene(path)
    assert loaded.source == str(path) and loaded.warnings == []
    assert loaded.build_options == options
    assert loaded.scene.num_bodies == scene.num_bodies
    assert_same_build(scene.build(**options), loaded.build())
    # A second save of the loaded scene writes the same file.
    again = tmp_path / "again.json"
    sf.save_scene(again, loaded.scene, **loaded.build_options)
    assert json.loads(again.read_text()) == json.loads(path.read_text())


def test_saved_file_holds_what_the_user_gave():
    data = sf.scene_to_dict(scene_3d())
    assert data["format"] == "jaxrb-scene" and data["version"] == 2 and data["dim"] == 3
    assert data["gravity"] == [0.1, 0.0, -9.7]
    crate = data["bodies"][0]
    assert crate == {"shape": {"kind": "box", "half_extents": [0.1, 0.2, 0.3]}, "mass": 2.0,
                     "pos": [0.0, 0.0, 1.0], "quat": [1.0, 0.1, 0.2, 0.0], "vel": [1.0, 0.0, 0.0],
                     "name": "crate"}
    assert "shape" not in data["bodies"][4]
    assert data["planes"][0] == {"friction": 0.7}
    assert "build" not in data
    assert not {"joints", "equalities", "actuators", "exclusions"} & set(data)  # written where the scene has any
    json.dumps(data, allow_nan=False)  # plain data only


def test_saved_joints_are_written_as_the_user_gave_them():
    data = sf.scene_to_dict(scene_joints())
    assert data["version"] == 2
    assert data["bodies"][1] == {"shape": {"kind": "capsule", "radius": 0.05, "half_length": 0.2}, "mass": 1.0,
                                 "inertia": [0.01, 0.01, 0.002], "pos": [0.0, 0.0, 0.7], "com": [0.0, 0.0, -0.05],
                                 "shape_pos": [0.0, 0.0, -0.1], "shape_quat": [1.0, 0.1, 0.0, 0.0]}
    assert data["joints"] == [
        {"kind": "slide", "axis": [1, 0, 0], "child": 0, "range": [-1, 1], "damping": 0.5, "name": "rail"},
        {"kind": "hinge", "axis": [0.0, 1.0, 0.0], "anchor": [0.0, 0.0, 0.9], "child": 1, "parent": 0, "ref": 0.1,
         "stiffness": 3.0, "springref": 0.2, "armature": 0.01, "frictionloss": 0.05},
        {"kind": "ball", "anchor": [0.3, 0.0, 0.55], "child": 2, "parent": 1},
        {"kind": "fixed", "child": 3, "parent": 2},
        {"kind": "free", "child": 4}]
    assert data["equalities"] == [{"kind": "connect", "anchor": [0.3, 0.0, 0.3], "body_a": 3, "name": "pin"},
                                  {"kind": "weld", "body_a": 4, "body_b": 0}]
    assert data["actuators"] == [
        {"joint": 1, "kind": "position", "kp": 20.0, "kv": 1.0, "ctrlrange": [-1, 1]},
        {"joint": 0, "kind": "general", "gear": 2.0, "gain": 2.0, "bias": [0.1, -1.0, -0.2], "forcerange": [-5, 5]},
        {"joint": 0, "kind": "velocity", "kv": 0.5}, {"joint": 1, "kind": "motor"}]
    assert data["exclusions"] == [{"body_a": 0, "body_b": 2}, {"body_a": 3, "plane": 0}]
    json.dumps(data, allow_nan=False)


def test_recorded_arguments_are_copies():
    scene = rb.Scene(dim=3)
    pos = np.array([0.0, 0.0, 1.0])
    scene.add_body(rb.Sphere(radius=0.1), pos=pos)
    pos[2] = 5.0
    assert sf.scene_to_dict(scene)["bodies"][0]["pos"] == [0.0, 0.0, 1.0]


def test_rejected_body_is_not_recorded():
    scene = rb.Scene(dim=3)
    with pytest.raises(ValueError):
        scene.add_body(rb.Sphere(radius=0.1), mass=-1.0)
    scene.add_body(rb.Sphere(radius=0.1))
    assert len(sf.scene_to_dict(scene)["bodies"]) == 1


@pytest.mark.parametrize("options, stored", [
    (dict(dt=0.01, dtype="float32", contact=rb.Penalty(frequency=50.0, friction="regularized"), substeps=3),
     dict(dt=0.01, dtype="float32", contact="penalty", substeps=3, penalty_frequency=50.0,
          penalty_friction="regularized")),
    (dict(dt=0.005, dtype=np.float64, integrator="implicit_gyro", orientation="first_order",
          contact=rb.Impulse(solver="jacobi", iterations=6, relax_iterations=0, hertz=30.0, time_of_impact=True,
                             smoothing=0.01), broadphase="spheres", broadphase_capacity=4),
     dict(dt=0.005, dtype="float64", integrator="implicit_gyro", orientation="first_order",
          contact="impulse", solver="jacobi", iterations=6, relax_iterations=0, contact_hertz=30.0,
          time_of_impact=True, impulse_smoothing=0.01, broadphase="spheres", broadphase_capacity=4)),
    (dict(dt=0.02, integrator="rk4", contact="none"), dict(dt=0.02, integrator="rk4", contact="none")),
])
def test_build_options_round_trip(options, stored, tmp_path):
    """A contact group is stored flat (the format is unchanged) and read back as the same group."""
    scene = scene_3d()
    path = tmp_path / "scene.json"
    sf.save_scene(path, scene, **options)
    loaded = sf.load_scene(path)
    assert loaded.build_options == stored
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # the file's flat keys are not the user's
        built = loaded.build()
    assert_same_build(scene.build(**options), built)
    if options.get("dtype") == "float32":
        assert built[1].mass.dtype == np.float32 and built[2].pos.dtype == np.float32


def test_build_override_of_the_contact_model_drops_the_files_model_options():
    path_options = dict(dt=0.01, contact="penalty", penalty_stiffness=8000.0)
    loaded = sf.scene_from_dict(sf.scene_to_dict(scene_3d(), **path_options), source="p.json")
    model, params, _ = loaded.build()
    assert model.contact == "penalty" and float(params.penalty_stiffness) == 8000.0
    model, params, _ = loaded.build(contact=rb.Impulse(iterations=2))
    assert model.contact == "impulse" and model.iterations == 2
    model, params, _ = loaded.build(contact=rb.Penalty(stiffness=2e4))
    assert float(params.penalty_stiffness) == 2e4


def test_build_overrides_and_missing_dt():
    data = sf.scene_to_dict(scene_3d())
    loaded = sf.scene_from_dict(data, source="nodt.json")
    with pytest.raises(ValueError, match=r"nodt\.json: .*'dt'"):
        loaded.build()
    model, params, _ = loaded.build(dt=0.01, substeps=2, dtype="float32")
    assert model.substeps == 2 and params.dt.dtype == np.float32
    with pytest.raises(ValueError, match=r"unknown build option 'substep'.*substeps"):
        loaded.build(dt=0.01, substep=2)


def test_bad_option_value_in_file_fails_at_build_naming_the_file():
    data = sf.scene_to_dict(scene_3d(), dt=0.01)
    data["build"]["integrator"] = "verlet"
    loaded = sf.scene_from_dict(data, source="s.json")
    with pytest.raises(ValueError, match=r"s\.json: build: unknown integrator 'verlet'.*'rk4'"):
        loaded.build()


def test_every_add_body_and_build_keyword_is_typed():
    """New Scene keywords must get a JSON type check here (fails when scene.py grows one)."""
    body_keys = set(inspect.signature(rb.Scene.add_body).parameters) - {"self", "shape"}
    assert body_keys == set(sf._body_field_checkers(3))
    plane_keys = set(inspect.signature(rb.Scene.add_plane).parameters) - {"self"}
    assert plane_keys == set(sf._plane_field_checkers(3))
    kinds = scenefile_common._build_kinds()
    assert set(kinds) == (set(inspect.signature(rb.Scene.build).parameters) - {"self", "deprecated"}
                          | set(rb.model.options.FLAT_KEYWORDS))
    assert all(kind.rstrip("?") != "any" for kind in kinds.values()), kinds
    assert kinds["dt"] == "number" and kinds["substeps"] == "integer?" and kinds["contact"] == "string?"
    assert kinds["joint_friction"] == "string"
    for method, checkers in ((rb.Scene.add_joint, sf._joint_field_checkers()),
                             (rb.Scene.add_equality, sf._equality_field_checkers()),
                             (rb.Scene.add_actuator, sf._actuator_field_checkers()),
                             (rb.Scene.exclude_collision, sf._exclusion_field_checkers())):
        assert set(inspect.signature(method).parameters) - {"self", "kind"} == set(checkers) - {"kind"}, method
    # Every joint and loop-closure kind has a name in the file, and its fields a type check.
    assert set(sf.JOINT_KIND_NAMES.values()) == set(rb.model.joints.JOINT_KINDS)
    assert set(sf.EQUALITY_KIND_NAMES.values()) == set(rb.model.joints.EQUALITY_KINDS)


def _base():
    return {"format": "jaxrb-scene", "version": 1, "dim": 3,
            "bodies": [{"shape": {"kind": "box", "half_extents": [0.1, 0.1, 0.1]}, "mass": 1.0},
                       {"shape": {"kind": "sphere", "radius": 0.1}, "pos": [0, 0, 1]}],
            "planes": [{"normal": [0, 0, 1]}],
            "build": {"dt": 0.004}}


def _joint_base():
    return {"format": "jaxrb-scene", "version": 2, "dim": 3,
            "bodies": [{"shape": {"kind": "box", "half_extents": [0.1, 0.1, 0.1]}, "mass": 1.0, "pos": [0, 0, 1]},
                       {"shape": {"kind": "sphere", "radius": 0.1}, "pos": [0, 0, 0.5], "com": [0, 0, 0.01]}],
            "planes": [{}],
            "joints": [{"kind": "slide", "axis": [0, 0, 1], "child": 0},
                       {"kind": "hinge", "axis": [0, 1, 0], "anchor": [0, 0, 0.75], "child": 1, "parent": 0,
                        "range": [-1, 1]}],
            "equalities": [{"kind": "connect", "anchor": [0, 0, 0.5], "body_a": 1}],
            "actuators": [{"joint": 1, "kind": "position", "kp": 10.0}],
            "exclusions": [{"body_a": 1, "plane": 0}],
            "build": {"dt": 0.004, "joint_friction": "smooth"}}


def _edit(path, value, base=_base):
    """A copy of the base file with the field at ``path`` (a tuple of keys) set, or deleted if None."""
    data = copy.deepcopy(base())
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is None:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


MALFORMED = [
    (("version",), 3, r"version: unsupported version 3; this jaxrb reads version\(s\) 1, 2"),
    (("version",), "1", r"version: unsupported version '1'"),
    (("joints",), [], r"joints: needs version 2 of the format \(this file says version 1\)"),
    (("bodies", 0, "com"), [0, 0, 0], r"bodies\[0\]\.com: needs version 2"),
    (("format",), "mujoco", r"format: expected 'jaxrb-scene'"),
    (("dim",), None, r"missing required key 'dim'"),
    (("dim",), 4, r"dim: expected 2 or 3"),
    (("bodys",), [], r"bodys: unknown key 'bodys'; valid keys are: .*bodies"),
    (("bodies", 1, "frction"), 0.3, r"bodies\[1\]\.frction: unknown key 'frction'; valid keys are: .*friction"),
    (("bodies", 0, "shape", "half_extents"), [0.1, 0.1],
     r"bodies\[0\]\.shape\.half_extents: expected 3 numbers, got 2"),
    (("bodies", 0, "mass"), -1.0, r"bodies\[0\]\.mass: must be > 0"),
    (("bodies", 1, "shape", "radius"), 0.0, r"bodies\[1\]\.shape\.radius: must be positive"),
    (("bodies", 0, "shape", "kind"), "cube", r"bodies\[0\]\.shape\.kind: unknown shape kind .*'cube'.*box"),
    (("bodies", 0, "shape", "radius"), 0.1, r"bodies\[0\]\.shape\.radius: unknown key 'radius'.*half_extents"),
    (("bodies", 1, "pos"), "up", r"bodies\[1\]\.pos: expected a list of 3 numbers, got string 'up'"),
    (("bodies", 1, "pos"), [0, True, 1], r"bodies\[1\]\.pos\[1\]: expected a number, got bool"),
    (("bodies", 1, "restitution"), 1.5, r"bodies\[1\]\.restitution: must be <= 1"),
    (("bodies", 1, "angle"), 0.3, r"bodies\[1\]\.angle: is 2D only"),
    (("bodies", 1, "collision_mask"), 1.5, r"bodies\[1\]\.collision_mask: expected an integer"),
    (("planes", 0, "normal"), [0, 0, 0], r"planes\[0\]\.normal: must be non-zero"),
    (("build", "substep"), 4, r"build\.substep: unknown build option 'substep'; valid options are: .*substeps"),
    (("build", "substeps"), "4", r"build\.substeps: expected an integer, got string '4'"),
    (("build", "dtype"), "float8", r"build\.dtype: expected one of .*'float32'"),
    (("build", "dt"), None, None),  # valid: dt may come at build time
]


@pytest.mark.parametrize("path, value, message", MALFORMED,
                         ids=[".".join(map(str, case[0])) + f"={case[1]!r}" for case in MALFORMED])
def test_malformed_files_name_the_field(path, value, message):
    data = _edit(path, value)
    if message is None:
        assert sf.scene_from_dict(data, source="scene.json").scene.num_bodies == 2
        return
    with pytest.raises(ValueError, match="^scene\\.json: " + message):
        sf.scene_from_dict(data, source="scene.json")


MALFORMED_JOINTS = [
    (("joints", 1, "kind"), "hinges",
     r"joints\[1\]\.kind: unknown joint kind string 'hinges'; valid kinds are: hinge, slide, ball, fixed, free"),
    (("joints", 1, "kind"), None, r"joints\[1\]: missing required key 'kind'; valid kinds are: hinge"),
    (("joints", 0, "anchor"), [0, 0, 0],
     r"joints\[0\]\.anchor: unknown key 'anchor'; valid keys of a slide joint are: kind, axis, child, parent, range"),
    (("joints", 1, "dampnig"), 0.1, r"joints\[1\]\.dampnig: unknown key 'dampnig'; valid keys of a hinge joint are: "
                                     r"kind, axis, anchor, child, .*damping"),
    (("joints", 1, "axis"), [0, 1], r"joints\[1\]\.axis: expected 3 numbers, got 2"),
    (("joints", 1, "axis"), [0, 0, 0], r"joints\[1\]\.axis: must be non-zero"),
    (("joints", 1, "child"), 5, r"joints\[1\]\.child: must be a body index 0\.\.1, got 5"),
    (("joints", 1, "child"), None, r"joints\[1\]: missing required key 'child'"),
    (("joints", 1, "parent"), 0.0, r"joints\[1\]\.parent: expected an integer, got float 0\.0"),
    (("joints", 1, "range"), [1, -1], r"joints\[1\]\.range: must have lower <= upper"),
    (("joints", 0, "range"), [0, 1, 2], r"joints\[0\]\.range: expected 2 numbers, got 3"),
    (("joints", 1, "damping"), -1.0, r"joints\[1\]\.damping: must be >= 0"),
    (("joints", 0), "slide", r"joints\[0\]: expected an object, got string 'slide'"),
    (("joints",), {}, r"joints: expected a list of objects, got an object"),
    (("equalities", 0, "kind"), "pin", r"equalities\[0\]\.kind: unknown equality kind string 'pin'; "
                                       r"valid kinds are: connect, weld"),
    (("equalities", 0, "body_b"), 1, r"equalities\[0\]\.body_b: is body_a \(1\) itself"),
    (("equalities", 0, "anchor"), "origin", r"equalities\[0\]\.anchor: expected a list of 3 numbers"),
    (("actuators", 0, "kind"), "muscle", r"actuators\[0\]\.kind: unknown actuator kind string 'muscle'; "
                                         r"valid kinds are: motor, position, velocity, general"),
    (("actuators", 0, "gain"), 2.0, r"actuators\[0\]\.gain: does not apply to a 'position' actuator"),
    (("actuators", 0, "joint"), 7, r"actuators\[0\]\.joint: must be a joint index 0\.\.1, got 7"),
    (("actuators", 0, "joint"), None, r"actuators\[0\]: missing required key 'joint'"),
    (("actuators", 0, "ctrlrange"), [1, 0], r"actuators\[0\]\.ctrlrange: must have lower <= upper"),
    (("actuators", 0, "gian"), 1.0, r"actuators\[0\]\.gian: unknown key 'gian'; valid keys are: joint, kind, "
                                    r"gear, kp, kv, gain"),
    (("exclusions", 0, "plane"), 3, r"exclusions\[0\]\.plane: must be a plane index 0\.\.0, got 3"),
    (("exclusions", 0, "body_b"), 0, r"exclusions\[0\]\.body_b: give exactly one of body_b and plane"),
    (("bodies", 1, "shape_quat"), [0, 0, 0, 0], r"bodies\[1\]\.shape_quat: must be non-zero"),
    (("bodies", 1, "com"), [0, 0], r"bodies\[1\]\.com: expected 3 numbers, got 2"),
    (("build", "joint_friction"), "smooth", None),  # valid as it is
]


@pytest.mark.parametrize("path, value, message", MALFORMED_JOINTS,
                         ids=[".".join(map(str, case[0])) + f"={case[1]!r}" for case in MALFORMED_JOINTS])
def test_malformed_joint_entries_name_the_field(path, value, message):
    data = _edit(path, value, base=_joint_base)
    if message is None:
        model, _, state = sf.scene_from_dict(data, source="scene.json").build()
        assert model.joints.nq == 2 and model.joints.joint_friction == "smooth" and state.qpos.shape == (2,)
        return
    with pytest.raises(ValueError, match="^scene\\.json: " + message):
        sf.scene_from_dict(data, source="scene.json")


def test_joint_errors_at_build_and_in_2d_name_the_file():
    data = _edit(("build", "joint_friction"), "sticky", base=_joint_base)
    with pytest.raises(ValueError, match=r"^s\.json: build: unknown joint_friction 'sticky'"):
        sf.scene_from_dict(data, source="s.json").build()
    data = {"format": "jaxrb-scene", "version": 2, "dim": 2, "bodies": [{"shape": {"kind": "circle", "radius": 0.1}}],
            "joints": [{"kind": "ball", "child": 0}]}
    with pytest.raises(ValueError, match=r"^s\.json: joints\[0\]\.kind: a ball joint is 3D only"):
        sf.scene_from_dict(data, source="s.json")
    data["joints"] = [{"kind": "slide", "axis": [1, 0], "child": 0}, {"kind": "hinge", "anchor": [0, 0.1], "child": 0}]
    loaded = sf.scene_from_dict(data, source="s.json")
    assert sf.scene_from_dict(sf.scene_to_dict(loaded.scene)).build(dt=0.01)[0].joints.nq == 2


def test_version_1_files_still_read():
    """A version 1 file (no joints) builds what the same scene saved as version 2 builds."""
    first = sf.scene_from_dict(_base(), source="v1.json")
    data = sf.scene_to_dict(first.scene, **first.build_options)
    assert data["version"] == 2 and _base()["version"] == 1
    assert_same_build(first.build(), sf.scene_from_dict(data).build())


def test_2d_shape_errors_name_the_field():
    data = {"format": "jaxrb-scene", "version": 1, "dim": 2,
            "bodies": [{"shape": {"kind": "polygon", "vertices": [[0, 0], [1, 0], [2, 0]]}}]}
    with pytest.raises(ValueError, match=r"^s\.json: bodies\[0\]\.shape\.vertices: must form a strictly convex"):
        sf.scene_from_dict(data, source="s.json")
    data["bodies"] = [{"shape": {"kind": "sphere", "radius": 0.1}}]
    with pytest.raises(ValueError, match=r"^s\.json: bodies\[0\]\.shape: Sphere is not a 2D shape"):
        sf.scene_from_dict(data, source="s.json")
    data["bodies"] = [{"shape": {"kind": "point_masses", "points": [[0, 0]], "masses": [1.0]}}]
    with pytest.raises(ValueError, match=r"^s\.json: bodies\[0\]\.shape\.inertia: is singular"):
        sf.scene_from_dict(data, source="s.json")


@pytest.mark.parametrize("text, message", [
    ('{"format": "jaxrb-scene", "version": 1,', r"not valid JSON: .*line 1"),
    ('{"format": "jaxrb-scene", "format": "jaxrb-scene"}', r"not valid JSON: duplicate key 'format'"),
    ('{"format": "jaxrb-scene", "version": 1, "dim": 3, "gravity": [0, 0, NaN], "bodies": []}',
     r"not valid JSON: NaN is not a number"),
    ('[1, 2]', r"expected an object, got a list of 2"),
])
def test_bad_json_files(tmp_path, text, message):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"^{path}: " + message):
        sf.load_scene(path)


def test_suffixes(tmp_path):
    with pytest.raises(ValueError, match=r"unknown suffix '\.yaml'"):
        sf.load_scene(tmp_path / "scene.yaml")
    with pytest.raises(ValueError, match=r"'\.json' suffix"):
        sf.save_scene(tmp_path / "scene.txt", scene_2d())
    with pytest.raises(ValueError, match=r"save_scene: build\.dtype"):
        sf.save_scene(tmp_path / "scene.json", scene_2d(), dtype="int32")
    scene = rb.Scene(dim=2)
    scene.add_body(rb.Circle(radius=0.1), name=7)
    with pytest.raises(ValueError, match=r"save_scene: bodies\[0\]\.name: only string names"):
        sf.save_scene(tmp_path / "scene.json", scene)
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Sphere(radius=0.1))
    scene.add_joint(rb.Hinge(), 0, name=("shoulder", 1))
    with pytest.raises(ValueError, match=r"save_scene: joints\[0\]\.name: only string names"):
        sf.save_scene(tmp_path / "scene.json", scene)


def test_modules_split_without_a_cycle():
    """JSON (scenefile), MJCF (mjcf) and what they share (scenefile_common): the old names
    still import from jaxrb.files.scenefile, and neither mjcf nor scenefile_common imports scenefile."""
    assert sf.SceneFile is scenefile_common.SceneFile is rb.SceneFile
    assert sf.scene_from_mjcf is mjcf.scene_from_mjcf
    for module, forbidden in ((mjcf, {"jaxrb.files.scenefile"}),
                              (scenefile_common, {"jaxrb.files.scenefile", "jaxrb.files.mjcf"})):
        tree = ast.parse(pathlib.Path(module.__file__).read_text())
        imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                    for alias in node.names}
        imported |= {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
        imported |= {f"{node.module}.{alias.name}" for node in ast.walk(tree)
                     if isinstance(node, ast.ImportFrom) for alias in node.names}
        assert not imported & forbidden, (module.__name__, imported & forbidden)
