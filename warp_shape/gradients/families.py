"""The force families a differentiable replay or an equilibrium gradient composes, on arrays of its own.

``ReplayFamilies`` holds every force family of a host model that has elements besides the membrane's
own (springs, hinges, gas: the replay's fused kernels, ``kernels/adjoint.py``): the IPAM, other actuator
families and passive ones. Each family makes its device arrays through its own ``device_arrays`` (with
gradients on the floating-point ones), derives what follows the rest shape through its own ``build``
and adds its forces through its own ``eval_forces``, on a model whose ``differentiable`` flag asks for
kernels with adjoints: the launches the simulator makes, on the replay's arrays, so the two compose the
same forces and the adjoint is Warp's (or the family's own) for each. A family without an adjoint is
refused by name (``check_adjoints``).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import warp as wp

from ..errors import DesignError

__all__ = ["ReplayFamilies", "replayed_families", "check_adjoints", "family_parameters", "controls_gradient_name"]


def replayed_families(families, count) -> tuple:
    """The families of ``families`` with elements (``count(name)`` > 0), in the model's order."""
    return tuple(f for f in families if count(f.name))


def check_adjoints(families, count) -> tuple:
    """``replayed_families``, each differentiable: a family that is not is refused by name."""
    fams = replayed_families(families, count)
    bad = next((f for f in fams if not f.differentiable), None)
    if bad is not None:
        raise DesignError(f"this design holds {bad.plural} (force family {bad.name!r}), which has no adjoint, so its "
                          f"gradient cannot be taken; give the family kernels with adjoints and set differentiable = "
                          f"True (warp_shape.force_family), or take its {bad.plural} out of the design")
    return fams


def controls_gradient_name(family) -> str:
    """The gradient's name for an actuator family's controls per row (the IPAM's: ``ipam_pressures``)."""
    return getattr(family, "controls_gradient", f"{family.name}_controls")


def family_parameters(families, count) -> dict:
    """{gradient name: unit} of the replayed families' parameters (``<family>_<array>``) and, for an
    actuator family, its controls per history row (``controls_gradient_name``, (rows, n))."""
    out = {}
    for f in replayed_families(families, count):
        out.update({f"{f.name}_{p}": f"{unit}: the {f.plural}' {p}" for p, unit in f.parameters.items()})
        if f.controlled:
            out[controls_gradient_name(f)] = f"{f.control_unit}, (rows, n): each row's {f.control_name} of the {f.plural}"
    return out


class ReplayFamilies:
    """The replayed families of ``host`` (a ``model.HostModel``) on ``device`` in ``precision``, with the
    mesh's faces ``faces`` (F,) vec3i on the device: ``model`` (what their launches read: the host model,
    each family's device arrays, the faces, ``differentiable`` True), their ``base`` parameter values."""

    def __init__(self, host, faces: wp.array, scalar, vec3, np_dtype, device: str, precision: str):
        self.host, self.device, self.np_dtype, self.scalar = host, device, np_dtype, scalar
        self.families = check_adjoints(host.families, host.count)

        def arr(a, dtype=None):
            if dtype is None:
                a, dtype = np.asarray(a).astype(np_dtype), scalar
            grad = wp.types.type_is_float(getattr(dtype, "_wp_scalar_type_", dtype))
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=device, requires_grad=grad)

        self.model = SimpleNamespace(host=host, device=device, precision=precision, scalar=scalar, vec3=vec3,
                                     n_vertices=len(host.rest_vertices), n_faces=len(host.faces), faces=faces,
                                     differentiable=True,
                                     actuators={f.name: f.device_arrays(host.actuators[f.name], arr)
                                                for f in self.families})
        self.base = {f.name: {p: self.model.actuators[f.name][p].numpy().copy() for p in f.parameters}
                     for f in self.families}
        # every floating-point array as the simulator's model holds it (its build derives some within rounding)
        self.made = {(f.name, k): a.numpy().copy() for f in self.families
                     for k, a in self.model.actuators[f.name].items() if a.grad is not None}

    @property
    def parameter_names(self) -> set:
        """The gradient names (``<family>_<array>``) of the replayed families' parameters."""
        return {f"{f.name}_{p}" for f in self.families for p in f.parameters}

    def restore_arrays(self) -> None:
        """Every floating-point array back to its value as made from the host model (the simulator's)."""
        for (name, k), value in self.made.items():
            self.model.actuators[name][k].assign(value)

    @property
    def controlled(self) -> tuple:
        return tuple(f for f in self.families if f.controlled)

    def count(self, family) -> int:
        return self.host.count(family.name)

    def controls(self) -> SimpleNamespace:
        """One world's controls of the controlled families: values (1, n) float64 with gradients, enabled (1, n)."""
        shapes = {f.name: (1, max(self.count(f), 1)) for f in self.controlled}
        return SimpleNamespace(
            values={k: wp.zeros(s, dtype=wp.float64, device=self.device, requires_grad=True) for k, s in shapes.items()},
            enabled={k: wp.ones(s, dtype=wp.int32, device=self.device) for k, s in shapes.items()})

    def build(self, rest: wp.array, launch) -> None:
        """Every family's launches deriving its arrays from its parameters and the rest positions."""
        for fam in self.families:
            fam.build(self.model, rest, launch)

    def forces(self, controls: SimpleNamespace, xv: wp.array, fg: wp.array, launch, state=None) -> None:
        """Every family's forces at the point xv (2, 1, V) into fg[0] (the simulator's launches); ``state``:
        the jam fields in force (``jam_state``), or None (nothing jammed)."""
        for fam in self.families:
            fam.eval_forces(self.model, state, controls, xv[0], xv[1], fg[0], launch)

    @property
    def jamming(self) -> tuple:
        """The replayed families whose elements jam."""
        return tuple(f for f in self.families if f.jams)

    def jam_fields(self) -> dict:
        """{family: {field: array}} one world's jam fields of every family that jams, nothing jammed, the
        floating-point ones with gradients."""
        out = {}
        for fam in self.jamming:
            fields = fam.jam_fields(self.model, 1)
            out[fam.name] = {k: wp.zeros(a.shape, dtype=a.dtype, device=self.device,
                                         requires_grad=wp.types.type_is_float(a.dtype)) for k, a in fields.items()}
        return out

    @staticmethod
    def set_jam(fields: dict, values: dict) -> None:
        """{family: {field: array}} one world's jam fields set from host copies of the same layout (the world
        axis of size 1 kept, as ``State.family_jam`` holds them); nothing jammed where ``values`` has none."""
        for name, arrays in fields.items():
            for k, a in arrays.items():
                given = values.get(name, {}).get(k)
                a.assign(np.zeros(a.shape, dtype=a.numpy().dtype) if given is None
                         else np.asarray(given).astype(a.numpy().dtype).reshape(a.shape))

    @staticmethod
    def jam_state(fields: dict) -> SimpleNamespace:
        """What a family's ``eval_forces`` reads of a state in the replay: one world's jam fields."""
        return SimpleNamespace(worlds=1, family_jam=fields)

    def jam(self, fields_in: dict, fields_out: dict, now: dict, x: wp.array, launch) -> None:
        """Every jamming family's jam event (``ForceFamily.jam_event``): fields_in into fields_out
        ({family: {field: array}}), the elements where now[family] (n,) int32 is 1 jammed at x (1, V)."""
        for fam in self.jamming:
            fam.jam_event(self.model, fields_in[fam.name], fields_out[fam.name], now[fam.name], x, launch)

    def grad_arrays(self) -> list:
        """The family arrays that carry gradients (to zero before an adjoint)."""
        return [a for arrays in self.model.actuators.values() for a in arrays.values() if a.grad is not None]

    def set_parameters(self, given: dict | None = None) -> None:
        """Every family's parameter arrays at their design values, or at ``given``'s ({``<family>_<array>``: value})."""
        given = given or {}
        for fam in self.families:
            for p, base in self.base[fam.name].items():
                arr = self.model.actuators[fam.name][p]
                value = np.asarray(given.get(f"{fam.name}_{p}", base), dtype=arr.numpy().dtype)
                arr.assign(value.reshape(arr.numpy().shape))

    def parameter_gradients(self) -> dict:
        """{``<family>_<array>``: d loss / d array} of every family's parameters (after an adjoint)."""
        out = {}
        for fam in self.families:
            n = self.count(fam)
            for p in fam.parameters:
                g = self.model.actuators[fam.name][p].grad.numpy().astype(np.float64)
                out[f"{fam.name}_{p}"] = float(g[0]) if p in fam.scalar_parameters else g[:n]
        return out
