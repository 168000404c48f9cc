"""Every kernel module of warp_shape compiles for CUDA (sm_90 PTX through NVRTC), with no GPU needed.

Warp compiles CUDA kernels with NVRTC, which needs no driver, so a CUDA compile error (a construct
the CPU backend accepts and NVRTC rejects, a type mismatch in one precision only) is caught on any
machine. Generic kernels (``Any`` arguments) compile only for the overloads that exist: the
overloads are created here by driving the simulator through every launch it makes, in float32 and
float64, with ``wp.launch`` replaced by a recorder that creates the overload of each launch (as a
real launch would) and runs nothing, so no CPU kernel is compiled either. Non-generic kernels (the
ray casts) compile as they are. Each module is compiled to PTX and assembled to sm_90 machine code
(CUBIN); both run cold every time (a fresh output folder): about 15 s on a 2-core machine.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
from types import SimpleNamespace

import numpy as np
import pytest
import warp as wp

import warp_shape as ws
from warp_shape.physics.contact import add_hold, add_indenter
import warp_shape.kernels
from warp_shape.gradients import DifferentiableReplay
from warp_shape.physics import FORCE_TERMS
import warp_shape.simulator as simulator
from warp_shape.physics.pressure import pressure_rows_np

KERNEL_MODULES = sorted(f"warp_shape.kernels.{m.name}" for m in pkgutil.iter_modules(warp_shape.kernels.__path__))
PRECISIONS = ("float32", "float64")
ARCH = 90  # Hopper (H100, H200)


class _NoLaunch:
    """Stands in for a recorded launch (``wp.launch(..., record_cmd=True)``): replays nothing."""

    def launch(self, *args, **kwargs):
        return None


class OverloadRecorder:
    """While active, ``wp.launch`` creates the overload a launch would use and launches nothing.

    ``launched[(module, kernel key)]`` is the set of precisions under which it was launched."""

    def __init__(self):
        self.precision = None
        self.launched: dict[tuple[str, str], set] = {}
        self._saved = None

    def launch(self, kernel, dim, inputs=(), outputs=(), *args, record_cmd=False, **kwargs):
        sizes = [dim] if isinstance(dim, int) else list(dim)
        if int(np.prod(sizes)) > 0:  # Warp skips empty launches before choosing an overload
            params = list(inputs) + list(outputs)
            if kernel.is_generic:
                wp.overload(kernel, kernel.infer_argument_types(params))
            self.launched.setdefault((kernel.module.name, kernel.key), set()).add(self.precision)
        return _NoLaunch() if record_cmd else None

    def __enter__(self) -> "OverloadRecorder":
        self._saved = wp.launch
        wp.launch = self.launch
        return self

    def __exit__(self, *exc) -> None:
        wp.launch = self._saved


def _designs() -> list:
    """A design with every force family (IPAMs, cells, bending, an indenter and a held vertex), one without
    bending (k_t = 0) and one with the hyperelastic membrane (its triangles, jammed with a cell)."""
    rest = ws.icosphere(1, 0.04)
    c = rest.face_centroids()
    full = ws.Design(rest, ws.Material(bending_stiffness=2e-4))
    full.add_ipam(int(np.argmax(c[:, 2])), int(np.argmin(c[:, 2])))
    full.add_cell([0, 1, 2])
    x = rest.vertices
    add_indenter(full, "sphere", (0, 0, 1), x[int(np.argmax(x[:, 2]))] + [0.0, 0.0, 0.008])
    add_hold(full, [int(np.argmin(x[:, 2]))], x[[int(np.argmin(x[:, 2]))]], stiffness=1e3)
    plain = ws.Design(rest, ws.Material(bending_stiffness=0.0))
    hyper = full.replace(material=ws.Material(membrane="yeoh", yeoh_c2=1e3))
    return [full, plain, hyper]


def _drive(recorder: OverloadRecorder) -> None:
    """Every launch the simulator makes: both integrators, both bending variants, every force term
    read-out, jamming, edge read-outs, volumes, world copies and the static settle, with two worlds."""
    for precision in PRECISIONS:
        recorder.precision = precision
        for design in _designs():
            for integrator in ("rk4", "semi_implicit"):
                for bending in ("exact", "paper"):
                    sim = ws.Simulator(design, precision=precision, integrator=integrator, bending=bending,
                                       worlds=2, substeps=1, launch_mode="direct")
                    sim.step(1)
                    sim.forces()
                    for term in FORCE_TERMS:
                        sim.forces(term)
                    sim.edge_state()
                    sim.volume()
                    sim.load_worlds(sim.snapshot()[::-1])
                    if bending == "exact" and integrator == "rk4":
                        sim.settle_static()
                    if design.n_cells:
                        sim.jam(0)
                    for fam in sim.model.families:  # what the differentiable replay launches to build them
                        if fam.name != "ipam":
                            fam.build(sim.model, wp.array(design.rest.vertices, dtype=sim.model.vec3), wp.launch)
                        if fam.jams:  # and its jam event in the replay, on one world's fields
                            fields = [fam.jam_fields(sim.model, 1) for _ in range(2)]
                            fam.jam_event(sim.model, *fields, wp.zeros(fam.count(design), dtype=wp.int32),
                                          sim.state.x[0:1], wp.launch)


#: the differentiable replay's kernels are checked in float64, the precision of its checks and of the
#: suite's CPU runs: a float32 overload created here would make the suite's next CPU use of the module
#: rebuild it with both (45 s of compiling with a cold cache); float32 compiles on first use
ADJOINT_MODULE, ADJOINT_PRECISIONS = "warp_shape.kernels.adjoint", ("float64",)


def _drive_adjoint(recorder: OverloadRecorder) -> None:
    """Every launch of the differentiable replay's kernels (``ADJOINT_MODULE``): the build, a step of
    each integrator and bending variant, a jam event; in ``ADJOINT_PRECISIONS``."""
    for precision in ADJOINT_PRECISIONS:
        recorder.precision = precision
        for integrator in ("rk4", "semi_implicit"):
            for bending in ("exact", "paper"):
                sim = ws.SimulationSettings(integrator=integrator, bending=bending)
                recorded = SimpleNamespace(settings=SimpleNamespace(simulation=sim))
                for kernel, dim, inputs in DifferentiableReplay(_designs()[0], recorded,
                                                                precision=precision).kernel_launches():
                    wp.launch(kernel, dim, inputs)


@pytest.fixture(scope="module")
def launched():
    wp.init()
    # nothing is launched, so the state stays zero: the simulator's inside-out check (a zero volume after
    # a step) would stop the drive after its first step
    check, ws.Simulator.check_volume = ws.Simulator.check_volume, lambda self: None
    # and the stable step's pressure terms, read back from their kernel, would be zero: recorded, then
    # taken from the host formula
    device_rows = simulator.pressure_rows

    def pressure_rows(model, x, air, worlds=None):
        device_rows(model, x, air, worlds)
        W = x.shape[0] if worlds is None else worlds
        return pressure_rows_np(x.numpy()[:W].astype(np.float64), model.host.faces, air[:W], model.gas_rt,
                                model.atmospheric_pressure, 1.0 / model.host.mass)

    simulator.pressure_rows = pressure_rows
    # the drive's fixed one-substep steps are no physics (nothing runs): the stable-step check, which
    # counts the indenter's penalty, would refuse them
    fixed_step_check, simulator.check_fixed_step = simulator.check_fixed_step, lambda *args: None
    try:
        with OverloadRecorder() as recorder:
            _drive(recorder)
            _drive_adjoint(recorder)
    finally:
        ws.Simulator.check_volume = check
        simulator.pressure_rows = device_rows
        simulator.check_fixed_step = fixed_step_check
    return recorder.launched


def _kernels(module_name: str) -> dict:
    importlib.import_module(module_name)
    return wp.get_module(module_name).kernels


def test_every_generic_kernel_is_launched_in_both_precisions(launched):
    generic = {(m, key) for m in KERNEL_MODULES for key, k in _kernels(m).items() if k.is_generic}
    assert generic, "the physics kernels are generic over the precision"
    want = {m: ADJOINT_PRECISIONS if m == ADJOINT_MODULE else PRECISIONS for m in KERNEL_MODULES}
    missing = {f"{m}.{key}": sorted(set(want[m]) - launched.get((m, key), set())) for m, key in generic}
    missing = {k: v for k, v in missing.items() if v}
    assert not missing, f"generic kernels not launched by the simulator in these precisions: {missing}"


@pytest.mark.parametrize("module_name", KERNEL_MODULES)
def test_kernel_module_compiles_to_sm90_ptx(module_name, launched, tmp_path):
    kernels = _kernels(module_name)
    if not kernels:
        pytest.skip(f"{module_name} holds functions only (compiled into the modules that use them)")
    paths = wp.compile_aot_module(module_name, arch=ARCH, use_ptx=True, module_dir=tmp_path)
    assert len(paths) == 1 and paths[0].suffix == ".ptx" and paths[0].exists(), paths
    ptx = paths[0].read_text()
    assert re.search(rf"^\.target sm_{ARCH}\b", ptx, re.M), "PTX for the wrong architecture"
    entries = re.findall(r"\.entry\s+(\w+)", ptx)
    for key, kernel in kernels.items():
        want = len(kernel.overloads) if kernel.is_generic else 1
        got = sum(1 for e in entries if e.startswith(f"{key}_") and e.endswith("_cuda_kernel_forward"))
        assert got == want, f"{module_name}.{key}: {got} forward entries in the PTX, expected {want}"


@pytest.mark.parametrize("module_name", KERNEL_MODULES)
def test_kernel_module_assembles_to_sm90_machine_code(module_name, launched, tmp_path):
    """The PTX also assembles to sm_90 machine code (CUBIN), which catches register and
    shared-memory limits and assembler errors that PTX generation alone does not."""
    if not _kernels(module_name):
        pytest.skip(f"{module_name} holds functions only (compiled into the modules that use them)")
    paths = wp.compile_aot_module(module_name, arch=ARCH, use_ptx=False, module_dir=tmp_path)
    assert len(paths) == 1 and paths[0].suffix == ".cubin", paths
    data = paths[0].read_bytes()
    assert data[:4] == b"\x7fELF" and len(data) > 1000, f"{paths[0]} is not a CUDA binary"
