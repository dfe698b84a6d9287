"""Where the package's shared files (config/, launch/) are found at run time.

Installed with colcon or ament: <prefix>/share/train_localization; run from the
source tree (editable install, tests): the repository root.
"""
from __future__ import annotations

from pathlib import Path

SOURCE_ROOT = Path(__file__).resolve().parents[2]


def share_dir() -> Path:
    """The package's share directory (falls back to the source tree)."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        try:
            share = Path(get_package_share_directory("train_localization"))
            if (share / "config").is_dir():
                return share
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    return SOURCE_ROOT


def resolve(path: str | Path) -> Path:
    """An existing path as given, else relative to the share directory."""
    path = Path(path)
    if path.exists() or path.is_absolute():
        return path
    return share_dir() / path
