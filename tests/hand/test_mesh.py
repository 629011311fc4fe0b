"""Cylinder mesh: vertex count, closed outward surface, vertices on the bone cylinders."""

from __future__ import annotations

import numpy as np
import trimesh

from handradar.hand.mesh import (
    CylinderTemplate,
    bone_frames,
    bone_radii,
    bone_vertices,
    hand_mesh,
)
from handradar.hand.retarget import standard_hand


def test_template_is_a_closed_outward_cylinder_of_about_421_vertices():
    t = CylinderTemplate()
    assert t.n_vertices == 422 and t.n_faces == 840
    m = trimesh.Trimesh(t.vertices, t.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent
    # volume of the inscribed 20-gon prism, positive = outward normals
    assert np.isclose(m.volume, 0.5 * 20 * np.sin(2 * np.pi / 20))


def test_vertices_lie_on_each_bone_cylinder():
    joints = standard_hand() + [0.02, -0.05, 0.3]
    verts = bone_vertices(joints)  # (19, V, 3)
    start, axis, length = bone_frames(joints)
    rel = verts - start[:, None]
    along = (rel * axis[:, None]).sum(-1)
    radial = np.linalg.norm(rel - along[..., None] * axis[:, None], axis=-1)
    side = slice(0, 420)
    np.testing.assert_allclose(radial[:, side], np.broadcast_to(bone_radii()[:, None], (19, 420)), atol=1e-12)
    assert (along >= -1e-12).all() and (along <= length[:, None] + 1e-12).all()


def test_hand_mesh_concatenates_hands():
    j = np.stack([standard_hand(), standard_hand(hand="left") + [0.15, 0, 0]])
    m = hand_mesh(j)
    assert m.vertices.shape == (2 * 19 * 422, 3) and m.faces.shape == (2 * 19 * 840, 3)
