"""Where the packaged YAML configuration lives.

Search order: ``$DMF_SIM_CONFIG_DIR``; the source tree (``<repo>/config`` next to the package);
the ament index share directory (colcon install); ``<sys.prefix>/share/dmf_sim/config`` (pip).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE = 'dmf_sim'


def config_dir() -> Path:
    """Return the directory holding the packaged ``*.yaml`` configuration files."""
    env = os.environ.get('DMF_SIM_CONFIG_DIR')
    if env:
        return Path(env)
    candidates = [Path(__file__).resolve().parent.parent / 'config']
    try:  # colcon / ament install
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory(PACKAGE)) / 'config')
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
        pass
    candidates.append(Path(sys.prefix) / 'share' / PACKAGE / 'config')
    for cand in candidates:
        if (cand / 'truck_dmf.yaml').is_file():
            return cand
    raise FileNotFoundError(
        'dmf_sim config directory not found; set DMF_SIM_CONFIG_DIR (looked in '
        + ', '.join(str(c) for c in candidates) + ')')


def config_file(name_or_path: str | os.PathLike) -> Path:
    """Resolve a config name (``truck_dmf`` or ``truck_dmf.yaml``) or an explicit path."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml', '.csv') and path.is_file():
        return path
    name = path.name if path.suffix else path.name + '.yaml'
    found = config_dir() / name
    if not found.is_file():
        raise FileNotFoundError(f'config file not found: {name_or_path}')
    return found
