"""jaxrb.render: pictures show the bodies where they are, contacts where detection finds
them, animations and plots hold the right frames and numbers. Headless (Agg).

Trajectories are stacked by hand (no rollout to compile), so the only compiled code
is contact detection for the two contact scenes.
"""

import gc

import matplotlib

matplotlib.use("Agg")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib import animation as mpl_animation  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from mpl_toolkits.mplot3d import proj3d  # noqa: E402
from PIL import Image  # noqa: E402

import jaxrb as rb  # noqa: E402
import jaxrb.render as render  # noqa: E402

# The reference contacts, jitted (eager detection compiles op by op and is slower).
detect = jax.jit(rb.detect_contacts, static_argnums=0)

EXTENT_3D = (-0.5, 0.5, -0.5, 0.5, -0.1, 0.6)
EXTENT_2D = (-0.6, 0.6, -0.15, 0.6)


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def new_axes(dim, size=(5.0, 5.0)):
    fig = Figure(figsize=size, dpi=100)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    FigureCanvasAgg(fig)
    return fig.add_subplot(projection="3d" if dim == 3 else None)


def stack(states):
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *states)


def artists_with_gid(ax, gid):
    found = [a for a in ax.get_children() if a.get_gid() == gid]
    assert found, f"no artist with gid {gid!r}"
    return found


def pixel_of(ax, point):
    """(row, column) of a world point in figure_pixels' image (row 0 at the top)."""
    if len(point) == 3:
        x, y, _ = proj3d.proj_transform(*point, ax.get_proj())
        point = (x, y)
    x, y = ax.transData.transform(point)
    height = ax.figure.canvas.get_width_height()[1]
    return int(round(height - y)), int(round(x))


def hide_and_render(ax, gid):
    for artist in artists_with_gid(ax, gid):
        artist.set_visible(False)
    return render.figure_pixels(ax.figure)


# --------------------------------------------------------------------------------------
# Scenes


@pytest.fixture(scope="module")
def box_drop():
    """A 0.2 m cube resting on the plane z = 0 (centre at z = 0.1)."""
    scene = rb.Scene(dim=3)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.1))
    return scene.build(dt=1 / 60)


@pytest.fixture(scope="module")
def planar():
    """A 2D box (left) and a circle (right) resting on the half-plane y < 0."""
    scene = rb.Scene(dim=2)
    scene.add_plane(friction=0.5)
    scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(-0.3, 0.1))
    scene.add_body(rb.Circle(0.1), mass=1.0, pos=(0.3, 0.1), angle=0.7)
    return scene.build(dt=1 / 60)


@pytest.fixture(scope="module")
def every_shape_3d():
    scene = rb.Scene(dim=3)
    scene.add_plane()
    scene.add_body(rb.Box((0.1, 0.05, 0.08)), mass=1.0, pos=(0.0, 0.0, 0.5))
    scene.add_body(rb.Sphere(0.1), mass=1.0, pos=(0.4, 0.0, 0.3))
    scene.add_body(rb.Capsule(0.05, 0.1), mass=1.0, pos=(-0.4, 0.0, 0.3),
                   quat=(np.cos(0.4), np.sin(0.4), 0.0, 0.0))
    scene.add_body(rb.PointMasses(points=[(0, 0, 0), (0.2, 0, 0), (0, 0.2, 0), (0, 0, 0.2)],
                                  masses=[1.0, 1.0, 1.0, 3.0]), pos=(0.0, 0.4, 0.3),
                   quat=(np.cos(0.3), 0.0, 0.0, np.sin(0.3)))
    scene.add_body(None, mass=1.0, inertia=(0.1, 0.1, 0.1), pos=(0.0, -0.4, 0.3))
    return scene.build(dt=1 / 60, contact="none")


@pytest.fixture(scope="module")
def every_shape_2d():
    scene = rb.Scene(dim=2)
    scene.add_plane()
    scene.add_body(rb.Box((0.1, 0.05)), mass=1.0, pos=(0.0, 0.5), angle=0.2)
    scene.add_body(rb.Circle(0.1), mass=1.0, pos=(0.4, 0.3), angle=0.7)
    # A triangle whose centroid (0.1, 0.05) is not the body origin.
    scene.add_body(rb.Polygon([(0.0, 0.0), (0.2, 0.0), (0.1, 0.15)]), mass=1.0,
                   pos=(-0.4, 0.3), angle=0.5)
    scene.add_body(rb.PointMasses(points=[(0, 0), (0.2, 0), (0, 0.2)], masses=[1.0, 1.0, 2.0]),
                   pos=(0.0, 0.2), angle=-0.4)
    scene.add_body(None, mass=1.0, inertia=0.1, pos=(0.6, 0.6))
    return scene.build(dt=1 / 60, contact="none")


def falling_box_traj(box_drop, heights):
    """The box of ``box_drop`` at the given heights, falling at 1 m/s, 0.1 s apart."""
    model, params, state = box_drop
    states = [state.replace(pos=state.pos.at[0, 2].set(z), vel=state.vel.at[0, 2].set(-1.0),
                            time=jnp.asarray(0.1 * (k + 1), dtype=state.time.dtype))
              for k, z in enumerate(heights)]
    return stack(states)


# --------------------------------------------------------------------------------------
# Bodies are drawn where they are


def test_3d_box_pixels_only_where_the_box_projects(box_drop):
    model, params, state = box_drop
    ax = render.draw(model, params, state, ax=new_axes(3), extent=EXTENT_3D)
    with_box = render.figure_pixels(ax.figure)
    without_box = hide_and_render(ax, "jaxrb.body0")
    changed = np.any(with_box[..., :3] != without_box[..., :3], axis=-1)

    row, column = pixel_of(ax, (0.0, 0.0, 0.1))
    assert changed[row - 2:row + 3, column - 2:column + 3].all(), "box centre not drawn"
    corners = np.array([(x, y, z) for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (0.0, 0.2)])
    rows, columns = zip(*(pixel_of(ax, c) for c in corners))
    inside = np.zeros_like(changed)
    inside[min(rows) - 3:max(rows) + 4, min(columns) - 3:max(columns) + 4] = True
    assert changed.sum() > 200
    assert not (changed & ~inside).any(), "pixels changed away from the box"
    # Far above the box: untouched.
    row, column = pixel_of(ax, (0.0, 0.0, 0.5))
    assert not changed[row, column]


def test_2d_box_and_circle_pixels(planar):
    model, params, state = planar
    ax = render.draw(model, params, state, ax=new_axes(2, (6.0, 4.0)), extent=EXTENT_2D,
                     colors=["tab:blue", "tab:orange"])
    pixels = render.figure_pixels(ax.figure).astype(float)
    white = np.array([255.0, 255.0, 255.0])

    def colour_at(point):
        row, column = pixel_of(ax, point)
        return pixels[row, column, :3]

    # Inside the box and the disc the body colour shows (blended at alpha 0.65 on white).
    for point, name in (((-0.3, 0.05), "tab:blue"), ((0.25, 0.05), "tab:orange")):
        expected = (0.65 * np.array(to_rgba(name)[:3]) + 0.35) * 255.0
        assert np.abs(colour_at(point) - expected).max() < 12.0, (point, colour_at(point), expected)
    # Empty space stays white; the half-plane band is grey.
    for point in ((0.0, 0.4), (-0.3, 0.35), (0.45, 0.1), (-0.55, 0.5)):
        assert np.abs(colour_at(point) - white).max() < 1.0, point
    band = colour_at((0.0, -0.03))
    assert np.ptp(band) < 10.0 and band.max() < 235.0, band

    # Hiding the circle changes only pixels inside its disc (plus its edge line).
    before = pixels[..., :3]
    after = hide_and_render(ax, "jaxrb.body1")[..., :3].astype(float)
    changed = np.any(before != after, axis=-1)
    rows, columns = np.nonzero(changed)
    centre = np.array(pixel_of(ax, (0.3, 0.1)))
    radius = abs(pixel_of(ax, (0.4, 0.1))[1] - centre[1])
    distance = np.hypot(rows - centre[0], columns - centre[1])
    assert changed.sum() > 0.8 * np.pi * radius ** 2
    assert distance.max() <= radius + 3.0


def test_rotation_and_com_offset_in_2d(every_shape_2d):
    model, params, state = every_shape_2d
    ax = render.draw(model, params, state, ax=new_axes(2))
    # Circle: the radius line points along the body x axis.
    line = [a for a in artists_with_gid(ax, "jaxrb.body1") if hasattr(a, "get_xydata")][0]
    (x0, y0), (x1, y1) = line.get_xydata()
    assert np.allclose([x0, y0], [0.4, 0.3])
    assert np.allclose([x1, y1], [0.4 + 0.1 * np.cos(0.7), 0.3 + 0.1 * np.sin(0.7)])
    # Polygon: drawn at body origin + R v, although the state holds its centroid.
    patch = artists_with_gid(ax, "jaxrb.body2")[0]
    c, s = np.cos(0.5), np.sin(0.5)
    local = np.array([(0.0, 0.0), (0.2, 0.0), (0.1, 0.15)])
    expected = np.array([-0.4, 0.3]) + local @ np.array([[c, -s], [s, c]]).T
    drawn = patch.get_xy()[:3]
    assert np.allclose(drawn, expected), (drawn, expected)
    assert not np.allclose(np.asarray(state.pos[2]), [-0.4, 0.3])  # the state is the centroid


def test_every_shape_draws_in_3d(every_shape_3d):
    model, params, state = every_shape_3d
    ax = render.draw(model, params, state, ax=new_axes(3), title="all shapes")
    assert render.figure_pixels(ax.figure).shape == (500, 500, 4)
    for body in range(model.num_bodies):
        artists_with_gid(ax, f"jaxrb.body{body}")
    artists_with_gid(ax, "jaxrb.plane0")
    # The sphere mesh is centred on the sphere with the sphere's radius.
    sphere = artists_with_gid(ax, "jaxrb.body1")[0]
    vertices = sphere.jaxrb_faces.reshape(-1, 3)
    radii = np.linalg.norm(vertices - np.array([0.4, 0.0, 0.3]), axis=1)
    assert np.allclose(radii, 0.1, atol=1e-9)
    # Point masses sit at pos + R p (the shape frame origin is the first point).
    dots = [a for a in artists_with_gid(ax, "jaxrb.body3") if a.get_marker() == "o"][0]
    drawn = np.stack(dots.get_data_3d(), axis=1)
    c, s = np.cos(0.6), np.sin(0.6)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    points = np.array([(0, 0, 0), (0.2, 0, 0), (0, 0.2, 0), (0, 0, 0.2)])
    assert np.allclose(drawn, np.array([0.0, 0.4, 0.3]) + points @ rotation.T)
    # Automatic limits enclose every body.
    assert ax.get_xlim()[0] < -0.45 and ax.get_xlim()[1] > 0.5
    assert ax.get_zlim()[0] <= 0.0 and ax.get_zlim()[1] > 0.58


def test_every_shape_draws_in_2d(every_shape_2d):
    model, params, state = every_shape_2d
    ax = render.draw(model, params, state, show_time=True, title="all shapes")
    assert "t = 0.000 s" in ax.get_title()
    pixels = render.figure_pixels(ax.figure)
    assert pixels.dtype == np.uint8 and pixels.shape[2] == 4
    for body in range(model.num_bodies):
        artists_with_gid(ax, f"jaxrb.body{body}")
    dots = [a for a in artists_with_gid(ax, "jaxrb.body3") if hasattr(a, "get_offsets")][0]
    assert len(dots.get_offsets()) == 3
    x_low, x_high = ax.get_xlim()
    y_low, y_high = ax.get_ylim()
    assert x_low < -0.45 and x_high > 0.6 and y_low < 0.0 and y_high > 0.6


def lab(color):
    """CIELAB (D65) of a matplotlib colour: distances of ~40 or less read as one hue family."""
    rgb = np.array(to_rgba(color)[:3])
    linear = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722],
                    [0.0193, 0.1192, 0.9505]]) @ linear / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def test_default_body_colours_keep_clear_of_the_status_colours():
    # Issue 61: the default colours were the property cycle (blue, orange, green, red, ...),
    # so the second body was the orange of "separating" and the third the green of "resting".
    scene = rb.Scene(dim=2)
    for k in range(8):  # more bodies than the palette has colours: it cycles
        scene.add_body(rb.Box((0.05, 0.05)), mass=1.0, pos=(0.2 * k, 0.5))
    model, params, state = scene.build(dt=1 / 60, contact="none")
    ax = render.draw(model, params, state, ax=new_axes(2))
    drawn = [artists_with_gid(ax, f"jaxrb.body{k}")[0].get_facecolor() for k in range(8)]
    status = [lab(color) for color in render.STATUS_COLORS.values()]
    # The status colours are 40 apart among themselves (red, orange); bodies keep 60 from each.
    closest = min(np.linalg.norm(lab(color) - s) for color in drawn for s in status)
    assert closest > 60.0, closest
    assert len({tuple(np.round(c, 6)) for c in drawn}) == len(render.BODY_COLORS)
    assert to_rgba(drawn[1])[:3] == to_rgba(render.BODY_COLORS[1])[:3]
    # 3D meshes take the same default colours (their faces shaded darker or lighter).
    box_model, box_params, box_state = scene_3d_box()
    ax = render.draw(box_model, box_params, box_state, ax=new_axes(3))
    render.figure_pixels(ax.figure)
    faces = artists_with_gid(ax, "jaxrb.body0")[0].get_facecolor()[:, :3]
    blue = np.array(to_rgba(render.BODY_COLORS[0])[:3])
    scale = faces / blue
    assert np.allclose(scale, scale[:, :1], atol=1e-6)  # every face a shade of the same blue
    # Colours the user gives are used as they are, status-like or not.
    ax = render.draw(model, params, state, ax=new_axes(2), colors="tab:orange")
    assert to_rgba(artists_with_gid(ax, "jaxrb.body0")[0].get_facecolor())[:3] == \
        to_rgba("tab:orange")[:3]


def scene_3d_box():
    scene = rb.Scene(dim=3)
    scene.add_body(rb.Box((0.1, 0.1, 0.1)), mass=1.0, pos=(0.0, 0.0, 0.5))
    return scene.build(dt=1 / 60, contact="none")


def test_two_tilted_half_planes_show_a_v_not_an_x():
    # Issue 61: each half-plane was a line across the whole view with a thin band under
    # it, so a valley of two planes tilted 30 degrees showed as two crossing lines.
    tilt = np.radians(30.0)
    scene = rb.Scene(dim=2)
    scene.add_plane(normal=(np.sin(tilt), np.cos(tilt)))   # left slope, y = -x tan 30
    scene.add_plane(normal=(-np.sin(tilt), np.cos(tilt)))  # right slope, y = x tan 30
    scene.add_body(rb.Circle(0.05), mass=1.0, pos=(0.0, 0.1))
    model, params, state = scene.build(dt=1 / 60, contact="none")
    extent = (-0.6, 0.6, -0.3, 0.5)
    ax = render.draw(model, params, state, ax=new_axes(2, (6.0, 4.0)), extent=extent)
    corners = np.array([(x, y) for x in extent[:2] for y in extent[2:]])
    for index, (normal, offset) in enumerate(model.planes):
        normal = np.asarray(normal)
        other = np.asarray(model.planes[1 - index][0])
        artists = artists_with_gid(ax, f"jaxrb.plane{index}")
        (fill,) = [a for a in artists if hasattr(a, "get_xy")]
        (line,) = [a for a in artists if hasattr(a, "get_xydata")]
        # The fill is the plane's whole solid side in view: every vertex on that side,
        # every view corner on that side among its vertices.
        vertices = fill.get_xy()
        assert np.all(vertices @ normal - offset <= 1e-9)
        for corner in corners[corners @ normal - offset < 0.0]:
            assert np.min(np.linalg.norm(vertices - corner, axis=1)) < 1e-9, corner
        # The line: on the plane, inside the view, and only where the other plane is open,
        # so from the valley floor (0, 0) up its own slope to the edge of the view.
        ends = line.get_xydata()
        assert np.allclose(ends @ normal, offset, atol=1e-9)
        assert np.all(ends >= np.array(extent[0::2]) - 1e-9)
        assert np.all(ends <= np.array(extent[1::2]) + 1e-9)
        assert np.all(ends @ other >= -1e-9)
        assert np.min(np.linalg.norm(ends, axis=1)) < 1e-9
        assert np.max(np.abs(ends[:, 0])) == pytest.approx(0.6)
        assert np.all(ends[:, 0] * (1 if index == 0 else -1) <= 1e-9)  # left slope at x <= 0
    pixels = render.figure_pixels(ax.figure).astype(float)

    def colour_at(point):
        row, column = pixel_of(ax, point)
        return pixels[row, column, :3]

    # Solid under one slope only (below the other's line continued), solid under both,
    # and open space in the V.
    one, both, open_ = colour_at((0.5, 0.1)), colour_at((0.0, -0.2)), colour_at((-0.3, 0.35))
    assert np.ptp(one) < 10.0 and one.max() < 235.0, one
    assert both.max() < one.min(), (both, one)
    assert np.abs(open_ - 255.0).max() < 1.0, open_

    # 3D: the same valley along y; each plane's patch stops where the other plane's solid starts.
    scene = rb.Scene(dim=3)
    scene.add_plane(normal=(np.sin(tilt), 0.0, np.cos(tilt)))
    scene.add_plane(normal=(-np.sin(tilt), 0.0, np.cos(tilt)))
    scene.add_body(rb.Sphere(0.05), mass=1.0, pos=(0.0, 0.0, 0.1))
    model, params, state = scene.build(dt=1 / 60, contact="none")
    ax = render.draw(model, params, state, ax=new_axes(3), extent=(-0.6, 0.6, -0.3, 0.3, -0.3, 0.5))
    for index, (normal, offset) in enumerate(model.planes):
        (patch,) = artists_with_gid(ax, f"jaxrb.plane{index}")
        (polygon,) = patch.jaxrb_faces
        assert np.allclose(polygon @ np.asarray(normal), offset, atol=1e-9)
        assert np.all(polygon @ np.asarray(model.planes[1 - index][0]) >= -1e-9)
        assert np.all(polygon[:, 0] * (1 if index == 0 else -1) <= 1e-9)
        assert np.ptp(polygon[:, 1]) == pytest.approx(0.6) and np.max(polygon[:, 2]) > 0.3


# --------------------------------------------------------------------------------------
# Contacts


def contact_groups(ax):
    """[(dots, arrows)]: the visible contacts, then in 3D those hidden behind bodies."""
    suffixes = ("", "_hidden") if ax.name == "3d" else ("",)
    return [(artists_with_gid(ax, f"jaxrb.contact_points{suffix}")[0],
             artists_with_gid(ax, f"jaxrb.contact_normals{suffix}")[0]) for suffix in suffixes]


def check_contact_artists(ax, found):
    active = np.asarray(found.active)
    count = int(active.sum())
    assert count > 0
    render.figure_pixels(ax.figure)  # mplot3d fixes scatter colours (depth-sorted) when drawn
    groups = contact_groups(ax)
    for dots, arrows in groups:
        assert arrows.jaxrb_segments.shape[:2] == (3 * len(dots.get_offsets()), 2)
    assert sum(len(dots.get_offsets()) for dots, _ in groups) == count
    expected = [to_rgba(render.STATUS_COLORS[int(s)])[:3]
                for s in np.asarray(found.status)[active]]
    drawn = [tuple(c[:3]) for dots, _ in groups for c in np.round(dots.get_facecolors(), 6)]
    assert np.allclose(sorted(drawn), sorted(map(tuple, np.round(expected, 6))))
    return count


def test_contacts_3d(box_drop):
    model, params, state = box_drop
    resting = render.draw(model, params, state, ax=new_axes(3), contacts=True)
    found = detect(model, params, state)
    assert check_contact_artists(resting, found) == 4
    assert set(np.asarray(found.status)[np.asarray(found.active)]) == {rb.RESTING}
    # The same box moving down fast: four colliding contacts, drawn red.
    falling = state.replace(vel=state.vel.at[0, 2].set(-2.0))
    ax = render.draw(model, params, falling, ax=new_axes(3), contacts=True)
    found = detect(model, params, falling)
    assert set(np.asarray(found.status)[np.asarray(found.active)]) == {rb.COLLIDING}
    check_contact_artists(ax, found)
    # Without contacts=True nothing of the kind is drawn.
    plain = render.draw(model, params, state)  # a new pyplot 3D figure
    assert plain.name == "3d"
    assert not [a for a in plain.get_children() if str(a.get_gid()).startswith("jaxrb.physics.contact")]


def test_contacts_behind_a_box_are_covered_by_it_3d(box_drop):
    # Issue 61: every contact was drawn over the bodies, so the corner behind the box
    # showed through it. Seen from above (elevation 22, azimuth -60) the far bottom
    # corner (-0.1, 0.1, 0) is behind the box; from below, the whole bottom face shows.
    model, params, state = box_drop
    ax = render.draw(model, params, state, ax=new_axes(3), extent=EXTENT_3D, contacts=True)
    (seen, seen_arrows), (hidden, hidden_arrows) = contact_groups(ax)
    box = artists_with_gid(ax, "jaxrb.body0")[0]
    hidden_points = hidden_arrows.jaxrb_segments[0::3, 0]
    assert np.allclose(hidden_points, [[-0.1, 0.1, 0.0]], atol=1e-3), hidden_points
    assert len(seen.get_offsets()) == 3
    assert seen.get_zorder() > box.get_zorder() > hidden.get_zorder()
    assert seen_arrows.get_zorder() > box.get_zorder() > hidden_arrows.get_zorder()
    render.figure_pixels(ax.figure)
    assert np.allclose(seen.get_facecolors()[:, 3], 1.0)
    assert np.allclose(hidden.get_facecolors()[:, 3], 0.3)
    # In the picture the box covers the hidden contact (dot and arrow, which points up
    # into the box): hiding it changes no pixel. The visible ones show.
    with_contacts = render.figure_pixels(ax.figure)
    assert (hide_and_render(ax, "jaxrb.contact_points_hidden") == with_contacts).all()
    assert (hide_and_render(ax, "jaxrb.contact_normals_hidden") == with_contacts).all()
    row, column = pixel_of(ax, (0.1, -0.1, 0.0))  # the near corner
    without_seen = hide_and_render(ax, "jaxrb.contact_points")
    assert (without_seen[row - 2:row + 3, column - 2:column + 3]
            != with_contacts[row - 2:row + 3, column - 2:column + 3]).any()

    below = render.draw(model, params, state, ax=new_axes(3), extent=EXTENT_3D, contacts=True,
                        view=(-30.0, -60.0))
    (seen, _), (hidden, _) = contact_groups(below)
    assert len(seen.get_offsets()) == 4 and len(hidden.get_offsets()) == 0


def test_contacts_2d(planar):
    model, params, state = planar
    ax = render.draw(model, params, state, ax=new_axes(2), contacts=True)
    found = detect(model, params, state)
    check_contact_artists(ax, found)
    # Arrows start at the contact points and follow the normals (+y from the ground).
    (arrows,) = artists_with_gid(ax, "jaxrb.contact_normals")
    shafts = np.asarray(arrows.get_segments())[0::3]
    assert np.allclose(shafts, arrows.jaxrb_segments[0::3])
    active = np.asarray(found.active)
    assert np.allclose(shafts[:, 0], np.asarray(found.point)[active])
    direction = shafts[:, 1] - shafts[:, 0]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    assert np.allclose(direction, np.asarray(found.normal)[active])


# --------------------------------------------------------------------------------------
# Animation and saving


@pytest.fixture(scope="module")
def box_animation(box_drop):
    model, params, _ = box_drop
    traj = falling_box_traj(box_drop, [0.5, 0.42, 0.34, 0.26, 0.18, 0.1])
    anim = render.animate(model, params, traj, every=2, fps=10, title="drop", figsize=(3, 3),
                          dpi=60)
    return anim, traj


def test_animation_frames_limits_and_title(box_animation):
    anim, traj = box_animation
    painter = anim.jaxrb_painter
    ax = painter.ax
    limits = (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())
    assert len(painter.frames) == 3  # every=2 of 6 states
    assert np.allclose(painter.frames.time, [0.1, 0.3, 0.5])
    for frame in range(3):
        painter.set_frame(frame)
        assert (ax.get_xlim(), ax.get_ylim(), ax.get_zlim()) == limits, "limits moved"
        assert ax.get_title() == f"drop   t = {0.1 + 0.2 * frame:.3f} s"
    # Limits hold the highest box (top face at 0.6) and the floor.
    assert limits[2][0] <= 0.0 and limits[2][1] >= 0.6


def test_save_gif_and_html(box_animation, tmp_path):
    anim, _ = box_animation
    gif = render.save_animation(anim, tmp_path / "drop.gif")
    assert gif.exists()
    with Image.open(gif) as image:
        assert image.n_frames == 3
        assert image.size == (180, 180)
    html = render.save_animation(anim, tmp_path / "drop.html")
    assert "<script" in html.read_text()
    assert "<script" in render.to_html(anim)


def test_save_rejects_unknown_suffix_and_missing_ffmpeg(box_animation, tmp_path, monkeypatch):
    anim, _ = box_animation
    with pytest.raises(ValueError, match=r"\.gif.*\.mp4.*\.html"):
        render.save_animation(anim, tmp_path / "drop.avi")
    monkeypatch.setattr(mpl_animation.writers, "is_available", lambda name: False)
    with pytest.raises(ValueError, match="ffmpeg.*gif"):
        render.save_animation(anim, tmp_path / "drop.mp4")
    assert not (tmp_path / "drop.avi").exists() and not (tmp_path / "drop.mp4").exists()


def test_animation_with_contacts_2d(planar, tmp_path):
    model, params, state = planar
    lifted = state.replace(pos=state.pos + jnp.array([0.0, 0.3]))  # nothing touches
    traj = stack([lifted.replace(time=jnp.asarray(0.0)), state.replace(time=jnp.asarray(0.1))])
    anim = render.animate(model, params, traj, contacts=True, figsize=(3, 2), dpi=50)
    painter = anim.jaxrb_painter
    counts = []
    for frame in range(2):
        painter.set_frame(frame)
        (dots,) = artists_with_gid(painter.ax, "jaxrb.contact_points")
        counts.append(len(dots.get_offsets()))
    assert counts[0] == 0
    assert counts[1] == int(detect(model, params, state).active.sum()) > 0
    with Image.open(render.save_animation(anim, tmp_path / "planar.gif")) as image:
        assert image.n_frames == 2


@pytest.fixture(scope="module")
def sliding_box():
    """A 2D box sliding along x at 1 m/s, 60 states per second, with its initial state."""
    scene = rb.Scene(dim=2)
    scene.add_body(rb.Box((0.1, 0.1)), mass=1.0, pos=(0.0, 0.5), vel=(1.0, 0.0))
    model, params, state = scene.build(dt=1 / 60, contact="none")

    def run(seconds):
        steps = int(round(seconds * 60))
        # As rb.rollout makes them: the states after each step, time summed in float32.
        times = np.cumsum(np.full(steps, np.float32(1 / 60)), dtype=np.float32)
        traj = stack([state.replace(pos=state.pos.at[0, 0].add(t), time=jnp.asarray(t))
                      for t in times])
        return traj
    return model, params, state, run


def playback(anim):
    """(frames, seconds each) of an animation, as a player shows it."""
    return len(list(anim.new_frame_seq())), 1.0 / anim.jaxrb_fps


@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")
def test_animation_plays_in_real_time_from_the_initial_state(sliding_box):
    # Issue 61: animate played 30 frames per second whatever dt was (a 3 s run at 60 Hz
    # played for 6 s) and could not show the state the rollout started from.
    model, params, state, run = sliding_box
    traj = run(3.0)
    anim = render.animate(model, params, traj, initial=state, figsize=(2, 2), dpi=40)
    frames, seconds = playback(anim)
    assert abs(frames * seconds - 3.0) <= seconds  # within one frame of 3 s
    assert seconds == pytest.approx(1 / 30)  # 60 Hz over the 30 fps cap: every second state
    painter = anim.jaxrb_painter
    assert np.allclose(painter.frames.time, np.arange(frames) * 2 / 60)
    assert np.isclose(painter.frames.time[-1], 3.0)
    # Frame 0 is the initial state: the box at x = 0, t = 0.
    painter.set_frame(0)
    (patch,) = artists_with_gid(painter.ax, "jaxrb.body0")
    assert np.allclose(patch.get_xy()[:4].mean(axis=0), [0.0, 0.5])
    assert painter.ax.get_title() == "t = 0.000 s"
    # Without it, frame 0 is the first state after a step; still 3 s.
    anim = render.animate(model, params, traj, figsize=(2, 2), dpi=40)
    frames, seconds = playback(anim)
    assert abs(frames * seconds - 3.0) <= seconds
    assert anim.jaxrb_painter.frames.time[0] == pytest.approx(1 / 60)
    # speed scales time; every thins the states (each frame then lasts longer); fps fixes
    # the rate (the old behaviour, now asked for by name).
    frames, seconds = playback(render.animate(model, params, traj, initial=state, speed=0.5,
                                              figsize=(2, 2), dpi=40))
    assert abs(frames * seconds - 6.0) <= seconds and seconds == pytest.approx(1 / 30)
    frames, seconds = playback(render.animate(model, params, traj, initial=state, every=6,
                                              figsize=(2, 2), dpi=40))
    assert (frames, seconds) == (31, pytest.approx(0.1))
    frames, seconds = playback(render.animate(model, params, traj, fps=30, figsize=(2, 2),
                                              dpi=40))
    assert (frames, seconds) == (180, pytest.approx(1 / 30))
    with pytest.raises(ValueError, match="'fps'.*'speed'"):
        render.animate(model, params, traj, fps=30, speed=2.0)
    with pytest.raises(ValueError, match="'initial'.*before"):
        render.animate(model, params, traj, initial=state.replace(time=jnp.asarray(1.0)))
    with pytest.raises(ValueError, match="'speed'"):
        render.animate(model, params, traj, speed=0.0)
    del anim, painter, patch
    gc.collect()  # the unplayed animations go here, under this test's warning filter


@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")
def test_saved_gif_keeps_real_time(sliding_box, tmp_path):
    # A GIF keeps frame durations in 1/100 s: 33 ms frames stored as 30 ms ran 10 % fast.
    model, params, state, run = sliding_box
    anim = render.animate(model, params, run(0.5), initial=state, figsize=(1.5, 1.5), dpi=30)
    frames, seconds = playback(anim)
    assert frames == 16
    with Image.open(render.save_animation(anim, tmp_path / "slide.gif")) as image:
        durations = []
        for index in range(image.n_frames):
            image.seek(index)
            durations.append(image.info["duration"])
    assert len(durations) == frames and set(durations) <= {30, 40}
    assert abs(sum(durations) - 1000 * frames * seconds) <= 10
    del anim
    gc.collect()


@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")
def test_draw_and_animate_say_what_they_return(box_drop):
    # Issue 61: a new user took draw's result for a Figure (savefig failed on an Axes).
    model, params, state = box_drop
    ax = render.draw(model, params, state)
    assert isinstance(ax, matplotlib.axes.Axes) and isinstance(ax.figure, matplotlib.figure.Figure)
    returns = render.draw.__doc__.split("Returns:")[1]
    assert "Axes" in returns and "not a Figure" in returns and "ax.figure" in returns
    for plot in (render.plot_energy, render.plot_angular_momentum, render.plot_series):
        assert "ax.figure" in plot.__doc__.split("Returns:")[1], plot.__name__
    anim = render.animate(model, params, stack([state, state.replace(time=jnp.asarray(0.1))]))
    assert isinstance(anim, mpl_animation.FuncAnimation)
    assert isinstance(anim.jaxrb_painter.ax.figure, Figure)
    returns = render.animate.__doc__.split("Returns:")[1]
    assert "FuncAnimation" in returns and "anim.jaxrb_painter.ax.figure" in returns
    assert "path" in render.save_animation.__doc__.split("Returns:")[1]
    anim.jaxrb_painter.set_frame(0)
    del anim
    gc.collect()


# --------------------------------------------------------------------------------------
# Bad input


def test_batched_or_mismatched_input_is_rejected(box_drop, planar):
    model, params, state = box_drop
    batched = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), state)
    with pytest.raises(ValueError, match="index"):
        render.draw(model, params, batched)
    with pytest.raises(ValueError, match="time axis"):
        render.animate(model, params, state)
    with pytest.raises(ValueError, match="index"):
        render.animate(model, params, stack([batched, batched]))
    with pytest.raises(ValueError, match="3D Axes"):
        render.draw(model, params, state, ax=new_axes(2))
    with pytest.raises(ValueError, match="'extent'"):
        render.draw(model, params, state, extent=(0, 1, 0, 1))
    with pytest.raises(ValueError, match="'colors'"):
        render.draw(model, params, state, colors=["red", "blue"])
    with pytest.raises(ValueError, match="'every'"):
        render.animate(model, params, stack([state, state]), every=0)
    model2, params2, state2 = planar
    with pytest.raises(ValueError, match=r"state.pos"):
        render.draw(model2, params2, state)
    with pytest.raises(ValueError, match="com_offset"):
        render.draw(model2, jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), params2), state2)


# --------------------------------------------------------------------------------------
# Plots over time


def test_plot_energy_matches_closed_form(box_drop):
    model, params, _ = box_drop
    heights = [0.5, 0.4, 0.3]
    traj = falling_box_traj(box_drop, heights)
    ax = render.plot_energy(model, params, traj)
    lines = {line.get_label(): line for line in ax.get_lines()}
    kinetic = np.full(3, 0.5 * 1.0 * 1.0 ** 2)  # m = 1 kg at 1 m/s, no spin
    potential = 1.0 * 9.81 * np.array(heights)
    assert np.allclose(lines["kinetic"].get_xdata(), [0.1, 0.2, 0.3])
    assert np.allclose(lines["kinetic"].get_ydata(), kinetic)
    assert np.allclose(lines["potential"].get_ydata(), potential)
    assert np.allclose(lines["total"].get_ydata(), kinetic + potential)


def test_plot_angular_momentum_3d_and_2d(box_drop, planar):
    model, params, state = box_drop
    spin = state.replace(angvel=state.angvel.at[0].set(jnp.array([0.0, 0.0, 3.0])),
                         vel=state.vel.at[0].set(jnp.array([2.0, 0.0, 0.0])))
    traj = stack([spin, spin.replace(time=jnp.asarray(0.5))])
    ax = render.plot_angular_momentum(model, params, traj)
    lines = {line.get_label(): line.get_ydata() for line in ax.get_lines()}
    # Cube of 1 kg, side 0.2 m: I = m a²/6; orbital r × m v = (0, 0, 0.1) × (2, 0, 0)
    # = (0, 0.2, 0).
    spin_z = 1.0 * 0.2 ** 2 / 6.0 * 3.0
    assert np.allclose(lines["L_x"], 0.0)
    assert np.allclose(lines["L_y"], 0.2)
    assert np.allclose(lines["L_z"], spin_z)
    assert np.allclose(lines["|L|"], np.hypot(0.2, spin_z))

    model2, params2, state2 = planar
    turning = state2.replace(angvel=jnp.array([1.0, 0.0]))
    ax = render.plot_angular_momentum(model2, params2, stack([turning, turning]))
    (line,) = ax.get_lines()
    assert np.allclose(line.get_ydata(), 1.0 * 0.2 ** 2 / 6.0)  # square: m (w² + h²)/12


def test_plot_series():
    times = np.linspace(0.0, 1.0, 5)
    values = np.stack([times, 2 * times, 3 * times], axis=1)
    ax = render.plot_series(times, values, labels=["a", "b", "c"], ylabel="ω (rad/s)")
    assert [line.get_label() for line in ax.get_lines()] == ["a", "b", "c"]
    assert np.allclose(ax.get_lines()[2].get_ydata(), 3 * times)
    assert ax.get_ylabel() == "ω (rad/s)"
    with pytest.raises(ValueError, match="'labels'"):
        render.plot_series(times, values, labels=["a"])
    with pytest.raises(ValueError, match="'values'"):
        render.plot_series(times, values[:3])


def test_figure_pixels_shape_and_content():
    fig = Figure(figsize=(2.0, 1.0), dpi=50)
    fig.patch.set_facecolor((1.0, 0.0, 0.0, 1.0))
    pixels = render.figure_pixels(fig)  # a bare Figure: no Agg canvas attached
    assert pixels.shape == (50, 100, 4) and pixels.dtype == np.uint8
    assert (pixels[..., 0] == 255).all() and (pixels[..., 1] == 0).all()


# --------------------------------------------------------------------------------------
# The package


def test_render_package_splits_by_meaning_without_import_cycles():
    import ast
    import importlib
    import pathlib

    folder = pathlib.Path(render.__file__).parent
    modules = {path.stem: path for path in folder.glob("*.py")}
    assert {"common", "geometry", "draw2d", "draw3d", "painter", "animation", "plots"} <= set(modules)
    graph = {}
    for name, path in modules.items():
        text = path.read_text()
        assert len(text.splitlines()) < 500, (name, len(text.splitlines()))
        imported = set()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jaxrb.render"):
                assert node.module != "jaxrb.render" or name == "__init__", name
                imported.add(node.module.rsplit(".", 1)[-1])
        graph[name] = imported - {"render"}
    # No module imports itself through others: a topological order exists.
    done = set()
    while len(done) < len(graph):
        ready = {name for name, needs in graph.items() if name not in done and needs <= done}
        assert ready, f"import cycle among {sorted(set(graph) - done)}"
        done |= ready
    # The public names are where they were, documented as jaxrb.render.<name>.
    for name in render.__all__:
        assert getattr(rb.render, name) is getattr(importlib.import_module("jaxrb.render"), name)
    for name in ("draw", "animate", "save_animation", "to_html", "figure_pixels", "plot_energy",
                 "plot_angular_momentum", "plot_series"):
        assert getattr(render, name).__module__ == "jaxrb.render", name
    assert {"STATUS_COLORS", "BODY_COLORS"} <= set(render.__all__)

