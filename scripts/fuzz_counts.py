"""Fuzz the public API and the scene / mesh loaders with seeded bad input; count the outcomes.

Every case must end in a warp_shape error (clear) or a valid result (a simulator that steps to
finite positions, a scene, a mesh); anything else (another exception type, NaN, a case running
past its time limit) is counted as "other" and listed. tests/test_fuzz.py runs the same cases
(smaller N) and asserts there are none of those.

    python scripts/fuzz_counts.py [--n 400] [--seed 0] [--timeout 20]
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import tempfile
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

#: odd values tried for every argument
WEIRD = [None, True, False, 0, -1, 1, 2.5, -0.0, 1e-300, 1e-45, 1e-12, 1e12, 1e30, 1e41, 1e300, float("nan"),
         float("inf"), -float("inf"), "x", "1", "", [1, 2], [[1, 2], [3]], (0, float("inf")), {}, object(),
         np.float32(1e-3), np.int64(2**40), 2**70, complex(1, 1), np.array([np.nan]), np.bool_(True)]
SIM_KEYS = ["integrator", "dt", "precision", "bending", "substeps", "launch_mode", "reestimate_every", "worlds"]
MATERIAL_KEYS = ["youngs_modulus", "thickness", "areal_density", "bending_stiffness", "spring_damping",
                 "viscous_damping", "jam_stretch_factor", "jam_bend_factor", "temperature", "atmospheric_pressure"]
IPAM_KEYS = ["stiffness", "area", "free_length", "pressure_limits", "damping"]


class Hang(BaseException):
    """A case ran past its time limit."""


def _alarm(signum, frame):
    raise Hang()


def outcome(fn, timeout: float) -> tuple[str, str]:
    """("clear" | "valid" | "other", detail) of running the case ``fn``."""
    import warp_shape as ws

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            result = fn()
        bad = not_finite(result)
        return ("other", f"non-finite result: {bad}") if bad else ("valid", "")
    except ws.WarpShapeError as exc:
        return "clear", type(exc).__name__
    except Hang:
        return "other", f"hang (over {timeout:g} s)"
    except Exception as exc:  # noqa: BLE001 - counting exactly these
        return "other", f"{type(exc).__name__}: {str(exc)[:120]}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def not_finite(result) -> str:
    """What is not finite in a case's result ('' when everything is)."""
    import warp_shape as ws

    if isinstance(result, ws.Simulator):
        checks = {"positions": result.positions, "velocities": result.velocities, "volume": result.volume(),
                  "pressure": result.pressure()}
    elif isinstance(result, ws.TriMesh):
        checks = {"vertices": result.vertices, "volume": result.volume()}
    else:
        return ""
    return ", ".join(k for k, v in checks.items() if not np.all(np.isfinite(v)))


def _pick(rng, seq):
    return seq[int(rng.integers(len(seq)))]


# ---------------------------------------------------------------------------------------------- API cases
def _design(ws, ipam=True, cell=True, material=None):
    d = ws.Design(ws.icosphere(1, 0.04), material)
    c = d.rest.face_centroids()
    if ipam:
        d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])))
    if cell:
        d.add_cell([1, 2, 3])
    return d


def _stepped(sim, n=1):
    sim.step(n)
    return sim


def api_case(rng):
    """One API call with an odd argument, then a step where the call made a simulator."""
    state = rng.bit_generator.state["state"]["state"]
    fn = _api_case(rng)
    values = [c.cell_contents for c in fn.__closure__ or [] if not hasattr(c.cell_contents, "__path__")]
    fn.desc = f"api case (rng state {state}) {fn.__code__.co_names[:4]} {values!r}"[:300]  # what "other" names
    return fn


def _api_case(rng):
    import warp_shape as ws

    w = _pick(rng, WEIRD)
    kind = int(rng.integers(17))
    if kind >= 12:
        return _more_api_case(ws, rng, kind, w)
    if kind == 0:
        key = _pick(rng, SIM_KEYS)
        return lambda: _stepped(ws.Simulator(_design(ws), **{key: w}))
    if kind == 1:
        key = _pick(rng, MATERIAL_KEYS)
        return lambda: _stepped(ws.Simulator(_design(ws, ipam=False, material=ws.Material(**{key: w}))))
    if kind == 2:
        key = _pick(rng, IPAM_KEYS)
        return lambda: _stepped(ws.Simulator(_ipam_design(ws, **{key: w})))
    if kind == 3:
        return lambda: _design(ws, cell=False).add_cell(w)
    if kind == 4:
        return lambda: _set(ws, "positions", _array_like(rng, w, scale=True))
    if kind == 5:
        return lambda: _set(ws, "velocities", _array_like(rng, w))
    if kind == 6:
        return lambda: _set(ws, "air_moles", w if rng.random() < 0.5 else _scalar_times(w, 0.01))
    if kind == 7:
        return lambda: _set(ws, "ipam_pressures", w if rng.random() < 0.5 else [_scalar_times(w, 1e3)])
    if kind == 8:
        world = _pick(rng, WEIRD) if rng.random() < 0.5 else None
        return lambda: _jam(ws, w, world)
    if kind == 9:  # a huge step count is a long run asked for, not a hang: those are left out
        n = w if not (isinstance(w, (int, np.integer)) and w > 100) else 3
        return lambda: ws.Simulator(_design(ws)).step(n)
    if kind == 10:
        return lambda: _mesh_from_arrays(ws, rng, w)
    face = _pick(rng, WEIRD)
    return lambda: _design(ws, ipam=False).add_ipam(w, face)


def _more_api_case(ws, rng, kind, w):
    """Settings, scenes, read-outs and sequences of calls."""
    from warp_shape.io.scene_read import load_scene
    from warp_shape.io.scene_schema import Scene

    if kind == 12:
        group = _pick(rng, ["simulation", "designer", "bad group", 3, None])
        return lambda: Scene(design=_design(ws), settings={group: {_pick(rng, SIM_KEYS): w}}).simulation_settings
    if kind == 13:
        return lambda: ws.Material.from_dict({_pick(rng, MATERIAL_KEYS): w} if rng.random() < 0.7 else w)
    if kind == 14:
        return lambda: load_scene(w)
    if kind == 15:
        return lambda: ws.Simulator(_design(ws)).forces(w)
    ops = [("air_moles", 3.0), ("jam", 0), ("ipam_pressures", [5e4]), ("step", 2), ("positions", 1.05)]
    seq = [ops[int(rng.integers(len(ops)))] for _ in range(4)]
    return lambda: _sequence(ws, seq, w)


def _sequence(ws, seq, w):
    """Calls in a row on one simulator (each possibly refused), then a step; an odd value in the middle."""
    sim = ws.Simulator(_design(ws))
    for i, (name, value) in enumerate(seq):
        try:
            if name == "step":
                sim.step(value)
            elif name == "jam":
                sim.jam(value)
            elif name == "positions":
                sim.positions = sim.positions * value
            elif name == "air_moles":
                sim.air_moles = sim.air_moles * value if i != 2 else w
            else:
                sim.ipam_pressures = value if i != 2 else w
        except ws.WarpShapeError:
            pass
    return _stepped(sim)


def _ipam_design(ws, **kwargs):
    d = _design(ws, ipam=False)
    c = d.rest.face_centroids()
    d.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])), **kwargs)
    return d


def _scalar_times(w, scale):
    try:
        return float(w) * scale
    except (TypeError, ValueError, OverflowError):
        return w


def _array_like(rng, w, scale=False):
    """Rest-shaped arrays with odd entries, odd scales, or the odd value itself."""
    import warp_shape as ws

    x = ws.icosphere(1, 0.04).vertices.copy() if scale else np.zeros((42, 3))
    r = rng.random()
    if r < 0.3:
        return w
    if r < 0.6:
        factor = _scalar_times(w, 1.0)
        return x * factor if isinstance(factor, float) else w
    i, j = int(rng.integers(42)), int(rng.integers(3))
    try:
        x[i, j] = w
    except (TypeError, ValueError, OverflowError):
        return x.tolist()[:i] + [w]
    return x


def _set(ws, name, value):
    sim = ws.Simulator(_design(ws))
    setattr(sim, name, value)
    return _stepped(sim)


def _jam(ws, cell, world):
    sim = ws.Simulator(_design(ws), worlds=2)
    sim.jam(cell, world=world)
    return _stepped(sim)


def _mesh_from_arrays(ws, rng, w):
    m = ws.icosphere(1, 0.04)
    v, f = m.vertices.copy(), m.faces.astype(np.int64)
    r = rng.random()
    if r < 0.25:
        f[int(rng.integers(len(f))), int(rng.integers(3))] += int(rng.choice([2**32, -1, 42, 2**31]))
        return ws.TriMesh(v, f)
    if r < 0.5:
        return ws.TriMesh(v, f.astype(str) if rng.random() < 0.5 else w)
    if r < 0.75:
        return ws.TriMesh(w, f)
    v[int(rng.integers(len(v)))] *= _scalar_times(w, 1.0) if isinstance(_scalar_times(w, 1.0), float) else 1.0
    return ws.TriMesh(v, f)


# ---------------------------------------------------------------------------------------------- file cases
def base_files(folder: Path) -> dict:
    """A small scene (.usda and .usdc) and mesh files (.ply, .obj, .stl) to mutate."""
    import warp_shape as ws
    from warp_shape.io.scene_schema import Scene
    from warp_shape.io.scene_write import save_scene

    d = _design(ws)
    sc = Scene(design=d, targets=[ws.icosphere(1, 0.03)], settings={"simulation": {"dt": 1e-3},
                                                                    "designer": {"actuators": 2}})
    out = {}
    for ext in ("usda", "usdc"):
        out[ext] = save_scene(sc, folder / f"base.{ext}").read_bytes()
    mesh = ws.icosphere(1, 0.04).to_trimesh()
    for ext, kwargs in (("ply", {"encoding": "ascii"}), ("obj", {}), ("stl", {"file_type": "stl_ascii"})):
        p = folder / f"base.{ext}"
        mesh.export(str(p), **{"file_type": ext, **kwargs})
        out[ext] = p.read_bytes()
    return out


TEXT_SUBS = [b"nan", b"inf", b"-1", b"0", b"1e40", b"-1e-300", b"abc", b"", b"2147483648", b"4294967296",
             b'"four"', b"(", b"]"]


def mutate(rng, data: bytes, binary: bool) -> bytes:
    """One random mutation: a number replaced, a line dropped or doubled, a type renamed, a byte flip,
    a truncation, or a sublayer / setting line added."""
    kind = int(rng.integers(7 if not binary else 3))
    if kind == 0 or binary and kind == 2:
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 8))):
            k = int(rng.integers(len(b)))
            b[k] ^= int(rng.integers(1, 256))
        return bytes(b)
    if kind == 1:
        return data[: int(rng.integers(len(data)))]
    lines = data.split(b"\n")
    i = int(rng.integers(len(lines)))
    if kind == 2:
        del lines[i]
    elif kind == 3:
        lines.insert(i, lines[i])
    elif kind == 4:
        nums = [k for k, ln in enumerate(lines) if any(c in ln for c in b"0123456789")]
        if nums:
            i = _pick(rng, nums)
            toks = lines[i].replace(b",", b" , ").replace(b"(", b" ( ").replace(b")", b" ) ").split(b" ")
            idx = [k for k, t in enumerate(toks) if t[:1].isdigit() or t[:1] == b"-"]
            if idx:
                toks[_pick(rng, idx)] = _pick(rng, TEXT_SUBS)
            lines[i] = b" ".join(toks)
    elif kind == 5:
        for a, b_ in ((b"double", b"string"), (b"int[]", b"float[]"), (b"point3d", b"double2"),
                      (b"int64", b"bool"), (b"Mesh", b"Xform")):
            if a in lines[i]:
                lines[i] = lines[i].replace(a, b_, 1)
                break
    else:
        extra = [b"    custom double warpShape:simulation:dtt = 0.001",
                 b"    custom int64 warpShape:simulation:integrator = 4",
                 b'    custom string warpShape:designer:actuators = "four"',
                 b"    custom double warpShape:simulation:dt",
                 b"    subLayers = [@/etc/hostname@]",
                 b"    custom double warpShape:simulation:dt = 1e-30"]
        lines.insert(i, _pick(rng, extra))
    return b"\n".join(lines)


def file_case(rng, folder: Path, bases: dict, n: int):
    """Load one mutated scene or mesh file; a loaded scene with a design is simulated one step."""
    import warp_shape as ws
    from warp_shape.io.scene_read import load_scene

    ext = _pick(rng, list(bases))
    data = mutate(rng, bases[ext], binary=ext == "usdc")
    path = folder / f"case{n}.{ext}"
    path.write_bytes(data)

    def run():
        if ext in ("usda", "usdc"):
            sc = load_scene(path)
            if sc.design is None:
                return sc
            sim = ws.Simulator(sc.design, **sc.simulation_settings.to_dict())
            return _stepped(sim)
        return ws.TriMesh.load(path)

    return run


# ---------------------------------------------------------------------------------------------- driver
def fuzz(n: int, seed: int = 0, timeout: float = 20.0, folder: Path | None = None, verbose: bool = False) -> dict:
    """Run ``n`` API cases and ``n`` file cases; return {family: Counter} and the "other" details."""
    import logging

    import warp as wp

    wp.config.quiet = True
    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    rng = np.random.default_rng(seed)
    tmp = tempfile.TemporaryDirectory() if folder is None else None
    folder = Path(tmp.name) if tmp else Path(folder)
    counts = {"api": Counter(), "files": Counter()}
    others: list[str] = []
    try:
        bases = base_files(folder)
        for i in range(n):
            for family, make in (("api", lambda: api_case(rng)), ("files", lambda: file_case(rng, folder, bases, i))):
                try:
                    case = make()
                except Exception as exc:  # noqa: BLE001 - a case that cannot even be built is a fuzz bug
                    raise RuntimeError(f"building a {family} case failed: {exc!r}") from exc
                kind, detail = outcome(case, timeout)
                counts[family][kind] += 1
                if kind == "other":
                    others.append(f"{family} case {i}: {detail}")
                    if verbose:
                        print(f"{family} case {i}: {detail} [{getattr(case, 'desc', '')}]", file=sys.stderr)
    finally:
        if tmp:
            tmp.cleanup()
    return {"counts": counts, "others": others}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=400, help="API cases and file cases each")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds before a case counts as a hang")
    args = ap.parse_args(argv)
    res = fuzz(args.n, args.seed, args.timeout, verbose=True)
    total = Counter()
    for family, c in res["counts"].items():
        total.update(c)
        print(f"{family:<6} tried {sum(c.values()):5d}  clear error {c['clear']:5d}  valid {c['valid']:5d}  "
              f"other {c['other']:5d}")
    print(f"{'all':<6} tried {sum(total.values()):5d}  clear error {total['clear']:5d}  valid {total['valid']:5d}  "
          f"other {total['other']:5d}")
    kinds = Counter(o.split(": ", 1)[1].split(":")[0] for o in res["others"])
    for k, v in kinds.most_common():
        print(f"  other: {v:4d} x {k}")
    return 0 if not res["others"] else 1


if __name__ == "__main__":
    sys.exit(main())
