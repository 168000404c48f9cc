"""Hyperelastic triangle membrane (SPEC section 15): a thin incompressible sheet in plane stress.

Each triangle holds its rest frame: ``rest`` (F, 5) = the inverse Dm^-1 (d00, d01, d10, d11) of the
2x2 matrix of its rest edge vectors x1 - x0, x2 - x0 in an orthonormal frame of its plane, and its
rest area A0. Its deformation gradient F = [x1 - x0, x2 - x0] Dm^-1 (3x2) gives the right
Cauchy-Green tensor C = F^T F (2x2); incompressibility sets the stretch through the thickness to
1 / sqrt(det C), so I1 = tr C + 1 / det C. The energy of a triangle is
A0 (c1 (I1 - 3) + c2 (I1 - 3)^2 + c3 (I1 - 3)^3) with ``moduli`` (F, 3) = t (C1, C2, C3) in N/m
(the Yeoh law; neo-Hookean: c2 = c3 = 0), and its forces are that energy's negative gradient.
"""

from typing import Any

import warp as wp


@wp.func
def yeoh_slope(i1m3: Any, c1: Any, c2: Any, c3: Any):
    """dW/dI1 of W = c1 i + c2 i^2 + c3 i^3 at i = I1 - 3."""
    two = type(i1m3)(2.0)
    three = type(i1m3)(3.0)
    return c1 + two * c2 * i1m3 + three * c3 * i1m3 * i1m3


@wp.func
def yeoh_energy(i1m3: Any, c1: Any, c2: Any, c3: Any):
    """W = c1 i + c2 i^2 + c3 i^3 at i = I1 - 3."""
    return i1m3 * (c1 + i1m3 * (c2 + i1m3 * c3))


@wp.func
def deformation_columns(x0: Any, x1: Any, x2: Any, d00: Any, d01: Any, d10: Any, d11: Any):
    """The two columns (fa, fb) of F = [x1 - x0, x2 - x0] Dm^-1."""
    e1 = x1 - x0
    e2 = x2 - x0
    return e1 * d00 + e2 * d10, e1 * d01 + e2 * d11


@wp.func
def first_invariant(fa: Any, fb: Any):
    """(I1 = tr C + 1 / det C, det C) of C = F^T F with F's columns fa, fb."""
    c00 = wp.dot(fa, fa)
    c01 = wp.dot(fa, fb)
    c11 = wp.dot(fb, fb)
    det = c00 * c11 - c01 * c01
    return c00 + c11 + type(det)(1.0) / det, det


@wp.func
def membrane_gradients(x0: Any, x1: Any, x2: Any, d00: Any, d01: Any, d10: Any, d11: Any, area: Any, c1: Any,
                       c2: Any, c3: Any, relax: int):
    """(g1, g2): the triangle energy's gradient with respect to x1 and x2 (x0's is -(g1 + g2)). With
    ``relax`` the tension-field energy: where the minor principal stretch l2 is below l1^-1/2 (its
    stress would be compressive) the sheet wrinkles across it and W = W(l1^2 + 2 / l1), the uniaxial
    state of the major stretch l1; where l1 <= 1 too it is slack (no energy)."""
    fa, fb = deformation_columns(x0, x1, x2, d00, d01, d10, d11)
    c00 = wp.dot(fa, fa)
    c01 = wp.dot(fa, fb)
    c11 = wp.dot(fb, fb)
    det = c00 * c11 - c01 * c01
    zero = type(det)(0.0)
    one = type(det)(1.0)
    two = type(det)(2.0)
    three = type(det)(3.0)
    inv = one / det
    i1 = c00 + c11 + inv
    s = area * yeoh_slope(i1 - three, c1, c2, c3)
    # dI1/dF = 2 F - (2 / det C) F C^-1, F C^-1 = [fa c11 - fb c01, fb c00 - fa c01] / det C
    k = two * inv * inv
    pa = fa * two - (fa * c11 - fb * c01) * k
    pb = fb * two - (fb * c00 - fa * c01) * k
    if relax != 0:
        # the major eigenvalue L = l1^2 of C and its unit eigenvector n (the better conditioned of two forms)
        half = wp.sqrt(type(det)(0.25) * (c00 - c11) * (c00 - c11) + c01 * c01)
        big = type(det)(0.5) * (c00 + c11) + half
        na0 = c01
        na1 = big - c00
        nb0 = big - c11
        nb1 = c01
        use_a = na0 * na0 + na1 * na1 >= nb0 * nb0 + nb1 * nb1
        n0 = wp.where(use_a, na0, nb0)
        n1 = wp.where(use_a, na1, nb1)
        norm = wp.max(wp.sqrt(n0 * n0 + n1 * n1), type(det)(1e-30))
        n0 = n0 / norm
        n1 = n1 / norm
        wrinkled = det * det < big  # l2^4 L < 1 with l2^2 = det / L
        if big <= one:  # slack
            s = zero
        elif wrinkled:
            # W(I1*), I1* = L + 2 L^-1/2, dI1*/dF = (1 - L^-3/2) 2 (F n) n^T
            root = wp.sqrt(big)
            s = area * yeoh_slope(big + two / root - three, c1, c2, c3) * (one - one / (big * root))
            fn = fa * n0 + fb * n1
            pa = fn * (two * n0)
            pb = fn * (two * n1)
    # dW/d[x1 - x0, x2 - x0] = dW/dF Dm^-T
    return (pa * d00 + pb * d01) * s, (pa * d10 + pb * d11) * s


@wp.kernel
def eval_membrane_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,) vertex indices
    rest: wp.array2d(dtype=Any),  # (F, 5) Dm^-1 (d00, d01, d10, d11) in 1/m, rest area A0 in m^2
    moduli: wp.array2d(dtype=Any),  # (F, 3) t C1, t C2, t C3 in N/m
    relax: int,  # 1: the tension-field energy (membrane_gradients); 0: the solid sheet
    use_jam: int,  # 1: read the jam fields below; 0: nothing jammed (they are placeholders)
    # State in:
    jam_in: wp.array3d(dtype=Any),  # (6, W, F) a jammed triangle's Dm^-1, rest area, moduli multiplier
    jammed_in: wp.array2d(dtype=wp.int32),  # (W, F) 1 where jammed
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    # Out:
    f_out: wp.array2d(dtype=Any),  # (W, V) N, accumulated
):
    """The membrane forces of every triangle in every world; a jammed triangle's rest frame and moduli
    multiplier are its world's jam fields."""
    w, i = wp.tid()
    face = faces[i]
    # a jammed triangle reads its world's jam fields (selected without a branch; the indices are kept
    # inside the (1, 1) placeholders where nothing is jammed)
    wj = wp.min(w, jammed_in.shape[0] - 1)
    ij = wp.min(i, jammed_in.shape[1] - 1)
    frozen = use_jam != 0 and jammed_in[wj, ij] != 0
    d00 = wp.where(frozen, jam_in[0, wj, ij], rest[i, 0])
    d01 = wp.where(frozen, jam_in[1, wj, ij], rest[i, 1])
    d10 = wp.where(frozen, jam_in[2, wj, ij], rest[i, 2])
    d11 = wp.where(frozen, jam_in[3, wj, ij], rest[i, 3])
    # the multiplier scales the energy as the area does
    area = wp.where(frozen, jam_in[4, wj, ij] * jam_in[5, wj, ij], rest[i, 4])
    g1, g2 = membrane_gradients(x_in[w, face[0]], x_in[w, face[1]], x_in[w, face[2]], d00, d01, d10, d11, area,
                                moduli[i, 0], moduli[i, 1], moduli[i, 2], relax)
    wp.atomic_add(f_out, w, face[0], g1 + g2)
    wp.atomic_add(f_out, w, face[1], -g1)
    wp.atomic_add(f_out, w, face[2], -g2)


@wp.func
def rest_frame(x0: Any, x1: Any, x2: Any):
    """(d00, d01, d10, d11, A0): Dm^-1 of a triangle in an orthonormal frame of its plane (u along
    x1 - x0) and its area."""
    e1 = x1 - x0
    e2 = x2 - x0
    l1 = wp.length(e1)
    n = wp.cross(e1, e2)
    a2 = wp.length(n)  # twice the area
    u = e1 / l1
    v = wp.cross(n / a2, u)
    # Dm = [[l1, e2.u], [0, e2.v]]
    b = wp.dot(e2, u)
    c = wp.dot(e2, v)
    one = type(l1)(1.0)
    half = type(l1)(0.5)
    return one / l1, -b / (l1 * c), type(l1)(0.0), one / c, half * a2


@wp.kernel
def membrane_rest_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,) vertex indices
    x_rest: wp.array(dtype=Any),  # (V,) rest positions, m
    # Out:
    rest_out: wp.array2d(dtype=Any),  # (F, 5) Dm^-1 and rest area
):
    """Each triangle's rest frame from the rest positions (see ``rest_frame``)."""
    i = wp.tid()
    face = faces[i]
    d00, d01, d10, d11, area = rest_frame(x_rest[face[0]], x_rest[face[1]], x_rest[face[2]])
    rest_out[i, 0] = d00
    rest_out[i, 1] = d01
    rest_out[i, 2] = d10
    rest_out[i, 3] = d11
    rest_out[i, 4] = area


@wp.kernel(enable_backward=False)
def add_vertex_diagonal_kernel(
    # Model:
    vertex_in: wp.array(dtype=Any),  # (V,) N/m: the triangles' stiffness estimate per vertex
    # Out:
    diag_out: wp.array2d(dtype=Any),  # (W, V) N/m, accumulated
):
    """The static settle's preconditioner part of the membrane: diag += its stiffness per vertex."""
    w, i = wp.tid()
    diag_out[w, i] = diag_out[w, i] + vertex_in[i]


@wp.kernel(enable_backward=False)
def jam_membrane_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,) vertex indices
    cell_faces: wp.array(dtype=wp.int32),  # (n,) faces of the cell being jammed
    world_mask: wp.array(dtype=wp.int32),  # (W,) 1 for worlds that jam now
    jam_factor: Any,  # moduli multiplier of a jammed triangle
    rest: wp.array2d(dtype=Any),  # (F, 5) rest frames and areas
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) m
    # Out (read and updated):
    jam_out: wp.array3d(dtype=Any),  # (6, W, F) Dm^-1, rest area, moduli multiplier
    jammed_out: wp.array2d(dtype=wp.int32),  # (W, F) 1 where jammed
):
    """A jammed triangle takes its current shape as its rest shape and its moduli times the jam factor;
    its material keeps its volume, so the thickness is the current one (the multiplier
    jam_factor A0 / A makes A t' C = jam_factor A0 t C). A triangle already jammed keeps its values."""
    w, j = wp.tid()
    if world_mask[w] == 0:
        return
    i = cell_faces[j]
    if jammed_out[w, i] != 0:
        return
    face = faces[i]
    d00, d01, d10, d11, area = rest_frame(x_in[w, face[0]], x_in[w, face[1]], x_in[w, face[2]])
    jam_out[0, w, i] = d00
    jam_out[1, w, i] = d01
    jam_out[2, w, i] = d10
    jam_out[3, w, i] = d11
    jam_out[4, w, i] = area
    jam_out[5, w, i] = jam_factor * rest[i, 4] / area
    jammed_out[w, i] = 1


@wp.kernel
def membrane_moduli_kernel(
    # Model:
    face_scale: wp.array(dtype=Any),  # (F,) multiplier of each triangle's moduli (Design.stretch_scale)
    shear_modulus: wp.array(dtype=Any),  # (1,) mu, Pa
    yeoh_c2: wp.array(dtype=Any),  # (1,) C2, Pa
    yeoh_c3: wp.array(dtype=Any),  # (1,) C3, Pa
    thickness: wp.array(dtype=Any),  # (1,) t, m
    # Out:
    moduli_out: wp.array2d(dtype=Any),  # (F, 3) t C1, t C2, t C3 in N/m
):
    """Each triangle's moduli from the law's constants (C1 = mu / 2), as the host model derives them."""
    i = wp.tid()
    t = thickness[0]
    s = face_scale[i]
    moduli_out[i, 0] = t * (type(t)(0.5) * shear_modulus[0]) * s
    moduli_out[i, 1] = t * yeoh_c2[0] * s
    moduli_out[i, 2] = t * yeoh_c3[0] * s


@wp.kernel
def membrane_plate_kernel(
    # Model:
    shear_modulus: wp.array(dtype=Any),  # (1,) mu, Pa
    thickness: wp.array(dtype=Any),  # (1,) t, m
    factor: Any,  # 3 / (12 (1 - nu^2)): D = factor mu t^3 (E = 3 mu)
    # Out:
    plate_out: wp.array(dtype=Any),  # (1,) the plate stiffness D, N m
):
    """The plate bending stiffness D = E t^3 / 12 (1 - nu^2) with E = 3 mu (Material.plate_stiffness)."""
    t = thickness[0]
    plate_out[0] = factor * shear_modulus[0] * t * t * t


@wp.kernel
def jam_membrane_grad_kernel(
    # Model:
    faces: wp.array(dtype=wp.vec3i),  # (F,) vertex indices
    jam_now: wp.array(dtype=wp.int32),  # (F,) 1 for the triangles that jam at this event
    jam_factor: Any,  # moduli multiplier of a jammed triangle
    rest: wp.array2d(dtype=Any),  # (F, 5) rest frames and areas
    # State in:
    x_in: wp.array2d(dtype=Any),  # (1, V) the positions the cells jam at, m
    jam_in: wp.array3d(dtype=Any),  # (6, 1, F) the jam fields before the event
    jammed_in: wp.array2d(dtype=wp.int32),  # (1, F)
    # Out:
    jam_out: wp.array3d(dtype=Any),  # (6, 1, F) after it
    jammed_out: wp.array2d(dtype=wp.int32),  # (1, F)
):
    """A jam event of the differentiable replay (one world): the jamming triangles take their current
    shape as rest shape and the multiplier jam_factor A0 / A (as ``jam_membrane_kernel``), writing fresh
    output arrays so that Warp's adjoint reaches the positions and the rest areas; the others keep theirs."""
    i = wp.tid()
    if jam_now[i] == 0:
        for r in range(6):
            jam_out[r, 0, i] = jam_in[r, 0, i]
        jammed_out[0, i] = jammed_in[0, i]
        return
    face = faces[i]
    d00, d01, d10, d11, area = rest_frame(x_in[0, face[0]], x_in[0, face[1]], x_in[0, face[2]])
    jam_out[0, 0, i] = d00
    jam_out[1, 0, i] = d01
    jam_out[2, 0, i] = d10
    jam_out[3, 0, i] = d11
    jam_out[4, 0, i] = area
    jam_out[5, 0, i] = jam_factor * rest[i, 4] / area
    jammed_out[0, i] = 1
