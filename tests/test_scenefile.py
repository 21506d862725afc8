"""Scene files: JSON round trips, malformed files, and MJCF import checked against MuJoCo."""

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
EXAMPLE = pathlib.Path(__file__).resolve().parent.parent / "examples" / "box_drop.xml"


def assert_same_build(first, second):
    """Two (model, params, state) triples are equal: static Model, every leaf and its dtype."""
    (model_a, params_a, state_a), (model_b, params_b, state_b) = first, second
    assert model_a == model_b
    leaves_a = jax.tree_util.tree_leaves_with_path((params_a, state_a))
    leaves_b = jax.tree_util.tree_leaves((params_b, state_b))
    assert len(leaves_a) == len(leaves_b)
    for (path, a), b in zip(leaves_a, leaves_b):
        assert a.dtype == b.dtype, jax.tree_util.keystr(path)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))


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


@pytest.mark.parametrize("make_scene", [scene_3d, scene_2d], ids=["3d", "2d"])
def test_json_round_trip_rebuilds_identical_model_params_state(make_scene, tmp_path):
    scene = make_scene()
    path = tmp_path / "scene.json"
    sf.save_scene(path, scene, dt=0.004, substeps=2)
    loaded = sf.load_scene(path)
    assert loaded.source == str(path) and loaded.warnings == []
    assert loaded.build_options == {"dt": 0.004, "substeps": 2}
    assert loaded.scene.num_bodies == scene.num_bodies
    assert_same_build(scene.build(dt=0.004, substeps=2), loaded.build())
    # A second save of the loaded scene writes the same file.
    again = tmp_path / "again.json"
    sf.save_scene(again, loaded.scene, **loaded.build_options)
    assert json.loads(again.read_text()) == json.loads(path.read_text())


def test_saved_file_holds_what_the_user_gave():
    data = sf.scene_to_dict(scene_3d())
    assert data["format"] == "jaxrb-scene" and data["version"] == 1 and data["dim"] == 3
    assert data["gravity"] == [0.1, 0.0, -9.7]
    crate = data["bodies"][0]
    assert crate == {"shape": {"kind": "box", "half_extents": [0.1, 0.2, 0.3]}, "mass": 2.0,
                     "pos": [0.0, 0.0, 1.0], "quat": [1.0, 0.1, 0.2, 0.0], "vel": [1.0, 0.0, 0.0],
                     "name": "crate"}
    assert "shape" not in data["bodies"][4]
    assert data["planes"][0] == {"friction": 0.7}
    assert "build" not in data
    json.dumps(data, allow_nan=False)  # plain data only


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


def _base():
    return {"format": "jaxrb-scene", "version": 1, "dim": 3,
            "bodies": [{"shape": {"kind": "box", "half_extents": [0.1, 0.1, 0.1]}, "mass": 1.0},
                       {"shape": {"kind": "sphere", "radius": 0.1}, "pos": [0, 0, 1]}],
            "planes": [{"normal": [0, 0, 1]}],
            "build": {"dt": 0.004}}


def _edit(path, value):
    """A copy of the base file with the field at ``path`` (a tuple of keys) set, or deleted if None."""
    data = copy.deepcopy(_base())
    target = data
    for key in path[:-1]:
        target = target[key]
    if value is None:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return data


MALFORMED = [
    (("version",), 2, r"version: unsupported version 2; this jaxrb reads version\(s\) 1"),
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


# --------------------------------------------------------------------------- #
# MJCF
# --------------------------------------------------------------------------- #

def test_example_box_drop_loads():
    loaded = sf.load_scene(EXAMPLE)
    assert loaded.warnings == []
    assert loaded.build_options == {"dt": 0.002, "integrator": "semi_implicit", "contact": "impulse",
                                    "substeps": 2}
    model, params, state = loaded.build()
    assert model.shapes == (rb.Box(half_extents=(0.1, 0.1, 0.1)),) and model.names == ("box",)
    assert model.planes == (((0.0, 0.0, 1.0), 0.0),) and model.contact == "impulse"
    np.testing.assert_allclose(params.mass, [1.0])
    np.testing.assert_allclose(params.inertia[0], np.eye(3) * 0.04 / 6.0)
    np.testing.assert_allclose(params.friction, [0.8])
    np.testing.assert_allclose(params.plane_friction, [0.8])
    np.testing.assert_allclose(params.dt, 0.002)
    np.testing.assert_allclose(state.pos, [[0.0, 0.0, 0.5]])
    half = np.radians(15.0)
    np.testing.assert_allclose(state.quat, [[np.cos(half), 0.0, 0.0, np.sin(half)]], atol=1e-15)


def test_mjcf_scene_saves_as_json(tmp_path):
    loaded = sf.load_scene(EXAMPLE)
    path = tmp_path / "box_drop.json"
    sf.save_scene(path, loaded.scene, **loaded.build_options)
    assert_same_build(loaded.build(), sf.load_scene(path).build())


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
def test_mjcf_poses_and_inertia_match_mujoco(compiler):
    """Orientation conventions (quat order, euler sequences, axis-angle, xyaxes, zaxis,
    fromto, degrees/radians), geom offsets and inertial frames, against MuJoCo's compiler."""
    mujoco = pytest.importorskip("mujoco")
    xml = POSES.format(compiler=compiler)
    mj_model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(mj_model)
    mujoco.mj_forward(mj_model, data)
    loaded = sf.scene_from_mjcf(xml)
    assert loaded.warnings and "friction" in loaded.warnings[-1]  # 0.6 plane vs 1.0 bodies
    model, params, state = loaded.build()
    normal, offset = model.planes[0]
    plane_z = data.geom_xmat[0].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(normal, plane_z, atol=1e-12)
    np.testing.assert_allclose(offset, data.geom_xpos[0] @ plane_z, atol=1e-12)
    for index in range(model.num_bodies):
        body = index + 1
        rotation = mjcf._rotation(np.asarray(state.quat[index]))
        mj_rotation = data.ximat[body].reshape(3, 3)
        np.testing.assert_allclose(state.pos[index], data.xipos[body], atol=1e-12)
        np.testing.assert_allclose(params.mass[index], mj_model.body_mass[body], rtol=1e-12)
        np.testing.assert_allclose(rotation @ np.asarray(params.inertia[index]) @ rotation.T,
                                   mj_rotation @ np.diag(mj_model.body_inertia[body]) @ mj_rotation.T,
                                   atol=1e-10)
        if index < 4:  # the jaxrb body frame is the geom frame
            geom_rotation = data.geom_xmat[body].reshape(3, 3)
            np.testing.assert_allclose(state.pos[index], data.geom_xpos[body], atol=1e-12)
            if index == 0:
                np.testing.assert_allclose(rotation, geom_rotation, atol=1e-12)
            elif index in (1, 2):  # a capsule's frame is fixed up to a turn about its axis
                np.testing.assert_allclose(abs(rotation[:, 2] @ geom_rotation[:, 2]), 1.0, atol=1e-12)
    assert model.shapes[4] is None
    assert model.shapes[2] == rb.Capsule(radius=0.05, half_length=0.5 * np.sqrt(0.14))


def _rest_height(run_step, state, params, steps):
    trajectory = rb.rollout(run_step, state, params, num_steps=steps)
    return np.asarray(trajectory.pos[-1, :, 2]), np.asarray(trajectory.vel[-1])


def test_mjcf_box_and_sphere_rest_like_mujoco():
    """The example box and a sphere, dropped for 1.5 s in MuJoCo and in jaxrb, rest at the
    same height (their centres 0.1 m above the plane) within 5 mm."""
    text = EXAMPLE.read_text().replace(
        "</worldbody>", '<body name="ball" pos="1 0 0.3"><freejoint/>'
        '<geom type="sphere" size="0.1" mass="0.5" friction="0.8"/></body></worldbody>')
    loaded = sf.scene_from_mjcf(text)
    assert loaded.warnings == []
    model, params, state = loaded.build()
    steps = round(1.5 / 0.002)
    heights, velocities = _rest_height(jax.jit(rb.make_step(model)), state, params, steps)
    np.testing.assert_allclose(heights, [0.1, 0.1], atol=5e-4)
    assert np.max(np.abs(velocities)) < 1e-2

    mujoco = pytest.importorskip("mujoco")
    mj_model = mujoco.MjModel.from_xml_string(text)
    assert mj_model.opt.timestep == 0.002
    data = mujoco.MjData(mj_model)
    for _ in range(steps):
        mujoco.mj_step(mj_model, data)
    mj_heights = data.geom_xpos[1:, 2]
    np.testing.assert_allclose(mj_heights, [0.1, 0.1], atol=5e-3)
    np.testing.assert_allclose(heights, mj_heights, atol=5e-3)


def _mjcf(body="", world="", top=""):
    return (f"<mujoco>{top}<worldbody><geom type='plane' size='1 1 .1'/>{world}"
            f"<body name='b' pos='0 0 1'>{body}</body></worldbody></mujoco>")


FREE_BOX = "<freejoint/><geom type='box' size='.1 .1 .1'/>"

UNSUPPORTED = [
    (_mjcf("<joint type='hinge'/><geom size='.1'/>"), r"<joint>: attribute 'type'='hinge'"),
    (_mjcf("<joint/><geom size='.1'/>"), r"<joint>: attribute 'type'='hinge'"),
    (_mjcf("<geom size='.1'/>"), r"<body name='b'>: a body without a free joint"),
    (_mjcf(FREE_BOX + "<body><freejoint/><geom size='.1'/></body>"), r"<body name='b'> <body>: nested bodies"),
    (_mjcf(FREE_BOX + "<geom name='g2' size='.1'/>"), r"<geom name='g2'>: a body may have at most one geom"),
    (_mjcf("<freejoint/><geom type='mesh' mesh='m'/>"), r"<geom>: attribute 'type'='mesh'"),
    (_mjcf("<freejoint/><geom type='cylinder' size='.1 .1'/>"), r"<geom>: attribute 'type'='cylinder'"),
    (_mjcf("<freejoint/><geom type='box' size='.1 .1'/>"), r"<geom>: attribute 'size': expected at least 3"),
    (_mjcf("<freejoint/><geom type='sphere' size='.1' fromto='0 0 0 1 0 0'/>"), r"attribute 'fromto'"),
    (_mjcf("<freejoint/><geom size='.1' contype='1' conaffinity='2'/>"), r"'contype'='1', 'conaffinity'='2'"),
    (_mjcf("<freejoint/><geom size='.1' euler='1 2 3' quat='1 0 0 0'/>"), r"give at most one orientation"),
    (_mjcf("<freejoint/><geom size='.1' pos='0.1 0 0'/><inertial pos='0 0 0' mass='1' diaginertia='1 1 1'/>"),
     r"<inertial>: attribute 'pos'.*centre of mass"),
    (_mjcf("<freejoint damping='1'/><geom size='.1'/>"), r"<freejoint>: attribute 'damping'"),
    (_mjcf("<joint type='free' damping='1'/><geom size='.1'/>"), r"<joint>: attribute 'damping'=1.0"),
    (_mjcf(FREE_BOX, world="<geom type='box' size='1 1 .1'/>"), r"<worldbody> <geom>: attribute 'type'='box'"),
    (_mjcf(FREE_BOX, top="<default><geom friction='.5'/></default>"), r"<default>: element <default>"),
    (_mjcf(FREE_BOX, top="<include file='x.xml'/>"), r"<include>: element <include>"),
    (_mjcf(FREE_BOX).replace("</mujoco>", "<actuator><motor joint='j'/></actuator></mujoco>"),
     r"<actuator>: element <actuator>"),
    (_mjcf(FREE_BOX).replace("</mujoco>", "<tendon/></mujoco>"), r"<tendon>: element <tendon>"),
    (_mjcf(FREE_BOX).replace("</mujoco>", "<equality/></mujoco>"), r"<equality>: element <equality>"),
    (_mjcf(FREE_BOX, top="<option><flag contact='disable'/></option>"), r"<option> <flag>"),
    (_mjcf(FREE_BOX, top="<option viscosity='0.1'/>"), r"<option>: attribute 'viscosity'"),
    (_mjcf(FREE_BOX, top="<option timestep='-1'/>"), r"<option>: attribute 'timestep': must be positive"),
    (_mjcf(FREE_BOX, top="<compiler angle='grad'/>"), r"<compiler>: attribute 'angle'"),
    (_mjcf(FREE_BOX).replace("<body name='b'", "<body name='b' childclass='c'"),
     r"<body name='b'>: attribute 'childclass' is not supported"),
    (_mjcf("<freejoint/><geom size='.1' mass='-1'/>"), r"<geom>: attribute 'mass': must be positive"),
    (_mjcf("<freejoint/><geom size='abc'/>"), r"<geom>: attribute 'size': expected numbers, got 'abc'"),
    ("<!DOCTYPE m [<!ENTITY x 'y'>]><mujoco/>", r"document: DOCTYPE and ENTITY"),
    ("<mujoco><worldbody>", r"document: not well-formed XML"),
    ("<robot/>", r"<robot>: the root element must be <mujoco>"),
]


@pytest.mark.parametrize("xml, message", UNSUPPORTED, ids=[case[1][:40] for case in UNSUPPORTED])
def test_unsupported_mjcf_is_an_error_naming_the_element(xml, message):
    with pytest.raises(ValueError, match=r"^m\.xml: .*" + message):
        sf.scene_from_mjcf(xml, source="m.xml")


def test_mjcf_harmless_attributes_become_warnings():
    xml = _mjcf("<freejoint/><geom size='.1' solref='0.01 1' rgba='1 0 0 1' condim='4'/><site/>",
                top="<option integrator='RK4' cone='elliptic'/><visual/>")
    xml = xml.replace("</mujoco>", "<sensor/></mujoco>")
    loaded = sf.scene_from_mjcf(xml)
    text = "\n".join(loaded.warnings)
    for expected in ("solref='0.01 1'", "rgba='1 0 0 1'", "condim='4' ignored", "no torsional", "<site>", "<visual>",
                     "<sensor>", "integrator='RK4'", "cone='elliptic'"):
        assert expected in text, (expected, text)
    assert not any(warning.startswith("friction") for warning in loaded.warnings)  # both default 1
    assert loaded.scene.num_bodies == 1


def test_mjcf_friction_mixing_warning_and_values():
    loaded = sf.scene_from_mjcf(_mjcf("<freejoint/><geom size='.1' friction='0.25'/>"))
    assert len(loaded.warnings) == 1
    warning = loaded.warnings[0]
    assert "max()" in warning and "'b' (0.25) with plane 0 (1): MuJoCo 1, jaxrb 0.5" in warning
    _, params, _ = loaded.build()
    np.testing.assert_allclose(params.friction, [0.25])
    np.testing.assert_allclose(params.plane_friction, [1.0])


def test_mjcf_defaults_and_collision_bits():
    xml = ("<mujoco><option timestep='0.005' gravity='0 0 -3'/><worldbody>"
           "<geom type='plane' size='1 1 .1' contype='2' conaffinity='2'/>"
           "<body><freejoint/><geom size='0.1' contype='3' conaffinity='3'/></body></worldbody></mujoco>")
    loaded = sf.scene_from_mjcf(xml)
    assert loaded.build_options["dt"] == 0.005 and loaded.build_options["substeps"] == 5
    model, params, _ = loaded.build()
    assert model.shapes == (rb.Sphere(radius=0.1),)
    np.testing.assert_allclose(params.mass, [1000.0 * 4.0 / 3.0 * np.pi * 0.1 ** 3])
    np.testing.assert_allclose(params.gravity, [0.0, 0.0, -3.0])
    body, plane = loaded.scene._bodies[0], loaded.scene._planes[0]
    assert body.collision_filter == (3, 3) and plane.collision_filter == (2, 2)
