"""The one error hierarchy of the project: what went wrong, phrased as what the user must fix.

``SceneReconError`` is the root; its four families say where the fix lies:

* ``InputError``   the data given (a recording, a frame folder, an entity or graph file, a TF tree);
* ``ConfigError``  a configuration file, an option or a class table;
* ``ModelError``   a model the user brought (an ONNX segmentation export, a CAD asset);
* ``StorageError`` reading or writing state on disk (checkpoints, output folders).

The CLI turns any ``SceneReconError`` into a one-line message and a non-zero exit (a traceback only
with ``--debug``). Concrete errors also derive from the built-in exception their callers have always
caught (``ValueError``, ``KeyError``, ``LookupError``, ``RuntimeError``), so narrowing an ``except``
is never required.
"""

from __future__ import annotations


class SceneReconError(Exception):
    """Root of every error this project raises on purpose."""


class InputError(SceneReconError, ValueError):
    """The input data cannot be used as given; the message says what is wrong with it."""


class ConfigError(SceneReconError, ValueError):
    """A configuration file, option or class table is invalid; the message names the key."""


class ModelError(SceneReconError, RuntimeError):
    """A user-supplied model (segmentation network, CAD asset) cannot be loaded or run."""


class StorageError(SceneReconError, OSError):
    """State on disk cannot be read or written (a damaged checkpoint, a path outside the root)."""


class PathConfinementError(StorageError, ValueError):
    """A path a request or message names is empty, malformed or outside the configured data root."""


class CheckpointError(StorageError, ValueError):
    """A saved map or checkpoint is damaged or incomplete (truncated file, bad JSON, mismatched pair)."""


class DatasetError(InputError):
    """A recording or frame folder is unusable or a frame in it is malformed."""


class TransformLookupError(InputError, LookupError):
    """A TF transform is not available at the requested time (gap, extrapolation, unknown frame)."""


class EntityError(InputError):
    """An entity cannot be used (no geometry, non-finite values, bad face indices)."""


class GraphError(InputError):
    """A contact graph is malformed (unknown parent, cycle, duplicate id)."""


class UnknownClassError(ConfigError, KeyError):
    """A class name or id is not in the class table (or has no CAD builder)."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


class SegmentationError(ModelError):
    """A segmentation backend cannot produce labels for a frame (bad model, bad outputs)."""


class CadImportError(ModelError):
    """A CAD asset (URDF + meshes) cannot be imported; the message names the file."""


__all__ = [
    "CadImportError",
    "CheckpointError",
    "ConfigError",
    "DatasetError",
    "EntityError",
    "GraphError",
    "InputError",
    "ModelError",
    "PathConfinementError",
    "SceneReconError",
    "SegmentationError",
    "StorageError",
    "TransformLookupError",
    "UnknownClassError",
]
