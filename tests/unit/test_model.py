"""The parametric UAV mesh (Table 1.1) and CAD-file loading."""

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
