"""Stress recovery for output: corotated element stress of solids, Gauss-point stress of
shells, and nodal von Mises values of both."""

from __future__ import annotations

import numpy as np
import warp as wp

from .kernels import tet_p1, tet_p2, tri_p2
from .model import Model, State


def element_stress(model: Model, state: State) -> tuple[np.ndarray, np.ndarray]:
    """Per-element Cauchy stress (M, 3, 3) in world axes and von Mises stress (M,), in Pa.

    The stress is the corotated linear one, ``R sigma(sym(R^T F) - I) R^T``, with the
    rotations of the state's last step; for quadratic elements, the mean over the Gauss points.
    """
    stress = wp.empty(model.tet_count, dtype=wp.mat33, device=model.device)
    von_mises = wp.empty(model.tet_count, dtype=float, device=model.device)
    if model.tet_order == 2:
        wp.launch(tet_p2.tet_stress, model.tet_count, device=model.device,
                  inputs=[model.tet_indices, model.tet_poses, model.tet_stiffness, state.tet_rotation,
                          state.particle_q],
                  outputs=[stress, von_mises])
    else:
        wp.launch(tet_p1.tet_stress, model.tet_count, device=model.device,
                  inputs=[model.tet_indices, model.tet_poses, model.tet_stiffness, model.tet_rest_volume,
                          state.tet_rotation, state.particle_q],
                  outputs=[stress, von_mises])
    return stress.numpy(), von_mises.numpy()


def von_mises(stress: np.ndarray) -> np.ndarray:
    """Von Mises stress (Pa) of Cauchy stress tensors (..., 3, 3): ``sqrt(3/2 s:s)`` with ``s``
    the deviator (a plane stress in world axes included: the invariant needs no local frame)."""
    stress = np.asarray(stress, dtype=np.float64)
    deviator = stress - np.trace(stress, axis1=-2, axis2=-1)[..., None, None] / 3.0 * np.eye(3)
    return np.sqrt(1.5 * np.einsum("...ij,...ij->...", deviator, deviator))


def vertex_von_mises(model: Model, state: State) -> np.ndarray:
    """Von Mises stress (Pa) per vertex: the mean over its elements weighted by their rest
    volume (solids) or area (shells: each triangle's value the mean over its Gauss points)."""
    if model.tri_count:
        vm = von_mises(shell_gauss_stress(model, state)).mean(axis=1)  # equal Gauss weights
        size, elements = model.tri_rest_area.numpy(), model.mesh.triangles
    else:
        _, vm = element_stress(model, state)
        size, elements = model.tet_rest_volume.numpy(), model.mesh.tets
    total = np.zeros(model.particle_count)
    weight = np.zeros(model.particle_count)
    nodes = elements.shape[1]
    np.add.at(total, elements.ravel(), np.repeat(vm * size, nodes))
    np.add.at(weight, elements.ravel(), np.repeat(size, nodes))
    return total / weight


def shell_gauss_stress(model: Model, state: State) -> np.ndarray:
    """Cauchy stress (T, 3, 3, 3) in Pa at the three Gauss points of every shell triangle, in
    world axes: the corotated plane stress ``R sigma(S - I) R^T`` of ``wcut.kernels.tri_p2``."""
    stress = wp.empty((model.tri_count, 3), dtype=wp.mat33, device=model.device)
    wp.launch(tri_p2.tri_stress, model.tri_count, device=model.device,
              inputs=[model.tri_indices, model.tri_poses, model.tri_lame, state.particle_q], outputs=[stress])
    return stress.numpy().astype(np.float64)
