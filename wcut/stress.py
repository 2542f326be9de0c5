"""Stress recovery for output: corotated element stress and nodal von Mises values."""

from __future__ import annotations

import numpy as np
import warp as wp

from .kernels import tet_p1
from .model import Model, State


def element_stress(model: Model, state: State) -> tuple[np.ndarray, np.ndarray]:
    """Per-element Cauchy stress (M, 3, 3) in world axes and von Mises stress (M,), in Pa.

    The stress is the corotated linear one, ``R sigma(sym(R^T F) - I) R^T``, with the
    rotations of the state's last step.
    """
    stress = wp.empty(model.tet_count, dtype=wp.mat33, device=model.device)
    von_mises = wp.empty(model.tet_count, dtype=float, device=model.device)
    wp.launch(tet_p1.tet_stress, model.tet_count, device=model.device,
              inputs=[model.tet_indices, model.tet_poses, model.tet_stiffness, model.tet_rest_volume,
                      state.tet_rotation, state.particle_q],
              outputs=[stress, von_mises])
    return stress.numpy(), von_mises.numpy()


def vertex_von_mises(model: Model, state: State) -> np.ndarray:
    """Von Mises stress (Pa) per vertex: the volume-weighted mean over its elements."""
    _, vm = element_stress(model, state)
    volume = model.tet_rest_volume.numpy()
    tets = model.mesh.tets
    total = np.zeros(model.particle_count)
    weight = np.zeros(model.particle_count)
    np.add.at(total, tets.ravel(), np.repeat(vm * volume, 4))
    np.add.at(weight, tets.ravel(), np.repeat(volume, 4))
    return total / weight
