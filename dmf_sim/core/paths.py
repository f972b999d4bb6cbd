"""Where the packaged configuration lives, and reading a configuration file (one place).

Search order for the config directory: ``$DMF_SIM_CONFIG_DIR``; the source tree (``<repo>/config``
next to the package); the ament index share directory (colcon install);
``<sys.prefix>/share/dmf_sim/config`` (pip).

A configuration source is a *name* (``truck_dmf``, ``truck_dmf.yaml``: looked up in the config
directory first) or a *path*. Every problem with it is one line naming the file and what is
wrong (:class:`dmf_sim.core.errors.ConfigFileError` / :class:`~dmf_sim.core.errors.ConfigError`):
not found, a directory, unreadable, not text, invalid YAML (with line and column), not a mapping.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import yaml

from dmf_sim.core.errors import ConfigError, ConfigFileError

__all__ = ['PACKAGE', 'CONFIG_SUFFIXES', 'config_dir', 'config_file', 'config_reference',
           'read_text', 'parse_yaml',
           'read_yaml_mapping']

PACKAGE = 'dmf_sim'
CONFIG_SUFFIXES = ('.yaml', '.yml', '.csv')


def config_dir() -> Path:
    """Return the directory holding the packaged ``*.yaml`` configuration files."""
    env = os.environ.get('DMF_SIM_CONFIG_DIR')
    if env:
        return Path(env)
    candidates = [Path(__file__).resolve().parents[2] / 'config']
    try:  # colcon / ament install
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory(PACKAGE)) / 'config')
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
        pass
    candidates.append(Path(sys.prefix) / 'share' / PACKAGE / 'config')
    for cand in candidates:
        if (cand / 'truck_dmf.yaml').is_file():
            return cand
    raise ConfigFileError(
        'dmf_sim config directory not found; set DMF_SIM_CONFIG_DIR (looked in '
        + ', '.join(str(c) for c in candidates) + ')')


def config_file(name_or_path: str | os.PathLike) -> Path:
    """Resolve a config name (``truck_dmf`` or ``truck_dmf.yaml``, in :func:`config_dir`) or a
    path.

    Raises ConfigFileError (one line) if it is missing, a directory, unreadable or a name the
    file system refuses."""
    raw = os.fspath(name_or_path)
    if not str(raw).strip():
        raise ConfigFileError('config file name is empty')
    try:
        return _existing_config(raw)
    except ConfigFileError:
        raise
    except OSError as exc:          # e.g. a name longer than the file system allows
        raise ConfigFileError(f'{raw}: cannot be read ({exc.strerror or exc})') from None


def _existing_config(raw: str) -> Path:
    path = Path(raw)
    if path.parent == Path('.') and not str(raw).startswith('.'):
        name = path.name if path.suffix in CONFIG_SUFFIXES else path.name + '.yaml'
        found = config_dir() / name
        if found.is_file():
            return found
    if path.is_dir():
        raise ConfigFileError(f'{raw}: is a directory, not a configuration file')
    if path.exists():
        if not os.access(path, os.R_OK):
            raise ConfigFileError(f'{raw}: not readable (permission denied)')
        return path
    raise ConfigFileError(f'config file not found: {raw} (a path, or a name in {config_dir()})')


def config_reference(name_or_path: str | os.PathLike) -> str:
    """How a bag names a configuration so that another working directory finds it again: a
    packaged name as given, a file by its absolute path (as given where it does not resolve)."""
    raw = os.fspath(name_or_path)
    try:
        found = config_file(raw)
    except ConfigFileError:
        return raw
    return raw if found.parent == config_dir() else str(found.resolve())


def read_text(path: Path) -> str:
    """The file's text; one-line ConfigFileError if it cannot be read or is not UTF-8 text."""
    try:
        return Path(path).read_text(encoding='utf-8')
    except UnicodeDecodeError:
        raise ConfigFileError(f'{path}: not a text file (not UTF-8)') from None
    except OSError as exc:
        raise ConfigFileError(f'{path}: cannot be read ({exc.strerror or exc})') from None


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader refusing a key given twice in one mapping (PyYAML keeps the last
    one silently; YAML 1.2 says keys are unique). Keys merged in with ``<<`` may be overridden,
    as YAML's merge key allows."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == 'tag:yaml.org,2002:merge':
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:            # an unhashable key: PyYAML's own error follows
                    continue
                if first is not key_node:
                    raise yaml.constructor.ConstructorError(
                        'while constructing a mapping', node.start_mark,
                        f'duplicate key {key!r} (first given on line '
                        f'{first.start_mark.line + 1})', key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def parse_yaml(text: str, where: str) -> Any:
    """``yaml.safe_load`` with errors as one line ``where:line:column: problem``; a key given
    twice in one mapping is such an error (named, at its second occurrence)."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        pos = f':{mark.line + 1}:{mark.column + 1}' if mark is not None else ''
        what = exc.problem or exc.context or 'syntax error'
        raise ConfigError(f'{where}{pos}: invalid YAML: {what}') from None
    except yaml.YAMLError as exc:
        raise ConfigError(f'{where}: invalid YAML: {" ".join(str(exc).split())}') from None


def read_yaml_mapping(source: str | os.PathLike, what: str = 'configuration') -> tuple[Path, dict]:
    """Resolve ``source`` (:func:`config_file`) and read it as a YAML mapping.

    Returns (path, mapping). ``what`` names the expected content in the error message
    (e.g. 'driveline'): ``/etc/passwd: not a driveline YAML mapping (the file holds a str)``."""
    path = config_file(source)
    data = parse_yaml(read_text(path), str(path))
    if not isinstance(data, dict):
        got = 'nothing (empty file)' if data is None else f'a {type(data).__name__}'
        article = 'an' if what[:1].lower() in 'aeiou' else 'a'
        raise ConfigError(f'{path}: not {article} {what} YAML mapping (the file holds {got})')
    return path, data

