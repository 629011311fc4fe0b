"""Cylinder mesh of the hand: one capped cylinder per bone (19 per hand), as in Tang et al.

Each bone is a cylinder from its parent joint to its child joint with a fixed radius. The
template has ``sections`` vertices around and ``rings`` rings along the axis plus one centre
vertex per cap: 20 x 21 + 2 = 422 vertices and 840 triangles per bone by default (the paper's
"about 421 vertices" per cylinder).

Radii (metres) are half the adult finger breadths of Greiner (1991, US Army Natick TR-92/011;
index breadth ~21 mm at the PIP joint, ~18 mm at the DIP joint, thumb ~23 mm), tapering from
proximal to distal; the wrist-MCP cylinders stand for the strips of the palm over each
metacarpal (palm breadth ~85 mm over four rays -> ~10 mm radius).

Public API (numpy, float64 inside, float32 out where noted):

    BONE_RADIUS_M: dict[bone name, radius m];  bone_radii() -> (19,) metres (BONES order)
    CylinderTemplate(sections=20, rings=21): unit cylinder (radius 1, z in [0, 1]) with
        .vertices (V, 3), .faces (F, 3), .vertex_faces (V, max_degree) padded with -1,
        .n_vertices, .homogeneous (V, 4) = (x, y, z, 1); .occluder_faces (80, 3) the same closed
        surface without the inner rings, .occluder_face_plane (80,) side 0..S-1 / bottom S / top S+1
    bone_frames(joints (..., 21, 3)) -> (start (..., 19, 3), axis unit (..., 19, 3), length (..., 19))
    bone_basis(axis (..., 3)) -> (e1, e2): the cross-section axes of the template's x and y
    bone_frame_matrix(joints (..., 21, 3), radii=None) -> (..., 19, 3, 4) metres: template (x, y, z, 1) -> bone
    bone_vertices(joints (..., 21, 3), radii=None, template=None) -> (..., 19, V, 3) metres
    hand_mesh(joints (H, 21, 3), radii=None, template=None) -> trimesh.Trimesh of H hands x 19
        cylinders, vertices ordered (hand, bone, template vertex); ``process=False`` so indices stay
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from handradar.hand.skeleton import BONE_CHILD, BONE_NAMES, BONE_PARENT, N_BONES

BONE_RADIUS_M: dict[str, float] = {
    "thumb_proximal": 0.0115, "thumb_intermediate": 0.0105, "thumb_distal": 0.0095,
    "index_metacarpal": 0.010, "index_proximal": 0.0100, "index_intermediate": 0.0090, "index_distal": 0.0080,
    "middle_metacarpal": 0.010, "middle_proximal": 0.0100, "middle_intermediate": 0.0090, "middle_distal": 0.0080,
    "ring_metacarpal": 0.010, "ring_proximal": 0.0095, "ring_intermediate": 0.0085, "ring_distal": 0.0075,
    "pinky_metacarpal": 0.010, "pinky_proximal": 0.0085, "pinky_intermediate": 0.0075, "pinky_distal": 0.0070,
}
assert set(BONE_RADIUS_M) == set(BONE_NAMES)


def bone_radii() -> np.ndarray:
    """(19,) cylinder radii in metres, BONES order."""
    return np.array([BONE_RADIUS_M[n] for n in BONE_NAMES], dtype=np.float64)


class CylinderTemplate:
    """Unit capped cylinder: radius 1, axis z from 0 to 1, ``rings`` x ``sections`` side vertices
    (ring-major) followed by the two cap centres (z = 0, then z = 1)."""

    def __init__(self, sections: int = 20, rings: int = 21) -> None:
        if sections < 3 or rings < 2:
            raise ValueError(f"a cylinder needs >= 3 sections and >= 2 rings, found {sections}, {rings}")
        self.sections, self.rings = sections, rings
        phi = 2 * np.pi * np.arange(sections) / sections
        z = np.linspace(0.0, 1.0, rings)
        side = np.stack([np.broadcast_to(np.cos(phi), (rings, sections)),
                         np.broadcast_to(np.sin(phi), (rings, sections)),
                         np.broadcast_to(z[:, None], (rings, sections))], axis=-1).reshape(-1, 3)
        self.vertices = np.concatenate([side, [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
        n_side = rings * sections
        faces = []
        for r in range(rings - 1):  # outward-facing side quads as two triangles
            for s in range(sections):
                a, b = r * sections + s, r * sections + (s + 1) % sections
                c, d = a + sections, b + sections
                faces += [(a, b, d), (a, d, c)]
        top = (rings - 1) * sections
        for s in range(sections):  # caps, outward normals -z and +z
            faces.append((n_side, (s + 1) % sections, s))
            faces.append((n_side + 1, top + s, top + (s + 1) % sections))
        self.faces = np.asarray(faces, dtype=np.int64)
        mesh = trimesh.Trimesh(self.vertices, self.faces, process=False)
        self.vertex_faces = np.asarray(mesh.vertex_faces, dtype=np.int64)
        # The same closed surface with the intermediate rings left out: the side quads of a straight
        # cylinder are coplanar along its length, so 80 triangles (default) bound exactly what the
        # 840 do. Ray casting uses these (a 10x smaller BVH); vertices keep their indices.
        occ = []
        for s_ in range(sections):
            a, b = s_, (s_ + 1) % sections
            c, d = top + a, top + b
            occ += [(a, b, d), (a, d, c)]
        for s_ in range(sections):
            occ.append((n_side, (s_ + 1) % sections, s_))
            occ.append((n_side + 1, top + s_, top + (s_ + 1) % sections))
        self.occluder_faces = np.asarray(occ, dtype=np.int64)
        # the plane of each occluder triangle: side s (two per section), then bottom / top cap
        self.occluder_face_plane = np.concatenate([np.repeat(np.arange(sections), 2),
                                                   np.tile([sections, sections + 1], sections)])
        self.vertex_occluder_faces = self._adjacency(self.occluder_faces)
        # the vertices those triangles use (end rings + cap centres), and the faces re-indexed onto them
        self.occluder_vertices = np.unique(self.occluder_faces)
        remap = np.full(self.vertices.shape[0], -1, dtype=np.int64)
        remap[self.occluder_vertices] = np.arange(len(self.occluder_vertices))
        self.occluder_faces_compact = remap[self.occluder_faces]
        # vertices with the same occluder triangles (the 19 inner rings of a section line) share one
        # facing test: (G, max_degree) distinct adjacency rows and each vertex's row
        self.facing_groups, inverse = np.unique(self.vertex_occluder_faces, axis=0, return_inverse=True)
        self.vertex_facing_group = inverse.reshape(-1)
        self.homogeneous = np.concatenate([self.vertices, np.ones((self.n_vertices, 1))], axis=1)

    def _adjacency(self, faces: np.ndarray) -> np.ndarray:
        """(V, max_degree) indices of the triangles of ``faces`` each vertex lies on, padded with -1."""
        tri = self.vertices[faces]  # (F, 3, 3)
        e0, e1 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        n = np.cross(e0, e1)
        rel = self.vertices[:, None, :] - tri[None, :, 0]  # (V, F, 3)
        on_plane = np.abs((rel * n).sum(-1)) < 1e-9
        # barycentric coordinates of the projection
        d00, d01, d11 = (e0 * e0).sum(-1), (e0 * e1).sum(-1), (e1 * e1).sum(-1)
        d20, d21 = (rel * e0).sum(-1), (rel * e1).sum(-1)
        den = d00 * d11 - d01 * d01
        v = (d11 * d20 - d01 * d21) / den
        w = (d00 * d21 - d01 * d20) / den
        inside = on_plane & (v >= -1e-9) & (w >= -1e-9) & (v + w <= 1 + 1e-9)
        deg = inside.sum(1).max()
        out = np.full((self.vertices.shape[0], deg), -1, dtype=np.int64)
        for i, row in enumerate(inside):
            idx = np.flatnonzero(row)
            out[i, : len(idx)] = idx
        return out

    @property
    def n_vertices(self) -> int:
        return self.vertices.shape[0]

    @property
    def n_faces(self) -> int:
        return self.faces.shape[0]


@functools.cache
def default_template(sections: int = 20, rings: int = 21) -> CylinderTemplate:
    return CylinderTemplate(sections, rings)


def bone_frames(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start point, unit axis and length (metres) of each bone: (..., 19, 3), (..., 19, 3), (..., 19).

    A zero-length bone gets a zero axis."""
    joints = np.asarray(joints, dtype=np.float64)
    start = joints[..., BONE_PARENT, :]
    vec = joints[..., BONE_CHILD, :] - start
    length = np.linalg.norm(vec, axis=-1)
    axis = np.divide(vec, length[..., None], out=np.zeros_like(vec), where=length[..., None] > 1e-9)
    return start, axis, length


def bone_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``axis`` (..., 3) to a right-handed frame (zeros stay zeros)."""
    helper = np.where(np.abs(axis[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    n1 = np.linalg.norm(e1, axis=-1, keepdims=True)
    e1 = np.divide(e1, n1, out=np.zeros_like(e1), where=n1 > 1e-12)
    return e1, np.cross(axis, e1)


def bone_frame_matrix(joints: np.ndarray, radii: np.ndarray | None = None) -> np.ndarray:
    """(..., 19, 3, 4) affine maps of the unit template onto each bone cylinder, metres: columns
    radius * e1, radius * e2, length * axis and start, so bone point = M @ (x, y, z, 1)."""
    radii = bone_radii() if radii is None else np.asarray(radii, dtype=np.float64)
    start, axis, length = bone_frames(joints)
    e1, e2 = bone_basis(axis)
    r = radii[:, None]  # (19, 1)
    return np.stack([r * e1, r * e2, length[..., None] * axis, start], axis=-1)


def bone_vertices(joints: np.ndarray, radii: np.ndarray | None = None,
                  template: CylinderTemplate | None = None) -> np.ndarray:
    """Mesh vertices of every bone cylinder, (..., 19, V, 3) metres (a transposed view)."""
    template = template or default_template()
    m = bone_frame_matrix(joints, radii)
    # one matrix product for all bones (~25x faster than broadcasting the frame over the vertices)
    flat = m.reshape(-1, 4) @ template.homogeneous.T  # (... * 19 * 3, V)
    return np.swapaxes(flat.reshape(*m.shape[:-1], template.n_vertices), -1, -2)


def hand_mesh(joints: np.ndarray, radii: np.ndarray | None = None,
              template: CylinderTemplate | None = None) -> trimesh.Trimesh:
    """One mesh of all bone cylinders of ``joints`` (H, 21, 3): H x 19 cylinders, unprocessed."""
    template = template or default_template()
    verts = bone_vertices(joints, radii, template).reshape(-1, 3)
    n_cyl = verts.shape[0] // template.n_vertices
    faces = (template.faces[None] + template.n_vertices * np.arange(n_cyl)[:, None, None]).reshape(-1, 3)
    return trimesh.Trimesh(verts, faces, process=False, validate=False)


N_BONES_PER_HAND = N_BONES
