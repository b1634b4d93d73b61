"""Where numba keeps the compiled kernels: a folder named after a hash of the package's sources.

numba's on-disk cache keys a compiled function on its own source file only. A kernel that calls (and
inlines) a kernel of another module therefore kept the old callee's machine code after an update of that
module alone (``git pull`` in an editable install), silently. The cache lives instead in
``$XDG_CACHE_HOME/depthguard/numba/<hash of every .py file of the package>`` (default ``~/.cache``), so
any change of any source recompiles everything once. ``NUMBA_CACHE_DIR`` set by the user wins.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["source_hash", "use_versioned_cache"]


def source_hash(root: Path) -> str:
    """16 hex digits over the relative path and bytes of every ``.py`` file under ``root``."""
    h = hashlib.blake2b(digest_size=8)
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(b"\0")
        h.update(p.read_bytes())
    return h.hexdigest()


def use_versioned_cache(root: Path) -> str | None:
    """Point numba's cache at the folder for this version of the sources (module docstring). Returns the
    folder, or None when the user chose one (``NUMBA_CACHE_DIR``) or no cache folder can be created (then
    numba's default applies)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "depthguard" / "numba"
    folder = base / source_hash(root)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    import sys

    if "numba" in sys.modules:  # imported before us: numba read its configuration already
        sys.modules["numba"].config.CACHE_DIR = str(folder)
    return str(folder)
