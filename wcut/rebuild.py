"""Applying a topological change to a running simulation, in one call.

After a cut (:class:`wcut.Blade`, :class:`wcut.cut.Cutter`) or a crack, the model, both
states of the usual ping-pong, the control and the solver all describe the mesh of before.
:func:`apply_change` carries every one of them over the change, so a user's loop never
rebuilds them by hand.
"""

from __future__ import annotations

from .errors import SimulationError


def apply_change(mesh, change, model, solver, states, control=None):
    """Carry a running simulation over ``change`` (a :class:`~wcut.topology.TopologyChange`
    that led to ``mesh``).

    Args:
        mesh: the mesh after the change (``Blade.mesh()``, ``TetTopology.to_mesh()``).
        model: the :class:`~wcut.model.Model` of before. It must not be used afterwards: on
            the CPU its buffers are reused where they have room (``Model.rebuild(...,
            in_place=True)``).
        solver: its :class:`~wcut.solver.SolverCorotational`; the new one keeps its settings
            and its preconditioner's factor where the change left it valid
            (:meth:`~wcut.solver.SolverCorotational.rebuilt`).
        states: the states of before, the current one first (its positions and velocities
            are interpolated over the change; the others are made anew); every state gets the
            current one's external forces (``particle_f``) on the surviving vertices.
        control: the :class:`~wcut.model.Control` of before, or None; the new one keeps the
            attachment targets (a new ``model.control()`` would put them back at rest).

    Returns:
        ``(model, solver, states, control)``, ``states`` a tuple as long as the one given.
    """
    states = tuple(states)
    if not states:
        raise SimulationError("apply_change: give at least the current state")
    targets = control.attachment_target.numpy() if control is not None else None
    model, current = model.rebuild(mesh, change, states[0], in_place=True)
    others = []
    for _ in states[1:]:
        other = model.state()
        other.particle_f.assign(current.particle_f)
        others.append(other)
    new_control = None
    if control is not None:
        new_control = model.control()
        if len(targets) != model.attachment_count:
            raise SimulationError(f"apply_change: the control has {len(targets)} attachment targets, the model "
                                  f"after the change {model.attachment_count}")
        new_control.attachment_target.assign(targets)
    return model, solver.rebuilt(model, change), (current, *others), new_control


__all__ = ["apply_change"]
