"""Quasi-static settle kernels: limited-memory BFGS on the potential energy, one thread per world.

The force pass (hinge.eval_hinge*_kernel, the actuator families, pressure.finish_forces_kernel) at a
trial point with zero velocities gives -grad E there; ``lbfgs_iterate_kernel`` then takes one
iteration of every world: it judges the trial point (line search on the directional derivative),
accepts it into the L-BFGS history or shortens the step, computes the next search direction (the
two-loop recursion with a diagonal spring-stiffness preconditioner, rigid translations and rotations
projected out) and writes the next trial point. One iteration is so a fixed sequence of launches
(captured once). Every world is one thread that loops over its vertices: on the CPU (one core) that
is the whole arithmetic with one launch; reductions are accumulated in float64 for every precision.
docs/equilibria.md describes the method.
"""

from typing import Any

import warp as wp

# per-world integer flags (W, N_FLAGS)
F_ACTIVE = wp.constant(0)  # 1 while the world iterates
F_HEAD = wp.constant(1)  # next history slot
F_COUNT = wp.constant(2)  # history pairs held
F_PHASE = wp.constant(3)  # 0: the trial point is the start (first evaluation); 1: a line-search trial
F_EVALS = wp.constant(4)  # force evaluations taken
F_STATUS = wp.constant(5)  # STATUS_* below
F_REJECTS = wp.constant(6)  # trial points rejected in a row
F_SINCE = wp.constant(7)  # accepted steps since the residual last halved
N_FLAGS = 8

# per-world float64 scalars (W, N_SCALARS)
S_ALPHA = wp.constant(0)  # step length of the current trial
S_GD0 = wp.constant(1)  # g . d at the accepted point (< 0)
S_GAMMA = wp.constant(2)  # initial inverse-Hessian scale s.y / y.D.y
S_FMAX = wp.constant(3)  # largest vertex force at the accepted point, N
S_DMAX = wp.constant(4)  # largest vertex component of the direction, m
S_DE = wp.constant(5)  # energy change since the start (trapezoid estimate along the accepted steps), J
S_BEST = wp.constant(6)  # the residual at the last halving, N
N_SCALARS = 7

STATUS_RUNNING = wp.constant(0)
STATUS_CONVERGED = wp.constant(1)
STATUS_STALLED = wp.constant(2)  # no acceptable step length above the floor
STATUS_INVALID = wp.constant(3)  # the start is not a valid state (non-finite forces, no chamber)
STATUS_FLOOR = wp.constant(4)  # the residual stopped falling (the precision's rounding floor) above the tolerance


@wp.kernel(enable_backward=False)
def lbfgs_start_kernel(
    # State in:
    x_in: wp.array2d(dtype=Any),  # (W, V) positions, m
    # Out:
    xv_out: wp.array3d(dtype=Any),  # (2, W, V) trial point: the start, zero velocities
    fg_out: wp.array3d(dtype=Any),  # (2, W, V) forces, dV/dx: zeroed for the first evaluation
    volume_out: wp.array2d(dtype=wp.float64),  # (W, 1) m^3, zeroed
    flags_out: wp.array2d(dtype=wp.int32),  # (W, N_FLAGS) reset
    scalars_out: wp.array2d(dtype=wp.float64),  # (W, N_SCALARS) reset
):
    """Start every world at its current positions (phase 0: the first evaluation is at the start)."""
    w, i = wp.tid()
    x = x_in[w, i]
    zero = x * type(x[0])(0.0)
    xv_out[0, w, i] = x
    xv_out[1, w, i] = zero
    fg_out[0, w, i] = zero
    fg_out[1, w, i] = zero
    if i == 0:
        volume_out[w, 0] = wp.float64(0.0)
        for k in range(N_FLAGS):
            flags_out[w, k] = 0
        flags_out[w, F_ACTIVE] = 1
        for k in range(N_SCALARS):
            scalars_out[w, k] = wp.float64(0.0)
        scalars_out[w, S_GAMMA] = wp.float64(1.0)


@wp.kernel(enable_backward=False)
def diagonal_stiffness_kernel(
    # Model:
    hinges: wp.array(dtype=wp.vec4i),  # (E,) v0, v1 (edge), v2, v3 (wings)
    # State in:
    edge_in: wp.array3d(dtype=Any),  # (4, W, E) rest length, rest angle, stretch and bending stiffness
    # Out:
    diag_out: wp.array2d(dtype=Any),  # (W, V) N/m, accumulated (zero it first)
):
    """A diagonal stiffness estimate per vertex: every edge spring k_e on both ends and every hinge
    k_t / L^2 on its four vertices (L the rest length: the bending lever arm's scale)."""
    w, e = wp.tid()
    h = hinges[e]
    k = edge_in[2, w, e]
    L = edge_in[0, w, e]
    b = edge_in[3, w, e] / wp.max(L * L, type(L)(1.0e-12))
    wp.atomic_add(diag_out, w, h[0], k + b)
    wp.atomic_add(diag_out, w, h[1], k + b)
    wp.atomic_add(diag_out, w, h[2], b)
    wp.atomic_add(diag_out, w, h[3], b)


@wp.kernel(enable_backward=False)
def invert_diagonal_kernel(
    # Model:
    floor: Any,  # N/m: least stiffness a vertex is given
    # Out (read and updated):
    diag_out: wp.array2d(dtype=Any),  # (W, V) in: stiffness N/m; out: its inverse, m/N
):
    """diag <- 1 / max(diag, floor): the preconditioner D of the L-BFGS iteration."""
    w, i = wp.tid()
    diag_out[w, i] = type(floor)(1.0) / wp.max(diag_out[w, i], floor)


@wp.func
def dot64(a: Any, b: Any):
    """a . b (computed in a's precision) as a float64, for sums accumulated in float64."""
    return wp.float64(wp.dot(a, b))


@wp.func
def scaled(a: Any, c: wp.float64):
    """a * c with c converted to a's precision."""
    return a * type(a[0])(c)


@wp.func
def as_vec3d(a: Any):
    """a as a wp.vec3d."""
    return wp.vec3d(wp.float64(a[0]), wp.float64(a[1]), wp.float64(a[2]))


@wp.func
def history_slot(head: int, back: int, memory: int):
    """The history slot ``back`` pairs before the newest (0: the newest)."""
    return (head - 1 - back + 2 * memory) % memory


@wp.func
def lbfgs_direction(
    w: int,
    n: int,  # vertices
    rigid_free: int,  # 1: the energy is invariant under rigid motions, whose part of d is removed; 0: kept
    memory: int,
    x0: wp.array2d(dtype=Any),  # (W, V) accepted positions, m
    g0: wp.array2d(dtype=Any),  # (W, V) gradient there, N
    precond: wp.array2d(dtype=Any),  # (W, V) inverse diagonal stiffness, m/N
    hist_s: wp.array3d(dtype=Any),  # (memory, W, V) position changes, m
    hist_y: wp.array3d(dtype=Any),  # (memory, W, V) gradient changes, N
    rho: wp.array2d(dtype=wp.float64),  # (memory, W) 1 / (s . y)
    coef: wp.array2d(dtype=wp.float64),  # (memory, W) scratch of the two-loop recursion
    d: wp.array2d(dtype=Any),  # (W, V) out: the search direction
    flags: wp.array2d(dtype=wp.int32),  # (W, N_FLAGS)
    scalars: wp.array2d(dtype=wp.float64),  # (W, N_SCALARS)
):
    """The L-BFGS direction d = -H g0 (two-loop recursion, H0 = gamma D) with its rigid part removed:
    the mean (a translation) and the best-fitting infinitesimal rotation about the centroid (unit
    weights), so the settle keeps the centroid and the orientation. Each pass over the vertices
    finishes one update and accumulates the next dot product (2 count + 2 passes). A direction that
    does not descend restarts the history (preconditioned steepest descent). Writes g0 . d and the
    largest |d_i| into the scalars."""
    for attempt in range(2):
        count = flags[w, F_COUNT]
        head = flags[w, F_HEAD]
        gamma = scalars[w, S_GAMMA]
        if count == 0:
            gamma = wp.float64(1.0)
        # first loop, newest to oldest: a_j = rho_j s_j . q; q -= a_j y_j (q = g0 at first)
        acc = wp.float64(0.0)
        if count > 0:
            j = history_slot(head, 0, memory)
            for i in range(n):
                acc += dot64(hist_s[j, w, i], g0[w, i])
        for t in range(count):
            j = history_slot(head, t, memory)
            a = acc * rho[j, w]
            coef[j, w] = a
            acc = wp.float64(0.0)
            last = t + 1 == count
            jn = history_slot(head, t + 1, memory)
            for i in range(n):
                q = g0[w, i]
                if t > 0:
                    q = d[w, i]
                q = q - scaled(hist_y[j, w, i], a)
                if last:  # r = gamma D q, and the oldest pair's y . r for the second loop
                    q = scaled(q, gamma * wp.float64(precond[w, i]))
                    acc += dot64(hist_y[j, w, i], q)
                else:
                    acc += dot64(hist_s[jn, w, i], q)
                d[w, i] = q
        # second loop, oldest to newest: b = rho_j y_j . r; r += (a_j - b) s_j; the rigid sums on the last pass
        sx = wp.vec3d(0.0, 0.0, 0.0)
        sr = wp.vec3d(0.0, 0.0, 0.0)
        sxr = wp.vec3d(0.0, 0.0, 0.0)
        sxx = wp.mat33d(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        if count == 0:
            for i in range(n):
                r = scaled(g0[w, i], wp.float64(precond[w, i]))
                d[w, i] = r
                xi = as_vec3d(x0[w, i])
                ri = as_vec3d(r)
                sx = sx + xi
                sr = sr + ri
                sxr = sxr + wp.cross(xi, ri)
                sxx = sxx + wp.outer(xi, xi)
        for t in range(count):
            j = history_slot(head, count - 1 - t, memory)
            c = coef[j, w] - acc * rho[j, w]
            acc = wp.float64(0.0)
            last = t + 1 == count
            jn = history_slot(head, count - 2 - t, memory)
            for i in range(n):
                r = d[w, i] + scaled(hist_s[j, w, i], c)
                d[w, i] = r
                if last:
                    xi = as_vec3d(x0[w, i])
                    ri = as_vec3d(r)
                    sx = sx + xi
                    sr = sr + ri
                    sxr = sxr + wp.cross(xi, ri)
                    sxx = sxx + wp.outer(xi, xi)
                else:
                    acc += dot64(hist_y[jn, w, i], r)
        # rigid part: translation m (the mean), rotation omega about the centroid c: I omega = L
        nv = wp.float64(n)
        cen = sx / nv
        m = sr / nv
        L = sxr - wp.cross(cen, m) * nv
        eye = wp.identity(n=3, dtype=wp.float64)
        inertia = eye * (wp.trace(sxx) - nv * wp.dot(cen, cen)) - (sxx - wp.outer(cen, cen) * nv)
        omega = wp.inverse(inertia) * L
        if rigid_free == 0:  # a force holds the membrane in space: its rigid motions are part of the settle
            m = wp.vec3d(0.0, 0.0, 0.0)
            omega = wp.vec3d(0.0, 0.0, 0.0)
        gd = wp.float64(0.0)
        dmax = wp.float64(0.0)
        for i in range(n):
            rigid = m + wp.cross(omega, as_vec3d(x0[w, i]) - cen)
            di = d[w, i]
            di = -(di - type(di)(type(di[0])(rigid[0]), type(di[0])(rigid[1]), type(di[0])(rigid[2])))
            d[w, i] = di
            gd += dot64(g0[w, i], di)
            dmax = wp.max(dmax, dot64(di, di))
        scalars[w, S_GD0] = gd
        scalars[w, S_DMAX] = wp.sqrt(dmax)
        if gd < wp.float64(0.0) or count == 0:
            return
        flags[w, F_COUNT] = 0  # not a descent direction: forget the history and take the preconditioned gradient


@wp.func
def write_trial(
    w: int,
    n: int,
    alpha: wp.float64,
    x0: wp.array2d(dtype=Any),  # (W, V) accepted positions, m
    d: wp.array2d(dtype=Any),  # (W, V) direction
    xv: wp.array3d(dtype=Any),  # (2, W, V) out: row 0 the trial positions
    fg: wp.array3d(dtype=Any),  # (2, W, V) out: zeroed for the next evaluation
    volume: wp.array2d(dtype=wp.float64),  # (W, 1) out: zeroed
    scalars: wp.array2d(dtype=wp.float64),  # (W, N_SCALARS)
):
    """Trial point x0 + alpha d of world w, its force accumulators cleared."""
    scalars[w, S_ALPHA] = alpha
    for i in range(n):
        xv[0, w, i] = x0[w, i] + scaled(d[w, i], alpha)
        f = fg[0, w, i]
        z = f * type(f[0])(0.0)
        fg[0, w, i] = z
        fg[1, w, i] = z
    volume[w, 0] = wp.float64(0.0)


@wp.func
def first_alpha(w: int, max_move: wp.float64, scalars: wp.array2d(dtype=wp.float64)):
    """Unit step (the quasi-Newton step), shortened so that no vertex moves more than max_move."""
    dmax = scalars[w, S_DMAX]
    alpha = wp.float64(1.0)
    if dmax * alpha > max_move:
        alpha = max_move / dmax
    return alpha


@wp.kernel(enable_backward=False)
def lbfgs_iterate_kernel(
    # Model:
    n_vertices: int,
    memory: int,  # history pairs kept
    force_tol: wp.float64,  # N: converged when every vertex force is below this
    max_move: wp.float64,  # m: most a vertex moves in one step
    min_move: wp.float64,  # m: a step shorter than this (largest vertex move) stalls the world
    x_bound: wp.float64,  # m: a trial vertex beyond |x| = x_bound is rejected (runaway)
    sufficient: wp.float64,  # c1 of the sufficient-decrease test
    patience: int,  # accepted steps without the residual halving after which a world stops at its floor
    rigid_free: int,  # 1: no force holds the membrane in space (rigid motions removed from each step); 0: one does
    precond: wp.array2d(dtype=Any),  # (W, V) inverse diagonal stiffness, m/N
    # State in:
    volume: wp.array2d(dtype=wp.float64),  # (W, 1) chamber volume at the trial point, m^3 (zeroed here)
    # Out (read and updated):
    fg: wp.array3d(dtype=Any),  # (2, W, V) total force at the trial point (row 0), N; zeroed for the next one
    xv: wp.array3d(dtype=Any),  # (2, W, V) trial point: row 0 written here, row 1 zero velocities
    x0: wp.array2d(dtype=Any),  # (W, V) accepted positions, m
    g0: wp.array2d(dtype=Any),  # (W, V) gradient (minus the force) at x0, N
    d: wp.array2d(dtype=Any),  # (W, V) search direction
    hist_s: wp.array3d(dtype=Any),  # (memory, W, V) position changes of the accepted steps, m
    hist_y: wp.array3d(dtype=Any),  # (memory, W, V) gradient changes, N
    rho: wp.array2d(dtype=wp.float64),  # (memory, W) 1 / (s . y)
    coef: wp.array2d(dtype=wp.float64),  # (memory, W) two-loop scratch
    flags: wp.array2d(dtype=wp.int32),  # (W, N_FLAGS)
    scalars: wp.array2d(dtype=wp.float64),  # (W, N_SCALARS)
):
    """One L-BFGS iteration of every active world from the forces at its trial point (module docstring).

    The trial x0 + alpha d is accepted when it is finite, within the bound, has a chamber and its
    directional derivative g1 . d is at most (1 - 2 c1) |g0 . d|: the trapezoid estimate of the energy
    change, alpha (g0 . d + g1 . d) / 2, is then at most c1 alpha g0 . d (exact for a quadratic). A
    rejected trial is replaced by the secant step to the zero of the directional derivative (within
    [0.1, 0.5] alpha), or alpha / 4 where the trial was not valid."""
    w = wp.tid()
    if flags[w, F_ACTIVE] == 0:
        return
    n = n_vertices
    flags[w, F_EVALS] = flags[w, F_EVALS] + 1
    phase = flags[w, F_PHASE]
    gd1 = wp.float64(0.0)
    f2max = wp.float64(0.0)
    sy = wp.float64(0.0)
    ss = wp.float64(0.0)
    yy = wp.float64(0.0)
    ydy = wp.float64(0.0)
    x2max = wp.float64(0.0)
    for i in range(n):
        f = fg[0, w, i]
        gd1 -= dot64(f, d[w, i])
        f2max = wp.max(f2max, dot64(f, f))
        xt = xv[0, w, i]
        x2max = wp.max(x2max, dot64(xt, xt))
        if phase == 1:
            s = xt - x0[w, i]
            y = -f - g0[w, i]
            sy += dot64(s, y)
            ss += dot64(s, s)
            yy += dot64(y, y)
            ydy += dot64(y, y) * wp.float64(precond[w, i])
    vol = volume[w, 0]
    ok = wp.isfinite(gd1 + f2max + sy + ydy + vol) and vol > wp.float64(0.0) and x2max <= x_bound * x_bound
    fmax = wp.sqrt(f2max)
    if phase == 0:
        if not ok:
            flags[w, F_STATUS] = STATUS_INVALID
            flags[w, F_ACTIVE] = 0
            return
        for i in range(n):
            g0[w, i] = -fg[0, w, i]
        scalars[w, S_FMAX] = fmax
        scalars[w, S_BEST] = fmax
        if fmax < force_tol:
            flags[w, F_STATUS] = STATUS_CONVERGED
            flags[w, F_ACTIVE] = 0
            return
        flags[w, F_PHASE] = 1
        lbfgs_direction(w, n, rigid_free, memory, x0, g0, precond, hist_s, hist_y, rho, coef, d, flags, scalars)
        write_trial(w, n, first_alpha(w, max_move, scalars), x0, d, xv, fg, volume, scalars)
        return
    alpha = scalars[w, S_ALPHA]
    gd0 = scalars[w, S_GD0]
    if ok and gd1 <= (wp.float64(1.0) - wp.float64(2.0) * sufficient) * (-gd0):
        # accepted: the pair (s, y) enters the history when its curvature is positive
        keep = sy > wp.float64(1.0e-8) * wp.sqrt(ss * yy)
        head = flags[w, F_HEAD]
        for i in range(n):
            xt = xv[0, w, i]
            gt = -fg[0, w, i]
            if keep:
                hist_s[head, w, i] = xt - x0[w, i]
                hist_y[head, w, i] = gt - g0[w, i]
            x0[w, i] = xt
            g0[w, i] = gt
        scalars[w, S_DE] = scalars[w, S_DE] + wp.float64(0.5) * alpha * (gd0 + gd1)
        if keep:
            rho[head, w] = wp.float64(1.0) / sy
            flags[w, F_HEAD] = (head + 1) % memory
            flags[w, F_COUNT] = wp.min(flags[w, F_COUNT] + 1, memory)
            scalars[w, S_GAMMA] = sy / wp.max(ydy, wp.float64(1.0e-300))
        flags[w, F_REJECTS] = 0
        scalars[w, S_FMAX] = fmax
        if fmax < force_tol:
            flags[w, F_STATUS] = STATUS_CONVERGED
            flags[w, F_ACTIVE] = 0
            return
        flags[w, F_SINCE] = flags[w, F_SINCE] + 1
        if fmax < wp.float64(0.5) * scalars[w, S_BEST]:
            scalars[w, S_BEST] = fmax
            flags[w, F_SINCE] = 0
        if flags[w, F_SINCE] > patience:
            flags[w, F_STATUS] = STATUS_FLOOR
            flags[w, F_ACTIVE] = 0
            return
        lbfgs_direction(w, n, rigid_free, memory, x0, g0, precond, hist_s, hist_y, rho, coef, d, flags, scalars)
        write_trial(w, n, first_alpha(w, max_move, scalars), x0, d, xv, fg, volume, scalars)
        return
    # rejected: a shorter step along the same direction
    shrink = wp.float64(0.25)
    if ok:
        shrink = gd0 / (gd0 - gd1)  # secant: zero of the directional derivative
        shrink = wp.min(wp.max(shrink, wp.float64(0.1)), wp.float64(0.5))
    alpha = alpha * shrink
    flags[w, F_REJECTS] = flags[w, F_REJECTS] + 1
    if alpha * scalars[w, S_DMAX] < min_move:
        if flags[w, F_COUNT] > 0:  # the quasi-Newton direction failed: restart from the preconditioned gradient
            flags[w, F_COUNT] = 0
            lbfgs_direction(w, n, rigid_free, memory, x0, g0, precond, hist_s, hist_y, rho, coef, d, flags, scalars)
            write_trial(w, n, first_alpha(w, max_move, scalars), x0, d, xv, fg, volume, scalars)
            return
        flags[w, F_STATUS] = STATUS_STALLED
        flags[w, F_ACTIVE] = 0
        return
    write_trial(w, n, alpha, x0, d, xv, fg, volume, scalars)
