"""The parametric UAV mesh (Table 1.1): its counts, closure and geometry (dihedral, camber, thickness,
centre of gravity); CAD-file loading and what it refuses."""

import numpy as np
import pytest
import trimesh

from uav_landing_vision.model import CHORD, LENGTH, SPAN, Mesh, MeshError, fixed_wing_mesh, load_mesh


@pytest.fixture(scope="module", params=["high", "low"])
def mesh(request):
    return fixed_wing_mesh(request.param)


def test_triangle_counts():
    assert 2700 <= fixed_wing_mesh("high").triangle_count <= 3300
    assert 650 <= fixed_wing_mesh("low").triangle_count <= 950


def test_closed_watertight_consistently_wound_outward(mesh):
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert tm.is_watertight and tm.is_winding_consistent and tm.is_volume
    assert mesh.is_closed
    assert mesh.signed_volume > 0  # outward normals
    assert len(tm.split(only_watertight=False)) == 4  # fuselage, wing, tailplane, fin


def test_dimensions_match_table_1_1(mesh):
    ext = mesh.extents
    assert ext[0] == pytest.approx(LENGTH, rel=0.03) and LENGTH == 1.2
    assert ext[1] == pytest.approx(SPAN, rel=0.03) and SPAN == 1.8
    tip = mesh.vertices[np.abs(mesh.vertices[:, 1] - mesh.bounds[1, 1]) < 1e-6]
    assert np.ptp(tip[:, 0]) == pytest.approx(CHORD, rel=0.03) and CHORD == 0.24
    assert SPAN * CHORD == pytest.approx(0.432)  # Table 1.1 wing area
    assert mesh.extents[2] < 0.3  # a low fixed-wing profile, fin included


def test_body_frame_is_flu(mesh):
    v = mesh.vertices
    nose = v[np.argmax(v[:, 0])]
    np.testing.assert_allclose(nose[1:], 0.0, atol=1e-6)  # nose on the x axis, forward
    fin_top = v[np.argmax(v[:, 2])]
    assert fin_top[0] < -0.5  # the fin (up, +z) is at the tail
    np.testing.assert_allclose(v.mean(axis=0)[1], 0.0, atol=1e-6)  # symmetric in y
    assert -0.5 < v[:, 0].mean() < 0.5


def test_mesh_validation():
    with pytest.raises(MeshError):
        Mesh(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(MeshError):
        Mesh(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(MeshError, match="level"):
        fixed_wing_mesh("medium")
    with pytest.raises(MeshError, match="finite"):
        Mesh([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]])
    open_mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]))
    assert not open_mesh.is_closed
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tetra = Mesh(corners, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    assert tetra.is_closed and tetra.signed_volume == pytest.approx(1 / 6)
    flipped = Mesh(tetra.vertices, tetra.faces[[0, 1, 2]].tolist() + [[1, 3, 2]])
    assert not flipped.is_closed  # one face wound against the others


@pytest.mark.parametrize("suffix", ["obj", "stl", "ply"])
def test_load_round_trip(tmp_path, suffix):
    ref = fixed_wing_mesh("low")
    path = tmp_path / f"uav.{suffix}"
    trimesh.Trimesh(ref.vertices * 1000.0, ref.faces, process=False).export(path)
    loaded = load_mesh(path, unit="mm")
    assert loaded.triangle_count == ref.triangle_count
    assert loaded.is_closed and loaded.signed_volume > 0
    np.testing.assert_allclose(loaded.bounds, ref.bounds, atol=1e-4)


def test_load_turns_every_inside_out_body_outward(tmp_path):
    """A CAD file of separate bodies, one wound inward: the shaded view needs each outward."""
    ref = fixed_wing_mesh("low")
    bodies = trimesh.Trimesh(ref.vertices, ref.faces, process=False).split(only_watertight=False)
    wing = int(np.argmax([np.ptp(b.vertices[:, 1]) for b in bodies]))
    bodies[wing].invert()
    path = tmp_path / "uav.obj"
    trimesh.util.concatenate(bodies).export(path)
    loaded = load_mesh(path)
    assert loaded.is_closed and loaded.signed_volume == pytest.approx(ref.signed_volume, rel=1e-4)
    parts = trimesh.Trimesh(loaded.vertices, loaded.faces, process=False).split(only_watertight=False)
    assert len(parts) == 4 and all(p.volume > 0 for p in parts)


def test_load_textured_obj_is_closed(tmp_path):
    """Per-corner texture coordinates (as CAD exporters write them) split no vertex."""
    ref = fixed_wing_mesh("low")
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in ref.vertices.tolist()]
    lines += ["vt 0 0", "vt 1 0", "vt 0 1"] * ref.triangle_count
    lines += [f"f {a}/{3 * i + 1} {b}/{3 * i + 2} {c}/{3 * i + 3}" for i, (a, b, c) in enumerate(ref.faces + 1)]
    path = tmp_path / "uav.obj"
    path.write_text("\n".join(lines) + "\n")
    loaded = load_mesh(path)
    assert loaded.is_closed and len(loaded.vertices) == len(ref.vertices)


def test_load_drops_collapsed_triangles(tmp_path):
    """A triangle with two equal corners (tessellators leave them) covers nothing and would
    make the closed model look open (its edge used three times)."""
    ref = fixed_wing_mesh("low")
    a, b = ref.faces[0, :2]
    path = tmp_path / "uav.stl"
    trimesh.Trimesh(ref.vertices, np.vstack([ref.faces, [[a, a, b]]]), process=False).export(path)
    loaded = load_mesh(path)
    assert loaded.is_closed and loaded.triangle_count == ref.triangle_count


def test_load_wrong_unit_names_the_probable_one(tmp_path):
    ref = fixed_wing_mesh("low")
    path = tmp_path / "uav.stl"
    trimesh.Trimesh(ref.vertices * 1000.0, ref.faces).export(path)
    with pytest.raises(MeshError, match="probably in 'mm'"):
        load_mesh(path)
    path_m = tmp_path / "uav_m.stl"
    trimesh.Trimesh(ref.vertices, ref.faces).export(path_m)
    with pytest.raises(MeshError, match="probably in 'm'"):
        load_mesh(path_m, unit="mm")
    with pytest.raises(MeshError, match="unknown unit"):
        load_mesh(path_m, unit="inch")


@pytest.mark.parametrize("axis, side", [(0, 1), (1, -1), (2, 1)])
def test_a_model_whose_origin_is_outside_it_is_not_in_the_body_frame(tmp_path, axis, side):
    """The body frame's origin is the centre of gravity, which lies within the body's box: a CAD
    file with its origin elsewhere (at a drawing's corner, say) would be tracked off by that
    offset."""
    ref = fixed_wing_mesh("low")
    shift = np.zeros(3)
    shift[axis] = side * 0.2 - ref.bounds[0 if side > 0 else 1][axis]  # the whole model 0.2 m to that side
    path = tmp_path / "uav.stl"
    trimesh.Trimesh(ref.vertices + shift, ref.faces).export(path)
    with pytest.raises(MeshError, match="does not hold its own origin"):
        load_mesh(path)


def test_load_errors(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        load_mesh(tmp_path / "missing.obj")
    bad_suffix = tmp_path / "uav.fbx"
    bad_suffix.write_text("x")
    with pytest.raises(MeshError, match="unsupported"):
        load_mesh(bad_suffix)
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(b"solid\x00\xff this is not an STL file \x01\x02" * 3)
    with pytest.raises(MeshError):
        load_mesh(garbage)
    garbage_ply = tmp_path / "garbage.ply"
    garbage_ply.write_text("ply\nformat nonsense\nend_header\n1 2 3\n")
    with pytest.raises(MeshError):
        load_mesh(garbage_ply)
    empty = tmp_path / "empty.obj"
    empty.write_text("# no geometry\n")
    with pytest.raises(MeshError, match="no triangles"):
        load_mesh(empty)
    nonfinite = tmp_path / "nan.obj"
    nonfinite.write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    with pytest.raises(MeshError, match="non-finite"):
        load_mesh(nonfinite)
    collinear = tmp_path / "collinear.obj"
    collinear.write_text("v -0.5 0 0\nv 0.5 0 0\nv 1.0 0 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="no surface"):
        load_mesh(collinear)


def test_open_mesh_loads_with_warning(tmp_path):
    ref = fixed_wing_mesh("low")
    path = tmp_path / "open.ply"
    trimesh.Trimesh(ref.vertices, ref.faces[1:], process=False).export(path)
    with pytest.warns(UserWarning, match="not closed"):
        mesh = load_mesh(path)
    assert not mesh.is_closed and mesh.triangle_count == ref.triangle_count - 1


_PLY_HEAD = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
             "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n")


@pytest.mark.parametrize(
    "name, text, message",
    [
        # A PLY face naming a vertex it does not have: an IndexError from trimesh before.
        ("beyond.ply", _PLY_HEAD + "3 0 1 9\n", "face index out of range"),
        # Three vertices are indexed 0..2: index 3 is one past the end.
        ("one_past.ply", _PLY_HEAD + "3 0 1 3\n", "face index out of range"),
        # A negative PLY index (not a relative reference, as in OBJ) was read as the last vertex.
        ("negative.ply", _PLY_HEAD + "3 0 1 -1\n", "face index out of range"),
        # Coordinates whose squared extent overflows: an OverflowError before.
        ("huge.obj", "v 0 0 0\nv 1e300 0 0\nv 0 1e300 0\nf 1 2 3\n", "implausible for a UAV"),
    ],
)
@pytest.mark.filterwarnings("ignore:invalid value encountered in cast:RuntimeWarning")  # trimesh, huge.obj
def test_corrupt_mesh_files_are_mesh_errors(tmp_path, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(MeshError, match=message):
        load_mesh(path)


# --- CAD files at the edges of what is accepted ---------------------------------------------------

_TETRA_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _obj_text(vertices, faces) -> str:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, float).tolist()]
    lines += [f"f {a} {b} {c}" for a, b, c in (np.asarray(faces) + 1).tolist()]
    return "\n".join(lines) + "\n"


def test_upper_case_cad_suffixes_are_accepted(tmp_path):
    """CAD exporters on Windows write ``UAV.STL``: the suffix is matched without case."""
    ref = fixed_wing_mesh("low")
    lower = tmp_path / "uav.stl"
    trimesh.Trimesh(ref.vertices, ref.faces, process=False).export(lower)
    upper = lower.rename(tmp_path / "UAV.STL")
    loaded = load_mesh(upper)
    assert loaded.triangle_count == ref.triangle_count and loaded.is_closed


@pytest.mark.parametrize("collapsed", [[0, 1, 0], [1, 0, 0], [0, 0, 1]])
def test_triangles_collapsed_on_any_pair_of_corners_are_dropped(tmp_path, collapsed):
    """Whichever two corners coincide (first-second, second-third or third-first), the triangle
    has no area and is dropped, so the closed model stays closed."""
    ref = fixed_wing_mesh("low")
    a, b = ref.faces[0, :2]
    extra = np.where(np.array(collapsed) == 0, a, b)
    path = tmp_path / "uav.obj"
    path.write_text(_obj_text(ref.vertices, np.vstack([ref.faces, extra[None]])))
    loaded = load_mesh(path)
    assert loaded.triangle_count == ref.triangle_count and loaded.is_closed


@pytest.mark.parametrize("size, unit", [(1.8, "cm"), (0.05, "m"), (0.099, "m")])
def test_models_below_a_tenth_of_a_metre_are_refused(tmp_path, size, unit):
    """A 1.8 m UAV read as centimetres is 1.8 cm across: a unit mistake, not a UAV."""
    ref = fixed_wing_mesh("low")
    path = tmp_path / "uav.stl"
    trimesh.Trimesh(ref.vertices * (size / ref.extents.max()), ref.faces, process=False).export(path)
    with pytest.raises(MeshError, match="implausible for a UAV"):
        load_mesh(path, unit=unit)


@pytest.mark.parametrize("length_m", [21.0, 60.0])
def test_models_beyond_twenty_metres_are_refused(tmp_path, length_m):
    ref = fixed_wing_mesh("low")
    path = tmp_path / "uav.stl"
    trimesh.Trimesh(ref.vertices * (length_m / ref.extents.max()), ref.faces, process=False).export(path)
    with pytest.raises(MeshError, match="implausible for a UAV"):
        load_mesh(path)


@pytest.mark.parametrize("length_m", [0.101, 19.9])
def test_models_just_inside_the_size_limits_are_accepted(tmp_path, length_m):
    ref = fixed_wing_mesh("low")
    path = tmp_path / "uav.stl"
    trimesh.Trimesh(ref.vertices * (length_m / ref.extents.max()), ref.faces, process=False).export(path)
    assert load_mesh(path).extents.max() == pytest.approx(length_m, rel=1e-5)


def test_a_nearly_collinear_triangle_has_no_surface(tmp_path):
    """Three points on one line, whose area rounding leaves at ~1e-17 m² rather than 0."""
    d = np.array([0.1, 0.7, 0.3])
    vertices = np.array([-1.0 * d, 0.4 * d, 1.3 * d])
    assert 0 < trimesh.Trimesh(vertices, [[0, 1, 2]], process=False).area < 1e-15
    path = tmp_path / "line.obj"
    path.write_text(_obj_text(vertices, [[0, 1, 2]]))
    with pytest.raises(MeshError, match="no surface"):
        load_mesh(path)


def test_a_model_whose_origin_is_a_corner_of_its_box_is_accepted(tmp_path):
    """The origin on the boundary of the model's box (a corner here) still lies within it."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    path = tmp_path / "tetra.obj"
    path.write_text(_obj_text(corners, _TETRA_FACES))
    mesh = load_mesh(path)
    assert mesh.is_closed and mesh.signed_volume == pytest.approx(1 / 6)


def test_mesh_refuses_faces_that_are_not_triangles():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    with pytest.raises(MeshError, match="faces"):
        Mesh(square, np.array([[0, 1, 2, 3]]))


def test_mesh_refuses_negative_face_indices():
    """A negative index would silently wrap around to the last vertices."""
    with pytest.raises(MeshError, match="out of range"):
        Mesh(np.eye(3), np.array([[0, 1, -1]]))


def test_mesh_with_an_edge_used_by_three_faces_is_not_closed():
    """A tetrahedron plus a fin sharing one of its edges: that edge has three faces."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0], [1, 1, -1.0]])
    faces = np.vstack([_TETRA_FACES, [[0, 1, 4]]])
    assert not Mesh(corners, faces).is_closed


def test_mesh_whose_directed_edges_repeat_is_not_closed():
    """Two tetrahedra sharing an edge (a non-manifold bow-tie): every edge has its reverse, but
    the shared one appears twice in each direction, so the mesh is not closed."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0], [1, -1, 0], [1, 0, -1.0]])
    second = np.array([[0, 4, 1], [0, 1, 5], [0, 5, 4], [1, 4, 5]])
    one = Mesh(corners, _TETRA_FACES)
    assert one.is_closed
    two = Mesh(corners, np.vstack([_TETRA_FACES, second]))
    assert Mesh(corners, second).signed_volume != 0
    assert not two.is_closed
    assert not Mesh(corners, np.vstack([_TETRA_FACES, _TETRA_FACES])).is_closed  # every face twice


# --- the generated fixed-wing UAV -------------------------------------------------------------


def _wing_tip(mesh: Mesh, side: int) -> np.ndarray:
    v = mesh.vertices.astype(float)
    y = side * SPAN / 2
    return v[np.abs(v[:, 1] - y) < 1e-6]


def _wing_root(mesh: Mesh) -> np.ndarray:
    """The wing's section at y = 0: inside the fuselage, between the wing's leading and trailing
    edges and below the fuselage's top (z = 0.065 m)."""
    v = mesh.vertices.astype(float)
    sel = (np.abs(v[:, 1]) < 1e-9) & (v[:, 0] <= 0.07 + 1e-6) & (v[:, 0] >= 0.07 - CHORD - 1e-6)
    return v[sel & (v[:, 2] > 0.0) & (v[:, 2] < 0.06)]


@pytest.mark.parametrize("side", [1, -1])
def test_wing_tips_are_raised_by_a_three_degree_dihedral(mesh, side):
    """The wing has a root section at y = 0 with its chord 3 cm above the body axis, and each
    tip section is the same section raised by (SPAN/2)·tan 3° ≈ 4.7 cm."""
    tip, root = _wing_tip(mesh, side), _wing_root(mesh)
    assert len(root) == len(tip) > 10
    np.testing.assert_allclose(np.sort(tip[:, 0]), np.sort(root[:, 0]), atol=1e-6)
    rise = np.mean(tip[:, 2]) - np.mean(root[:, 2])
    assert rise == pytest.approx(SPAN / 2 * np.tan(np.radians(3.0)), abs=1e-5)
    chord_z = root[np.argmax(root[:, 0]), 2]  # the leading edge lies on the chord line
    assert chord_z == pytest.approx(0.03, abs=1e-6)


def test_centre_of_gravity_is_at_29_percent_of_the_wing_chord(mesh):
    """The body origin lies behind the wing's leading edge by 29 % of the 0.24 m chord."""
    tip = _wing_tip(mesh, 1)
    le, te = tip[:, 0].max(), tip[:, 0].min()
    assert te < 0.0 < le
    assert le - te == pytest.approx(CHORD, rel=1e-6)
    assert le / (le - te) == pytest.approx(0.29, abs=0.005)


def test_wing_section_is_ten_percent_thick_and_cambered_upwards(mesh):
    """NACA 4-digit thickness law (10 %) on the a=1.0 mean line with design lift 0.4: maximum
    thickness 0.10·c; camber (1/4π)·0.4·ln 2 ≈ 2.2 % of the chord at mid-chord, upwards."""
    tip = _wing_tip(mesh, 1)
    x = (tip[:, 0].max() - tip[:, 0]) / CHORD  # 0 at the leading edge, 1 at the trailing edge
    z = (tip[:, 2] - np.mean(tip[:, 2][[np.argmin(x), np.argmax(x)]])) / CHORD  # about the chord line
    stations = np.unique(np.round(x, 5))
    thickness, camber = [], []
    for s in stations[1:-1]:
        at = z[np.abs(x - s) < 2e-5]
        assert len(at) == 2
        thickness.append(at.max() - at.min())
        camber.append(0.5 * (at.max() + at.min()))
    thickness, camber, inner = np.array(thickness), np.array(camber), stations[1:-1]
    # The true maximum (0.30 c) falls between cosine-spaced stations: a little under 10 %.
    assert 0.095 <= thickness.max() <= 0.1001
    mid = np.argmin(np.abs(inner - 0.5))
    assert camber[mid] == pytest.approx(0.4 / (4 * np.pi) * np.log(2.0), abs=0.003)
    assert np.all(camber > -1e-9)


def test_fin_stands_up_from_the_tail(mesh):
    """The fin rises 0.19 m above the tail boom's axis, in the plane y = 0 (up is +z in FLU)."""
    v = mesh.vertices.astype(float)
    tail = v[v[:, 0] < -0.6]
    top = tail[np.argmax(tail[:, 2])]
    assert top[2] == pytest.approx(0.19, abs=1e-6)
    assert abs(top[1]) < 0.01
    assert tail[:, 2].min() > -0.03  # nothing of the tail hangs below the boom


def _naca_section_area(thickness: float) -> float:
    """Area of the NACA 4-digit section of unit chord, by a fine trapezoid integral of 2·y_t."""
    x = np.linspace(0.0, 1.0, 200_001)
    yt = 5 * thickness * (0.2969 * np.sqrt(x) - 0.1260 * x - 0.3516 * x**2 + 0.2843 * x**3 - 0.1036 * x**4)
    return float(np.trapezoid(2 * yt, x))


def test_lifting_surfaces_enclose_the_volume_of_their_sections(mesh):
    """Each part is a simple solid: wing (10 %, chord 0.24, span 1.8), tailplane (9 %, chord
    0.12, span 0.5) and fin (9 %, chord 0.14 → 0.08 over 0.19 m) enclose their section area
    times span (times the mean squared chord for the tapered fin), as sampled."""
    parts = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).split(only_watertight=False)
    by_size = {tuple(np.round(np.ptp(p.vertices, axis=0), 2)): p for p in parts}
    wing = next(p for k, p in by_size.items() if k[1] == 1.8)
    tail = next(p for k, p in by_size.items() if k[1] == 0.5)
    fin = next(p for k, p in by_size.items() if k[2] == 0.19)
    assert all(p.is_volume for p in (wing, tail, fin))
    assert wing.volume == pytest.approx(_naca_section_area(0.10) * CHORD**2 * SPAN, rel=0.015)
    assert tail.volume == pytest.approx(_naca_section_area(0.09) * 0.12**2 * 0.5, rel=0.04)
    mean_sq_chord = (0.14**2 + 0.14 * 0.08 + 0.08**2) / 3
    assert fin.volume == pytest.approx(_naca_section_area(0.09) * mean_sq_chord * 0.19, rel=0.04)


def test_triangle_counts_are_the_documented_ones():
    """fixed_wing_mesh: "high" 3 092 triangles, "low" 788."""
    assert fixed_wing_mesh("high").triangle_count == 3092
    assert fixed_wing_mesh("low").triangle_count == 788


@pytest.mark.parametrize("size", [0.1, 20.0])
def test_models_exactly_at_the_size_limits_are_accepted(tmp_path, size):
    """0.1 m and 20 m across (a tetrahedron with its corner at the origin) are within 0.1–20 m."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * size
    path = tmp_path / "tetra.obj"
    path.write_text(_obj_text(corners, _TETRA_FACES))
    assert load_mesh(path).extents.max() == pytest.approx(size)


def test_fuselage_encloses_the_solid_its_rings_describe(mesh):
    """The fuselage (1.2 m long) is its rings of equal regular polygons joined by frusta, and a cone
    from each end ring to the nose (x = 0.45) or tail (x = −0.75) point: its volume is theirs."""
    parts = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).split(only_watertight=False)
    fuselage = next(p for p in parts if np.ptp(p.vertices[:, 0]) > 1.1)
    v = fuselage.vertices.astype(float)
    assert v[:, 0].max() == pytest.approx(0.45) and v[:, 0].min() == pytest.approx(-0.75)
    xs = np.unique(v[:, 0])
    rings = [v[v[:, 0] == x] for x in xs[1:-1]]
    n = len(rings[0])
    area = np.array([0.5 * n * np.hypot(r[:, 1], r[:, 2]).mean() ** 2 * np.sin(2 * np.pi / n) for r in rings])
    h = np.diff(xs)
    frusta = h[1:-1] / 3 * (area[:-1] + area[1:] + np.sqrt(area[:-1] * area[1:]))
    cones = (h[0] * area[0] + h[-1] * area[-1]) / 3
    assert fuselage.volume == pytest.approx(frusta.sum() + cones, rel=1e-6)
