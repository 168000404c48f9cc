"""Stable internal step of a model: frequency and damping-rate bounds composed from the force families.

The highest undamped frequency omega is bounded through M^-1/2 K M^-1/2 (Gershgorin row sums, or a
short Lanczos run for the elastic part), the fastest damping rate gamma through Gershgorin rows;
a solver is stable for h <= stability_constant / (omega + gamma).
"""

from __future__ import annotations

import math

import numpy as np

from .display import DEFAULT_IPAM_DAMPING, DEFAULT_IPAM_STIFFNESS
from .errors import DesignError, SimulationError, StabilityError
from .force_family import ForceFamily
from .material import GAS_CONSTANT, Material
from .model import HostModel, Model
from .physics.bending import bending_rows_np, hinge_gradients_np
from .physics.damping import viscous_rows_np
from .physics.jamming import jammed_factor_np
from .physics.pressure import pressure_rows_np, volumes_np
from .physics.springs import spring_operator_terms, spring_rows_np

__all__ = ["stable_dt_estimate", "elastic_omega2_bound", "lanczos_upper_bound", "lanczos_upper_bounds", "ElasticOperator",
           "BatchedElasticOperator", "substeps_for",
           "jammed_stiffness", "jam_rows", "gershgorin_rows", "check_fixed_step", "worlds_identical", "LANCZOS_SAFETY",
           "LANCZOS_STEPS", "check_stable_dt", "substeps_error", "check_chamber", "check_storable"]

#: Lanczos bound safety factor on omega^2. Over meshes of 162-10242 vertices, jammed or not, the
#: 12-step bound was 0.95-1.04 of a 100-step one and, where a dense eigensolve is affordable (162
#: vertices), 1.21-1.24 of the true largest eigenvalue; 1.2 covers the shortfall with margin.
LANCZOS_SAFETY = 1.2
LANCZOS_STEPS = 12


class ElasticOperator:
    """y = M^-1/2 K M^-1/2 u for the elastic stiffness K of one world at positions x: edge springs
    (axial k d d^T plus the tension's transverse |k (1 - L_0/L)| (I - d d^T)), hinges (Gauss-Newton
    k_t g g^T with g = d(theta)/dx) and IPAM sub-springs (axial plus transverse). K is symmetric
    positive semi-definite, so Lanczos on it bounds its largest eigenvalue. Vectors are (3, V)
    structure-of-arrays, flattened. k_edge and rest_len are (E,), kt (E,) or None without bending;
    jammed (E,) bool the edges' jam flags (for the families that jam)."""

    def __init__(self, model: Model, x: np.ndarray, k_edge: np.ndarray, rest_len: np.ndarray, kt: np.ndarray | None,
                 jammed: np.ndarray | None = None):
        h = model.host
        self.V = model.n_vertices
        self.inv_sqrt = 1.0 / np.sqrt(h.mass)
        hinges = h.hinges
        xT = np.ascontiguousarray(x.T)
        a, b = [hinges[:, 0]], [hinges[:, 1]]
        k_ax, k_tr, d = spring_operator_terms(xT, hinges[:, 0], hinges[:, 1], k_edge, rest_len)
        k_ax, k_tr, dirs = [k_ax], [k_tr], [d]
        for fam in model.families:
            jam = {"jammed": jammed} if fam.jams and jammed is not None else {}
            terms = fam.operator_terms(xT, h.actuators[fam.name], **jam)
            for part, term in zip((a, b, k_ax, k_tr, dirs), terms or ()):
                part.append(term)
        self.a, self.b = np.concatenate(a), np.concatenate(b)
        self.dir = np.concatenate(dirs, axis=1)
        k_ax, self.k_tr = np.concatenate(k_ax), np.concatenate(k_tr)
        self.k_diff = k_ax - self.k_tr
        self.idx2 = np.concatenate([self.a, self.b])
        self.grad = None
        if kt is not None:
            self.hinges = [hinges[:, c] for c in range(4)]
            self.kt = kt
            self.grad = hinge_gradients_np(xT, hinges)  # 4 x (3, E)
            self.idx4 = np.concatenate(self.hinges)

    def scatter(self, idx: np.ndarray, vals: np.ndarray) -> np.ndarray:
        """(3, V) sums of vals (3, n) by vertex index idx (n,)."""
        return np.stack([np.bincount(idx, weights=vals[c], minlength=self.V) for c in range(3)])

    @staticmethod
    def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Column-wise dot products of two (3, n) arrays."""
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]

    def __call__(self, u: np.ndarray) -> np.ndarray:
        u = u.reshape(3, -1) * self.inv_sqrt
        du = u[:, self.b] - u[:, self.a]
        ax = self.dot3(du, self.dir)
        kb = self.dir * (self.k_diff * ax) + du * self.k_tr  # (K u) on b; a takes -kb
        out = self.scatter(self.idx2, np.concatenate([-kb, kb], axis=1))
        if self.grad is not None:
            s = sum(self.dot3(g, u[:, hc]) for g, hc in zip(self.grad, self.hinges)) * self.kt
            out += self.scatter(self.idx4, np.concatenate([g * s for g in self.grad], axis=1))
        return (out * self.inv_sqrt).reshape(-1)


def lanczos_upper_bound(op, n: int, steps: int = 12, seed: int = 0) -> float:
    """Upper estimate of the largest eigenvalue of a symmetric PSD operator: the largest Ritz value of
    ``steps`` plain Lanczos steps plus the last off-diagonal beta (the bound estimator of Zhou and
    Saad, 2006). For the spring networks here it is a few percent above the largest eigenvalue (a
    lower-bound Ritz value plus the residual), where Gershgorin is 2-3x above it."""
    rng = np.random.default_rng(seed)
    q = rng.standard_normal(n)
    q /= math.sqrt(float(np.sum(q * q)))  # plain reductions: no BLAS threads for these short vectors
    q_prev = np.zeros(n)
    alpha, beta = [], []
    b = 0.0
    for _ in range(steps):
        w = op(q)
        a = float(np.sum(q * w))
        w -= a * q + b * q_prev
        alpha.append(a)
        b = math.sqrt(float(np.sum(w * w)))
        beta.append(b)
        if b <= 1e-14 * max(abs(a), 1e-300):
            break
        q_prev, q = q, w / b
    k = len(alpha)
    T = np.diag(alpha) + np.diag(beta[: k - 1], 1) + np.diag(beta[: k - 1], -1)
    return float(np.linalg.eigvalsh(T).max() + beta[k - 1])


def jammed_stiffness(model: Model, edge_jammed: np.ndarray):
    """(k_e (W, E), k_t (W, E) or None without bending) with the jam factors applied."""
    h = model.host
    k_edge = h.edge_stiffness[None, :] * jammed_factor_np(edge_jammed, model.jam_stretch_factor)
    kt = h.bend_stiffness * jammed_factor_np(edge_jammed, model.jam_bend_factor) if model.has_bending else None
    return k_edge, kt


class BatchedElasticOperator:
    """The ``ElasticOperator`` of W worlds applied at once: y (W, n) = M^-1/2 K_w M^-1/2 u (W, n) for
    every world w, with the same arithmetic per world as ``ElasticOperator`` (so the same values, bit
    for bit): one NumPy pass per term over all worlds instead of one per world. ``ops``: the per-world
    operators of one model (same springs, hinges and actuator elements; their stiffness and positions
    may differ)."""

    def __init__(self, ops: list):
        first = ops[0]
        self.W, self.V, self.inv_sqrt = len(ops), first.V, first.inv_sqrt
        self.a, self.b = first.a, first.b
        self.dir = np.stack([op.dir for op in ops])  # (W, 3, n)
        self.k_diff = np.stack([op.k_diff for op in ops])[:, None, :]  # (W, 1, n)
        self.k_tr = np.stack([op.k_tr for op in ops])[:, None, :]
        self.grad = None
        base = (np.arange(self.W) * self.V)[:, None]
        self.idx2 = (base + first.idx2[None]).reshape(-1)
        if first.grad is not None:
            self.hinges = first.hinges
            self.kt = np.stack([op.kt for op in ops])[:, None, :]  # (W, 1, E)
            self.grad = [np.stack([op.grad[c] for op in ops]) for c in range(4)]  # 4 x (W, 3, E)
            self.idx4 = (base + first.idx4[None]).reshape(-1)

    def scatter(self, idx: np.ndarray, vals: np.ndarray) -> np.ndarray:
        """(W, 3, V) sums of vals (W, 3, n) by vertex index; idx (W n,) holds w V + vertex, world-major."""
        n = self.W * self.V
        return np.stack([np.bincount(idx, weights=vals[:, c].reshape(-1), minlength=n).reshape(self.W, self.V)
                         for c in range(3)], axis=1)

    @staticmethod
    def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Dot products over the coordinate axis of two (W, 3, n) arrays: (W, 1, n)."""
        return (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2])[:, None, :]

    def __call__(self, u: np.ndarray) -> np.ndarray:
        u = u.reshape(self.W, 3, -1) * self.inv_sqrt
        du = u[:, :, self.b] - u[:, :, self.a]
        ax = self.dot3(du, self.dir)
        kb = self.dir * (self.k_diff * ax) + du * self.k_tr
        out = self.scatter(self.idx2, np.concatenate([-kb, kb], axis=2))
        if self.grad is not None:
            s = sum(self.dot3(g, u[:, :, hc]) for g, hc in zip(self.grad, self.hinges)) * self.kt
            out += self.scatter(self.idx4, np.concatenate([g * s for g in self.grad], axis=2))
        return (out * self.inv_sqrt).reshape(self.W, -1)


def lanczos_upper_bounds(op, worlds: int, n: int, steps: int = 12, seed: int = 0) -> np.ndarray:
    """(W,) ``lanczos_upper_bound`` of every world of a batched operator ``op`` ((W, n) -> (W, n)),
    all worlds in one pass per step with the same start vector and arithmetic per world as the
    single-world run (the same values, bit for bit). A world whose Krylov space closes early (tiny
    beta) keeps its shorter tridiagonal matrix, as the single-world run does."""
    rng = np.random.default_rng(seed)
    q1 = rng.standard_normal(n)
    q1 /= math.sqrt(float(np.sum(q1 * q1)))
    q = np.tile(q1, (worlds, 1))
    q_prev = np.zeros((worlds, n))
    alpha, beta = np.zeros((worlds, steps)), np.zeros((worlds, steps))
    length = np.full(worlds, steps)
    b = np.zeros(worlds)
    live = np.ones(worlds, dtype=bool)
    for k in range(steps):
        w = op(q)
        a = np.sum(q * w, axis=1)
        w -= a[:, None] * q + b[:, None] * q_prev
        b = np.sqrt(np.sum(w * w, axis=1))
        alpha[live, k], beta[live, k] = a[live], b[live]
        closed = live & (b <= 1e-14 * np.maximum(np.abs(a), 1e-300))
        length[closed] = k + 1
        live &= ~closed
        if not live.any():
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            q_prev, q = q, np.where(live[:, None], w / b[:, None], q)
    out = np.zeros(worlds)
    for k in np.unique(length):
        sel = np.flatnonzero(length == k)
        T = np.zeros((sel.size, k, k))
        i = np.arange(k)
        T[:, i, i] = alpha[sel, :k]
        T[:, i[:-1], i[1:]] = beta[sel, :k - 1]
        T[:, i[1:], i[:-1]] = beta[sel, :k - 1]
        out[sel] = np.linalg.eigvalsh(T).max(axis=1) + beta[sel, k - 1]
    return out


#: worlds per batched Lanczos pass: at 642 vertices 4-16 worlds together took 6.1 ms per world of CPU time
#: against 6.7 ms one by one and 9.0 ms all 64 at once (the larger passes' temporaries leave the caches)
LANCZOS_BATCH = 16


def elastic_omega2_bound(model: Model, edge_jammed: np.ndarray, x: np.ndarray,
                         rest_length: np.ndarray | None = None, steps: int = LANCZOS_STEPS) -> np.ndarray:
    """(W,) bound on the largest eigenvalue of M^-1/2 K M^-1/2 for the elastic stiffness (springs,
    hinges, IPAMs): LANCZOS_SAFETY x a short Lanczos bound. Depends on the jam state and, mildly, on
    positions (directions, tension); the Simulator caches it between jams, position sets and periodic
    re-estimates, and stable_dt_estimate caps it by the Gershgorin bound. The worlds run together
    (``lanczos_upper_bounds``, up to ``LANCZOS_BATCH`` at a time), each with the value a run of its own gives."""
    h = model.host
    W = x.shape[0]
    E = h.hinges.shape[0]
    rest = np.broadcast_to(h.rest_length, (W, E)) if rest_length is None else rest_length
    k_edge, kt = jammed_stiffness(model, edge_jammed)
    out = np.zeros(W)
    for start in range(0, W, LANCZOS_BATCH):
        ws = range(start, min(W, start + LANCZOS_BATCH))
        ops = [ElasticOperator(model, x[w], k_edge[w], rest[w], None if kt is None else kt[w], edge_jammed[w])
               for w in ws]
        out[start:start + len(ops)] = LANCZOS_SAFETY * lanczos_upper_bounds(
            BatchedElasticOperator(ops), len(ops), 3 * model.n_vertices, steps)
    return out


def jam_rows(model: Model, edge_jammed: np.ndarray):
    """The Gershgorin row sums (W, V) that depend on the jam state alone: of M^-1/2 K M^-1/2 for the
    elastic stiffness (edge, hinge and IPAM springs at their jammed stiffness, the hinges' at the rest
    geometry) and of the damping rates (spring and IPAM dampers, viscous). Returns (stiff, damp)."""
    h = model.host
    W = edge_jammed.shape[0]
    inv_m = 1.0 / h.mass
    inv_sqrt = np.sqrt(inv_m)
    a, b = h.hinges[:, 0], h.hinges[:, 1]
    stiff = np.zeros((W, model.n_vertices))
    damp = np.zeros((W, model.n_vertices))
    k_edge, kt = jammed_stiffness(model, edge_jammed)
    spring_rows_np(stiff, a, b, k_edge, inv_m, inv_sqrt)
    spring_rows_np(damp, a, b, np.full((W, a.size), model.spring_damping), inv_m, inv_sqrt)
    damp += viscous_rows_np(model.viscous_damping, inv_m)
    if kt is not None:
        bending_rows_np(stiff, h.hinges, kt, h.rest_vertices, inv_sqrt)
    for fam in model.families:
        jam = {"jammed": np.asarray(edge_jammed, dtype=bool)} if fam.jams else {}
        fam.stiffness_rows(stiff, damp, h.actuators[fam.name], inv_m, inv_sqrt, **jam)
    return stiff, damp


def gershgorin_rows(model: Model, edge_jammed: np.ndarray, air: np.ndarray, x: np.ndarray, rows=None,
                    pressure=None):
    """Gershgorin row sums (W, V) of M^-1/2 K M^-1/2: elastic (edge, hinge and IPAM springs at their
    jammed stiffness), pressure (geometric stiffness), and of the damping rates (spring and IPAM
    dampers, viscous); plus the gas compressibility eigenvalue (W,). Returns (stiff, press, gas, damp).
    ``rows``: ``jam_rows`` of these jam states, ``pressure``: (press, gas) of these positions and air
    (``physics.pressure.pressure_rows``, on the device), where known already."""
    stiff, damp = jam_rows(model, edge_jammed) if rows is None else rows
    if pressure is None:
        pressure = pressure_rows_np(x, model.host.faces, air, model.gas_rt, model.atmospheric_pressure,
                                    1.0 / model.host.mass)
    press, gas_eig = pressure
    return stiff, press, gas_eig, damp


def outside_operator_rows(model: Model, edge_jammed: np.ndarray) -> np.ndarray:
    """(W, V) Gershgorin rows of the families the elastic operator does not hold (no ``operator_terms``:
    contact penalties, holds): the Lanczos bound does not see them, so they are added to it (Weyl)."""
    h = model.host
    inv_m = 1.0 / h.mass
    stiff = np.zeros((edge_jammed.shape[0], model.n_vertices))
    damp = np.zeros_like(stiff)
    for fam in model.families:
        if type(fam).operator_terms is ForceFamily.operator_terms:
            jam = {"jammed": np.asarray(edge_jammed, dtype=bool)} if fam.jams else {}
            fam.stiffness_rows(stiff, damp, h.actuators[fam.name], inv_m, np.sqrt(inv_m), **jam)
    return stiff


def stable_dt_estimate(model: Model, solver_cls, edge_jammed: np.ndarray, air: np.ndarray, x: np.ndarray,
                       rest_length: np.ndarray | None = None, refine: bool = True,
                       elastic_bound: np.ndarray | None = None, rows=None, pressure=None) -> np.ndarray:
    """Conservative stable internal step per world (s).

    The highest undamped frequency omega is bounded by Gershgorin row sums of M^-1/2 K M^-1/2
    (edge, hinge and IPAM springs at their jammed stiffness, pressure's geometric stiffness), plus the
    rank-one gas compressibility term; with ``refine`` the elastic part (springs, hinges, IPAMs) is
    instead bounded by ``elastic_omega2_bound`` (a short Lanczos run with a safety factor; pass
    ``elastic_bound`` (W,) to reuse one; ``rows`` and ``pressure`` as ``gershgorin_rows`` takes them),
    never above its Gershgorin bound, plus the rows of the families outside that operator (contact,
    holds: ``outside_operator_rows``), and the pressure terms
    are added to it (Weyl: lambda_max(A + B) <= lambda_max(A) + lambda_max(B)). The fastest damping
    rate gamma is bounded by Gershgorin. Returns stability_constant / (omega + gamma). edge_jammed: (W, E) bool;
    air: (W,) mol; x: (W, V, 3) positions; rest_length: (W, E) current spring rest lengths.
    """
    stiff, press, gas_eig, damp = gershgorin_rows(model, edge_jammed, air, x, rows, pressure)
    omega2 = (stiff + press).max(axis=1) + gas_eig  # Gershgorin bound
    if refine:
        if elastic_bound is None:
            elastic_bound = elastic_omega2_bound(model, edge_jammed, x, rest_length)
        elastic = np.minimum(elastic_bound + outside_operator_rows(model, edge_jammed).max(axis=1),
                             stiff.max(axis=1))
        omega2 = np.minimum(omega2, elastic + press.max(axis=1) + gas_eig)
    omega = np.sqrt(omega2)
    gamma = damp.max(axis=1)
    return solver_cls.stability_constant / (omega + gamma)


def worlds_identical(*arrays: np.ndarray) -> bool:
    """Whether each array (leading world axis) holds the same values in every world, so that one
    world's stable step is every world's."""
    for a in arrays:
        if a.shape[0] > 1 and not all(np.array_equal(a[0], a[w]) for w in range(1, a.shape[0])):
            return False
    return True


def substeps_for(dt: float, dt_stable: float) -> int:
    """Fewest equal internal steps of an output step ``dt`` (s) within ``dt_stable`` (s)."""
    return max(1, int(math.ceil(dt / dt_stable - 1e-9)))


def check_fixed_step(dt: float, substeps: int, dt_stable: float, integrator: str) -> None:
    """Refuse (``StabilityError`` naming a safe dt) an internal step dt / substeps beyond dt_stable (s)."""
    h = dt / substeps
    if h > dt_stable:
        raise StabilityError(
            f"internal step dt/substeps = {h:.4g} s is beyond the stable step estimate "
            f"{dt_stable:.4g} s of this model ({integrator}, current stiffness and pressure); "
            f"use dt <= {dt_stable * substeps:.4g} s with substeps={substeps}, "
            f"substeps >= {substeps_for(dt, dt_stable)}, or substeps=None to choose automatically")


def check_stable_dt(dt_stable: float, step: int, time: float) -> float:
    """``dt_stable`` (s) when it is a positive finite number; else the state has no stable step (it is
    not finite or degenerate) and ``SimulationError`` says so."""
    if not (math.isfinite(dt_stable) and dt_stable > 0):
        raise SimulationError(
            f"the stable step estimate is {dt_stable} at output step {step} (t = {time:.6g} s): the state is "
            f"not finite or degenerate (collapsed or inside-out membrane, non-finite air); set positions, "
            f"velocities and air to sane values", step=step, quantity="estimate")
    return dt_stable


#: the finest relative resolution (float spacing at the positions / shortest rest edge) a state may have
RESOLUTION_LIMIT = 1e-4


def check_chamber(x: np.ndarray, faces: np.ndarray, dtype=np.float64, edge: float | None = None) -> None:
    """Refuse positions x (W, V, 3) that enclose no positive volume (mirrored, inside out, collapsed):
    the chamber's pressure n R T / V has no meaning there; and positions so far from the origin that
    ``dtype`` resolves them coarser than RESOLUTION_LIMIT x the shortest rest ``edge`` (m)."""
    if edge is not None:
        far = float(np.abs(x).max())
        spacing = float(np.spacing(np.asarray(far, dtype=dtype)))
        if spacing > RESOLUTION_LIMIT * edge:
            raise DesignError(
                f"positions up to {far:.3g} m from the origin: {np.dtype(dtype).name} resolves them only to "
                f"{spacing:.2g} m, too coarse for edges of {edge:.3g} m; keep the membrane near the origin "
                f"or use precision='float64'")
    with np.errstate(over="ignore", invalid="ignore"):
        vol = volumes_np(x, faces)
    if not np.all(vol > 0):
        w = int(np.argmin(vol))
        raise DesignError(
            f"positions enclose a volume of {vol[w]:.3g} m^3 (world {w}): a chamber needs a positive volume; "
            f"these positions are mirrored, inside out or collapsed (keep the rest mesh's orientation)")


def check_storable(h: HostModel, mat, precision: str) -> None:
    """Refuse a design (host model ``h``, material ``mat``) whose model values (stiffness, inverse mass,
    damping) do not fit in ``precision`` (float32 overflows near 3.4e38 and underflows to zero near
    1e-45), naming the Material field."""
    dtype = np.float32 if precision == "float32" else np.float64
    values = {"youngs_modulus x thickness (edge stiffness)": h.edge_stiffness, "areal_density (1 / vertex mass)":
              1.0 / h.mass, "areal_density (vertex mass)": h.mass,
              "bending_stiffness x jam_bend_factor": h.bend_stiffness * mat.jam_bend_factor,
              "spring_damping": mat.spring_damping, "viscous_damping": mat.viscous_damping,
              "youngs_modulus x thickness x jam_stretch_factor": h.edge_stiffness * mat.jam_stretch_factor}
    values = {("Material", what): v for what, v in values.items()}
    for fam in h.families:  # each actuator family's values, named by where they are set
        values.update({(fam.owner, what): v for what, v in fam.storable_values(h.actuators[fam.name]).items()})
    with np.errstate(all="ignore"):
        for (owner, what), v in values.items():
            v = np.asarray(v, dtype=np.float64)
            kept = v.astype(dtype)
            if not np.all(np.isfinite(v)) or not np.all(np.isfinite(kept)) or np.any((kept == 0) & (v != 0)):
                raise DesignError(
                    f"{owner} {what} = {float(np.abs(v).max()):.3g} (SI) does not fit in "
                    f"{precision}; use realistic values or precision='float64'")


def _suspects(design, term: str, air: float, x: np.ndarray) -> list:
    """(how far from normal, description) of the values that can make ``term`` extreme."""
    mat, base, rest = design.material, Material(), design.rest
    size = float(np.ptp(x, axis=0).max() / np.ptp(rest.vertices, axis=0).max())
    air0 = mat.atmospheric_pressure * rest.volume() / (GAS_CONSTANT * mat.temperature)
    out = [(base.areal_density / mat.areal_density, f"areal_density = {mat.areal_density:.3g} kg/m^2 (light "
                                                    f"vertices move fast)")]
    k_ipam = max((ip.stiffness for ip in design.ipams), default=0.0)
    c_ipam = max((ip.damping for ip in design.ipams), default=0.0)
    if term == "damping":
        out += [(mat.spring_damping / base.spring_damping, f"spring_damping = {mat.spring_damping:.3g} N s/m"),
                (mat.viscous_damping / base.viscous_damping, f"viscous_damping = {mat.viscous_damping:.3g} N s/m"),
                (c_ipam / DEFAULT_IPAM_DAMPING, f"an IPAM damping of {c_ipam:.3g} N s/m")]
    elif term == "elastic":
        out += [(k_ipam / DEFAULT_IPAM_STIFFNESS, f"an IPAM stiffness of {k_ipam:.3g} N/m")]
        out += [(mat.stretch_modulus / base.stretch_modulus, f"youngs_modulus x thickness = "
                                                             f"{mat.stretch_modulus:.3g} N/m"),
                (mat.bending_stiffness / base.bending_stiffness * mat.jam_bend_factor / base.jam_bend_factor,
                 f"bending_stiffness = {mat.bending_stiffness:.3g} N m/rad (x{mat.jam_bend_factor:g} jammed)"),
                (mat.jam_stretch_factor / base.jam_stretch_factor, f"jam_stretch_factor = {mat.jam_stretch_factor:g}"),
                (1.0 / max(size, 1e-300), f"positions at {size:.3g} x the rest size (tiny edges)")]
    else:
        out += [(air / air0, f"air_moles = {air:.3g} mol ({air / air0:.3g} x the air at rest)"),
                (1.0 / max(size, 1e-300) ** 3, f"positions at {size:.3g} x the rest size (tiny chamber)")]
    return out


def substeps_error(design, model: Model, edge_jammed: np.ndarray, air: np.ndarray, x: np.ndarray, dt: float,
                   dt_stable: float, max_substeps: int) -> StabilityError:
    """The error for an output step ``dt`` that needs more than ``max_substeps`` internal steps of
    ``dt_stable``, naming the rate that limits the step (elastic, pressure, gas or damping) and the
    material or state value furthest from normal behind it."""
    with np.errstate(all="ignore"):
        stiff, press, gas_eig, damp = gershgorin_rows(model, edge_jammed, air, x)
        rates = np.sqrt((stiff + press).max(axis=1) + gas_eig) + damp.max(axis=1)
        w = int(np.nanargmax(rates)) if np.any(np.isfinite(rates)) else 0
        terms = {"elastic": math.sqrt(stiff[w].max()), "pressure": math.sqrt(press[w].max()),
                 "gas": math.sqrt(max(gas_eig[w], 0.0)), "damping": float(damp[w].max())}
        term = max(terms, key=lambda k: terms[k] if math.isfinite(terms[k]) else math.inf)
        ratio, cause = max(_suspects(design, term, float(air[w]), x[w]), key=lambda t: t[0])
    if not ratio > 10.0:  # every value near normal: the output step itself is what is long
        cause = f"the output step dt = {dt:.4g} s itself (material and state look ordinary); use a shorter dt"
    needed = dt / dt_stable
    return StabilityError(
        f"an output step of {dt:.4g} s needs {needed:.3g} internal steps of the stable step {dt_stable:.3g} s, "
        f"more than max_substeps = {max_substeps}: the {term} rate ({terms[term]:.3g} 1/s) is extreme, "
        f"most likely from {cause}. Use realistic values (SI units), or raise max_substeps "
        f"(SimulationSettings / Simulator keyword) if this is intended")
