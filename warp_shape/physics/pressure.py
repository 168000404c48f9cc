"""Chamber pressure: launch wrappers, volume, gauge pressure, gas energy and stable-step terms."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from warp_shape.kernels import pressure as kp

from . import Launch

if TYPE_CHECKING:
    from ..model import Control, Model

__all__ = ["eval_volume", "eval_pressure", "eval_pressure_gradient", "volumes_np", "gauge_pressure_np",
           "gas_energy_np", "pressure_rows_np", "pressure_rows"]


def eval_volume(model: Model, x, volume, launch: Launch):
    """Accumulate each world's enclosed volume (m^3, float64) at x (W, V) into volume (W,)."""
    launch(kp.eval_volume_kernel, (x.shape[0], model.n_faces), [model.faces, x, volume])


def eval_pressure(model: Model, x, volume, control: Control, f, launch: Launch):
    """Add the pressure force p A / 3 n_hat of every face (p gauge, from air and volume) into f."""
    launch(kp.eval_pressure_kernel, (x.shape[0], model.n_faces),
           [model.faces, wp.float64(model.gas_rt), wp.float64(model.atmospheric_pressure), x, volume,
            control.air, f])


def eval_pressure_gradient(model: Model, control: Control, fg, volume2d, slot: int, launch: Launch):
    """Add p dV/dx to the forces of a fused evaluation: fg (2, W, V) holds (forces, dV/dx), the
    volume is column ``slot`` of volume2d (W, slots)."""
    _, W, V = fg.shape
    launch(kp.finish_forces_kernel, (W * V,),
           [wp.float64(model.gas_rt), wp.float64(model.atmospheric_pressure), W, V, volume2d, slot, control.air, fg])


def volumes_np(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Enclosed volume (m^3, float64) of each world's membrane by the divergence theorem; x is (W, V, 3)."""
    xf = x[:, faces]
    return np.einsum("wfi,wfi->w", xf[:, :, 0], np.cross(xf[:, :, 1], xf[:, :, 2])) / 6.0


def gauge_pressure_np(air, volume, gas_rt: float, p_atm: float):
    """Gauge pressure n R T / V - p_atm in Pa: air in mol, volume in m^3, gas_rt = R T in J/mol."""
    return air * gas_rt / volume - p_atm


def gas_energy_np(volume, air, gas_rt: float, p_atm: float):
    """Gas energy p_atm V - n R T ln V in J (up to a constant): its negative gradient is the pressure
    force, so the total energy is conserved by the undamped dynamics with fixed air."""
    return p_atm * volume - air * gas_rt * np.log(volume)


def pressure_rows_np(x: np.ndarray, faces: np.ndarray, air: np.ndarray, gas_rt: float, p_atm: float,
                     inv_m: np.ndarray):
    """Stable-step terms of the chamber at positions x (W, V, 3) with air (W,) mol: the Gershgorin
    rows (W, V) of the pressure's geometric stiffness (|p| perimeter / 6 per face vertex, over its
    mass) and the largest eigenvalue (W,) of the gas compressibility term (p_abs / V) g g^T, g = dV/dx
    (rank one, so exact: p_abs / V |M^-1/2 g|^2)."""
    W, V = x.shape[0], x.shape[1]
    volumes = np.maximum(volumes_np(x, faces), 1e-300)
    # every world at once; the sums run in the order a per-world np.add.at takes (the same values)
    xf = x[:, faces]  # (W, F, 3, 3)
    n2a = np.cross(xf[:, :, 1] - xf[:, :, 0], xf[:, :, 2] - xf[:, :, 0])
    p_abs = air * gas_rt / volumes
    p_gauge = np.abs(p_abs - p_atm)
    perim = sum(np.linalg.norm(xf[:, :, (k + 1) % 3] - xf[:, :, k], axis=2) for k in range(3))
    flat = faces.reshape(-1)
    idx = (np.arange(W)[:, None] * V + flat[None]).reshape(-1)
    rows = np.repeat(p_gauge[:, None] * perim / 6.0, 3, axis=1) * inv_m[flat][None]
    press = np.bincount(idx, weights=rows.reshape(-1), minlength=W * V).reshape(W, V)
    g = np.repeat(n2a / 6.0, 3, axis=1)  # (W, 3F, 3)
    grad_v = np.stack([np.bincount(idx, weights=g[:, :, c].reshape(-1), minlength=W * V).reshape(W, V)
                       for c in range(3)], axis=2)
    gas_eig = p_abs / volumes * np.sum(np.einsum("wij,wij->wi", grad_v, grad_v) * inv_m, axis=1)
    return press, gas_eig


def pressure_rows(model: Model, x, air: np.ndarray, worlds: int | None = None):
    """``pressure_rows_np`` of the first ``worlds`` worlds (default all) of the device positions x
    (W, V), computed in one kernel launch (float64 whatever the precision; the same values to
    rounding): (press (W, V), gas_eig (W,)) as NumPy arrays."""
    W = x.shape[0] if worlds is None else int(worlds)
    V, dev = x.shape[1], x.device
    volume = wp.zeros(W, dtype=wp.float64, device=dev)
    perimeter = wp.zeros((W, V), dtype=wp.float64, device=dev)
    grad = wp.zeros((W, V), dtype=wp.vec3d, device=dev)
    wp.launch(kp.pressure_rows_kernel, dim=(W, model.n_faces), inputs=[model.faces, x],
              outputs=[volume, perimeter, grad], device=dev)
    inv_m = 1.0 / model.host.mass
    volumes = np.maximum(volume.numpy(), 1e-300)
    p_abs = np.asarray(air[:W], dtype=np.float64) * model.gas_rt / volumes
    p_gauge = np.abs(p_abs - model.atmospheric_pressure)
    g = grad.numpy()
    press = p_gauge[:, None] * perimeter.numpy() * inv_m[None]
    gas_eig = p_abs / volumes * np.sum(np.einsum("wij,wij->wi", g, g) * inv_m, axis=1)
    return press, gas_eig
