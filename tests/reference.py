"""Float64 NumPy reference implementation of the membrane physics (SPEC section 4).

This module is a test oracle: a direct, vectorized, double-precision transcription of
the mass-spring model of the soft shape display (paper section III), written without
any dependency on the simulator package so that the Warp kernels can be compared
against it.

Conventions
-----------
* Positions ``x`` and velocities ``v`` are ``(V, 3)`` float64 arrays.
* ``faces`` is an ``(F, 3)`` integer array wound counter-clockwise seen from outside,
  so ``(x1 - x0) x (x2 - x0)`` points outward.
* ``hinge_arr`` is the ``(E, 4)`` array returned by :func:`hinges`: row
  ``(v0, v1, v2, v3)`` with the directed edge ``v0 -> v1`` in face A, whose third vertex
  is ``v2`` (face A = ``(v0, v1, v2)`` up to cyclic rotation), and ``v1 -> v0`` in face
  B, whose third vertex is ``v3`` (face B = ``(v1, v0, v3)``).  Boundary edges (only
  one adjacent face) carry ``v3 = -1`` and are skipped by the bending terms.
* Every function returning forces returns a new ``(V, 3)`` array (sum over terms is
  done by the caller or by :func:`total_forces`).

Dihedral angle (sign convention shared with the kernels)
--------------------------------------------------------
With ``e = x1 - x0``, ``nA = e x (x2 - x0)`` and ``nB = (x0 - x1) x (x3 - x1)`` (both
outward for a consistently wound surface) and unit vectors ``^``::

    theta = atan2( (nA^ x nB^) . e^ ,  nA^ . nB^ )        in (-pi, pi]

``theta`` is 0 for a flat hinge and positive for a convex one (every hinge of a convex,
outward-wound closed mesh has ``theta > 0``).  It is invariant under swapping
``(v0, v1, v2, v3) -> (v1, v0, v3, v2)``.

Gradient (Bridson et al. 2003), with ``hA``/``hB`` the distances of ``x2``/``x3`` to
the edge line and ``aA = (x2 - x0).e / |e|^2``, ``aB = (x3 - x0).e / |e|^2``::

    dtheta/dx2 = -nA^ / hA
    dtheta/dx3 = -nB^ / hB
    dtheta/dx0 = -(1 - aA) dtheta/dx2 - (1 - aB) dtheta/dx3
    dtheta/dx1 = -aA dtheta/dx2 - aB dtheta/dx3
"""

from __future__ import annotations

import itertools

import numpy as np

R_GAS = 8.314462618  # J / (mol K)
T_DEFAULT = 293.15  # K
P_ATM_DEFAULT = 101325.0  # Pa

__all__ = [
    "R_GAS",
    "T_DEFAULT",
    "P_ATM_DEFAULT",
    "edge_key",
    "hinges",
    "cell_edge_mask",
    "face_areas",
    "face_normals",
    "vertex_masses",
    "edge_lengths",
    "spring_stiffness",
    "spring_energy",
    "spring_forces",
    "spring_damper_dissipation",
    "dihedral",
    "dihedral_gradient",
    "bending_energy",
    "bending_forces_exact",
    "bending_forces_paper",
    "volume",
    "volume_gradient",
    "pressure",
    "pressure_forces",
    "gas_energy",
    "damping_forces",
    "ipam_pairs",
    "ipam_length",
    "ipam_natural_length",
    "ipam_axial_force",
    "ipam_forces",
    "ipam_energy",
    "jam",
    "total_forces",
    "total_energy",
    "net_force",
    "net_torque",
    "icosphere",
    "random_perturbed_icosphere",
]


# ----------------------------------------------------------------------------------
# small utilities
# ----------------------------------------------------------------------------------
def _f64(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("...i,...i->...", a, a))


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _scatter(n_vertices: int, idx: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Sum rows ``vals`` into an ``(n_vertices, 3)`` array at rows ``idx``."""
    out = np.zeros((n_vertices, 3), dtype=np.float64)
    np.add.at(out, np.asarray(idx).ravel(), vals.reshape(-1, 3))
    return out


def edge_key(a: int, b: int) -> tuple[int, int]:
    """Canonical key of the undirected edge ``{a, b}``: ``(min, max)``."""
    a, b = int(a), int(b)
    return (a, b) if a <= b else (b, a)


# ----------------------------------------------------------------------------------
# topology
# ----------------------------------------------------------------------------------
def hinges(faces, return_faces: bool = False):
    """Hinge (edge + two wings) table of a triangle mesh.

    Parameters
    ----------
    faces : (F, 3) int
        Consistently wound (outward, CCW) triangles.
    return_faces : bool
        Also return the ``(E, 2)`` indices ``(face A, face B)`` (``-1`` for a missing B).

    Returns
    -------
    (E, 4) int64 array of ``(v0, v1, v2, v3)``, one row per undirected edge, sorted by
    ``(min(v0, v1), max(v0, v1))``.  ``v0 -> v1`` is a directed edge of face A (third
    vertex ``v2``) and ``v1 -> v0`` a directed edge of face B (third vertex ``v3``).
    When both directions exist the row is oriented so that ``v0 < v1``.  A boundary
    edge (one face only) has ``v3 = -1``.

    Raises ``ValueError`` for a directed edge used twice (inconsistent winding or a
    non-manifold edge).
    """
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError("faces must be (F, 3)")
    n_faces = f.shape[0]
    src = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    dst = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    opp = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
    fid = np.tile(np.arange(n_faces, dtype=np.int64), 3)
    if np.any(src == dst):
        raise ValueError("degenerate face with a repeated vertex")
    n = int(f.max()) + 1 if f.size else 0

    dkey = src * n + dst
    if np.unique(dkey).size != dkey.size:
        raise ValueError("a directed edge appears twice: inconsistent winding or non-manifold mesh")

    lo = np.minimum(src, dst)
    hi = np.maximum(src, dst)
    ukey = lo * n + hi
    # sort by undirected key, and within a key put the lo->hi direction first
    order = np.lexsort(((src != lo).astype(np.int64), ukey))
    uk_sorted = ukey[order]
    _, start, counts = np.unique(uk_sorted, return_index=True, return_counts=True)
    first = order[start]
    has_b = counts == 2
    second = np.where(has_b, order[np.minimum(start + 1, order.size - 1)], -1)

    e_count = start.size
    out = np.empty((e_count, 4), dtype=np.int64)
    out[:, 0] = src[first]
    out[:, 1] = dst[first]
    out[:, 2] = opp[first]
    out[:, 3] = np.where(has_b, opp[second], -1)
    if return_faces:
        fa = fid[first]
        fb = np.where(has_b, fid[second], -1)
        return out, np.stack([fa, fb], axis=1)
    return out


def cell_edge_mask(faces, cell_faces) -> np.ndarray:
    """Boolean ``(E,)`` mask (rows of :func:`hinges`) of every edge of the given faces."""
    h, hf = hinges(faces, return_faces=True)
    sel = np.zeros(np.asarray(faces).shape[0], dtype=bool)
    sel[np.asarray(cell_faces, dtype=np.int64)] = True
    fa, fb = hf[:, 0], hf[:, 1]
    return sel[fa] | ((fb >= 0) & sel[np.maximum(fb, 0)])


# ----------------------------------------------------------------------------------
# geometry, mass
# ----------------------------------------------------------------------------------
def face_areas(x, faces) -> np.ndarray:
    """``(F,)`` triangle areas."""
    x = _f64(x)
    f = np.asarray(faces)
    c = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])
    return 0.5 * _norm(c)


def face_normals(x, faces) -> np.ndarray:
    """``(F, 3)`` outward unit normals ``(x1-x0) x (x2-x0) / |.|``."""
    x = _f64(x)
    f = np.asarray(faces)
    c = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])
    return c / _norm(c)[:, None]


def vertex_masses(rest_x, faces, areal_density) -> np.ndarray:
    """``(V,)`` lumped masses: ``rho_A * sum over adjacent faces of area / 3``."""
    x = _f64(rest_x)
    f = np.asarray(faces)
    a = face_areas(x, f)
    m = np.zeros(x.shape[0], dtype=np.float64)
    for j in range(3):
        np.add.at(m, f[:, j], a / 3.0)
    return float(areal_density) * m


# ----------------------------------------------------------------------------------
# edge springs and dampers
# ----------------------------------------------------------------------------------
def edge_lengths(x, hinge_arr) -> np.ndarray:
    """``(E,)`` lengths ``|x[v1] - x[v0]|``."""
    x = _f64(x)
    h = np.asarray(hinge_arr)
    return _norm(x[h[:, 1]] - x[h[:, 0]])


def spring_stiffness(rest_x, faces, hinge_arr, E_modulus, thickness) -> np.ndarray:
    """``(E,)`` edge stiffness ``k_e = E * t * A(T_e) / c^2``.

    ``A(T_e)`` is the summed rest area of the (one or two) faces of edge ``e`` and ``c``
    its rest length.  The faces are recovered from the vertices of the hinge row
    (face A = ``(v0, v1, v2)``, face B = ``(v1, v0, v3)``).
    """
    x = _f64(rest_x)
    h = np.asarray(hinge_arr)
    x0, x1, x2 = x[h[:, 0]], x[h[:, 1]], x[h[:, 2]]
    e = x1 - x0
    area = 0.5 * _norm(np.cross(e, x2 - x0))
    has_b = h[:, 3] >= 0
    x3 = x[np.where(has_b, h[:, 3], 0)]
    area_b = 0.5 * _norm(np.cross(x0 - x1, x3 - x1))
    area = area + np.where(has_b, area_b, 0.0)
    c2 = _dot(e, e)
    return float(E_modulus) * float(thickness) * area / c2


def spring_energy(x, hinge_arr, rest_len, k) -> float:
    """``sum_e 0.5 k_e (|x_j - x_i| - L_e)^2``."""
    length = edge_lengths(x, hinge_arr)
    return float(np.sum(0.5 * np.broadcast_to(_f64(k), length.shape) * (length - _f64(rest_len)) ** 2))


def spring_forces(x, v, hinge_arr, rest_len, k, c_s=0.0) -> np.ndarray:
    """Edge spring + linear damper forces, ``(V, 3)``.

    For edge ``(i, j) = (v0, v1)``, ``d = x_j - x_i``::

        f_i = [k (|d| - L) + c_s ((v_j - v_i) . d^)] d^,   f_j = -f_i
    """
    x = _f64(x)
    h = np.asarray(hinge_arr)
    i, j = h[:, 0], h[:, 1]
    d = x[j] - x[i]
    length = _norm(d)
    dh = d / length[:, None]
    mag = np.broadcast_to(_f64(k), length.shape) * (length - _f64(rest_len))
    if v is not None and np.any(_f64(c_s) != 0.0):
        v = _f64(v)
        mag = mag + _f64(c_s) * _dot(v[j] - v[i], dh)
    fi = mag[:, None] * dh
    out = _scatter(x.shape[0], i, fi)
    out -= _scatter(x.shape[0], j, fi)
    return out


def spring_damper_dissipation(x, v, hinge_arr, c_s) -> float:
    """Rayleigh function ``sum_e 0.5 c_s ((v_j - v_i) . d^)^2``; the damper force is
    minus its gradient with respect to ``v``."""
    x, v = _f64(x), _f64(v)
    h = np.asarray(hinge_arr)
    d = x[h[:, 1]] - x[h[:, 0]]
    dh = d / _norm(d)[:, None]
    rate = _dot(v[h[:, 1]] - v[h[:, 0]], dh)
    return float(np.sum(0.5 * np.broadcast_to(_f64(c_s), rate.shape) * rate**2))


# ----------------------------------------------------------------------------------
# bending (dihedral springs)
# ----------------------------------------------------------------------------------
def _interior(hinge_arr) -> np.ndarray:
    return np.asarray(hinge_arr)[:, 3] >= 0


def _hinge_geometry(x, h):
    x0, x1, x2, x3 = x[h[:, 0]], x[h[:, 1]], x[h[:, 2]], x[h[:, 3]]
    e = x1 - x0
    elen = _norm(e)
    nA = np.cross(e, x2 - x0)
    nB = np.cross(-e, x3 - x1)
    lA = _norm(nA)
    lB = _norm(nB)
    nAh = nA / lA[:, None]
    nBh = nB / lB[:, None]
    eh = e / elen[:, None]
    return x0, x1, x2, x3, e, elen, eh, nAh, nBh, lA / elen, lB / elen


def dihedral(x, hinge_arr) -> np.ndarray:
    """``(E,)`` signed dihedral angles in ``(-pi, pi]``.

    ``theta = atan2((nA^ x nB^) . e^, nA^ . nB^)`` with face A = ``(v0, v1, v2)``,
    face B = ``(v1, v0, v3)``, ``e = x1 - x0``.  0 when flat, positive when convex.
    Boundary rows (``v3 = -1``) give 0.
    """
    x = _f64(x)
    h = np.asarray(hinge_arr)
    theta = np.zeros(h.shape[0], dtype=np.float64)
    m = _interior(h)
    if not np.any(m):
        return theta
    _, _, _, _, _, _, eh, nAh, nBh, _, _ = _hinge_geometry(x, h[m])
    s = _dot(np.cross(nAh, nBh), eh)
    c = _dot(nAh, nBh)
    t = np.arctan2(s, c)
    t = np.where(t <= -np.pi, t + 2.0 * np.pi, t)
    theta[m] = t
    return theta


def dihedral_gradient(x, hinge_arr):
    """Per-hinge gradient of ``theta``: ``(E, 4, 3)`` w.r.t. ``(x0, x1, x2, x3)``.

    Boundary rows are zero.  See the module docstring for the formulas.
    """
    x = _f64(x)
    h = np.asarray(hinge_arr)
    g = np.zeros((h.shape[0], 4, 3), dtype=np.float64)
    m = _interior(h)
    if not np.any(m):
        return g
    x0, _, x2, x3, e, elen, _, nAh, nBh, hA, hB = _hinge_geometry(x, h[m])
    e2 = elen**2
    aA = _dot(x2 - x0, e) / e2
    aB = _dot(x3 - x0, e) / e2
    g2 = -nAh / hA[:, None]
    g3 = -nBh / hB[:, None]
    g0 = -(1.0 - aA)[:, None] * g2 - (1.0 - aB)[:, None] * g3
    g1 = -aA[:, None] * g2 - aB[:, None] * g3
    g[m] = np.stack([g0, g1, g2, g3], axis=1)
    return g


def _kt_per_edge(kt, n_edges) -> np.ndarray:
    return np.broadcast_to(_f64(kt), (n_edges,)).astype(np.float64)


def bending_energy(x, hinge_arr, theta0, kt) -> float:
    """``sum_e 0.5 kt_e (theta_e - theta0_e)^2`` (``kt`` scalar or ``(E,)``)."""
    h = np.asarray(hinge_arr)
    th = dihedral(x, h)
    kte = _kt_per_edge(kt, h.shape[0]) * _interior(h)
    return float(np.sum(0.5 * kte * (th - _f64(theta0)) ** 2))


def bending_forces_exact(x, hinge_arr, theta0, kt) -> np.ndarray:
    """Exact negative gradient of :func:`bending_energy`, ``(V, 3)``.

    Per hinge ``F_k = -kt (theta - theta0) dtheta/dx_k`` for ``k = v0, v1, v2, v3``.
    """
    x = _f64(x)
    h = np.asarray(hinge_arr)
    m = _interior(h)
    th = dihedral(x, h)
    tau = -_kt_per_edge(kt, h.shape[0]) * (th - _f64(theta0))
    g = dihedral_gradient(x, h)
    f = tau[:, None, None] * g
    f = f[m]
    return _scatter(x.shape[0], h[m], f)


def bending_forces_paper(x, hinge_arr, theta0, kt) -> np.ndarray:
    """Paper eqs. (6)-(9), ``(V, 3)``.

    ``tau = -kt (theta - theta0)``; ``F_A = tau / |r_A| n_A`` on wing ``v2`` and
    ``F_B = tau / |r_B| n_B`` on wing ``v3``, where ``|r|`` is the wing's distance to the
    edge line and ``n_A = -nA^``, ``n_B = -nB^`` (the inward face normals: with this
    sign the wing forces are identical to the exact-gradient ones).  The edge vertices
    each take ``F_v0 = F_v1 = -(F_A + F_B) / 2``.  Zero net force, non-zero net torque.
    """
    x = _f64(x)
    h = np.asarray(hinge_arr)
    m = _interior(h)
    hm = h[m]
    if hm.shape[0] == 0:
        return np.zeros_like(x)
    th = dihedral(x, h)[m]
    th0 = np.broadcast_to(_f64(theta0), (h.shape[0],))[m]
    tau = -_kt_per_edge(kt, h.shape[0])[m] * (th - th0)
    _, _, _, _, _, _, _, nAh, nBh, hA, hB = _hinge_geometry(x, hm)
    FA = (tau / hA)[:, None] * (-nAh)
    FB = (tau / hB)[:, None] * (-nBh)
    Fe = -0.5 * (FA + FB)
    f = np.stack([Fe, Fe, FA, FB], axis=1)
    return _scatter(x.shape[0], hm, f)


# ----------------------------------------------------------------------------------
# pressure
# ----------------------------------------------------------------------------------
def volume(x, faces) -> float:
    """Enclosed volume by the divergence theorem, ``sum_f x0 . (x1 x x2) / 6``."""
    x = _f64(x)
    f = np.asarray(faces)
    return float(np.sum(_dot(x[f[:, 0]], np.cross(x[f[:, 1]], x[f[:, 2]]))) / 6.0)


def volume_gradient(x, faces) -> np.ndarray:
    """Analytic ``dV/dx``, ``(V, 3)``: vertex ``x0`` of each face gets ``x1 x x2 / 6``."""
    x = _f64(x)
    f = np.asarray(faces)
    a, b, c = x[f[:, 0]], x[f[:, 1]], x[f[:, 2]]
    out = _scatter(x.shape[0], f[:, 0], np.cross(b, c) / 6.0)
    out += _scatter(x.shape[0], f[:, 1], np.cross(c, a) / 6.0)
    out += _scatter(x.shape[0], f[:, 2], np.cross(a, b) / 6.0)
    return out


def pressure(n, V, T=T_DEFAULT, p_atm=P_ATM_DEFAULT) -> float:
    """Gauge pressure ``n R T / V - p_atm``."""
    return float(n) * R_GAS * float(T) / float(V) - float(p_atm)


def pressure_forces(x, faces, p) -> np.ndarray:
    """Each face pushes each of its vertices by ``p * area_f / 3 * n^_f`` (outward).

    Equals ``p * dV/dx`` exactly for a closed mesh.
    """
    x = _f64(x)
    f = np.asarray(faces)
    c = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])  # 2 area n^
    per = float(p) * c / 6.0
    per3 = np.repeat(per[:, None, :], 3, axis=1)
    return _scatter(x.shape[0], f, per3)


def gas_energy(x, faces, n, T=T_DEFAULT, p_atm=P_ATM_DEFAULT) -> float:
    """``p_atm V - n R T ln V``; its negative gradient is the pressure force."""
    V = volume(x, faces)
    return float(p_atm) * V - float(n) * R_GAS * float(T) * np.log(V)


# ----------------------------------------------------------------------------------
# viscous damping
# ----------------------------------------------------------------------------------
def damping_forces(v, c_v) -> np.ndarray:
    """``-c_v v`` on every vertex (``c_v`` scalar or ``(V,)``)."""
    v = _f64(v)
    c = _f64(c_v)
    if c.ndim == 1:
        c = c[:, None]
    return -c * v


# ----------------------------------------------------------------------------------
# IPAM
# ----------------------------------------------------------------------------------
def ipam_pairs(rest_x, faces, face_a, face_b):
    """Build-time pairing of the IPAM sub-springs.

    The three vertices of face ``a`` (in face order) are joined to the vertices of face
    ``b`` permuted by the first permutation (``itertools.permutations(faces[b])`` order)
    with strictly least total rest length.

    Returns ``(pairs, offsets)``: ``pairs`` ``(3, 2)`` int vertex pairs ``(va, vb)``,
    ``offsets`` ``(3,)`` = each pair's rest length minus the rest centroid distance.
    """
    x = _f64(rest_x)
    f = np.asarray(faces, dtype=np.int64)
    fa = [int(i) for i in f[int(face_a)]]
    best, best_len = None, np.inf
    for perm in itertools.permutations([int(i) for i in f[int(face_b)]]):
        total = float(sum(np.linalg.norm(x[pb] - x[pa]) for pa, pb in zip(fa, perm)))
        if total < best_len:
            best, best_len = perm, total
    pairs = np.array(list(zip(fa, best)), dtype=np.int64)
    lens = _norm(x[pairs[:, 1]] - x[pairs[:, 0]])
    offsets = lens - ipam_length(x, f, face_a, face_b)
    return pairs, offsets


def ipam_length(x, faces, a, b) -> float:
    """Distance between the centroids of faces ``a`` and ``b``."""
    x = _f64(x)
    f = np.asarray(faces)
    ca = x[f[int(a)]].mean(axis=0)
    cb = x[f[int(b)]].mean(axis=0)
    return float(np.linalg.norm(cb - ca))


def ipam_natural_length(k, area, L0, P) -> float:
    """``L_n = L0 + (A / k) P`` with gauge pressure ``P``."""
    return float(L0) + float(area) / float(k) * float(P)


def ipam_axial_force(x, faces, a, b, k, area, L0, P) -> float:
    """Reported axial force ``k (L - L_n)`` (positive = tension)."""
    return float(k) * (ipam_length(x, faces, a, b) - ipam_natural_length(k, area, L0, P))


def ipam_forces(x, v, pairs, offsets, k, area, L0, P, c_d=0.0) -> np.ndarray:
    """IPAM sub-spring forces, ``(V, 3)``.

    Three springs of stiffness ``k/3`` with natural length ``L_n + offset_s`` between
    ``pairs[s] = (i, j)``, each with a linear damper ``c_d`` (same form as
    :func:`spring_forces`: ``f_i = [k/3 (|d| - L_s) + c_d (v_j - v_i).d^] d^``).
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    h = np.concatenate([pairs, -np.ones_like(pairs)], axis=1)
    rest = ipam_natural_length(k, area, L0, P) + _f64(offsets)
    return spring_forces(x, v, h, rest, float(k) / 3.0, c_d)


def ipam_energy(x, pairs, offsets, k, area, L0, P) -> float:
    """``sum_s 0.5 (k/3) (|d_s| - (L_n + offset_s))^2``."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    rest = ipam_natural_length(k, area, L0, P) + _f64(offsets)
    return spring_energy(x, pairs, rest, float(k) / 3.0)


# ----------------------------------------------------------------------------------
# jamming
# ----------------------------------------------------------------------------------
def jam(x, hinge_arr, edge_mask, rest_len, theta0, k, kt,
        stretch_factor=10.0, bend_factor=30.0, already=None):
    """Jam the masked edges once.

    For every edge with ``edge_mask`` set and not yet in ``already``: rest length :=
    current length, rest angle := current dihedral, ``k *= stretch_factor``,
    ``kt *= bend_factor``.  Edges already jammed are left untouched.

    Returns new arrays ``(rest_len, theta0, k, kt_per_edge, jammed_mask)``.
    """
    h = np.asarray(hinge_arr)
    n_e = h.shape[0]
    mask = np.asarray(edge_mask, dtype=bool).reshape(n_e)
    prev = np.zeros(n_e, dtype=bool) if already is None else np.asarray(already, dtype=bool).copy()
    new = mask & ~prev
    rest_len = np.broadcast_to(_f64(rest_len), (n_e,)).copy()
    theta0 = np.broadcast_to(_f64(theta0), (n_e,)).copy()
    k = np.broadcast_to(_f64(k), (n_e,)).copy()
    kt = _kt_per_edge(kt, n_e).copy()
    rest_len[new] = edge_lengths(x, h)[new]
    theta0[new] = dihedral(x, h)[new]
    k[new] *= float(stretch_factor)
    kt[new] *= float(bend_factor)
    return rest_len, theta0, k, kt, prev | new


# ----------------------------------------------------------------------------------
# totals and diagnostics
# ----------------------------------------------------------------------------------
def total_forces(x, v, faces, hinge_arr, *, rest_len, k, c_s=0.0, theta0=0.0, kt=0.0,
                 bending="exact", n=None, T=T_DEFAULT, p_atm=P_ATM_DEFAULT, c_v=0.0,
                 ipams=()) -> np.ndarray:
    """Sum of all force terms, ``(V, 3)``.

    ``n`` is the air amount (mol; ``None`` = no pressure term).  ``ipams`` is a sequence
    of dicts with keys ``pairs, offsets, k, area, L0, P`` and optional ``c_d``.
    ``bending`` is ``"exact"`` or ``"paper"``.
    """
    x, v = _f64(x), _f64(v)
    f = spring_forces(x, v, hinge_arr, rest_len, k, c_s)
    if np.any(_f64(kt) != 0.0):
        if bending == "exact":
            f += bending_forces_exact(x, hinge_arr, theta0, kt)
        elif bending == "paper":
            f += bending_forces_paper(x, hinge_arr, theta0, kt)
        else:
            raise ValueError(f"unknown bending variant {bending!r}")
    if n is not None:
        f += pressure_forces(x, faces, pressure(n, volume(x, faces), T, p_atm))
    if np.any(_f64(c_v) != 0.0):
        f += damping_forces(v, c_v)
    for ip in ipams:
        f += ipam_forces(x, v, ip["pairs"], ip["offsets"], ip["k"], ip["area"], ip["L0"],
                         ip["P"], ip.get("c_d", 0.0))
    return f


def total_energy(x, faces, hinge_arr, *, rest_len, k, theta0=0.0, kt=0.0, n=None,
                 T=T_DEFAULT, p_atm=P_ATM_DEFAULT, ipams=()) -> float:
    """Potential energy matching the conservative part of :func:`total_forces`
    (exact bending)."""
    e = spring_energy(x, hinge_arr, rest_len, k)
    e += bending_energy(x, hinge_arr, theta0, kt)
    if n is not None:
        e += gas_energy(x, faces, n, T, p_atm)
    for ip in ipams:
        e += ipam_energy(x, ip["pairs"], ip["offsets"], ip["k"], ip["area"], ip["L0"], ip["P"])
    return e


def net_force(f) -> np.ndarray:
    """``sum_i f_i``."""
    return _f64(f).sum(axis=0)


def net_torque(x, f, origin=None) -> np.ndarray:
    """``sum_i (x_i - origin) x f_i`` (origin defaults to 0)."""
    x = _f64(x)
    if origin is not None:
        x = x - _f64(origin)
    return np.cross(x, _f64(f)).sum(axis=0)


# ----------------------------------------------------------------------------------
# test meshes
# ----------------------------------------------------------------------------------
def icosphere(subdivisions: int = 2, radius: float = 1.0):
    """Icosahedron subdivided ``subdivisions`` times and projected to ``radius``.

    Returns ``(x, faces)`` with ``V = 10 * 4**s + 2`` vertices and outward CCW winding.
    """
    t = (1.0 + 5.0**0.5) / 2.0
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0),
             (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
             (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
             (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
             (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
             (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    pts = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in verts]
    for _ in range(int(subdivisions)):
        cache: dict[tuple[int, int], int] = {}

        def mid(a, b):
            key = (a, b) if a < b else (b, a)
            if key not in cache:
                m = pts[a] + pts[b]
                pts.append(m / np.linalg.norm(m))
                cache[key] = len(pts) - 1
            return cache[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    x = np.array(pts, dtype=np.float64) * float(radius)
    f = np.array(faces, dtype=np.int64)
    # enforce outward winding (the icosahedron table above is already outward)
    c = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])
    flip = _dot(c, x[f].mean(axis=1)) < 0
    f[flip] = f[flip][:, [0, 2, 1]]
    return x, f


def random_perturbed_icosphere(subdivisions: int = 2, radius: float = 1.0,
                               noise: float = 0.0, seed: int = 0):
    """:func:`icosphere` with i.i.d. Gaussian noise of std ``noise * radius`` added to
    every vertex coordinate.  Returns ``(x, faces)``."""
    x, f = icosphere(subdivisions, radius)
    rng = np.random.default_rng(seed)
    x = x + float(noise) * float(radius) * rng.standard_normal(x.shape)
    return x, f
