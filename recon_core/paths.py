"""Confinement of paths that come from outside (service requests, messages) to a configured root.

A ROS service or message may name a file to write or read (``save_map``'s folder, an entity's
``mesh_uri``). Such a name is never trusted: `confined_path` resolves it under a root folder the
node was configured with and refuses, with a `PathConfinementError`, anything that could reach
elsewhere:

* an empty name, or one holding a NUL byte;
* a ``..`` component anywhere (even one that would end up inside the root again);
* an absolute path outside the root;
* a path whose resolution (symbolic links followed, for the part that exists) leaves the root.

Relative names are taken relative to the root; absolute names are accepted only when they lie in
it. The check is made on the resolved path, so a link inside the root pointing out is refused.
(Between this check and the use of the path another process able to write inside the root could
swap a component for a link: the root must not be writable by untrusted users.)
"""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath
from urllib.parse import unquote, urlparse

from recon_core.errors import PathConfinementError


def confined_path(root: str | Path, requested: str | os.PathLike[str]) -> Path:
    """The resolved absolute path `requested` names under `root`; raises PathConfinementError if unsafe.

    `requested` is relative to `root` or absolute inside it. The result need not exist.
    """
    text = os.fspath(requested)
    if not isinstance(text, str):
        raise PathConfinementError(f"path must be text, not {type(text).__name__}")
    if not text.strip():
        raise PathConfinementError("empty path refused: name a file or folder under the data root")
    if "\x00" in text:
        raise PathConfinementError(f"path {text!r} refused: it holds a NUL byte")
    if ".." in PurePosixPath(text).parts:
        raise PathConfinementError(f"path {text!r} refused: '..' components are not allowed")
    base = Path(root).expanduser().resolve()
    candidate = Path(text) if os.path.isabs(text) else base / text
    resolved = candidate.resolve()  # follows every symbolic link of the existing part
    if resolved != base and not resolved.is_relative_to(base):
        how = "resolves (through a symbolic link)" if candidate.absolute() != resolved else "lies"
        raise PathConfinementError(f"path {text!r} refused: it {how} outside the data root {base}")
    return resolved


def confined_uri(root: str | Path | None, uri: str) -> Path:
    """The local file a ``file://`` URI (or a plain path) names, confined to `root` (None: refuse all).

    Other schemes (http, package, ...) are refused: nothing is fetched because a message said so.
    """
    if root is None:
        raise PathConfinementError(f"URI {uri!r} refused: no data root is configured for reading files by URI")
    if "\x00" in uri:
        raise PathConfinementError(f"URI {uri!r} refused: it holds a NUL byte")
    parsed = urlparse(uri)
    if parsed.scheme not in ("", "file") or (parsed.scheme == "file" and parsed.netloc not in ("", "localhost")):
        raise PathConfinementError(f"URI {uri!r} refused: only file:// URIs of this host are read")
    return confined_path(root, unquote(parsed.path) if parsed.scheme else uri)


__all__ = ["PathConfinementError", "confined_path", "confined_uri"]
