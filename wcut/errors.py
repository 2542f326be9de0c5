"""Errors raised by wcut.

Every error a user can cause with bad input (a broken mesh, a wrong scene key, a missing file,
a NaN) is a :class:`WcutError`. The message says what is wrong and where, so the command line
can print it as one line and exit with status 2.
"""


class WcutError(Exception):
    """Base class of every error wcut raises for bad input."""


class MeshError(WcutError):
    """A mesh is invalid: degenerate or non-manifold elements, NaN coordinates, bad indices."""


class SceneError(WcutError):
    """A scene file has an unknown key, a value of the wrong type, or names a missing file."""


class ExportError(WcutError):
    """An output file could not be written or does not validate."""


class SimulationError(WcutError):
    """A simulation diverged (NaN or infinite values) or was configured inconsistently."""


class ModelError(WcutError):
    """Model parameters are out of range or inconsistent (material, constraints, springs)."""


class FractureError(WcutError):
    """Input of fracture (stress recovery, criterion, crack growth) is invalid: shapes, NaN,
    indices or strength."""


class CaptureError(WcutError):
    """A capture directory (video or frames, camera.json, mask.png, model, internal
    structures, params.toml) is missing a file or holds an inconsistent one; the message
    names the file."""


class MeshNotice(UserWarning):
    """Something about an input mesh was repaired on loading (vertices no cell uses dropped);
    a warning, so that a library user can filter it, and one line ``wcut: note: ...`` on the
    command line."""
