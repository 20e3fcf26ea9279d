"""``ModalModel``: construction checks, exact save/load round trip, damaged files, atomic writes."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from dataclasses import FrozenInstanceError

import numpy as np
import pytest

import modalfem
from modalfem.errors import InputError, ModelFileError
from modalfem.mesh import box
from modalfem.mesh.surface import boundary_surface, mass_properties
from modalfem.model import ModalModel, payload_checksum, storage_report

PIP_PATH = {"backend": "skfem", "solver": "scipy"}  # runs without FEniCSx
HEAVY = ("scipy", "skfem", "dolfinx", "petsc4py")


def _tet_model(**changes) -> ModalModel:
    """A hand-built model on the surface of one tetrahedron (no FE solve)."""
    rng = np.random.default_rng(0)
    kw = {
        "vertices": np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) * 0.1,
        "triangles": np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]),
        "shapes": rng.standard_normal((12, 3)),
        "omega": np.array([10.0, 20.0, 20.0]),
        "mass": 1.3,
        "center_of_mass": np.array([0.025, 0.025, 0.025]),
        "inertia": np.diag([2e-3, 3e-3, 4e-3]) + 1e-4 * (np.ones((3, 3)) - np.eye(3)),
        "material": {"name": "steel", "E": 200e9, "nu": 0.3, "rho": 7850.0},
        "damping": (0.5, 1e-6),
        "provenance": {"mesh_hash": "abc", "degree": 2, "fixed": None, "versions": {"numpy": np.__version__}},
    }
    kw.update(changes)
    return ModalModel(**kw)


def _rotation(r: int = 3, seed: int = 1) -> dict:
    """Random rotation-coupling tensors of the right shapes for r modes."""
    rng = np.random.default_rng(seed)
    return {"rotation_T": rng.standard_normal((3, 3, r, r)), "rotation_S": rng.standard_normal((3, 3, r))}


def _same(a: ModalModel, b: ModalModel) -> None:
    for k in ("vertices", "triangles", "shapes", "omega", "center_of_mass", "inertia"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), k
    for k in ("rotation_T", "rotation_S"):
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype == np.float64 and x.shape == y.shape and x.tobytes() == y.tobytes(), k
    assert a.mass == b.mass and a.material == b.material and a.damping == b.damping
    assert a.provenance == b.provenance and a.checksum() == b.checksum()


@pytest.fixture(scope="module")
def free_box():
    mesh = box(size=(0.3, 0.05, 0.02), cells=(6, 2, 2))
    res = modalfem.modes(mesh, modalfem.ALUMINIUM, k=4, degree=2, **PIP_PATH)
    return mesh, res


# ---------------------------------------------------------------- construction


def test_round_trip_is_exact(tmp_path):
    m = _tet_model()
    path = tmp_path / "m.npz"
    m.save(path)
    back = ModalModel.load(path)
    _same(m, back)
    assert back.SCHEMA_VERSION == 1 and back.mode_count == 3 and back.vertex_count == 4
    assert os.listdir(tmp_path) == ["m.npz"]  # no temporary files left
    m.save(path)  # overwriting an existing model works and gives identical bytes
    assert ModalModel.load(path).checksum() == m.checksum()


def test_round_trip_with_and_without_the_rotation_coupling(tmp_path):
    plain, rotating = _tet_model(), _tet_model(**_rotation())
    assert plain.rotation_T is None and plain.rotation_S is None and not plain.has_rotation_coupling
    assert rotating.has_rotation_coupling and rotating.checksum() != plain.checksum()
    for name, m in (("plain.npz", plain), ("rotating.npz", rotating)):
        m.save(tmp_path / name)
        back = ModalModel.load(tmp_path / name)
        _same(m, back)
    assert "rotation_T" not in _entries(tmp_path / "plain.npz")  # absent, as in files written before
    assert {"rotation_T", "rotation_S"} <= set(_entries(tmp_path / "rotating.npz"))
    with pytest.raises(ValueError):
        rotating.rotation_T[0, 0, 0, 0] = 1.0  # read-only like the other arrays


def test_a_model_without_rotation_tensors_keeps_the_schema_1_checksum():
    """Files written before the optional arrays existed must still verify: the hash of a model
    without them is the original schema-1 hash (re-implemented here from its specification)."""
    import hashlib

    m = _tet_model()
    h = hashlib.sha256()
    h.update(b"modalfem.ModalModel\0")
    h.update(b"schema=1\0")
    for key in ("center_of_mass", "inertia", "omega", "shapes", "triangles", "vertices"):
        a = np.ascontiguousarray(getattr(m, key), dtype="<i8" if key == "triangles" else "<f8")
        h.update(f"{key}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    h.update(b"meta\0")
    h.update(m._meta().encode("utf-8"))
    assert m.checksum() == h.hexdigest()


@pytest.mark.parametrize(
    "changes, needle",
    [
        ({"rotation_T": np.zeros((3, 3, 3, 3))}, "rotation_T without rotation_S"),
        ({"rotation_S": np.zeros((3, 3, 3))}, "rotation_S without rotation_T"),
        (dict(_rotation(), rotation_T=np.zeros((3, 3, 3, 2))), "rotation_T must have shape"),
        (dict(_rotation(), rotation_S=np.zeros((3, 3, 2))), "rotation_S must have shape"),
        (dict(_rotation(), rotation_S=np.full((3, 3, 3), np.nan)), "rotation_S holds 27 NaN"),
    ],
)
def test_construction_rejects_inconsistent_rotation_tensors(changes, needle):
    with pytest.raises(ModelFileError, match=needle):
        _tet_model(**changes)


def test_model_is_frozen_and_read_only():
    m = _tet_model()
    with pytest.raises(FrozenInstanceError):
        m.mass = 2.0
    with pytest.raises(ValueError):
        m.shapes[0, 0] = 1.0
    assert m.triangles.dtype == np.int64 and m.shapes.dtype == np.float64


def test_derived_quantities():
    m = _tet_model()
    assert np.allclose(m.frequencies_hz * 2 * np.pi, m.omega)
    assert np.allclose(m.modal_damping, 0.5 + 1e-6 * m.omega**2)
    q = np.array([1.0, -2.0, 0.5])
    u = m.displacement(q)
    assert u.shape == (4, 3) and np.allclose(u[2, 1], m.shapes[3 * 2 + 1] @ q)


@pytest.mark.parametrize(
    "changes, needle",
    [
        ({"omega": np.array([10.0, -1.0, 20.0])}, "omega must be > 0"),
        ({"omega": np.array([30.0, 20.0, 10.0])}, "ascending"),
        ({"omega": np.array([10.0, 20.0])}, "omega must have shape"),
        ({"shapes": np.full((12, 3), np.nan)}, "NaN"),
        ({"shapes": np.zeros((11, 3))}, "shapes must have shape"),
        ({"triangles": np.array([[0, 1, 4]])}, "index vertices"),
        ({"triangles": np.array([[0.0, 1, 2]])}, "integer"),
        ({"vertices": np.zeros((4, 2))}, "vertices must have shape"),
        ({"mass": 0.0}, "mass must be > 0"),
        ({"mass": float("inf")}, "mass must be finite"),
        ({"inertia": np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]])}, "symmetric"),
        ({"inertia": np.diag([1.0, -1.0, 1.0])}, "positive definite"),
        ({"center_of_mass": np.zeros(2)}, "center_of_mass"),
        ({"material": {"name": "x", "E": 1e9, "nu": 0.6, "rho": 1.0}}, "not physical"),
        ({"material": {"E": 1e9, "nu": 0.3, "rho": 1.0}}, "lacks name"),
        ({"damping": (-1.0, 0.0)}, "damping"),
        ({"damping": 3.0}, "damping"),
        ({"provenance": {"when": object()}}, "JSON"),
    ],
)
def test_construction_rejects_inconsistent_data(changes, needle):
    with pytest.raises(ModelFileError, match=needle):
        _tet_model(**changes)


# ---------------------------------------------------------------- damaged files


def _entries(path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _rewrite(path, entries: dict, *, fix_checksum: bool) -> None:
    entries = dict(entries)
    if fix_checksum:
        entries["checksum"] = np.array(payload_checksum(int(entries["schema_version"]), entries, str(entries["meta"])))
    with open(path, "wb") as f:
        np.savez(f, **entries)


@pytest.fixture
def saved(tmp_path):
    path = tmp_path / "model.npz"
    _tet_model().save(path)
    return path


def _load_error(path) -> str:
    with pytest.raises(ModelFileError) as info:
        ModalModel.load(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_truncated_file(saved):
    data = saved.read_bytes()
    for cut in (len(data) // 2, len(data) - 10, 30):
        saved.write_bytes(data[:cut])
        assert "truncated" in _load_error(saved)


def test_one_byte_edited_in_an_array(saved):
    data = bytearray(saved.read_bytes())
    raw = _tet_model().shapes.tobytes()
    at = bytes(data).index(raw[:64]) + 40  # inside the stored shapes array
    data[at] ^= 0x01
    saved.write_bytes(bytes(data))
    assert "damaged" in _load_error(saved)  # zip CRC-32 catches the raw edit


def test_edited_array_in_a_valid_archive_fails_the_checksum(saved):
    e = _entries(saved)
    e["omega"] = e["omega"] * (1 + 1e-12)
    _rewrite(saved, e, fix_checksum=False)
    assert "checksum" in _load_error(saved)
    e = _entries(saved)
    e["meta"] = np.array(str(e["meta"]).replace("steel", "steal"))
    _rewrite(saved, e, fix_checksum=False)
    assert "checksum" in _load_error(saved)


def test_newer_schema_version_names_both_versions(saved):
    e = _entries(saved)
    e["schema_version"] = np.array(2, dtype=np.int64)
    _rewrite(saved, e, fix_checksum=True)
    msg = _load_error(saved)
    assert "schema version 2" in msg and "version 1" in msg and "upgrade" in msg


@pytest.mark.parametrize("key", ["shapes", "checksum", "meta", "schema_version"])
def test_missing_entry(saved, key):
    e = _entries(saved)
    del e[key]
    _rewrite(saved, e, fix_checksum=False)
    msg = _load_error(saved)
    assert key in msg


def test_unexpected_entry(saved):
    e = _entries(saved)
    e["extra"] = np.zeros(3)
    _rewrite(saved, e, fix_checksum=False)
    assert "unexpected entries extra" in _load_error(saved)


def test_wrong_shape_and_dtype_with_a_valid_checksum(saved):
    good = _entries(saved)
    e = dict(good, shapes=good["shapes"][:-1])
    _rewrite(saved, e, fix_checksum=True)
    assert "shapes must have shape" in _load_error(saved)
    e = dict(good, inertia=good["inertia"].reshape(9))
    _rewrite(saved, e, fix_checksum=True)
    assert "inertia must have shape" in _load_error(saved)
    e = dict(good, triangles=good["triangles"].astype(np.int32))
    _rewrite(saved, e, fix_checksum=True)
    assert "dtype" in _load_error(saved)


def test_damaged_rotation_tensors_in_a_file(tmp_path):
    path = tmp_path / "rot.npz"
    _tet_model(**_rotation()).save(path)
    good = _entries(path)
    e = dict(good, rotation_T=good["rotation_T"] * (1 + 1e-12))
    _rewrite(path, e, fix_checksum=False)
    assert "checksum" in _load_error(path)
    e = {k: v for k, v in good.items() if k not in ("rotation_T", "rotation_S")}
    _rewrite(path, e, fix_checksum=False)  # both stripped: the checksum covered them
    assert "checksum" in _load_error(path)
    e = {k: v for k, v in good.items() if k != "rotation_S"}
    _rewrite(path, e, fix_checksum=True)
    assert "rotation_T without rotation_S" in _load_error(path)
    e = dict(good, rotation_S=good["rotation_S"][:, :, :2])
    _rewrite(path, e, fix_checksum=True)
    assert "rotation_S must have shape" in _load_error(path)
    e = dict(good, rotation_T=good["rotation_T"].astype(np.float32))
    _rewrite(path, e, fix_checksum=True)
    assert "rotation_T has dtype" in _load_error(path)


def test_not_an_npz_file(tmp_path):
    text = tmp_path / "notes.npz"
    text.write_text("hello, I am not a model\n")
    assert "not a .npz archive" in _load_error(text)
    text.write_bytes(b"")
    assert "not a .npz archive" in _load_error(text)
    npy = tmp_path / "array.npz"
    with open(npy, "wb") as f:
        np.save(f, np.zeros(3))
    assert "single .npy array" in _load_error(npy)
    with zipfile.ZipFile(tmp_path / "zip.npz", "w") as zf:
        zf.writestr("schema_version", "1")
    assert "non-numpy entries" in _load_error(tmp_path / "zip.npz")
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    assert "no schema_version" in _load_error(other)


def test_missing_file_and_directory(tmp_path):
    assert "does not exist" in _load_error(tmp_path / "nope.npz")
    assert "directory" in _load_error(tmp_path)


# ---------------------------------------------------------------- atomic writes


@pytest.mark.parametrize("exc", [OSError(28, "No space left on device"), RuntimeError("boom")])
def test_failed_save_leaves_target_unchanged_and_no_temp_files(tmp_path, monkeypatch, exc):
    path = tmp_path / "model.npz"
    old = _tet_model()
    old.save(path)
    before = path.read_bytes()

    def boom(*a, **k):
        raise exc

    monkeypatch.setattr(np, "savez", boom)
    expected = ModelFileError if isinstance(exc, OSError) else RuntimeError
    with pytest.raises(expected):
        _tet_model(mass=2.0).save(path)
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["model.npz"]
    monkeypatch.undo()
    _same(ModalModel.load(path), old)


def test_save_into_missing_directory_or_onto_a_directory(tmp_path):
    with pytest.raises(ModelFileError, match="cannot write model file"):
        _tet_model().save(tmp_path / "no" / "such" / "m.npz")
    with pytest.raises(ModelFileError, match="is a directory"):
        _tet_model().save(tmp_path)
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------- from a modal analysis


def test_from_modes_free_body_keeps_deformation_modes_on_boundary_vertices(free_box, tmp_path):
    mesh, res = free_box
    m = ModalModel.from_modes(res, mesh, modalfem.ALUMINIUM, damping=(0.1, 2e-7))
    surf = boundary_surface(mesh)
    assert res.rigid_mode_count == 6 and m.mode_count == len(res.omega) == 4
    assert np.array_equal(m.omega, res.omega) and np.all(m.omega > 0)
    assert np.array_equal(m.vertices, mesh.points[surf.mesh_vertices])
    for i in range(m.mode_count):  # restriction = the full shape at the surface vertices
        assert np.array_equal(m.displacement(np.eye(m.mode_count)[i]), res.shape(i)[surf.mesh_vertices])
    mp = mass_properties(mesh, modalfem.ALUMINIUM.rho)
    assert m.mass == mp.mass and np.array_equal(m.inertia, mp.inertia)
    p = m.provenance
    assert p["mesh_hash"] == mesh.fingerprint and p["degree"] == 2 and p["fixed"] is None
    assert p["rigid_mode_count"] == 6 and p["backend"] == "skfem" and p["solver"] == "scipy"
    assert {"modalfem", "numpy", "scipy"} <= set(p["versions"]) and p["created"].endswith("+00:00")
    assert m.material == {"name": "aluminium", "E": 69e9, "nu": 0.33, "rho": 2700.0}
    assert m.damping == (0.1, 2e-7)
    m.save(tmp_path / "box.npz")
    _same(ModalModel.load(tmp_path / "box.npz"), m)
    rep = storage_report(res, m)
    assert rep["boundary_bytes"] < rep["full_bytes"] and rep["ratio"] > 1
    assert rep["full_nodes"] == mesh.node_count(2) and rep["boundary_vertices"] == surf.vertex_count


def test_from_modes_stores_the_rotation_coupling_of_the_full_mesh(free_box):
    from modalfem.backends.skfem import assemble
    from modalfem.runtime import RotationCoupling

    mesh, res = free_box
    _, M = assemble(mesh, modalfem.ALUMINIUM, degree=2)
    m = ModalModel.from_modes(res, mesh, modalfem.ALUMINIUM)
    ref = RotationCoupling.from_matrices(res.shapes, M, res.dof_points, m.center_of_mass)
    assert m.rotation_T.shape == (3, 3, 4, 4) and m.rotation_S.shape == (3, 3, 4)
    np.testing.assert_allclose(m.rotation_T, ref.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.rotation_S, ref.S, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sum(m.rotation_T[a, a] for a in range(3)), np.eye(4), atol=1e-8)  # mass-normalised
    given = ModalModel.from_modes(res, mesh, modalfem.ALUMINIUM, mass_matrix=M)
    assert given.rotation_T.tobytes() == m.rotation_T.tobytes()
    assert ModalModel.from_modes(res, mesh, modalfem.ALUMINIUM, rotation_coupling=False).rotation_T is None
    with pytest.raises(InputError, match="mass matrix must have shape"):
        ModalModel.from_modes(res, mesh, modalfem.ALUMINIUM, mass_matrix=M[:-3, :-3])


def test_from_modes_clamped_body_records_the_constraint():
    mesh = box(size=(0.3, 0.03, 0.03), cells=(6, 1, 1))
    res = modalfem.modes(mesh, modalfem.STEEL, k=2, degree=1, fixed="x0", **PIP_PATH)
    m = ModalModel.from_modes(res, mesh, modalfem.STEEL, provenance={"fixed": "x0", "source": "test"})
    assert m.provenance["fixed"] == "x0" and m.provenance["source"] == "test"
    assert m.provenance["rigid_mode_count"] == 0 and m.provenance["degree"] == 1
    plain = ModalModel.from_modes(res, mesh, modalfem.STEEL)
    assert "DOFs held" in plain.provenance["fixed"]
    assert m.provenance["certificate_passed"] is True
    for other in (box(size=(0.3, 0.03, 0.03), cells=(5, 1, 1)), box(size=(0.31, 0.03, 0.03), cells=(6, 1, 1))):
        with pytest.raises(InputError, match="not computed on this mesh"):
            ModalModel.from_modes(res, other, modalfem.STEEL)
    as_dict = ModalModel.from_modes(res, mesh, {"name": "steel", "E": 200e9, "nu": 0.3, "rho": 7850.0})
    assert as_dict.material == m.material and as_dict.mass == m.mass


@pytest.mark.parametrize("body", ["cantilever", pytest.param("tuning_fork", marks=pytest.mark.slow),
                                  pytest.param("bell", marks=pytest.mark.slow)])
def test_boundary_only_storage_is_smaller_on_tutorial_shapes(body):
    from modalfem.mesh import bell, tuning_fork

    mesh, fixed, mat = {
        "cantilever": lambda: (box(size=(1.0, 0.02, 0.02), cells=(40, 2, 2)), "x0", modalfem.STEEL),
        "tuning_fork": lambda: (tuning_fork(h=0.004), None, modalfem.STEEL),
        "bell": lambda: (bell(h=0.03), None, modalfem.BRASS),
    }[body]()
    res = modalfem.modes(mesh, mat, k=4, degree=2, fixed=fixed, **PIP_PATH)
    rep = storage_report(res, ModalModel.from_modes(res, mesh, mat))
    assert rep["boundary_bytes"] < rep["full_bytes"] and rep["ratio"] > 1
    assert rep["boundary_bytes"] <= rep["all_vertex_bytes"] < rep["full_bytes"]
    assert rep["boundary_bytes"] == 8 * 3 * rep["boundary_vertices"] * 4 and rep["full_nodes"] == mesh.node_count(2)


# ---------------------------------------------------------------- numpy-only import


def test_importing_the_model_module_loads_no_heavy_dependency():
    code = f"import sys, modalfem.model; print(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"import modalfem.model loaded {r.stdout.strip()}"
